"""Sharp inside corners: the part's concave vertical edges, and the stock a round tool leaves in them.

A round end mill of radius r cannot finish an inside corner whose walls meet at an angle theta: it
leaves a sliver along the corner, r (1 / sin(theta / 2) - 1) thick on the bisector (0.41 r at 90 deg)
and as tall as the walls. The material-removal grid cannot see that sliver: it lies within a cell
diagonal of both walls, where :func:`cadcam.stock.excess` grows the part so that cells a finished
wall passes through are not taken for stock. So the corners come from the part's own geometry (its
concave vertical edges) and the grid only says whether stock still stands beside them.

A facetted round (a hole, a fillet) is a string of such edges at 170-179 deg, whose slivers are
micrometres: :func:`corners_left` keeps only corners whose sliver, left by the finest end mill of
the program, is thicker than the tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from cadcam.stock import SHARP_CORNER, Simulation, Unreached, excess

__all__ = ["InsideCorners", "corners_left", "inside_corners", "sliver"]

#: A face is a wall when its normal is within this of horizontal (|n_z| below it).
_WALL_NZ = 0.2
#: An edge is vertical when its Z extent is at least this share of its length.
_VERTICAL = 0.9


@dataclass(frozen=True)
class InsideCorners:
    """The part's concave vertical edges, one row each, in work coordinates.

    Attributes
    ----------
    xy : (n, 2) float
        The edge's place [mm].
    z_low, z_high : (n,) float
        Its bottom and top [mm].
    angle : (n,) float
        The angle the two walls make on the open side [deg]: 90 for a square pocket's corner, near 180
        between two facets of a round.
    """

    xy: np.ndarray
    z_low: np.ndarray
    z_high: np.ndarray
    angle: np.ndarray

    def __len__(self) -> int:
        return len(self.angle)


def inside_corners(triangles: np.ndarray) -> InsideCorners:
    """The concave vertical edges between two walls of ``triangles`` ((m, 3, 3) float [mm], work
    coordinates, a closed part's faces pointing out of the material)."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    empty = InsideCorners(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros(0))
    if len(tri) < 2:
        return empty
    mesh = trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(3 * len(tri)).reshape(-1, 3),
                           process=False, validate=False)
    mesh.merge_vertices(digits_vertex=6)
    pairs = mesh.face_adjacency
    if not len(pairs):
        return empty
    normals = mesh.face_normals
    walls = (np.abs(normals[pairs[:, 0], 2]) < _WALL_NZ) & (np.abs(normals[pairs[:, 1], 2]) < _WALL_NZ)
    ends = mesh.vertices[mesh.face_adjacency_edges]
    span = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(span, axis=1)
    vertical = np.abs(span[:, 2]) >= _VERTICAL * np.maximum(length, 1e-12)
    keep = walls & vertical & ~mesh.face_adjacency_convex & (length > 0)
    between = np.degrees(mesh.face_adjacency_angles[keep])  # 0: coplanar
    e = ends[keep]
    return InsideCorners(xy=e[:, 0, :2].copy(), z_low=e[:, :, 2].min(axis=1), z_high=e[:, :, 2].max(axis=1),
                         angle=180.0 - between)


def sliver(radius: float, angle: np.ndarray) -> np.ndarray:
    """Thickness of the stock an end mill of ``radius`` [mm] leaves on the bisector of inside corners
    of ``angle`` [deg]: ``r (1 / sin(angle / 2) - 1)`` [mm]."""
    half = np.radians(np.clip(np.asarray(angle, dtype=np.float64), 1.0, 180.0)) / 2.0
    return radius * (1.0 / np.sin(half) - 1.0)


def corners_left(sim: Simulation, corners: InsideCorners, above: float, radius: float,
                 listed: tuple[Unreached, ...] = ()) -> tuple[Unreached, ...]:
    """The sharp inside corners of ``corners`` that still hold stock beside them, as regions of stock left.

    A corner counts when the sliver the finest end mill of the program (``radius`` [mm]) leaves in it
    is thicker than ``above`` [mm] (:func:`sliver`), and a grid point within a cell diagonal of it
    holds more than ``above`` over the part there (:func:`cadcam.stock.excess` without the grid's slack)
    above the corner's floor. Corners inside a region already ``listed`` are that region's. Each
    region: at the corner, the sliver's thickness square (at least a cell, at most two cell
    diagonals: the grid sees a thicker one), its depth the most stock beside it, its bottom the corner's; ``why`` :data:`cadcam.stock.SHARP_CORNER`.
    """
    thick = sliver(radius, corners.angle) > above
    if not thick.any() or radius <= 0:
        return ()
    g = sim.grid
    raw = excess(sim, 0.0, grid_slack=False)
    standing = raw > above
    if not standing.any():
        return ()
    reach = g.cell * math.sqrt(2.0)
    k = int(math.ceil(reach / g.cell))
    found: dict[tuple[int, int], Unreached] = {}
    for n in np.flatnonzero(thick):
        x, y = corners.xy[n]
        # a listed region stops a cell diagonal short of the walls (excess's slack): its corner is just outside
        if any(abs(x - u.x) <= u.size_x / 2 + 2 * reach and abs(y - u.y) <= u.size_y / 2 + 2 * reach for u in listed):
            continue
        i, j = int(round((x - g.x0) / g.cell)), int(round((y - g.y0) / g.cell))
        box = np.s_[max(j - k, 0):j + k + 1, max(i - k, 0):i + k + 1]
        ii, jj = np.meshgrid(np.arange(g.nx)[box[1]], np.arange(g.ny)[box[0]])
        near = np.hypot(g.x0 + ii * g.cell - x, g.y0 + jj * g.cell - y) <= reach
        hold = near & standing[box] & (sim.stock_top[box] > corners.z_low[n] + above)
        if not hold.any():
            continue
        depth = float(raw[box][hold].max())
        key = (int(round(x / g.cell)), int(round(y / g.cell)))  # a corner's edge, split along Z, is one corner
        old = found.get(key)
        z_low = float(corners.z_low[n]) if old is None else min(old.z_bottom, float(corners.z_low[n]))
        # what the grid sees, beyond two cell diagonals, is unreached's: thicker slivers are listed there
        size = min(max(float(sliver(radius, corners.angle[n])), g.cell), 2.0 * reach)
        found[key] = Unreached(x=float(x), y=float(y), size_x=size, size_y=size,
                               depth=max(depth, 0.0 if old is None else old.depth), z_bottom=z_low, why=SHARP_CORNER)
    return tuple(sorted(found.values(), key=lambda u: (-u.depth, u.x, u.y)))
