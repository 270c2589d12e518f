"""What a process record says about the cell: throughput, OEE, cycle times, alarms, every part.

:func:`cell_report` reads a record (:mod:`factory.record`, any database URL it accepts) and returns
a JSON-ready dict; :func:`report_text` and :func:`dashboard` show it as text and as a one-page
picture. Computed over the chosen runs (default: all), each run's figures summed.

Definitions (times in simulated seconds [s]):

- **Planned production time** *P*: the run's makespan, from its first event to its last (a run
  that never finished: to the last event it recorded).
- **Downtime** *D*: time lost to faults: for each alarm the time of the attempt it ended (the
  rack camera's look and the missed grasp, the program cut short by an alarm, a timed-out step),
  plus every machine reset after an alarm. A failed inspection loses quality, not time.
- **Operating time** *O* = *P* − *D*.
- **Availability** = *O* / *P*.
- **Performance** = Σ ideal cycle time / *O*, over every part *made* (its program ran to the end,
  then it was inspected: good or rejected); a part's ideal cycle is its operation's
  ``ideal_cycle_s``: the cell's fault-free steady-state cycle on that part (locate, fetch, load,
  machining, the faster way out of the vise). A part scrapped after machine alarms is not made: its time is downtime.
- **Quality** = good parts / parts made.
- **OEE** = availability × performance × quality (= Σ ideal cycle of the good parts / *P* when
  every part has the same ideal cycle).
- **Throughput**: good parts per hour of planned time.
- **Cycle time of a part**: from its start (the rack camera looks for its blank) to its sort into
  the out-tray or the reject bin (its flow time through the cell); the distribution is over the
  parts sorted (made or scrapped).
- **Alarm Pareto**: alarms per kind, most frequent first, with the time each kind lost and the
  cumulative share of all alarms.
"""

from __future__ import annotations

import statistics
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import sqlalchemy as sa

from factory.core.errors import RecordError
from factory.record import (Record, alarm, job_response, job_state, measurement, operation, part_unit, robot_move,
                            run_table, work_order)

#: Part outcomes that came out of the machine and were sorted; of them, the parts made (program run to the end).
SORTED = ("good", "rejected", "scrap")
MADE = ("good", "rejected")
#: Bins of the cycle-time histogram.
HISTOGRAM_BINS = 10


def _ratio(a: float, b: float) -> float | None:
    return round(a / b, 4) if b > 0 else None


def cell_report(record: Record, runs: Sequence[int] | None = None) -> dict[str, Any]:
    """The report of ``runs`` (ids; default every run in the record).

    Returns
    -------
    dict
        ``record`` (its URL, password masked), ``runs`` (one summary per run), ``throughput``,
        ``oee``, ``cycle_time`` (statistics and a histogram), ``alarms`` (the Pareto),
        ``parts`` (one per serial: order, part, outcome, cycle time, alarms, measurements, and its
        ``history`` of state transitions).

    Raises
    ------
    RecordError
        A run id not in the record, or the database cannot be read.
    """
    try:
        with record.engine.connect() as conn:
            return _report(conn, record, runs)
    except sa.exc.SQLAlchemyError as e:
        raise RecordError(f"cannot read the record: {type(e).__name__}", source=record.shown) from None


