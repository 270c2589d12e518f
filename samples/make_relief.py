"""Make the sample relief ``samples/relief.stl``: ``python samples/make_relief.py [OUT_DIR]``.

A carved-sign-like relief, 120 x 80 mm: a heightfield (a low plinth with two domes, a ridge
and ripples, 0 to 9 mm high) meshed as an *open sheet*: no sides, no bottom, the way scans and
terrain exports come. ``factory plan`` machines it from above as a relief (cadcam/relief.py).
Binary STL, deterministic (same bytes on every run); the tests mesh their own heightfields with
:func:`heightfield_sheet`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent


def heightfield_sheet(x: np.ndarray, y: np.ndarray, z: np.ndarray, sides_to: float | None = None,
                      keep: np.ndarray | None = None) -> trimesh.Trimesh:
    """An open sheet over the grid ``x`` (nx,) by ``y`` (ny,) with heights ``z`` (ny, nx) [mm].

    ``sides_to``: also mesh vertical sides from the sheet's edge down to this z (still open
    underneath). ``keep`` (ny-1, nx-1) bool: grid cells to mesh (False leaves a hole).
    Each cell is two triangles facing up.
    """
    nx, ny = len(x), len(y)
    X, Y = np.meshgrid(x, y)
    v = np.column_stack([X.ravel(), Y.ravel(), np.asarray(z, dtype=np.float64).ravel()])
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1))
    a = (j * nx + i).ravel()
    b, c, d = a + 1, a + nx, a + nx + 1
    cells = np.ones((ny - 1) * (nx - 1), bool) if keep is None else np.asarray(keep, bool).ravel()
    faces = [np.column_stack([a, b, d])[cells], np.column_stack([a, d, c])[cells]]
    if sides_to is not None:
        # The rim, counter-clockwise seen from above, each edge hung down to sides_to.
        rim = np.concatenate([np.arange(nx - 1), (nx - 1) + nx * np.arange(ny - 1),
                              nx * ny - 1 - np.arange(nx - 1), nx * (ny - 1) - nx * np.arange(ny - 1)])
        low = len(v) + np.arange(len(rim))
        v = np.vstack([v, np.column_stack([v[rim, :2], np.full(len(rim), sides_to)])])
        nxt = np.roll(np.arange(len(rim)), -1)
        faces += [np.column_stack([rim, low, low[nxt]]), np.column_stack([rim, low[nxt], rim[nxt]])]
    return trimesh.Trimesh(v, np.concatenate(faces), process=False)


def relief_heights(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The sample's heights [mm] over the grid (ny, nx)."""
    X, Y = np.meshgrid(x, y)
    z = 1.0 + 6.0 * np.exp(-((X - 35) ** 2 + (Y - 45) ** 2) / 300.0)
    z += 8.0 * np.exp(-((X - 85) ** 2 + (Y - 35) ** 2) / 180.0)
    z += 2.5 * np.exp(-((Y - 0.3 * X - 50) ** 2) / 20.0) * (X > 10) * (X < 110)
    z += 0.6 * np.sin(X / 4.0) * np.cos(Y / 5.0)
    return z


def relief(nx: int = 121, ny: int = 81) -> trimesh.Trimesh:
    x = np.linspace(0.0, 120.0, nx)
    y = np.linspace(0.0, 80.0, ny)
    return heightfield_sheet(x, y, relief_heights(x, y))


def main(out_dir: Path = HERE) -> None:
    mesh = relief()
    tri = mesh.triangles.astype("<f4")
    rec = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["n"] = mesh.face_normals.astype("<f4")
    rec["v"] = tri
    header = b"factory sample relief: open heightfield sheet, mm".ljust(80, b" ")
    (out_dir / "relief.stl").write_bytes(header + np.uint32(len(tri)).tobytes() + rec.tobytes())


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
