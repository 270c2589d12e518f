"""A picture of a cell simulation: what the robot, the machine and the cameras did when (a Gantt chart)."""

from __future__ import annotations

import numpy as np
from PIL import Image, ImageDraw

from .cellsim import SimulationResult

#: Rows of the chart: (label, resource, actions shown in it).
ROWS = (
    ("robot", "robot", ("fetch", "missed_grasp", "load", "flip", "unload", "unload_reject")),
    ("machine", "machine", ("cut", "reset")),
    ("rack camera", "camera", ("locate",)),
    ("tray camera", "camera", ("inspect",)),
)
#: Bar colours (RGB) per action.
COLOURS = {
    "fetch": (66, 133, 244), "missed_grasp": (234, 67, 53), "load": (52, 168, 83), "unload": (251, 188, 5),
    "unload_reject": (171, 71, 188), "cut": (120, 144, 156), "reset": (216, 27, 96), "locate": (0, 172, 193),
    "inspect": (0, 137, 123), "flip": (255, 112, 67),
}
#: Bar colours of the cuts of a part in two setups, by operation (a one-setup cut is ``cut``'s grey):
#: each its own, so the legend tells a one-setup cut, op 1 and op 2 apart; dark enough for the white
#: "op N" drawn on them.
OP_COLOURS = {1: (57, 73, 171), 2: (109, 76, 65)}
#: Outcomes drawn with a red frame: faults.
FAULTS = {"grasp_missed", "stock_not_found", "machine_alarm", "inspect_fail", "timeout"}


def activity_chart(result: SimulationResult, width: int = 1400) -> np.ndarray:
    """The simulation as a Gantt chart: one row per resource, a bar per activity, faults framed in
    red, hour ticks along the bottom, the summary figures on top. A part in two setups shows op 1
    and op 2 as two cut bars (shaded by :data:`OP_COLOURS`, labelled "op 1" / "op 2" where they
    are wide enough) with the robot's ``flip`` between them.

    Parameters
    ----------
    result : SimulationResult
    width : int
        Picture width [px] (>= 400).

    Returns
    -------
    (h, w, 3) uint8
        RGB picture.
    """
    width = max(int(width), 400)
    left, right, top, row_h, gap = 110, 20, 46, 34, 10
    height = top + len(ROWS) * (row_h + gap) + 40
    img = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    makespan = max(float(result.summary.get("makespan_s", 0.0)), 1e-9)
    span = width - left - right

    def x(t: float) -> float:
        return left + span * t / makespan

    s = result.summary
    draw.text((10, 8), f"{s.get('parts_good', 0)} good, {s.get('parts_rejected', 0)} rejected in "
                       f"{makespan / 3600:.2f} h: {s.get('parts_per_hour', 0):.2f} parts/h; robot "
                       f"{100 * s.get('robot_utilisation', 0):.1f} %, machine {100 * s.get('machine_utilisation', 0):.1f} %; "
                       f"faults {sum(s.get('faults', {}).values())}", fill=(0, 0, 0))
    for i, (label, resource, actions) in enumerate(ROWS):
        y0 = top + i * (row_h + gap)
        draw.rectangle([left, y0, width - right, y0 + row_h], fill=(245, 245, 245))
        draw.text((10, y0 + row_h / 2 - 6), label, fill=(0, 0, 0))
        for a in result.activities:
            if a.resource != resource or a.action not in actions:
                continue
            x0, x1 = x(a.start), max(x(a.end), x(a.start) + 1)
            colour = OP_COLOURS.get(a.op, COLOURS[a.action]) if a.action == "cut" else COLOURS[a.action]
            draw.rectangle([x0, y0 + 3, x1, y0 + row_h - 3], fill=colour)
            if a.op is not None and x1 - x0 > 30:
                draw.text((x0 + 3, y0 + 3), f"op {a.op}", fill=(255, 255, 255))  # above the middle line
            if a.outcome in FAULTS:
                draw.rectangle([x0 - 1, y0, x1 + 1, y0 + row_h], outline=(220, 0, 0), width=2)
    # hour ticks (or 10-minute ticks for short runs)
    step = 3600.0 if makespan > 3 * 3600 else 600.0
    axis = top + len(ROWS) * (row_h + gap)
    for k in range(int(makespan // step) + 1):
        t = k * step
        draw.line([x(t), top - 4, x(t), axis - gap], fill=(200, 200, 200))
        draw.text((x(t) - 8, axis), f"{t / 3600:.0f} h" if step == 3600.0 else f"{t / 60:.0f} min", fill=(0, 0, 0))
    lx = left
    legend = dict(COLOURS)
    if any(a.op is not None for a in result.activities):
        legend.update({f"op {k}": c for k, c in OP_COLOURS.items()})
    for name, colour in legend.items():
        draw.rectangle([lx, height - 16, lx + 10, height - 6], fill=colour)
        draw.text((lx + 14, height - 18), name, fill=(0, 0, 0))
        lx += 24 + 7 * len(name)
    return np.asarray(img, dtype=np.uint8).copy()
