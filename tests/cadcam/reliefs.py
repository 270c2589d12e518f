"""Generated open surfaces for the relief tests: heightfields meshed as sheets, and what breaks them."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import trimesh

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
heightfield_sheet = runpy.run_path(str(SAMPLES / "make_relief.py"))["heightfield_sheet"]


def wavy(nx: int = 25, ny: int = 17, size=(48.0, 32.0), amp: float = 3.0, base: float = 2.0):
    """Grid and heights of a smooth bumpy relief [mm]."""
    x = np.linspace(0.0, size[0], nx)
    y = np.linspace(0.0, size[1], ny)
    X, Y = np.meshgrid(x, y)
    z = base + amp * np.exp(-((X - 0.35 * size[0]) ** 2 + (Y - 0.5 * size[1]) ** 2) / (0.04 * size[0] ** 2))
    z += 0.4 * amp * np.sin(X / 5.0) * np.cos(Y / 6.0)
    return x, y, z


def stl_bytes(mesh: trimesh.Trimesh) -> bytes:
    return trimesh.exchange.stl.export_stl(mesh)


def unwelded(mesh: trimesh.Trimesh, noise: float = 0.0, seed: int = 0) -> trimesh.Trimesh:
    """Every triangle with its own three corners, each moved by up to ``noise`` [mm]."""
    v = np.asarray(mesh.triangles).reshape(-1, 3).copy()
    if noise:
        v += np.random.default_rng(seed).uniform(-noise, noise, v.shape)
    return trimesh.Trimesh(v, np.arange(len(v)).reshape(-1, 3), process=False)


def inverted(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(mesh.vertices, np.asarray(mesh.faces)[:, ::-1], process=False)


def overlapping_sheets() -> trimesh.Trimesh:
    """Three sheets: two side by side sharing an edge with a third, higher one overlapping both
    and hung from that same edge line: edges used by three triangles (non-manifold)."""
    x, y, z = wavy(13, 17, size=(24.0, 32.0))
    left = heightfield_sheet(x, y, z)
    right = heightfield_sheet(x + 24.0, y, z[:, ::-1])
    # A raised plateau over the middle, hung from the shared edge at x = 24 by a vertical strip.
    xm = np.linspace(24.0, 36.0, 7)
    ym = y
    zm = np.full((len(ym), len(xm)), 7.0)
    plateau = heightfield_sheet(xm, ym, zm)
    edge_z = z[:, -1]
    strip_v = np.vstack([np.column_stack([np.full(len(y), 24.0), y, edge_z]),
                         np.column_stack([np.full(len(y), 24.0), y, np.full(len(y), 7.0)])])
    n = len(y)
    a = np.arange(n - 1)
    strip_f = np.vstack([np.column_stack([a, a + 1, n + a + 1]), np.column_stack([a, n + a + 1, n + a])])
    strip = trimesh.Trimesh(strip_v, strip_f, process=False)
    return trimesh.util.concatenate([left, right, plateau, strip])


def hollow_ball_open_on_top(radius: float = 15.0, cap_deg: float = 45.0) -> trimesh.Trimesh:
    """A sphere with a cap cut off on top: from above, mostly its underside: it faces down."""
    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    polar = np.degrees(np.arccos(np.clip(ball.triangles_center[:, 2] / radius, -1, 1)))
    ball.update_faces(polar > cap_deg)
    ball.remove_unreferenced_vertices()
    ball.apply_translation([radius + 1, radius + 1, radius])
    return ball


def scattered_strips() -> trimesh.Trimesh:
    """Thin sheets scattered over a wide area: gaps over most of the footprint."""
    x, y, z = wavy(25, 17)
    keep = np.zeros((len(y) - 1, len(x) - 1), bool)
    keep[::5, :] = True  # one row of cells in five, each its own sheet
    return heightfield_sheet(x, y, z, keep=keep)