def _report(conn: sa.Connection, record: Record, wanted: Sequence[int] | None) -> dict[str, Any]:
    """The report (see :func:`cell_report`): the chosen runs read, then each part of it computed."""
    all_runs = [dict(r._mapping) for r in conn.execute(sa.select(run_table).order_by(run_table.c.id))]
    known = {r["id"] for r in all_runs}
    if wanted:
        missing = sorted(set(wanted) - known)
        if missing:
            raise RecordError(f"no run {missing[0]} in the record (runs: {', '.join(map(str, sorted(known))) or 'none'})",
                              source=record.shown)
    ids = sorted(set(wanted) if wanted else known)
    rows = _Rows.read(conn, ids)
    runs_out, planned, downtime = _runs(all_runs, ids, rows)
    units = rows.units
    done = [u for u in units if u["outcome"] in SORTED]
    made = [u for u in done if u["outcome"] in MADE]
    good = sum(1 for u in made if u["outcome"] == "good")
    operating = planned - downtime
    ideal = sum(float(u["ideal_cycle_s"] or 0.0) for u in made)
    availability, performance, quality = _ratio(operating, planned), _ratio(ideal, operating), _ratio(good, len(made))
    oee = round(availability * performance * quality, 4) if None not in (availability, performance, quality) else None
    return {
        "record": record.shown,
        "runs": runs_out,
        "throughput": {"parts_good": good, "parts_made": len(made),
                       "parts_rejected": sum(1 for u in made if u["outcome"] == "rejected"),
                       "parts_scrap": sum(1 for u in done if u["outcome"] == "scrap"),
                       "parts_failed": sum(1 for u in units if u["outcome"] == "failed"),
                       "planned_s": round(planned, 3),
                       "parts_per_hour": round(3600.0 * good / planned, 3) if planned > 0 else 0.0},
        "oee": {"availability": availability, "performance": performance, "quality": quality, "oee": oee,
                "planned_s": round(planned, 3), "downtime_s": round(downtime, 3), "operating_s": round(operating, 3),
                "ideal_s": round(ideal, 3)},
        "cycle_time": _cycle_times(done),
        "alarms": _alarm_pareto(rows.alarms),
        "parts": _parts(rows),
    }


@dataclass(frozen=True)
class _Rows:
    """What the record holds of the chosen runs, as rows (dicts by column name).

    ``last_event``: per run, its last event's time [s]; ``resets``: per run, the machine time its
    resets after alarms took [s]."""

    last_event: dict[int, float]
    units: list[dict[str, Any]]
    alarms: list[dict[str, Any]]
    resets: dict[int, float]
    measurements: list[dict[str, Any]]
    history: list[dict[str, Any]]
    orders: list[dict[str, Any]]

    @classmethod
    def read(cls, conn: sa.Connection, ids: list[int]) -> "_Rows":
        def where(table):
            return table.c.run_id.in_(ids)

        last_event: dict[int, float] = {}
        for table, column in ((job_state, job_state.c.time_s), (robot_move, robot_move.c.end_s),
                              (job_response, job_response.c.end_s)):
            for run_id, t in conn.execute(sa.select(table.c.run_id, sa.func.max(column)).where(where(table))
                                          .group_by(table.c.run_id)):
                last_event[run_id] = max(last_event.get(run_id, 0.0), float(t or 0.0))
        units = [dict(r._mapping) for r in conn.execute(
            sa.select(part_unit, work_order.c.order_ref, work_order.c.part, work_order.c.material,
                      operation.c.ideal_cycle_s)
            .join(work_order, part_unit.c.work_order_id == work_order.c.id)
            .join(operation, sa.and_(operation.c.work_order_id == work_order.c.id, operation.c.sequence == 1),
                  isouter=True)
            .where(where(part_unit)).order_by(part_unit.c.run_id, part_unit.c.job))]
        alarms = [dict(r._mapping) for r in conn.execute(sa.select(alarm).where(where(alarm)).order_by(alarm.c.id))]
        resets = {run_id: float(s or 0.0) for run_id, s in conn.execute(
            sa.select(job_response.c.run_id, sa.func.sum(job_response.c.machine_time_s))
            .where(where(job_response), job_response.c.kind == "reset").group_by(job_response.c.run_id))}
        measurements = [dict(r._mapping) for r in conn.execute(
            sa.select(measurement).where(where(measurement)).order_by(measurement.c.id))]
        history = [dict(r._mapping) for r in conn.execute(
            sa.select(job_state.c.part_unit_id, job_state.c.time_s, job_state.c.state, job_state.c.event,
                      job_state.c.message).where(where(job_state), job_state.c.part_unit_id.is_not(None))
            .order_by(job_state.c.id))]
        orders = [dict(r._mapping) for r in conn.execute(
            sa.select(work_order.c.run_id, work_order.c.outcome).where(where(work_order)))]
        return cls(last_event, units, alarms, resets, measurements, history, orders)


