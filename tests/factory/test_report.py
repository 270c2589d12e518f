"""The dashboard of `factory report` (factory.report.dashboard): what its text says and where it
stands, read from the drawing calls of a report made by hand."""

from __future__ import annotations

import pytest
from PIL import ImageDraw

from factory.report import dashboard


def _report(median: float) -> dict:
    part = {"serial": "R000001-00004", "order": "o2", "outcome": "good", "cycle_s": 1180.2,
            "alarms": [{"kind": "stock_not_found"}, {"kind": "grasp_missed"}]}
    quiet = {"serial": "R000001-00005", "order": "o2", "outcome": "good", "cycle_s": 100.0, "alarms": []}
    return {
        "record": "cell.sqlite",
        "runs": [{"id": 1, "cell": "test", "parts_good": 2, "parts_per_hour": 6.0, "downtime_s": 10.0,
                  "complete": True}],
        "throughput": {"parts_good": 2, "parts_made": 2, "parts_rejected": 0, "parts_scrap": 0, "parts_failed": 0,
                       "planned_s": 1200.0, "parts_per_hour": 6.0},
        "oee": {"availability": 0.9, "performance": 0.8, "quality": 1.0, "oee": 0.72},
        "cycle_time": {"count": 12, "min_s": 100.0, "median_s": median, "mean_s": 500.0, "p90_s": 1000.0,
                       "max_s": 1100.0,
                       "histogram": {"counts": [5, 1, 0, 0, 0, 0, 0, 0, 2, 4],
                                     "edges_s": [100.0 + 100.0 * k for k in range(11)]}},
        "alarms": [{"kind": "stock_not_found", "count": 1, "lost_s": 3.0, "cumulative": 0.5},
                   {"kind": "grasp_missed", "count": 1, "lost_s": 7.0, "cumulative": 1.0}],
        "parts": [part, quiet],
    }


@pytest.fixture
def drawn(monkeypatch):
    """Every text drawn (its top-left corner [px] and string) and every line (its points [px])."""
    texts, lines = [], []
    real_text, real_line = ImageDraw.ImageDraw.text, ImageDraw.ImageDraw.line

    def text(self, xy, s, *args, **kwargs):
        texts.append((tuple(map(float, xy)), s, self.textlength(s)))
        return real_text(self, xy, s, *args, **kwargs)

    def line(self, xy, *args, **kwargs):
        lines.append([tuple(map(float, p)) for p in xy] if len(xy) and not isinstance(xy[0], (int, float))
                     else [tuple(map(float, xy[i:i + 2])) for i in range(0, len(xy), 2)])
        return real_line(self, xy, *args, **kwargs)

    monkeypatch.setattr(ImageDraw.ImageDraw, "text", text)
    monkeypatch.setattr(ImageDraw.ImageDraw, "line", line)
    return texts, lines


def test_a_parts_alarms_are_set_off_from_its_cycle_time(drawn):
    """The picture's font draws a narrow space: the alarms follow punctuation, never `1180 sstock_not_found`."""
    texts, _ = drawn
    dashboard(_report(200.0))
    rows = [s for _, s, _ in texts if s.startswith("R000001-")]
    assert len(rows) == 2 and rows[1] == "R000001-00005 o2 good 100 s"
    assert rows[0] == "R000001-00004 o2 good 1180 s; alarms: stock_not_found, grasp_missed"


def test_a_part_with_many_alarms_keeps_whole_words_within_its_column(drawn):
    """A row never runs into the next column, and no alarm kind is cut mid-word: repeats are counted
    and what does not fit is named as a count."""
    texts, _ = drawn
    report = _report(200.0)
    kinds = ["stock_not_found", "grasp_missed", "machine_alarm", "inspection_failed", "door_fault"]
    report["parts"][0]["alarms"] = [{"kind": k} for k in kinds] + [{"kind": "stock_not_found"}] * 2
    dashboard(report)
    (xy, row, width), = [(xy, s, w) for xy, s, w in texts if s.startswith("R000001-00004")]
    assert xy[0] + width <= 16 + (1200 - 32) / 3, (row, width)
    head, alarms = row.split("; alarms: ")
    assert head == "R000001-00004 o2 good 1180 s"
    shown, _, more = alarms.partition(" +")
    names = [a.split(" x")[0] for a in shown.split(", ")]
    assert names == kinds[:len(names)] and shown.startswith("stock_not_found x3")
    assert more == f"{len(kinds) - len(names)} more" and len(names) < len(kinds)


@pytest.mark.parametrize("median", [150.0, 640.0, 1050.0])
def test_the_median_label_stands_at_the_median(drawn, median):
    """The histogram's axis runs 100..1100 s over x 620..1184 px: the median's line is at its time,
    and its label is centred under that line (kept inside the chart near an end)."""
    texts, lines = drawn
    dashboard(_report(median))
    x0, x1 = 620.0, 1200.0 - 16.0
    xm = x0 + (x1 - x0) * (median - 100.0) / 1000.0
    (xy, _, width), = [(xy, s, w) for xy, s, w in texts if s == f"median {median:.0f}"]
    centre = xy[0] + width / 2
    assert xy[0] >= x0 and xy[0] + width <= x1 + 1
    if x0 + width / 2 <= xm <= x1 - width / 2:
        assert centre == pytest.approx(xm, abs=1.0)
    else:
        assert xy[0] <= xm <= xy[0] + width
    assert any(len(p) == 2 and p[0][0] == pytest.approx(xm) and p[1][0] == pytest.approx(xm) for p in lines)
