"""Time ``factory verify``'s simulation on planned samples and print what it found.

For each ``DIR/PART.nc`` + ``DIR/PART.setup.json`` given (plan them first with
``factory plan samples/PART.stl -o DIR --no-robot``): parse, simulate with the finishing
flags from the program's op comments, and print CPU and wall seconds, the moves and
rapids checked, the deepest engagement and widest cut per tool, and the faults.

    python benchmarks/verify_safety.py /tmp/plans/bracket /tmp/plans/dome_mould --grid 0.2

Not a test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.sheet import read_setup_sheet  # noqa: E402
from cadcam.verify import VerifyOptions, finishing_moves, simulate  # noqa: E402
from cli.verify import part_triangles  # noqa: E402

SAMPLES = Path(__file__).resolve().parents[1] / "samples"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="plan output folders, one per sample")
    ap.add_argument("--grid", type=float, default=0.2, help="simulation grid [mm]")
    ap.add_argument("--reps", type=int, default=1)
    args = ap.parse_args()
    for d in args.dirs:
        nc = next(d.glob("*.nc"))
        name = nc.stem
        sheet = json.loads((d / f"{name}.setup.json").read_text())
        read = read_setup_sheet(sheet)
        setup, tools = read.setup, read.tools
        tri = part_triangles(SAMPLES / f"{name}.stl", setup)
        text = nc.read_text()
        t0 = time.perf_counter()
        moves = parse_gcode(text)
        parse_s = time.perf_counter() - t0
        best_cpu = best_wall = float("inf")
        for _ in range(args.reps):
            c0, w0 = time.process_time(), time.perf_counter()
            fin = finishing_moves(text, moves, sheet["operations"])
            report = simulate(moves, tools, setup, tri, VerifyOptions(cell=args.grid), finishing=fin).report
            best_cpu = min(best_cpu, time.process_time() - c0)
            best_wall = min(best_wall, time.perf_counter() - w0)
        eng = ", ".join(f"T{e.tool}{' (finishing)' if e.finishing else ''} {e.max_depth:.2f} mm deep "
                        f"(line {e.max_depth_line}), {e.max_width:.1f} mm wide" for e in report.engagement)
        faults = "; ".join(f"{f.kind} T{f.tool} {f.worst:.2f} mm on {len(f.lines)} line(s)" for f in report.faults)
        print(f"{name}: parse {parse_s:.2f} s, verify {best_cpu:.2f} s CPU / {best_wall:.2f} s wall, "
              f"{report.moves} moves, {report.rapids_checked} rapids checked | {eng} | "
              f"{'OK' if report.ok else 'FAILED: ' + faults}")


if __name__ == "__main__":
    main()