def _runs(all_runs: list[dict[str, Any]], ids: list[int], rows: _Rows) -> tuple[list[dict[str, Any]], float, float]:
    """One summary per chosen run, and their planned time and downtime summed [s]."""
    runs_out = []
    planned = downtime = 0.0
    for r in (r for r in all_runs if r["id"] in ids):
        complete = r["ended_at"] is not None
        span = float(r["makespan_s"]) if complete else rows.last_event.get(r["id"], 0.0)
        lost = sum(a["lost_s"] for a in rows.alarms if a["run_id"] == r["id"]) + rows.resets.get(r["id"], 0.0)
        good = sum(1 for u in rows.units if u["run_id"] == r["id"] and u["outcome"] == "good")
        planned += span
        downtime += lost
        runs_out.append({
            "id": r["id"], "cell": r["cell"], "started_at": str(r["started_at"]),
            "ended_at": str(r["ended_at"]) if complete else None, "complete": complete,
            "factory_version": r["factory_version"], "orders_file": r["orders_file"],
            "faults_seed": r["faults_seed"], "planned_s": round(span, 3), "downtime_s": round(lost, 3),
            "parts_good": good, "parts_per_hour": round(3600.0 * good / span, 3) if span > 0 else 0.0,
            "orders": {k: sum(1 for o in rows.orders if o["run_id"] == r["id"] and o["outcome"] == k)
                       for k in ("done", "rejected", "failed")},
        })
    return runs_out, planned, downtime


def _cycle_times(done: list[dict[str, Any]]) -> dict[str, Any]:
    """Statistics and a histogram of the sorted parts' cycle times [s]."""
    cycles = [float(u["ended_s"]) - float(u["started_s"]) for u in done]
    cycle: dict[str, Any] = {"count": len(cycles)}
    if cycles:
        arr = np.asarray(cycles)
        counts, edges = np.histogram(arr, bins=HISTOGRAM_BINS)
        cycle.update({"min_s": round(float(arr.min()), 3), "median_s": round(float(statistics.median(cycles)), 3),
                      "mean_s": round(float(arr.mean()), 3), "p90_s": round(float(np.percentile(arr, 90)), 3),
                      "max_s": round(float(arr.max()), 3),
                      "histogram": {"edges_s": [round(float(e), 3) for e in edges],
                                    "counts": [int(c) for c in counts]}})
    return cycle


