"""Print one table of what `factory plan` did for each part, from its PART.plan.json files.

    python samples/summarize.py build/*.plan.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def row(summary: dict) -> list[str]:
    ops = summary["operations"]
    v = summary["verify"]
    s = summary["seconds"]
    return [
        Path(summary["part"]).stem,
        str(summary["triangles"]),
        str(len(ops)),
        f"{sum(o['cut_mm'] for o in ops) / 1000:.2f}",
        f"{sum(o['rapid_mm'] for o in ops) / 1000:.2f}",
        f"{summary['estimated_cycle_s'] / 60:.1f}",
        str(summary["lines"]),
        f"{v['max_gouge']:.4f}",
        f"{v['remaining_max']:.3f}/{v['remaining_mean']:.3f}/{v['remaining_p95']:.3f}",
        str(len(v["rapid_crashes"])),
        f"{summary['robot']['motion_s']:.1f}" if summary.get("robot") else "-",
        " ".join(f"{k}={t:.1f}" for k, t in s.items()),
    ]


def main(paths: list[str]) -> None:
    header = ["part", "triangles", "ops", "cut m", "rapid m", "cycle min", "lines", "gouge mm",
              "left max/mean/p95 mm", "crashes", "robot s", "wall s per stage"]
    rows = [header] + [row(json.loads(Path(p).read_text())) for p in sorted(paths)]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows[1:]:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
