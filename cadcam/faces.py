"""The part's surface by kind, as a machinist reads it before choosing a strategy.

Every triangle of the part (work coordinates, +Z the spindle axis) falls in one class:

* **flat**: facing up within ``flat_angle`` of horizontal. Flats are grouped by their height
  (to :data:`_Z_DECIMALS`), so each pocket floor, step top or boss top is finished with a flat
  end mill at its exact Z.
* **wall**: within ``wall_angle`` of vertical, finished by the flank of a flat end mill.
* **steep** / **shallow**: every other up-facing triangle, freeform, split at ``steep_angle``
  from horizontal: waterline on steep, raster on shallow, both with a ball end mill.
* **hidden**: facing down (the part's bottom, undercuts): a top-side setup does not see it.

The XY masks (:meth:`FaceClasses.near`) tell the strategies where each kind lies, grown by
the reach of the tool that is to cut it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import shapely
import trimesh
from shapely.geometry.base import BaseGeometry

#: The class codes, in :attr:`FaceClasses.kind`.
FLAT, WALL, STEEP, SHALLOW, HIDDEN = 0, 1, 2, 3, 4
KIND_NAMES = ("flat", "wall", "steep", "shallow", "hidden")
#: Flat faces whose heights agree to this many decimals [mm] are one level.
_Z_DECIMALS = 3


@dataclass(frozen=True)
class FaceOptions:
    """Where one kind ends and the next begins.

    Attributes
    ----------
    flat_angle : float
        A triangle tilted at most this much from horizontal is flat [deg].
    wall_angle : float
        A triangle within this much of vertical is a wall [deg].
    steep_angle : float
        Freeform steeper than this from horizontal is steep [deg] (waterline), gentler is
        shallow (raster).
    """

    flat_angle: float = 0.5
    wall_angle: float = 1.0
    steep_angle: float = 50.0


@dataclass(frozen=True)
class FaceClasses:
    """The class of every triangle of one part.

    Attributes
    ----------
    kind : (n,) int8
        :data:`FLAT`, :data:`WALL`, :data:`STEEP`, :data:`SHALLOW` or :data:`HIDDEN` per triangle.
    area : (n,) float
        Triangle areas [mm^2].
    flat_z : (k,) float
        Heights of the flat levels, highest first [mm].
    flat_level : (n,) int
        Index into ``flat_z`` of each flat triangle, -1 for the others.
    triangles : (n, 3, 3) float
        The triangles [mm], for the masks.
    """

    kind: np.ndarray
    area: np.ndarray
    flat_z: np.ndarray
    flat_level: np.ndarray
    triangles: np.ndarray = field(repr=False)
    #: Footprints by kinds, and their grown copies by (kinds, reach): the planner asks for the same ones
    #: for every flat end mill and every rest check (plate_bosses: 13 % of its plan, mostly the unions).
    _shapes: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def areas(self) -> dict[str, float]:
        """Surface area per kind [mm^2]."""
        return {name: float(self.area[self.kind == k].sum()) for k, name in enumerate(KIND_NAMES)}

    @property
    def freeform(self) -> bool:
        """True if any steep or shallow freeform surface is there to finish with a ball."""
        return bool(np.isin(self.kind, (STEEP, SHALLOW)).any())

    def footprint(self, kinds: tuple[int, ...]) -> BaseGeometry:
        """XY union of the triangles of ``kinds`` (degenerate projections of walls grown a hair)."""
        key = tuple(kinds)
        if key not in self._shapes:
            self._shapes[key] = self._union(key)
        return self._shapes[key]

    def _union(self, kinds: tuple[int, ...]) -> BaseGeometry:
        sel = self.triangles[np.isin(self.kind, kinds)]
        if not len(sel):
            return shapely.Polygon()
        rings = np.concatenate([sel[:, :, :2], sel[:, :1, :2]], axis=1)
        polys = shapely.polygons(rings)
        # A vertical wall projects onto a segment: a polygon of no area. Its edges still count.
        flat = shapely.area(polys) < 1e-9
        if flat.any():
            polys[flat] = shapely.buffer(shapely.linestrings(rings[flat]), 1e-3, quad_segs=1)
        return shapely.union_all(shapely.make_valid(polys))

    def near(self, kinds: tuple[int, ...], reach: float):
        """``inside(xy) -> (m,) bool``: points within ``reach`` [mm] of the XY footprint of ``kinds``."""
        area = self.footprint(kinds)
        if area.is_empty:
            return lambda xy: np.zeros(len(np.asarray(xy).reshape(-1, 2)), dtype=bool)
        key = (tuple(kinds), float(reach))
        if key not in self._shapes:
            grown = area.buffer(reach, quad_segs=4)
            shapely.prepare(grown)
            self._shapes[key] = grown
        grown = self._shapes[key]

        def inside(xy: np.ndarray) -> np.ndarray:
            xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
            return shapely.contains_xy(grown, xy[:, 0], xy[:, 1])

        return inside

    def summary(self) -> dict:
        """JSON-ready: area per kind [mm^2] and the flat levels [mm]."""
        return {"area_mm2": {k: round(v, 1) for k, v in self.areas().items()},
                "flat_z_mm": [round(float(z), 3) for z in self.flat_z]}


def classify_faces(part: trimesh.Trimesh, options: FaceOptions = FaceOptions()) -> FaceClasses:
    """The class of every triangle of ``part`` (module docstring).

    Parameters
    ----------
    part : trimesh.Trimesh
        Part in work coordinates [mm]; normals point out of the material.
    options : FaceOptions

    Returns
    -------
    FaceClasses
    """
    tri = np.asarray(part.triangles, dtype=np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1)
    area = 0.5 * length
    with np.errstate(invalid="ignore", divide="ignore"):
        nz = np.where(length > 0, n[:, 2] / length, 0.0)
    kind = np.full(len(tri), HIDDEN, dtype=np.int8)
    flat = nz >= math.cos(math.radians(options.flat_angle))
    wall = np.abs(nz) <= math.sin(math.radians(options.wall_angle))
    up = (nz > 0) & ~flat & ~wall
    steep = up & (nz < math.cos(math.radians(options.steep_angle)))
    kind[flat], kind[wall], kind[steep], kind[up & ~steep] = FLAT, WALL, STEEP, SHALLOW
    z = np.round(tri[:, :, 2].mean(axis=1), _Z_DECIMALS)
    flat_z, inverse = np.unique(z[flat], return_inverse=True)
    order = np.argsort(-flat_z)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    level = np.full(len(tri), -1, dtype=np.int64)
    level[flat] = rank[inverse]
    for a in (kind, area, level, tri):
        a.setflags(write=False)
    flat_z = flat_z[order]
    flat_z.setflags(write=False)
    return FaceClasses(kind=kind, area=area, flat_z=flat_z, flat_level=level, triangles=tri)
