"""factory's drop-cutter against OpenCAMLib's BatchDropCutter (and Waterline), same work.

    python benchmarks/finishing_vs_ocl.py [--quick] [--sizes 1000 10000 100000] [--reps 3]
                                          [--step 1.0] [--no-samples] [--no-waterline] [--json]

OpenCAMLib (PyPI ``opencamlib``, imported as ``opencamlib``) is a benchmark-only dependency:
nothing outside ``benchmarks/`` imports it.

Meshes: the sample parts in ``samples/`` and one synthetic part (a 100 x 80 x 30 block with a
60 x 50 x 15 pocket and an ellipsoidal dome standing in it) tessellated at about each of
``--sizes`` triangles (deterministic: manifold3d, segment count from the size).

For each mesh and cutter (ball 6, flat 6, bull 8 r1) both libraries drop the same cutter
onto the same raster grid of CL points (spacing ``--step`` over the mesh's XY box grown by
the tool radius). Runs alternate factory / OpenCAMLib, ``--reps`` times; the median wall time
is reported. What is timed:

- factory: ``build_index`` + ``drop_cutter`` (numpy in one process);
- OpenCAMLib: ``BatchDropCutter.setSTL`` (builds its kd-tree) + ``run()`` with its OpenMP
  threads (all cores). Building the ``STLSurf`` and appending the ``CLPoint`` objects one by
  one from Python are binding overheads and are NOT timed.

Agreement: OpenCAMLib's CL z is the tool tip, like ours. Where nothing is under the cutter it
leaves the CL point at its initial z, so every CL point starts at the same floor we pass as
``floor_z`` (1 mm below the mesh bottom): every grid point is then comparable and the
maximum |z difference| over all of them is reported, plus how many sit on the floor.

Waterline (synthetic part, ball 6, several z levels): OpenCAMLib's ``Waterline`` with fiber
sampling ``s`` (its points are exact where a fiber crosses the loop) against factory's
drop-cutter height map on a grid of spacing ``s`` contoured at each level (contourpy), each
contour vertex then bisected along its grid edge onto the exact iso-line with the
drop-cutter (as ``waterline_finishing`` does): both sets of points are exact, at spacing
``s``. Reported: the largest distance from an OpenCAMLib loop point to our loops (densified
to s/10; this is the accuracy figure), and from our vertices to OpenCAMLib's points (bounded
below by their spacing), and the loop counts.

With ``--json`` the last line is one JSON object ``{"rows": [...], "waterline": [...]}``.
Timings are wall times on whatever machine this is and whatever else runs on it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.dropcutter import build_index, drop_cutter  # noqa: E402
from cadcam.model import Tool  # noqa: E402

CUTTERS = {
    "ball:6": Tool(1, "6 mm ball", "ball", 6.0, 3.0, 20.0, 2, 50.0),
    "flat:6": Tool(2, "6 mm flat", "flat", 6.0, 0.0, 20.0, 2, 50.0),
    "bull:8r1": Tool(3, "8 mm bull r1", "bull", 8.0, 1.0, 20.0, 2, 50.0),
}


def ocl_cutter(ocl, tool: Tool):
    length = tool.length
    if tool.shape == "ball":
        return ocl.BallCutter(tool.diameter, length)
    if tool.shape == "flat":
        return ocl.CylCutter(tool.diameter, length)
    return ocl.BullCutter(tool.diameter, tool.corner_radius, length)


def synthetic(triangles: int):
    """Block, pocket and dome with about ``triangles`` triangles (the dome takes nearly all)."""
    import manifold3d as mf
    import trimesh

    seg = max(16, int(round(2.0 * np.sqrt(triangles))))
    part = mf.Manifold.cube((100.0, 80.0, 30.0))
    part -= mf.Manifold.cube((60.0, 50.0, 20.0)).translate((20.0, 15.0, 15.0))
    dome = mf.Manifold.sphere(1.0, circular_segments=seg).scale((22.0, 18.0, 12.0)).translate((50.0, 40.0, 15.0))
    part += dome
    m = part.to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties[:, :3], dtype=np.float64),
                           np.asarray(m.tri_verts, dtype=np.int64), process=True)


def ocl_surface(ocl, tris: np.ndarray):
    surf = ocl.STLSurf()
    for a, b, c in tris.tolist():
        surf.addTriangle(ocl.Triangle(ocl.Point(*a), ocl.Point(*b), ocl.Point(*c)))
    return surf


def raster_grid(tris: np.ndarray, reach: float, step: float) -> np.ndarray:
    lo = tris[:, :, :2].reshape(-1, 2).min(axis=0) - reach
    hi = tris[:, :, :2].reshape(-1, 2).max(axis=0) + reach
    xs = np.arange(lo[0], hi[0] + 1e-9, step)
    ys = np.arange(lo[1], hi[1] + 1e-9, step)
    return np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)


def run_factory(tris, tool, xy, floor):
    t0 = time.perf_counter()
    index = build_index(tris)
    z = drop_cutter(index, tool, xy, floor)
    return z, time.perf_counter() - t0


def run_ocl(ocl, surf, tool, xy, floor):
    # OpenCAMLib keeps a bare pointer to the cutter: hold a reference until run() is done.
    cutter = ocl_cutter(ocl, tool)
    bdc = ocl.BatchDropCutter()
    bdc.setCutter(cutter)
    for x, y in xy.tolist():
        bdc.appendPoint(ocl.CLPoint(x, y, floor))
    t0 = time.perf_counter()
    bdc.setSTL(surf)
    bdc.run()
    dt = time.perf_counter() - t0
    z = np.array([p.z for p in bdc.getCLPoints()])
    del cutter
    return z, dt


def compare(ocl, name, tris, surf, tool_key, step, reps) -> dict:
    tool = CUTTERS[tool_key]
    floor = float(tris[:, :, 2].min()) - 1.0
    xy = raster_grid(tris, tool.radius, step)
    fs, os_ = [], []
    zf = zo = None
    for _ in range(reps):
        zf, t = run_factory(tris, tool, xy, floor)
        fs.append(t)
        zo, t = run_ocl(ocl, surf, tool, xy, floor)
        os_.append(t)
    f, o = statistics.median(fs), statistics.median(os_)
    dz = np.abs(zf - zo)
    worst = int(np.argmax(dz))
    return {
        "mesh": name,
        "triangles": int(len(tris)),
        "cutter": tool_key,
        "points": int(len(xy)),
        "step_mm": step,
        "factory_s": round(f, 4),
        "ocl_s": round(o, 4),
        "ratio": round(o / f, 3),
        "factory_cl_per_s": round(len(xy) / f),
        "ocl_cl_per_s": round(len(xy) / o),
        "max_dz_mm": float(f"{dz.max():.3g}"),
        "worst_xy": [round(float(v), 4) for v in xy[worst]],
        "on_floor": [int(np.sum(zf <= floor + 1e-9)), int(np.sum(zo <= floor + 1e-9))],
    }


# --------------------------------------------------------------------------- waterline


def _densify(loop: np.ndarray, spacing: float) -> np.ndarray:
    seg = np.diff(loop, axis=0)
    n = np.maximum(np.ceil(np.hypot(seg[:, 0], seg[:, 1]) / spacing).astype(int), 1)
    t = np.concatenate([np.arange(k) / k for k in n])
    i = np.repeat(np.arange(len(seg)), n)
    return np.vstack([loop[i] + t[:, None] * seg[i], loop[-1:]])


def _distances(ours: list[np.ndarray], theirs: list[np.ndarray], spacing: float) -> tuple[float, float]:
    """(max distance of OpenCAMLib's loop points to our loops, of our loop vertices to theirs) [mm].

    OpenCAMLib's loops are compared as point sets: their points are exact on fibers but
    consecutive points are not always neighbours along the loop (pieces, jumps), so
    joining them would invent chords. Our contour lines are ordered and densified.
    """
    from scipy.spatial import cKDTree

    if not ours or not theirs:
        return (float("inf"), float("inf")) if (ours or theirs) else (0.0, 0.0)
    pa = np.vstack([_densify(x, spacing) for x in ours])
    pb = np.vstack(theirs)
    return float(cKDTree(pa).query(pb)[0].max()), float(cKDTree(pb).query(np.vstack(ours))[0].max())


def _onto_level(index, tool, line: np.ndarray, level: np.ndarray, gx, gy, floor, steps: int = 24) -> np.ndarray:
    """Move contour vertices along their grid edge onto the exact iso-line (bisection)."""
    s = gx[1] - gx[0]
    on_x = np.abs((line[:, 0] - gx[0]) / s - np.round((line[:, 0] - gx[0]) / s)) < 1e-6
    a = line.copy()
    b = line.copy()
    # Vertices on a vertical grid line move along y within their cell, the others along x.
    ky = np.clip(np.floor((line[:, 1] - gy[0]) / s), 0, len(gy) - 2).astype(int)
    kx = np.clip(np.floor((line[:, 0] - gx[0]) / s), 0, len(gx) - 2).astype(int)
    a[on_x, 1], b[on_x, 1] = gy[ky[on_x]], gy[ky[on_x] + 1]
    a[~on_x, 0], b[~on_x, 0] = gx[kx[~on_x]], gx[kx[~on_x] + 1]
    za = drop_cutter(index, tool, a, floor)
    swap = za > level  # keep a below the level, b above
    a[swap], b[swap] = b[swap], a[swap].copy()
    for _ in range(steps):
        m = 0.5 * (a + b)
        up = drop_cutter(index, tool, m, floor) > level
        b[up] = m[up]
        a[~up] = m[~up]
    return 0.5 * (a + b)


def waterline(ocl, name, tris, surf, tool_key, levels, sampling) -> dict:
    import contourpy

    tool = CUTTERS[tool_key]
    floor = float(tris[:, :, 2].min()) - 1.0
    t0 = time.perf_counter()
    # An odd offset keeps grid lines off the part's round coordinates (no iso-line along a grid line).
    lo = tris[:, :, :2].reshape(-1, 2).min(axis=0) - tool.radius - 1.3137 * sampling
    hi = tris[:, :, :2].reshape(-1, 2).max(axis=0) + tool.radius + sampling
    gx = np.arange(lo[0], hi[0] + 1e-9, sampling)
    gy = np.arange(lo[1], hi[1] + 1e-9, sampling)
    X, Y = np.meshgrid(gx, gy)
    index = build_index(tris)
    Z = drop_cutter(index, tool, np.column_stack([X.ravel(), Y.ravel()]), floor).reshape(X.shape)
    gen = contourpy.contour_generator(gx, gy, Z, line_type="Separate")
    raw = [(z, np.asarray(c)) for z in levels for c in gen.lines(z) if len(c) >= 2]
    ours = {z: [] for z in levels}
    if raw:
        sizes = np.cumsum([len(c) for _, c in raw])[:-1]
        level = np.concatenate([np.full(len(c), z) for z, c in raw])
        moved = np.split(_onto_level(index, tool, np.vstack([c for _, c in raw]), level, gx, gy, floor), sizes)
        for (z, _), c in zip(raw, moved):
            ours[z].append(c)
    factory_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    theirs = {}
    cutter = ocl_cutter(ocl, tool)  # held: OpenCAMLib keeps a bare pointer
    for z in levels:
        wl = ocl.Waterline()
        wl.setSTL(surf)
        wl.setCutter(cutter)
        wl.setZ(z)
        wl.setSampling(sampling)
        wl.run()
        # Not closed here: near pocket corners OpenCAMLib may return a loop as several open pieces.
        theirs[z] = [np.array([(p.x, p.y) for p in loop]) for loop in wl.getLoops() if len(loop) >= 2]
    ocl_s = time.perf_counter() - t0
    per_level = []
    for z in levels:
        to_ours, to_theirs = _distances(ours[z], theirs[z], sampling / 10)
        per_level.append({"z": z, "loops": [len(ours[z]), len(theirs[z])], "hausdorff_mm": round(max(to_ours, to_theirs), 4),
                          "ocl_to_factory_mm": round(to_ours, 4), "factory_to_ocl_mm": round(to_theirs, 4)})
    return {"mesh": name, "triangles": int(len(tris)), "cutter": tool_key, "sampling_mm": sampling,
            "factory_s": round(factory_s, 3), "ocl_s": round(ocl_s, 3), "levels": per_level}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[1_000, 10_000, 100_000],
                    help="synthetic mesh sizes [triangles] (1000000 is possible, slow to build for OpenCAMLib)")
    ap.add_argument("--reps", type=int, default=3, help="alternating repetitions per row (median reported)")
    ap.add_argument("--step", type=float, default=1.0, help="raster CL grid spacing [mm]")
    ap.add_argument("--no-samples", action="store_true", help="skip the sample parts")
    ap.add_argument("--no-waterline", action="store_true", help="skip the waterline comparison")
    ap.add_argument("--waterline-size", type=int, default=10_000, help="synthetic mesh for the waterline comparison")
    ap.add_argument("--sampling", type=float, default=0.5, help="waterline sampling (fiber / grid spacing) [mm]")
    ap.add_argument("--grid-scaling", action="store_true", help="also time the 10k mesh at grid steps 1, 0.5, 0.25 mm")
    ap.add_argument("--quick", action="store_true", help="1k and 10k synthetic only, 1 mm grid, 1 repetition")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of all rows")
    args = ap.parse_args()
    import opencamlib as ocl
    import trimesh

    if args.quick:
        args.sizes, args.reps, args.step, args.no_samples = [1_000, 10_000], 1, 1.0, True
        args.waterline_size = 1_000

    cpu = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), platform.machine())
    print(f"# {cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, OpenCAMLib {ocl.version()} "
          f"({ocl.max_threads()} threads), grid {args.step} mm, {args.reps} reps", flush=True)

    meshes: list[tuple[str, np.ndarray]] = []
    if not args.no_samples:
        for path in sorted((ROOT / "samples").glob("*.stl")):
            meshes.append((path.stem, np.asarray(trimesh.load(path, force="mesh").triangles, dtype=np.float64)))
    for size in args.sizes:
        meshes.append((f"block_dome_{size}", np.asarray(synthetic(size).triangles, dtype=np.float64)))

    rows = []
    surfaces = {}
    print(f"{'mesh':>18} {'tri':>8} {'cutter':>9} {'points':>7} | {'factory s':>9} {'OCL s':>8} {'ratio':>6} | "
          f"{'factory CL/s':>12} {'OCL CL/s':>10} | max|dz| mm", flush=True)
    for name, tris in meshes:
        surf = surfaces[name] = ocl_surface(ocl, tris)
        for key in CUTTERS:
            r = compare(ocl, name, tris, surf, key, args.step, args.reps)
            rows.append(r)
            print(f"{name:>18} {r['triangles']:>8} {key:>9} {r['points']:>7} | {r['factory_s']:>9.3f} {r['ocl_s']:>8.3f} "
                  f"{r['ratio']:>6.2f} | {r['factory_cl_per_s']:>12,} {r['ocl_cl_per_s']:>10,} | {r['max_dz_mm']:.2e}",
                  flush=True)

    if args.grid_scaling:
        name, tris = next((m for m in meshes if m[0].endswith("_10000")), meshes[-1])
        for step in (1.0, 0.5, 0.25):
            r = compare(ocl, name, tris, surfaces[name], "ball:6", step, args.reps)
            r["grid_scaling"] = True
            rows.append(r)
            print(f"grid {step:>5} mm {name:>18} ball:6 {r['points']:>8} pts | factory {r['factory_s']:.3f} s "
                  f"OCL {r['ocl_s']:.3f} s ratio {r['ratio']:.2f}", flush=True)

    wl_rows = []
    if not args.no_waterline:
        name, tris = next((m for m in meshes if m[0] == f"block_dome_{args.waterline_size}"), meshes[-1])
        levels = [16.0, 19.0, 22.0, 25.0, 28.0]
        sampling = args.sampling
        w = waterline(ocl, name, tris, surfaces[name], "ball:6", levels, sampling)
        wl_rows.append(w)
        print(f"waterline {name} ball:6 sampling {sampling} mm: factory {w['factory_s']:.2f} s (grid + contour), "
              f"OCL {w['ocl_s']:.2f} s ({len(levels)} levels)", flush=True)
        for lv in w["levels"]:
            print(f"  z={lv['z']:5.1f} loops factory/OCL {lv['loops'][0]}/{lv['loops'][1]}  Hausdorff {lv['hausdorff_mm']:.4f} mm "
                  f"(OCL points to our loops {lv['ocl_to_factory_mm']:.4f}, our vertices to OCL points {lv['factory_to_ocl_mm']:.4f})")
    if args.json:
        print(json.dumps({"rows": rows, "waterline": wl_rows}))


if __name__ == "__main__":
    main()
