"""Where a posted program's minutes go: per operation and per kind of move (issue 32).

    python benchmarks/op1_breakdown.py OUT/PART.nc [more.nc ...] [--json]

The program is timed by the plan's clock (:func:`cadcam.gcode.parse_gcode`, then
:func:`cadcam.timeline.machine_timeline`, the timer ``freecad_peer.py`` uses). Each move belongs to the operation
whose ``(op N: ...)`` comment comes before its line, and is one of:

- ``rapid``: G0;
- ``plunge``: a feed move straight down (less than 0.01 mm across);
- ``entry``: a feed move down and across (a helix or a ramp);
- ``lift``: a feed move up;
- ``cut``: a level feed move;
- ``tool change``: the standing time before a new tool's first move.

Times in seconds.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.model import Motion  # noqa: E402
from cadcam.timeline import machine_timeline  # noqa: E402

KINDS = ("cut", "entry", "plunge", "lift", "rapid", "tool change")
_OP = re.compile(r"^\(op (\d+): (.*?) \[")


def breakdown(text: str) -> dict:
    """``{"ops": [{"op", "name", "tool", kind: seconds ..., "cut_mm", "feeds"}], "total_s"}`` of one program."""
    moves = parse_gcode(text)
    t = machine_timeline(moves)
    starts = [(i + 1, f"op {m.group(1)}: {m.group(2)}") for i, line in enumerate(text.splitlines())
              if (m := _OP.match(line))]
    op_lines = np.array([s for s, _ in starts])
    names = [n for _, n in starts]
    step = np.diff(t.points, axis=0)
    across = np.linalg.norm(step[:, :2], axis=1)
    seconds = t.end[1:] - t.start[1:]
    pause = t.start[1:] - t.end[:-1]
    rapid = moves.motion[1:] == Motion.RAPID
    kind = np.where(rapid, "rapid", np.where(step[:, 2] > 1e-9, "lift", np.where(
        step[:, 2] < -1e-9, np.where(across < 0.01, "plunge", "entry"), "cut")))
    which = np.searchsorted(op_lines, t.line[1:], side="right") - 1
    rows: dict[int, dict] = {}
    for i in range(len(seconds)):
        k = int(which[i])
        row = rows.setdefault(k, {"op": names[k] if k >= 0 else "start", "tool": int(t.tool[i + 1]),
                                  **{x: 0.0 for x in KINDS}, "cut_mm": 0.0, "feeds": defaultdict(float)})
        row[str(kind[i])] += float(seconds[i])
        row["tool change"] += float(pause[i])
        if kind[i] == "cut":
            row["cut_mm"] += float(np.linalg.norm(step[i]))
            row["feeds"][round(float(moves.feed[i + 1]))] += float(seconds[i])
    out = []
    for k in sorted(rows):
        r = rows[k]
        top = sorted(r["feeds"].items(), key=lambda kv: -kv[1])[:4]
        r["feeds"] = {f"F{f}": round(s, 1) for f, s in top}
        out.append({**r, **{x: round(r[x], 1) for x in KINDS}, "cut_mm": round(r["cut_mm"])})
    return {"ops": out, "total_s": round(float(t.end[-1]), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("programs", nargs="+", type=Path)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    for path in a.programs:
        b = breakdown(path.read_text())
        if a.json:
            print(json.dumps({"program": str(path), **b}))
            continue
        print(f"{path}: {b['total_s']:.1f} s ({b['total_s'] / 60:.2f} min)")
        print("| op | tool | " + " | ".join(KINDS) + " | total | cut mm | cutting time by feed |")
        print("|---|---|" + "---|" * (len(KINDS) + 3))
        sums = defaultdict(float)
        for r in b["ops"]:
            total = sum(r[x] for x in KINDS)
            for x in KINDS:
                sums[x] += r[x]
            print(f"| {r['op']} | T{r['tool']} | " + " | ".join(f"{r[x]:.1f}" for x in KINDS)
                  + f" | {total:.1f} | {r['cut_mm']} | {r['feeds']} |")
        print("| all | | " + " | ".join(f"{sums[x]:.1f}" for x in KINDS) + f" | {sum(sums.values()):.1f} | | |")


if __name__ == "__main__":
    main()
