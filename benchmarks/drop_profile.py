"""The drop-cutter kernels on issue 35's 100k-triangle relief (benchmarks/big_parts.py's
``relief_8_shells_100k``): CPU seconds per tool shape (ball, bull nose, flat), this checkout against
another one's ``cadcam/dropcutter.py``, in one process, alternating, so a loaded machine weighs on both
alike. Every CL height must be the same bit for bit; the script exits 1 if one differs.

    python benchmarks/drop_profile.py --other /path/to/old/checkout [--points 60000] [--repeats 3]

Raster and waterline finishing spend most of a big relief's plan in these kernels (``_edge_contacts``
alone more than half of both stages in a cProfile of the 100k relief). Run with ``FACTORY_THREADS=1``
to time the kernels without the thread pool.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cadcam.dropcutter as here  # noqa: E402
from benchmarks.big_parts import PARTS  # noqa: E402

#: (radius, corner radius) [mm]: a ball, a bull nose and a flat end mill.
TOOLS = ((3.0, 3.0), (5.0, 1.0), (4.0, 0.0))


def _module_of(checkout: Path):
    """``cadcam/dropcutter.py`` of another checkout, as a module of its own (it imports the rest from this one)."""
    spec = importlib.util.spec_from_file_location("other_dropcutter", checkout / "cadcam" / "dropcutter.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--other", type=Path, required=True, help="a checkout to compare with (e.g. a worktree of main)")
    ap.add_argument("--points", type=int, default=60_000, help="random tool axis positions over the relief")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    mesh = PARTS["relief_8_shells_100k"][0]()
    tris = np.asarray(mesh.triangles, dtype=np.float64)
    lo, hi = mesh.bounds[0, :2] - 4.0, mesh.bounds[1, :2] + 4.0
    xy = np.random.default_rng(1).uniform(lo, hi, size=(args.points, 2))
    modules = {"this": here, "other": _module_of(args.other.resolve())}
    same = True
    for radius, corner in TOOLS:
        indexes = {}
        for name, m in modules.items():
            indexes[name] = m.build_index(tris)
            m.drop_profile(indexes[name], radius, corner, xy[:5], -1.0)  # its buckets, not timed
        cpu: dict[str, list[float]] = {name: [] for name in modules}
        for _ in range(args.repeats):
            z = {}
            for name, m in modules.items():
                t0 = time.process_time()
                z[name] = m.drop_profile(indexes[name], radius, corner, xy, -1.0)
                cpu[name].append(time.process_time() - t0)
            same &= bool(np.array_equal(z["this"], z["other"]))
        print(json.dumps({"radius_mm": radius, "corner_mm": corner, "points": args.points,
                          "cpu_s": {name: round(min(v), 3) for name, v in cpu.items()},
                          "identical": same}), flush=True)
    sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
