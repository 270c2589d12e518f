"""What `factory plan` did for each part, from its PART.plan.json files, in at most 100 columns.

    python samples/summarize.py build/*.plan.json           # one table of every part
    python samples/summarize.py --line build/bracket.plan.json   # one line, as `make demo` prints per part
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HEADER = ["part", "ops", "cycle min", "gouge mm", "left max mm", "unreached", "crashes", "robot s", "plan s"]


def row(summary: dict) -> list[str]:
    """The table's cells for one plan: op 1 + op 2 cycle, op 1's verify figures, wall time of the plan."""
    v = summary["verify"]
    cycles = [s["estimated_cycle_s"] / 60 for s in summary["setups"]]
    unreached = len(summary.get("unreached", [])) + sum(len(s.get("unreached", [])) for s in summary["setups"][1:])
    return [
        Path(summary["part"]).stem,
        str(len(cycles)),
        " + ".join(f"{c:.1f}" for c in cycles),
        f"{v['max_gouge']:.4f}",
        f"{v['remaining_max']:.3f}",
        str(unreached),
        str(len(v["rapid_crashes"])),
        f"{summary['robot']['motion_s']:.1f}" if summary.get("robot") else "-",
        f"{sum(summary['seconds'].values()):.0f}",
    ]


def line(summary: dict) -> str:
    """One line for a part as it finishes: its verdict first."""
    cells = dict(zip(HEADER, row(summary)))
    # the finished part's: op 2's verdict carries what op 1 left on the part, and what op 1 left for op 2 is op 2's
    last = summary.get("verify_op2") or summary["verify"]
    left = sum(r.get("why") not in ("left for op 2", "outside the relief's surface") for r in last.get("left", []))
    verdict = ("verify FAILED" if not summary["verify"]["ok"] else
               f"stock left in {left} region{'s' if left > 1 else ''}" if left else "verify OK, finished")
    ops = "1 op" if cells["ops"] == "1" else f"{cells['ops']} ops"
    return (f"{cells['part']}: {verdict}, {ops}, {cells['cycle min']} min, left max {cells['left max mm']} mm, "
            f"robot {cells['robot s']} s, planned in {cells['plan s']} s")


def main(args: list[str]) -> None:
    if args[:1] == ["--line"]:
        for p in args[1:]:
            print(line(json.loads(Path(p).read_text())))
        return
    rows = [HEADER] + [row(json.loads(Path(p).read_text())) for p in sorted(args)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(HEADER))]
    for r in rows:
        print("  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))).rstrip())


if __name__ == "__main__":
    main(sys.argv[1:])
