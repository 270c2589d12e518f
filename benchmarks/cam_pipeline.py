"""Wall time of every CAM stage, and the throughput of the hot kernels, on the sample parts.

    python benchmarks/cam_pipeline.py [PART.stl ...] [--scallop 0.005] [--json]

For each part: load, setup, roughing, waterline, raster, post, parse, verify [s]; then
drop-cutter throughput (cutter locations per second, 6 mm ball on a 0.25 mm grid over the
stock), verify throughput (moves per second), and G-code lines per metre of cut with and
without arc fitting. With ``--json`` the last line is one JSON object ``{"rows": [...]}``.
Timings are single runs on whatever machine this is: compare runs on the same machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.dropcutter import build_index, drop_cutter  # noqa: E402
from cadcam.finishing import FinishingOptions, raster_finishing, waterline_finishing  # noqa: E402
from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.mesh import load_part  # noqa: E402
from cadcam.model import Job  # noqa: E402
from cadcam.post import PostOptions, post_process  # noqa: E402
from cadcam.roughing import zlevel_roughing  # noqa: E402
from cadcam.setup import make_setup  # noqa: E402
from cadcam.tools import load_tool_library  # noqa: E402
from cadcam.verify import VerifyOptions, simulate  # noqa: E402


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def bench_part(path: Path, scallop: float) -> dict:
    lib = load_tool_library()
    seconds: dict[str, float] = {}
    loaded, seconds["load"] = timed(load_part, path)
    (setup, part), seconds["setup"] = timed(make_setup, loaded.mesh)
    rough_tool, ball = lib.tool(1), lib.tool(3)
    finishing = FinishingOptions(scallop=scallop)
    rough, seconds["roughing"] = timed(zlevel_roughing, part, setup, rough_tool, lib.cutting_data(rough_tool, setup.material))
    cut = lib.cutting_data(ball, setup.material)
    water, seconds["waterline"] = timed(waterline_finishing, part, setup, ball, cut, finishing)
    raster, seconds["raster"] = timed(raster_finishing, part, setup, ball, cut, finishing)
    job = Job(path.stem, setup, tuple(op for op in (rough, water, raster) if len(op.points) > 1))
    program, seconds["post"] = timed(post_process, job, PostOptions())
    moves, seconds["parse"] = timed(parse_gcode, program.text)
    verified, seconds["verify"] = timed(
        simulate, moves, {t.number: t for t in job.tools}, setup, np.asarray(part.triangles), VerifyOptions(cell=0.2)
    )
    report = verified.report
    plain = post_process(job, PostOptions(arcs=False))

    # Drop-cutter kernel alone: a regular grid over the stock.
    index = build_index(np.asarray(part.triangles))
    xs = np.arange(setup.stock_min[0], setup.stock_max[0], 0.25)
    ys = np.arange(setup.stock_min[1], setup.stock_max[1], 0.25)
    xy = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    _, dc_s = timed(drop_cutter, index, ball, xy, float(setup.stock_min[2]))

    cut_m = sum(op.lengths()["cut"] + op.lengths()["plunge"] for op in job.operations) / 1000
    return {
        "part": path.stem,
        "triangles": int(len(loaded.mesh.faces)),
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
        "total_s": round(sum(seconds.values()), 2),
        "dropcutter_points": int(len(xy)),
        "dropcutter_cl_per_s": round(len(xy) / dc_s),
        "verify_moves": int(report.moves),
        "verify_moves_per_s": round(report.moves / seconds["verify"]),
        "gcode_lines": program.line_count,
        "gcode_lines_without_arcs": plain.line_count,
        "lines_per_m_cut": round(program.line_count / cut_m, 1),
        "lines_per_m_cut_without_arcs": round(plain.line_count / cut_m, 1),
        "max_gouge_mm": round(report.max_gouge, 4),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("parts", nargs="*", type=Path, default=sorted((ROOT / "samples").glob("*.stl")))
    ap.add_argument("--scallop", type=float, default=0.005, help="finishing scallop height [mm]")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of all rows")
    args = ap.parse_args()

    print(f"# {platform.processor() or platform.machine()}, {platform.python_version()}, scallop {args.scallop} mm")
    rows = []
    for path in args.parts:
        r = bench_part(path, args.scallop)
        rows.append(r)
        stages = " ".join(f"{k}={v:.2f}" for k, v in r["seconds"].items())
        print(f"{r['part']:>14} {r['triangles']:>7} tri | {stages} | total {r['total_s']:.1f} s | "
              f"drop-cutter {r['dropcutter_cl_per_s']:,} CL/s | verify {r['verify_moves_per_s']:,} moves/s | "
              f"{r['lines_per_m_cut']} lines/m ({r['lines_per_m_cut_without_arcs']} without arcs)", flush=True)
    if args.json:
        print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
