"""Big parts: `factory plan --no-robot` on generated reliefs of several shells and sizes, and on
solids of about 100k triangles, each in its own process: wall and CPU time [s], peak RSS [MB],
and the plan's stage times (issue 35: at most 60 s and 1.5 GB up to 100k triangles, 150 mm).

    python benchmarks/big_parts.py [--only NAME,...] [--keep DIR] [--json]
    python benchmarks/big_parts.py --write DIR      # only write the STL files
    python benchmarks/big_parts.py --only none --file PART.stp   # plan a file of your own the same way
    PYTHONPATH=/other/checkout python benchmarks/big_parts.py   # plans with that checkout's code

The reliefs are what scans and sculpting exports come as: open heightfield *patches* that overlap
one another (each its own shell), some with vertical sides, some folded with islands standing on
them. ``relief_public_like`` has the size and shell count of the public relief of issue 35
(86 x 43 x 27 mm, six shells, about 15.6k triangles). Each row is one run on a shared machine: the
load average (``uptime``) is printed with it; compare CPU seconds between versions.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.finishing_vs_ocl import synthetic  # noqa: E402
from tests.cadcam.reliefs import heightfield_sheet  # noqa: E402


def heights(X: np.ndarray, Y: np.ndarray, size: tuple[float, float, float]) -> np.ndarray:
    """A sculpted relief's heights [mm] over (X, Y): a tall head-like dome, a ridge, ripples."""
    sx, sy, sz = size
    z = 0.08 * sz + 0.85 * sz * np.exp(-(((X - 0.38 * sx) / (0.2 * sx)) ** 2 + ((Y - 0.5 * sy) / (0.3 * sy)) ** 2))
    z += 0.25 * sz * np.exp(-((Y - 0.35 * X / sx * sy - 0.3 * sy) ** 2) / (0.01 * sy * sy)) * (X > 0.55 * sx)
    z += 0.03 * sz * np.sin(X / (0.03 * sx)) * np.cos(Y / (0.05 * sy))
    return np.minimum(z, sz)


def relief(size=(86.0, 43.0, 27.0), shells: int = 6, triangles: int = 15_600, sides: bool = True) -> trimesh.Trimesh:
    """An open relief of ``shells`` overlapping heightfield patches, about ``triangles`` in all.

    The patches tile the footprint in a row-major grid, each overlapping its neighbours by 4 % of
    the size and lying 0.02 mm apart in z (a scan's patches never coincide); with ``sides`` every
    second patch hangs vertical sides to the base (open underneath), as sculpting tools export.
    """
    sx, sy, sz = size
    cols = int(np.ceil(np.sqrt(shells * sx / sy)))
    rows = int(np.ceil(shells / cols))
    per = triangles / shells / 2.0  # grid cells per patch
    lap = 0.04 * max(sx, sy)
    parts = []
    for k in range(shells):
        r, c = divmod(k, cols)
        if r == rows - 1:  # the last row shares the width among what is left
            n_last = shells - cols * (rows - 1)
            x0, x1 = c * sx / n_last, (c + 1) * sx / n_last
        else:
            x0, x1 = c * sx / cols, (c + 1) * sx / cols
        y0, y1 = r * sy / rows, (r + 1) * sy / rows
        x0, x1, y0, y1 = max(0.0, x0 - lap), min(sx, x1 + lap), max(0.0, y0 - lap), min(sy, y1 + lap)
        aspect = (x1 - x0) / (y1 - y0)
        ny = max(3, int(round(np.sqrt(per / aspect))) + 1)
        nx = max(3, int(round(per / (ny - 1))) + 1)
        x, y = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
        X, Y = np.meshgrid(x, y)
        z = heights(X, Y, size) + 0.02 * k
        parts.append(heightfield_sheet(x, y, z, sides_to=0.0 if sides and k % 2 else None))
    return trimesh.util.concatenate(parts)


def write_stl(mesh: trimesh.Trimesh, path: Path) -> Path:
    path.write_bytes(trimesh.exchange.stl.export_stl(mesh))
    return path


#: name: (maker, what it is)
PARTS = {
    "relief_public_like": (lambda: relief(), "86 x 43 x 27 mm, 6 shells, ~15.6k triangles"),
    "relief_3_shells_60k": (lambda: relief((120.0, 80.0, 20.0), 3, 60_000, sides=False), "120 x 80 x 20, 3 shells"),
    "relief_8_shells_100k": (lambda: relief((150.0, 100.0, 30.0), 8, 100_000), "150 x 100 x 30, 8 shells"),
    "solid_100k": (lambda: synthetic(100_000), "block, pocket and dome, 100 x 80 x 30, ~100k triangles"),
}


def load_average() -> str:
    return "%.2f %.2f %.2f" % os.getloadavg()


def plan_once(stl: Path, out: Path) -> dict:
    """`factory plan --no-robot --json` in a child process: its wall, CPU and peak RSS."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = load_average()
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", "from cli.main import main; main()", "plan", str(stl), "--no-robot",
                        "-o", str(out), "--overwrite", "--json"], capture_output=True, text=True,
                       cwd=out,  # not this checkout: the code is PYTHONPATH's
                       env={**os.environ, "PYTHONPATH": os.environ.get("PYTHONPATH", str(ROOT))})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    row = {"part": stl.stem, "exit": r.returncode, "wall_s": round(wall, 1),
           "cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
           "peak_rss_mb": round(after.ru_maxrss / 1024.0),  # the largest child so far: run one part per process
           "load_before": load0, "load_after": load_average()}
    if r.returncode in (0, 3):
        doc = json.loads(r.stdout)
        row.update(triangles=doc["triangles"], verify_ok=doc["verify"]["ok"],
                   max_gouge_mm=doc["verify"]["max_gouge"], stages_s=doc["seconds"])
    else:
        row["stderr"] = r.stderr.strip().splitlines()[-1:] or [""]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(PARTS))
    ap.add_argument("--write", type=Path, help="only write the parts' STL files into this folder")
    ap.add_argument("--keep", type=Path, help="write the plans' outputs here (else a temporary folder)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--file", type=Path, action="append", default=[],
                    help="also plan this part file (STL, STEP...), e.g. NIST FTC 10 (benchmarks/step_public.py says where from)")
    args = ap.parse_args()
    names = [n for n in args.only.split(",") if n != "none"]
    if args.write:
        args.write.mkdir(parents=True, exist_ok=True)
        for n in names:
            mesh = PARTS[n][0]()
            print(n, len(mesh.faces), "triangles", write_stl(mesh, args.write / f"{n}.stl"))
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = (args.keep or Path(tmp)).resolve()
        out.mkdir(parents=True, exist_ok=True)
        rows = []
        for n in names:
            # Each part in its own process: ru_maxrss of children is the largest one so far.
            r = subprocess.run([sys.executable, __file__, "--write", tmp, "--only", n], capture_output=True, text=True)
            if r.returncode:
                sys.exit(r.stderr)
            row = json.loads(subprocess.run(
                [sys.executable, "-c", "import sys, json; sys.path.insert(0, %r); from benchmarks.big_parts import "
                 "plan_once; from pathlib import Path; print(json.dumps(plan_once(Path(%r), Path(%r))))"
                 % (str(ROOT), str(Path(tmp) / f"{n}.stl"), str(out))],
                capture_output=True, text=True, check=True).stdout)
            rows.append(row)
            print(json.dumps(row) if args.json else row, flush=True)
        for path in args.file:
            row = plan_once(path.resolve(), out)
            rows.append(row)
            print(json.dumps(row) if args.json else row, flush=True)
        if args.json:
            print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
