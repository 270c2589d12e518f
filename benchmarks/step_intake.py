"""STEP intake speed: read, tessellate and recognise a part of about 500 B-rep faces.

    python benchmarks/step_intake.py [--columns 12 --rows 8] [--repeat 3] [--json]

Models a plate with a grid of features (tests/cadcam/stepparts.py ``feature_plate``: pockets with
R1.5 inside corners and holes through, flat and drill-point, about 500 faces at 12 x 8) with
build123d, writes it as STEP once, then times :func:`cadcam.step.read_step` (OpenCASCADE's read,
the tessellation at the default chordal deviation, feature recognition) and the whole
:func:`cadcam.mesh.load_part` (adds welding and the solid checks), each ``--repeat`` times in
this process after a warm-up read (so OpenCASCADE's import, ~0.5 s, is not counted). Prints
the median process CPU time [s], the figure to compare on a shared machine, the median wall
time [s] (counts the neighbours) and the load average. The issue's budget: 2 s.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.mesh import load_part  # noqa: E402
from cadcam.step import read_step  # noqa: E402
from tests.cadcam.stepparts import feature_plate, write_step  # noqa: E402


def timed(fn, repeat: int) -> tuple[float, float, object]:
    """Median CPU and wall seconds of ``repeat`` calls of ``fn``, and its last result."""
    cpu, wall = [], []
    result = None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        result = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return statistics.median(cpu), statistics.median(wall), result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--columns", type=int, default=12)
    ap.add_argument("--rows", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        part, holes = feature_plate(args.columns, args.rows)
        path = write_step(part, Path(d) / "feature_plate.step")
        model_s = time.perf_counter() - t0
        read_step(path)  # warm-up: imports OpenCASCADE
        read_cpu, read_wall, step = timed(lambda: read_step(path), args.repeat)
        load_cpu, load_wall, loaded = timed(lambda: load_part(path), args.repeat)
    f = step.features
    row = {
        "brep_faces": step.brep_faces, "triangles": int(len(step.faces)), "chordal_deviation_mm": step.chordal_deviation,
        "holes_modelled": len(holes), "holes": len(f.holes), "corners": len(f.corners), "flats": len(f.flats), "undercuts": len(f.undercuts),
        "read_step_cpu_s": round(read_cpu, 3), "read_step_wall_s": round(read_wall, 3),
        "load_part_cpu_s": round(load_cpu, 3), "load_part_wall_s": round(load_wall, 3),
        "watertight": bool(loaded.mesh.is_watertight), "model_s": round(model_s, 1),
        "load_average": [round(v, 1) for v in os.getloadavg()], "cpus": os.cpu_count(),
    }
    if args.json:
        print(json.dumps(row))
        return
    print(f"{row['brep_faces']} B-rep faces -> {row['triangles']} triangles at {step.chordal_deviation:g} mm; "
          f"{row['holes']} of {len(holes)} holes, {row['corners']} inside corners, {row['flats']} flat faces")
    print(f"read_step (read + tessellate + recognise): {read_cpu:.2f} s CPU, {read_wall:.2f} s wall")
    print(f"load_part (+ weld and solid checks):        {load_cpu:.2f} s CPU, {load_wall:.2f} s wall")
    print(f"load average {row['load_average']} on {row['cpus']} CPUs; modelling the part took {model_s:.0f} s")


if __name__ == "__main__":
    main()
