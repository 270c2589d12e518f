"""The Gantt chart of a simulation shows each resource busy for the share of time it was busy."""

from pathlib import Path

import numpy as np
import pytest

from robotprog.cellsim import FaultModel, PartProcess, simulate
from robotprog.gantt import COLOURS, OP_COLOURS, ROWS, activity_chart
from robotprog.orders import Order

PROC = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                   reject_s=5.0, regrasp_s=3.0)


@pytest.mark.parametrize("faults", [FaultModel(), FaultModel(0.2, 0.2, 0.2, 0.2, seed=3)])
def test_machine_row_is_cut_for_the_machine_utilisation(faults):
    result = simulate([Order(f"o{i}", Path("a.stl"), 2, "steel", 0) for i in range(4)], {Path("a.stl"): PROC},
                      faults)
    img = activity_chart(result, width=1400)
    assert img.shape[1] == 1400 and img.shape[2] == 3 and img.dtype == np.uint8
    # the middle line of the machine row: share of the plot width drawn in the cut colour
    row = [r[0] for r in ROWS].index("machine")
    y = 46 + row * (34 + 10) + 17
    line = img[y, 110:1400 - 20]
    cut = np.all(line == COLOURS["cut"], axis=1).mean()
    assert cut == pytest.approx(result.summary["machine_utilisation"], abs=0.01)
    # a fault run frames its faults in red somewhere
    red = np.all(img == (220, 0, 0), axis=2).any()
    assert red == (sum(result.summary["faults"].values()) > 0 and any(
        a.outcome in ("grasp_missed", "stock_not_found", "machine_alarm", "inspect_fail", "timeout")
        for a in result.activities))


def test_two_setups_show_op1_flip_op2():
    two = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                      reject_s=5.0, regrasp_s=3.0, flip_s=60.0, op2_machining_s=200.0)
    result = simulate([Order(f"o{i}", Path("a.stl"), 2, "steel", 0) for i in range(3)], {Path("a.stl"): two})
    img = activity_chart(result, width=1400)
    names = [r[0] for r in ROWS]
    span = result.summary["makespan_s"]

    def share(row, colour):
        y = 46 + names.index(row) * (34 + 10) + 17
        return np.all(img[y, 110:1400 - 20] == colour, axis=1).mean()

    def busy(action, op=None):
        return sum(a.end - a.start for a in result.activities if a.action == action and a.op == op) / span

    assert share("machine", OP_COLOURS[1]) == pytest.approx(busy("cut", 1), abs=0.01)
    assert share("machine", OP_COLOURS[2]) == pytest.approx(busy("cut", 2), abs=0.01)
    assert share("robot", COLOURS["flip"]) == pytest.approx(busy("flip"), abs=0.01)
    assert busy("flip") > 0


def test_every_bar_colour_is_its_own_and_named_in_the_legend(monkeypatch):
    """A one-setup cut, op 1 and op 2 (and every other action) each have a colour no other shares;
    the legend shows each colour beside its name."""
    from PIL import ImageDraw

    legend = {**COLOURS, **{f"op {k}": c for k, c in OP_COLOURS.items()}}
    assert len(set(legend.values())) == len(legend)
    drawn = []
    real_text = ImageDraw.ImageDraw.text
    monkeypatch.setattr(ImageDraw.ImageDraw, "text",
                        lambda self, xy, s, *a, **k: (drawn.append((xy, s)), real_text(self, xy, s, *a, **k))[1])
    two = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                      reject_s=5.0, regrasp_s=3.0, flip_s=60.0, op2_machining_s=200.0)
    result = simulate([Order("o1", Path("a.stl"), 2, "steel", 0), Order("o2", Path("b.stl"), 1, "steel", 0)],
                      {Path("a.stl"): two, Path("b.stl"): PROC})
    img = activity_chart(result, width=1400)
    height = img.shape[0]
    for name, colour in legend.items():
        (xy, _), = [(xy, s) for xy, s in drawn if s == name and xy[1] == height - 18]
        swatch = img[height - 11, int(xy[0]) - 9]  # the square left of the name
        assert tuple(swatch) == colour, name
    # the machine row holds all three kinds of cut, each in its own colour
    y = 46 + [r[0] for r in ROWS].index("machine") * (34 + 10) + 17
    line = img[y, 110:1400 - 20]
    for colour in (COLOURS["cut"], OP_COLOURS[1], OP_COLOURS[2]):
        assert np.all(line == colour, axis=1).any(), colour