def _alarm_pareto(alarms: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Alarms per kind, most frequent first, with the time each lost [s] and the cumulative share."""
    kinds: dict[str, dict[str, Any]] = {}
    for a in alarms:
        k = kinds.setdefault(a["kind"], {"kind": a["kind"], "count": 0, "lost_s": 0.0, "severity": a["severity"],
                                         "recovered": 0, "failed": 0})
        k["count"] += 1
        k["lost_s"] += float(a["lost_s"])
        k["severity"] = max(k["severity"], a["severity"])
        if a["outcome"] in ("recovered", "failed"):
            k[a["outcome"]] += 1
    pareto, running = [], 0
    for k in sorted(kinds.values(), key=lambda k: (-k["count"], -k["lost_s"], k["kind"])):
        running += k["count"]
        pareto.append({**k, "lost_s": round(k["lost_s"], 3), "cumulative": round(running / len(alarms), 4)})
    return pareto


def _parts(rows: _Rows) -> list[dict[str, Any]]:
    """One entry per serial: order, outcome, cycle time [s], its alarms, measurements and state history."""
    alarms_of: dict[int, list] = {}
    for a in rows.alarms:
        alarms_of.setdefault(a["part_unit_id"], []).append(
            {"kind": a["kind"], "severity": a["severity"], "time_s": a["raised_s"], "recovery": a["recovery"],
             "outcome": a["outcome"]})
    measured: dict[int, list] = {}
    for m in rows.measurements:
        measured.setdefault(m["part_unit_id"], []).append(
            {"characteristic": m["characteristic"], "unit": m["unit"], "nominal": m["nominal"],
             "tolerance": m["tolerance"], "actual": round(float(m["actual"]), 4), "passed": bool(m["passed"])})
    steps: dict[int, list] = {}
    for h in rows.history:
        steps.setdefault(h["part_unit_id"], []).append(
            {"time_s": round(float(h["time_s"]), 3), "state": h["state"], "event": h["event"],
             "message": h["message"]})
    return [{"serial": u["serial"], "run": u["run_id"], "order": u["order_ref"], "part": u["part"],
             "material": u["material"], "outcome": u["outcome"], "started_s": round(float(u["started_s"]), 3),
             "ended_s": None if u["ended_s"] is None else round(float(u["ended_s"]), 3),
             "cycle_s": None if u["ended_s"] is None else round(float(u["ended_s"]) - float(u["started_s"]), 3),
             "alarms": alarms_of.get(u["id"], []), "measurements": measured.get(u["id"], []),
             "history": steps.get(u["id"], [])} for u in rows.units]


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def report_text(report: dict[str, Any], serial: str | None = None) -> str:
    """The report as text; with ``serial``, that part's whole history instead of the parts table.

    Raises RecordError when ``serial`` is not in the report.
    """
    t, o, c = report["throughput"], report["oee"], report["cycle_time"]
    lines = [f"record {report['record']}: {len(report['runs'])} run(s)"]
    for r in report["runs"]:
        lines.append(f"  run {r['id']} {r['cell']} started {r['started_at']}"
                     f"{'' if r['complete'] else ' (incomplete)'}: {r['parts_good']} good in "
                     f"{r['planned_s'] / 3600:.2f} h, {r['parts_per_hour']:.2f} parts/h; orders "
                     + ", ".join(f"{k} {v}" for k, v in r["orders"].items()))
    lines.append(f"throughput: {t['parts_per_hour']:.2f} good parts/h ({t['parts_good']} good, {t['parts_rejected']} "
                 f"rejected, {t['parts_scrap']} scrap, {t['parts_failed']} failed in {t['planned_s'] / 3600:.2f} h)")
    lines.append(f"OEE {_pct(o['oee'])} = availability {_pct(o['availability'])} x performance "
                 f"{_pct(o['performance'])} x quality {_pct(o['quality'])} (downtime {o['downtime_s']:.0f} s of "
                 f"{o['planned_s']:.0f} s planned)")
    if c["count"]:
        lines.append(f"cycle time per part (start to sort, {c['count']} parts): min {c['min_s']:.1f} s, median "
                     f"{c['median_s']:.1f} s, mean {c['mean_s']:.1f} s, p90 {c['p90_s']:.1f} s, max {c['max_s']:.1f} s")
    else:
        lines.append("cycle time per part: no part sorted")
    lines.append("alarms (Pareto):" + (" none" if not report["alarms"] else ""))
    for a in report["alarms"]:
        lines.append(f"  {a['kind']:<16} {a['count']:>4}  {100 * a['cumulative']:5.1f} % cum.  lost {a['lost_s']:8.1f} s"
                     f"  severity {a['severity']}  recovered {a['recovered']}, failed {a['failed']}")
    if serial is not None:
        part = next((p for p in report["parts"] if p["serial"] == serial), None)
        if part is None:
            raise RecordError(f"no part with serial {serial} in the report", source=report["record"])
        lines.append(f"part {part['serial']} (run {part['run']}, order {part['order']}, {part['part']}, "
                     f"{part['material']}): {part['outcome'] or 'in progress'}")
        for h in part["history"]:
            lines.append(f"  {h['time_s']:10.1f} s  {h['event']:<16} -> {h['state']:<10} {h['message'] or ''}".rstrip())
        for m in part["measurements"]:
            lines.append(f"  measured {m['characteristic']}: {m['actual']:.3f} {m['unit']} (nominal {m['nominal']}, "
                         f"tolerance {m['tolerance']}) {'pass' if m['passed'] else 'FAIL'}")
        return "\n".join(lines)
    lines.append(f"parts ({len(report['parts'])}):")
    for p in report["parts"]:
        cycle = "-" if p["cycle_s"] is None else f"{p['cycle_s']:.1f} s"
        alarms = ", ".join(a["kind"] for a in p["alarms"]) or "-"
        lines.append(f"  {p['serial']}  {p['order']:<5} {p['outcome'] or 'running':<9} cycle {cycle:>9}  alarms {alarms}")
    return "\n".join(lines)


#: Colours (RGB) of the dashboard.
_INK, _GRID, _BAR, _BAD, _GOOD, _LINE = (0, 0, 0), (225, 225, 225), (66, 133, 244), (234, 67, 53), (52, 168, 83), \
    (251, 140, 0)


def dashboard(report: dict[str, Any], width: int = 1200, height: int = 900) -> np.ndarray:
    """The report on one page: figures on top, OEE bars, cycle-time histogram, alarm Pareto, parts.

    Returns
    -------
    (height, width, 3) uint8
        RGB picture (encode with :func:`factory.pictures.png_bytes`).
    """
    from PIL import Image, ImageDraw  # only the command that draws pays for the import

    img = Image.new("RGB", (width, height), (255, 255, 255))
    d = ImageDraw.Draw(img)
    t, o, c = report["throughput"], report["oee"], report["cycle_time"]
    d.text((16, 10), f"Process record {report['record']}: {len(report['runs'])} run(s), "
                     f"{t['planned_s'] / 3600:.2f} h planned", fill=_INK)
    tiles = [("good parts / h", f"{t['parts_per_hour']:.2f}"), ("good", str(t["parts_good"])),
             ("rejected", str(t["parts_rejected"])), ("scrap", str(t["parts_scrap"])),
             ("failed", str(t["parts_failed"])),
             ("OEE", _pct(o["oee"])), ("alarms", str(sum(a["count"] for a in report["alarms"])))]
    tile_w = (width - 32) / len(tiles)
    for i, (label, value) in enumerate(tiles):
        x0 = 16 + i * tile_w
        d.rectangle([x0 + 4, 34, x0 + tile_w - 4, 94], fill=(245, 245, 245))
        d.text((x0 + 14, 42), label, fill=(90, 90, 90))
        d.text((x0 + 14, 66), value, fill=_INK)

    # OEE and its factors as horizontal bars
    top = 116
    d.text((16, top), "OEE = availability x performance x quality", fill=_INK)
    for i, key in enumerate(("availability", "performance", "quality", "oee")):
        y = top + 24 + i * 30
        value = o[key] or 0.0
        d.text((16, y + 5), key, fill=_INK)
        d.rectangle([120, y, 120 + 440, y + 22], fill=(245, 245, 245))
        d.rectangle([120, y, 120 + 440 * min(value, 1.0), y + 22], fill=_GOOD if key != "oee" else _BAR)
        d.text((570, y + 5), _pct(o[key]), fill=_INK)

    # cycle-time histogram
    _histogram(d, (620, top, width - 16, top + 150), c)

    # alarm Pareto
    _pareto(d, (16, 300, width / 2 - 8, 560), report["alarms"])

    # runs
    x0, y = width / 2 + 8, 300
    d.text((x0, y), "runs", fill=_INK)
    for r in report["runs"][-10:]:
        y += 18
        d.text((x0, y), f"run {r['id']} {r['cell']}: {r['parts_good']} good, {r['parts_per_hour']:.2f}/h, "
                        f"downtime {r['downtime_s']:.0f} s{'' if r['complete'] else ', INCOMPLETE'}", fill=_INK)

    # parts by serial
    y = 580
    d.text((16, y), "parts by serial (outcome, cycle time, alarms)", fill=_INK)
    rows = report["parts"]
    per_column = (height - y - 30) // 16
    columns = 3
    shown = rows[:per_column * columns]
    for i, p in enumerate(shown):
        col, row = divmod(i, per_column)
        x, yy = 16 + col * (width - 32) / columns, y + 20 + row * 16
        colour = _GOOD if p["outcome"] == "good" else _BAD if p["outcome"] else (120, 120, 120)
        d.rectangle([x, yy + 3, x + 8, yy + 11], fill=colour)
        d.text((x + 14, yy), _part_row(p, lambda t: d.textlength(t) <= (width - 32) / columns - 20), fill=_INK)
    if len(rows) > len(shown):
        d.text((16, height - 20), f"... and {len(rows) - len(shown)} more parts (factory report --json)", fill=_INK)
    return np.asarray(img, dtype=np.uint8).copy()


def _part_row(p: dict[str, Any], fits: Callable[[str], bool] = lambda _: True) -> str:
    """A part's line on the dashboard: serial, order, outcome, cycle time [s], alarms.

    The alarms follow punctuation, not a bare space: the picture's font draws a space so narrow
    that ``107 s stock_not_found`` reads as ``107 sstock_not_found``. Repeated kinds are counted
    (``grasp_missed x3``). When the row does not ``fit`` its column, the last kinds give way to
    ``+N more``: whole words only, so no alarm is shown misspelt by a cut."""
    cycle = "-" if p["cycle_s"] is None else f"{p['cycle_s']:.0f} s"
    head = f"{p['serial']} {p['order']} {p['outcome'] or 'running'} {cycle}"
    counts = Counter(a["kind"] for a in p["alarms"])
    kinds = [k if n == 1 else f"{k} x{n}" for k, n in counts.items()]
    for shown in range(len(kinds), 0, -1):
        rest = len(kinds) - shown
        row = f"{head}; alarms: {', '.join(kinds[:shown])}" + (f" +{rest} more" if rest else "")
        if fits(row):
            return row
    return f"{head}; {len(p['alarms'])} alarms" if kinds else head


def _histogram(d, box: tuple[float, float, float, float], cycle: dict[str, Any]) -> None:
    x0, y0, x1, y1 = box
    d.text((x0, y0), f"cycle time per part [s] ({cycle['count']} parts)", fill=_INK)
    if not cycle["count"]:
        return
    counts, edges = cycle["histogram"]["counts"], cycle["histogram"]["edges_s"]
    top, bottom = y0 + 22, y1 - 18
    w = (x1 - x0) / len(counts)
    peak = max(counts) or 1
    for i, n in enumerate(counts):
        h = (bottom - top) * n / peak
        d.rectangle([x0 + i * w + 1, bottom - h, x0 + (i + 1) * w - 1, bottom], fill=_BAR)
        if n:
            d.text((x0 + i * w + 3, bottom - h - 12), str(n), fill=_INK)
    d.line([x0, bottom, x1, bottom], fill=_INK)
    d.text((x0, bottom + 4), f"{edges[0]:.0f}", fill=_INK)
    d.text((x1 - 40, bottom + 4), f"{edges[-1]:.0f}", fill=_INK)
    # the median where it falls on the time axis, its label centred under it on a row of its own
    # (below the axis' end labels, which it would hide when the median is near an end)
    span = edges[-1] - edges[0]
    xm = x0 + (x1 - x0) * ((cycle["median_s"] - edges[0]) / span if span > 0 else 0.5)
    d.line([xm, top, xm, bottom + 14], fill=_LINE, width=2)
    label = f"median {cycle['median_s']:.0f}"
    half = d.textlength(label) / 2
    d.text((min(max(xm - half, x0), x1 - 2 * half), bottom + 15), label, fill=_LINE)


def _pareto(d, box: tuple[float, float, float, float], pareto: list[dict[str, Any]]) -> None:
    x0, y0, x1, y1 = box
    d.text((x0, y0), "alarm Pareto (count per kind, cumulative share)", fill=_INK)
    if not pareto:
        d.text((x0, y0 + 24), "no alarms", fill=_INK)
        return
    top, bottom = y0 + 22, y1 - 30
    w = (x1 - x0) / len(pareto)
    peak = max(a["count"] for a in pareto)
    d.line([x0, bottom, x1, bottom], fill=_INK)
    points = []
    for i, a in enumerate(pareto):
        h = (bottom - top) * a["count"] / peak
        d.rectangle([x0 + i * w + 6, bottom - h, x0 + (i + 1) * w - 6, bottom], fill=_BAD)
        d.text((x0 + i * w + 8, bottom - h - 12), str(a["count"]), fill=_INK)
        d.text((x0 + i * w + 6, bottom + 4), a["kind"][:18], fill=_INK)
        d.text((x0 + i * w + 6, bottom + 16), f"{a['lost_s']:.0f} s lost", fill=(90, 90, 90))
        points.append((x0 + (i + 0.5) * w, bottom - (bottom - top) * a["cumulative"]))
    d.line([x0, top, x1, top], fill=_GRID)
    if len(points) > 1:
        d.line(points, fill=_LINE, width=2)
    for x, y in points:
        d.ellipse([x - 3, y - 3, x + 3, y + 3], fill=_LINE)
