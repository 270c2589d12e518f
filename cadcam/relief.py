"""Reliefs: open surfaces machined from above, as a 3-axis drop-cutter sees them.

A mesh that is not a closed solid can still be a part: a carved relief with open sides, a
terrain sheet with no sides and no bottom, a few sheets touching at non-manifold edges. A
3-axis cutter coming from above needs only the *upper envelope* of the triangles over their
*footprint* (the union of their projections on XY), not a closed shell. This module

* judges whether an open mesh is such a surface (:func:`judge_surface`, called by
  :func:`cadcam.mesh.load_part`), refusing with the failed test and its figure what has no
  surface to machine;
* places it in a block (:func:`relief_setup`): an ordinary :class:`~cadcam.model.Setup` whose
  stock runs from the surface's lowest point less a floor up to its top plus the top margin;
* gives the planner the surface it machines against (:func:`machining_surface`: the triangles
  turned to face up, on a base plane at the surface's lowest point, so nothing outside the
  footprint is cut below the relief) and the :class:`Boundary` the tool stays within.

Roughing, finishing, the rapid checks, verify and the setup sheet all use these same
triangles and boundary.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import shapely
import shapely.affinity
import shapely.errors
import trimesh
from scipy import ndimage
from shapely.geometry import Polygon
from shapely.geometry.base import BaseGeometry

from cadcam.heightmap import Grid, upper_envelope
from cadcam.model import Setup, ViseJaws, WorkOrigin
from cadcam.setup import StockMargins, make_setup
from factory.core.errors import MeshError, SetupError

if TYPE_CHECKING:
    from cadcam.stock import Simulation

log = logging.getLogger(__name__)

BoundaryMode = Literal["inside", "on", "outside"]
BOUNDARY_MODES: tuple[str, ...] = ("inside", "on", "outside")

#: Least share of the triangles that must share an edge with another: below it the mesh is a
#: soup of disjoint triangles, not a sheet.
MIN_SHARED_EDGE_SHARE = 0.5
#: Largest share of the surface's (non-vertical) area that may face down once every shell is
#: turned so that what is seen from above faces up: more is the underside of something.
MAX_FACING_DOWN = 0.5
#: Largest share of the footprint's outline that gaps (holes in the union of the projected
#: triangles, and gaps between pieces narrower than :data:`GAP_CLOSING` of its narrower side)
#: may take: more is scattered pieces, not a surface with a few holes.
MAX_GAP_SHARE = 0.5
#: Gaps between pieces narrower than twice this share of the footprint's narrower side count
#: as gaps in one surface, wider ones separate pieces of work.
GAP_CLOSING = 0.2

#: Deepest a finishing move may cut into what roughing left on a relief [mm] (``PlanOptions.
#: finish_engagement``), and the terrace stepdown that keeps the terraces under it. A relief is
#: shallow surface nearly everywhere, where z-level roughing leaves terraces a stepdown plus the
#: allowance high; the verify lets a finishing tool engage 1 mm, and the planner's stock model,
#: on a coarser grid, must stay clear of that with room to spare.
FINISH_ENGAGEMENT = 0.8
TERRACE_STEPDOWN = 0.4

# Triangles whose normal is this close to horizontal are walls: they add nothing to the footprint.
_WALL_NZ = 1e-9
# Segments of a buffer's quarter circle: the chord error is below 0.2 % of the tool radius.
_QUAD_SEGS = 16


@dataclass(frozen=True)
class SurfaceFound:
    """What intake found in a mesh that is an open surface rather than a closed solid.

    Attributes
    ----------
    boundary_edges : int
        Edges used by one triangle only, after welding.
    shells : int
        Pieces of the mesh connected through shared edges (non-manifold ones included).
    footprint_mm : (float, float)
        Extent of the footprint along X and Y [mm].
    facing_down : float
        Share of the non-vertical area facing down after orientation, in [0, 1].
    gaps : float
        Share of the footprint's outline not covered by any triangle, in [0, 1].
    footprint : shapely geometry
        The union of the projected triangles, in the file's XY axes [mm].
    """

    boundary_edges: int
    shells: int
    footprint_mm: tuple[float, float]
    facing_down: float
    gaps: float
    footprint: BaseGeometry

    def describe(self) -> str:
        """One line for the plan summary."""
        return (f"open surface, machined from above as a relief: {self.boundary_edges} boundary edges, "
                f"{self.shells} shell{'s' if self.shells != 1 else ''}, "
                f"footprint {self.footprint_mm[0]:.1f} \u00d7 {self.footprint_mm[1]:.1f} mm")

    def to_dict(self) -> dict[str, Any]:
        return {"boundary_edges": self.boundary_edges, "shells": self.shells,
                "footprint_mm": [round(v, 3) for v in self.footprint_mm],
                "facing_down": round(self.facing_down, 4), "gaps": round(self.gaps, 4)}


def _edge_groups(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face-edge (3 per face, in face order) its undirected edge id, and each edge's use count."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    if len(e) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # One integer per edge orders edges as np.unique(axis=0) does, several times faster.
    span = np.int64(e.max()) + 1
    _, inverse, counts = np.unique(e[:, 0] * span + e[:, 1], return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def _shells(faces: np.ndarray, edge_of: np.ndarray, n_edges: int) -> tuple[int, np.ndarray]:
    """Connected pieces through shared edges: their number and each face's label."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(faces)
    face_of = np.repeat(np.arange(n), 3)
    # Faces and edges as one bipartite graph: faces sharing any edge (manifold or not) join.
    graph = coo_matrix((np.ones(len(edge_of)), (face_of, n + edge_of)), shape=(n + n_edges, n + n_edges))
    _, label = connected_components(graph, directed=False)
    face_label = label[:n]
    _, face_label = np.unique(face_label, return_inverse=True)
    return int(face_label.max()) + 1, face_label


def _seen_from_above(tri: np.ndarray, nz: np.ndarray) -> np.ndarray:
    """(m,) bool: the triangle's centre lies on the upper envelope of all triangles."""
    from cadcam.dropcutter import build_index, drop_profile

    extent = float(np.ptp(tri.reshape(-1, 3), axis=0).max())
    centre = tri.mean(axis=1)
    flat = np.abs(nz) > _WALL_NZ
    seen = np.zeros(len(tri), dtype=bool)
    if not flat.any():
        return seen
    # A ball far smaller than any feature reads the envelope height; its tip rides at most
    # r (1/cos - 1) above a sloped facet, inside the tolerance below.
    r = 1e-7 * extent
    env = drop_profile(build_index(tri), r, r, centre[flat, :2], float(tri[:, :, 2].min()) - 1.0)
    seen[flat] = centre[flat, 2] >= env - 1e-5 * extent
    return seen


def footprint(triangles: np.ndarray, shell_of: np.ndarray | None = None) -> BaseGeometry:
    """The union of the triangles' XY projections.

    triangles : (m, 3, 3) float; shell_of : (m,) int, optional, the shell of each triangle.
    A shell whose projections do not overlap (a heightfield sheet) is merged with a fast
    coverage union; one that folds over itself, and the shells together, with a full union.
    """
    tri = np.asarray(triangles, dtype=np.float64)
    xy = tri[:, :, :2]
    a2 = (xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1]) - (xy[:, 1, 1] - xy[:, 0, 1]) * (
        xy[:, 2, 0] - xy[:, 0, 0])
    extent = float(np.ptp(xy.reshape(-1, 2), axis=0).max()) or 1.0
    keep = np.abs(a2) > 1e-12 * extent * extent
    if shell_of is None:
        shell_of = np.zeros(len(tri), dtype=np.int64)
    pieces = []
    for s in np.unique(shell_of[keep]):
        sel = keep & (shell_of == s)
        polys = shapely.polygons(xy[sel])
        total = float(0.5 * np.abs(a2[sel]).sum())
        try:
            merged = shapely.coverage_union_all(polys)
            fast = merged.is_valid and abs(merged.area - total) <= 1e-6 * max(total, 1e-12)
        except shapely.errors.GEOSException:
            fast = False
        if not fast:
            merged = shapely.union_all(polys)  # the shell overlaps itself in XY
        pieces.append(merged)
    if not pieces:
        return Polygon()
    return shapely.union_all(pieces) if len(pieces) > 1 else pieces[0]


def _filled(geom: BaseGeometry) -> BaseGeometry:
    polys = [geom] if isinstance(geom, Polygon) else list(getattr(geom, "geoms", []))
    return shapely.union_all([Polygon(p.exterior) for p in polys if isinstance(p, Polygon) and not p.is_empty])


def check_sheet(faces: np.ndarray, source: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Refuse a soup of disjoint triangles: fewer than :data:`MIN_SHARED_EDGE_SHARE` of them share an
    edge with another. Returns :func:`_edge_groups` of ``faces`` (m, 3) for further use.

    Raises
    ------
    MeshError
        Naming how many triangles share an edge.
    """
    faces = np.asarray(faces, dtype=np.int64)
    n = len(faces)
    edge_of, counts = _edge_groups(faces)
    k = int((counts[edge_of] >= 2).reshape(n, 3).any(axis=1).sum())
    if k < MIN_SHARED_EDGE_SHARE * n:
        raise MeshError(f"disjoint triangles, not a surface: {k} of {n} triangles share an edge with another "
                        f"({k / n:.0%}; a surface needs {MIN_SHARED_EDGE_SHARE:.0%}); nothing to machine",
                        source=source)
    return edge_of, counts


def judge_surface(mesh: trimesh.Trimesh, scale: float = 1.0,
                  source: str | None = None) -> tuple[trimesh.Trimesh, SurfaceFound, list[str]]:
    """Decide whether an open, welded mesh is a surface to machine from above; orient it.

    Tests, in order, each refusing with its figure:

    1. at least :data:`MIN_SHARED_EDGE_SHARE` of the triangles share an edge with another
       (else a soup of disjoint triangles);
    2. once each shell is wound consistently and turned so that what is seen from above
       faces up, at most :data:`MAX_FACING_DOWN` of the non-vertical area faces down (else
       it is the underside of something);
    3. gaps take at most :data:`MAX_GAP_SHARE` of the footprint's outline: the footprint
       closed over gaps narrower than ``2 * GAP_CLOSING`` of its narrower side, holes filled.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Welded, degenerate and duplicate faces removed, not a closed solid; file units.
    scale : float
        File units to mm, for the footprint figures.

    Returns
    -------
    mesh : trimesh.Trimesh
        A new mesh, every shell wound consistently and facing up (file units).
    found : SurfaceFound
    notes : list of str
        What was repaired (winding made consistent, shells turned over).

    Raises
    ------
    MeshError
        A test failed (its message names the test and the figure).
    """
    faces = np.asarray(mesh.faces, dtype=np.int64)
    n = len(faces)
    edge_of, counts = check_sheet(faces, source)
    n_shells, shell_of = _shells(faces, edge_of, len(counts))

    notes: list[str] = []
    out = mesh.copy()
    if not out.is_winding_consistent:
        trimesh.repair.fix_winding(out)
        notes.append("made face winding consistent")
    faces = np.asarray(out.faces, dtype=np.int64).copy()
    tri = np.asarray(out.triangles, dtype=np.float64)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length: twice the area
    area2 = np.linalg.norm(normals, axis=1)
    nz = np.divide(normals[:, 2], area2, out=np.zeros(n), where=area2 > 0)
    seen = _seen_from_above(tri, nz)
    # Each shell votes with the projected area it shows from above: up or down is its top side.
    vote = np.bincount(shell_of, weights=np.where(seen, normals[:, 2], 0.0), minlength=n_shells)
    flip = vote[shell_of] < 0
    if flip.any():
        faces[flip] = faces[flip][:, ::-1]
        nz = np.where(flip, -nz, nz)
        notes.append(f"turned {int(np.count_nonzero(vote < 0))} of {n_shells} shells over to face up")
    out = trimesh.Trimesh(vertices=np.asarray(out.vertices), faces=faces, process=False, validate=False)

    flat = np.abs(nz) > _WALL_NZ
    total = float(area2[flat].sum())
    down = float(area2[flat & (nz < 0)].sum()) / total if total > 0 else 1.0
    if down > MAX_FACING_DOWN:
        raise MeshError(f"surface faces down over {down:.0%} of its area (at most {MAX_FACING_DOWN:.0%}): it is "
                        "seen from below, not from above; nothing to machine from the top", source=source)

    foot = footprint(tri * scale, shell_of)
    x0, y0, x1, y1 = foot.bounds
    d = GAP_CLOSING * min(x1 - x0, y1 - y0)
    outline = shapely.union_all([_filled(foot), _filled(foot.buffer(d, quad_segs=4).buffer(-d, quad_segs=4))])
    gaps = 1.0 - foot.area / outline.area if outline.area > 0 else 1.0
    if gaps > MAX_GAP_SHARE:
        raise MeshError(f"envelope has gaps over {gaps:.0%} of its footprint (at most {MAX_GAP_SHARE:.0%}): "
                        "scattered pieces, not a surface", source=source)
    found = SurfaceFound(boundary_edges=int(np.count_nonzero(counts == 1)), shells=n_shells,
                         footprint_mm=(float(x1 - x0), float(y1 - y0)), facing_down=down, gaps=float(gaps),
                         footprint=foot)
    return out, found, notes


# --------------------------------------------------------------------------- planning


@dataclass(frozen=True)
class ReliefOptions:
    """How a relief is cut into its block.

    Attributes
    ----------
    floor : float
        Stock left under the surface's lowest point [mm], >= 0. Default 2.
    boundary : {"inside", "on", "outside"}
        Where the roughing tool may go relative to the footprint's outline: the whole tool
        inside it, the tool centre on it, or the tool outside it (touching it from outside).
    clearance : float
        How far every later tool stays from the wall of uncut stock the roughing tool leaves
        at the boundary [mm], > 0: a tool running along that wall would rub it with its side.
    """

    floor: float = 2.0
    boundary: BoundaryMode = "inside"
    clearance: float = 0.5

    def to_dict(self) -> dict[str, Any]:
        return {"floor": self.floor, "boundary": self.boundary, "clearance": self.clearance}


@dataclass(frozen=True)
class Boundary:
    """The region a relief's cutter stays within, in work coordinates.

    Attributes
    ----------
    outline : shapely geometry
        The footprint (union of the projected triangles) in work XY [mm].
    mode : {"inside", "on", "outside"}
    """

    outline: BaseGeometry
    mode: BoundaryMode
    clearance: float = 0.5

    def centre_region(self, radius: float) -> BaseGeometry:
        """Where the axis of the roughing tool, of ``radius`` [mm], may go."""
        if self.mode == "on":
            return self.outline
        if self.mode == "inside":
            # Enlarged so that the chords of the polygonal offset stay a full radius inside.
            step = (math.pi / 2) / _QUAD_SEGS
            return self.outline.buffer(-radius / math.cos(step / 2), quad_segs=_QUAD_SEGS)
        return self.outline.buffer(radius, quad_segs=_QUAD_SEGS)

    def cut_region(self, radius: float) -> BaseGeometry:
        """Where the roughing tool, of ``radius`` [mm], removes material: its centre region grown by
        the radius. Beyond it the stock stays whole: a wall up to the stock top."""
        step = (math.pi / 2) / _QUAD_SEGS
        return self.centre_region(radius).buffer(radius / math.cos(step / 2), quad_segs=_QUAD_SEGS)

    def after_roughing(self, rough_radius: float) -> Callable[[float], BaseGeometry]:
        """``within(radius)`` for every tool after the roughing tool of ``rough_radius`` [mm]: its
        axis stays ``radius + clearance`` inside the roughing tool's cut region, off the wall."""
        cut = self.cut_region(rough_radius)
        step = (math.pi / 2) / _QUAD_SEGS

        def within(radius: float) -> BaseGeometry:
            return cut.buffer(-(radius + self.clearance) / math.cos(step / 2), quad_segs=_QUAD_SEGS)

        return within

    def to_dict(self) -> dict[str, Any]:
        x0, y0, x1, y1 = self.outline.bounds
        return {"mode": self.mode, "area_mm2": round(float(self.outline.area), 1),
                "bounds_mm": [round(v, 3) for v in (x0, y0, x1, y1)]}


def block_margins(found: SurfaceFound, margins: StockMargins, gripped: float | None) -> StockMargins:
    """The margins of a relief's block: ``margins``, less across the jaws where the gripper needs it.

    A relief leaves the machine in its block, and the rim beyond its footprint is stock op 1 never
    cuts. Along the jaws (work X) the rim is what lets a blank seated off along them still hold the
    whole relief (:mod:`robotprog.seat`); across them the jaws square the blank up, and the rim holds
    nothing. The robot's fingers close across the block's narrower side: where that is work Y and the
    block with its rim is wider than ``gripped`` [mm] (the widest blank the gripper opens its fingers'
    clearance beside), the rim across Y is trimmed to what leaves that clearance, down to none: the
    footprint's own width, a flat bar that wide. A block the fingers would close across X, or one
    that leaves the clearance already, keeps ``margins``; ``gripped`` None (no cell): ``margins``.
    """
    fx, fy = (float(v) for v in found.footprint_mm)
    sides = margins.sides_xy
    if gripped is None or fy + 2 * sides[1] > fx + 2 * sides[0] or fy + 2 * sides[1] <= gripped:
        return margins
    across = max(0.0, (gripped - fy) / 2)
    log.info("relief block: %.1f mm across the jaws, not %.1f: the rim there trimmed to %.2f mm so the gripper "
             "opens its fingers' clearance beside it where it can (it takes %.1f mm with it)",
             fy + 2 * across, fy + 2 * sides[1], across, gripped)
    return dataclasses.replace(margins, across=across)


def relief_setup(
    part: trimesh.Trimesh,
    found: SurfaceFound,
    options: ReliefOptions = ReliefOptions(),
    *,
    stock_size: tuple[float, float, float] | None = None,
    margins: StockMargins = StockMargins(),
    origin: WorkOrigin = "top-front-left",
    material: str = "aluminium",
    safe_height: float = 5.0,
    mesh_scale: float = 1.0,
    jaws: ViseJaws | None = None,
    source: str | None = None,
) -> tuple[Setup, trimesh.Trimesh, Boundary]:
    """Place a relief in a block: the stock around its footprint, from its lowest point less
    ``options.floor`` up to its top plus ``margins.top``.

    The block is sized and placed by :func:`cadcam.setup.make_setup` as if the part filled the
    box from the floor to the surface's top over the footprint, so the setup is an ordinary one.

    Returns
    -------
    setup : Setup
    part_work : trimesh.Trimesh
        The surface in work coordinates [mm] (as loaded, moved).
    boundary : Boundary
        Its footprint in work XY and ``options.boundary``.

    Raises
    ------
    SetupError
        A negative or non-finite floor, an unknown boundary mode, or what :func:`make_setup` raises.
    """
    if not (math.isfinite(options.floor) and options.floor >= 0):
        raise SetupError(f"relief floor must be >= 0 mm, got {options.floor}", source=source)
    if not (math.isfinite(options.clearance) and options.clearance > 0):
        raise SetupError(f"relief clearance must be > 0 mm, got {options.clearance}", source=source)
    if options.boundary not in BOUNDARY_MODES:
        raise SetupError(f"unknown boundary mode {options.boundary!r}: expected one of {', '.join(BOUNDARY_MODES)}",
                         source=source)
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    fx0, fy0, fx1, fy1 = found.footprint.bounds
    block = trimesh.creation.box(bounds=[[fx0, fy0, lo[2] - options.floor], [fx1, fy1, hi[2]]])
    setup, _ = make_setup(block, stock_size=stock_size, margins=margins, origin=origin, material=material,
                          safe_height=safe_height, mesh_scale=mesh_scale, jaws=jaws, source=source)
    part_work = part.copy()
    part_work.apply_transform(setup.transform_mesh_to_work)
    shift = setup.transform_mesh_to_work[:3, 3]
    outline = shapely.affinity.translate(found.footprint, xoff=float(shift[0]), yoff=float(shift[1]))
    return setup, part_work, Boundary(outline=outline, mode=options.boundary, clearance=options.clearance)


def machining_surface(part_work: trimesh.Trimesh, setup: Setup) -> trimesh.Trimesh:
    """The triangles the planner and verify cut against: the surface, every triangle turned to
    face up, on a base plane at its lowest point spanning the stock.

    Facing up makes each triangle cast its shadow for z-level roughing (which reads the
    upward faces); the base plane keeps every tool from cutting below the relief's lowest
    point outside its footprint (what is outside the boundary is the boundary's business).
    """
    tri = np.asarray(part_work.triangles, dtype=np.float64).copy()
    nz = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
    tri[nz < 0] = tri[nz < 0][:, ::-1]
    z = float(tri[:, :, 2].min())
    lo, hi = np.asarray(setup.stock_min, dtype=np.float64), np.asarray(setup.stock_max, dtype=np.float64)
    grow = float(np.ptp([lo[:2], hi[:2]], axis=0).max())  # beyond any tool's reach over the stock edge
    x0, y0, x1, y1 = lo[0] - grow, lo[1] - grow, hi[0] + grow, hi[1] + grow
    base = np.array([[[x0, y0, z], [x1, y0, z], [x1, y1, z]], [[x0, y0, z], [x1, y1, z], [x0, y1, z]]])
    allt = np.concatenate([tri, base])  # the base last: surface_footprint leaves it out
    return trimesh.Trimesh(vertices=allt.reshape(-1, 3), faces=np.arange(3 * len(allt)).reshape(-1, 3),
                           process=False, validate=False)


def own_surface(machining: trimesh.Trimesh) -> trimesh.Trimesh:
    """The relief's own faces of :func:`machining_surface`, without the base plane laid round them
    (its last two triangles, which span far past the stock)."""
    return trimesh.Trimesh(vertices=machining.vertices, faces=machining.faces[:-_BASE_TRIANGLES], process=False,
                           validate=False)


def surface_under(machining_triangles: np.ndarray, grid: Grid) -> np.ndarray:
    """(ny, nx) bool: the grid points under the relief's own surface of :func:`machining_surface`'s
    triangles; the others lie under the base plane round it, outside the relief."""
    return np.isfinite(upper_envelope(np.asarray(machining_triangles)[:-_BASE_TRIANGLES], grid))


def surface_footprint(machining_triangles: np.ndarray, grid: Grid) -> np.ndarray:
    """(ny, nx) bool: the grid points well under the relief's own surface, not under the base plane
    :func:`machining_surface` lays round it, where the uncut rim outside the boundary stands.

    A grid point counts when its eight neighbours are under the surface too, as verify measures
    what is left against the part round each point: on the surface's edge the rim's wall stands
    beside the point, and the point would show the rim's height."""
    under = surface_under(machining_triangles, grid)
    return ndimage.binary_erosion(under, structure=np.ones((3, 3), dtype=bool), border_value=0)


#: Triangles of the base plane :func:`machining_surface` appends to the surface.
_BASE_TRIANGLES = 2


def block_corners(setup: Setup) -> np.ndarray:
    """(8, 3) float: the stock block's corners in the mesh file's axes and units.

    What leaves the machine is the block with the relief cut into its top: the robot grips and
    places the block, not the surface's own (thin) box.
    """
    lo, hi = np.asarray(setup.stock_min, dtype=np.float64), np.asarray(setup.stock_max, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return (corners - np.asarray(setup.transform_mesh_to_work)[:3, 3]) / float(setup.mesh_scale)


def clip_chains(chains: list[np.ndarray], region: BaseGeometry, iterations: int = 30) -> list[np.ndarray]:
    """Cut chains of tool positions where they leave ``region`` (tool axis positions in XY).

    chains : list of (n, 3) float [mm]. A move leaving or entering the region is cut at the
    crossing, found by bisection along the move (so the new end lies on the original move,
    inside the region). A move with both ends outside that crosses the region keeps the part
    inside (a finishing line over a flat is one move from edge to edge: op 2's raster across a
    plate between the jaws' keep-outs was dropped whole). Pieces of fewer than two points are dropped.
    """
    if region.is_empty:
        return []
    shapely.prepare(region)
    out: list[np.ndarray] = []
    for c in chains:
        inside = shapely.contains_xy(region, c[:, 0], c[:, 1])
        if not inside.all():
            c, inside = _through_moves(c, inside, region)
        if inside.all():
            out.append(c)
            continue
        if not inside.any():
            continue
        # Runs of inside points, each grown at its ends to the crossing on the adjoining move.
        d = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        for s, e in zip(starts, stops):
            piece = [c[s:e]]
            if s > 0:
                piece.insert(0, _crossing(region, c[s], c[s - 1], iterations)[None])
            if e < len(c):
                piece.append(_crossing(region, c[e - 1], c[e], iterations)[None])
            p = np.concatenate(piece)
            if len(p) >= 2:
                out.append(p)
    return out


def _through_moves(c: np.ndarray, inside: np.ndarray, region: BaseGeometry) -> tuple[np.ndarray, np.ndarray]:
    """``c`` ((n, 3) [mm]) with a point inside ``region`` added on each move whose ends both lie outside but which
    passes through it, one per piece it passes through, and a point outside between two pieces; with its
    ``inside`` flags. The runs of inside points then find each piece's crossings by bisection."""
    out = np.flatnonzero(~inside[:-1] & ~inside[1:])
    if not len(out):
        return c, inside
    lines = shapely.linestrings(np.stack([c[out, :2], c[out + 1, :2]], axis=1))
    hit = out[shapely.intersects(lines, region) & ~shapely.touches(lines, region)]
    if not len(hit):
        return c, inside
    points, flags = [c[:hit[0] + 1]], [inside[:hit[0] + 1]]
    for n, k in enumerate(hit):
        a, b = c[k], c[k + 1]
        length = float(np.hypot(*(b[:2] - a[:2])))
        along = lambda q: float(np.hypot(*(np.asarray(q) - a[:2]))) / length  # noqa: E731
        cut = shapely.intersection(shapely.linestrings([a[:2], b[:2]]), region)
        pieces = sorted(tuple(sorted((along(g.coords[0]), along(g.coords[-1]))))
                        for g in getattr(cut, "geoms", [cut]) if g.geom_type == "LineString" and g.length > 1e-9)
        ts: list[float] = []
        fs: list[bool] = []
        for i, (t0, t1) in enumerate(pieces):
            if i:  # outside between two pieces
                ts.append(0.5 * (pieces[i - 1][1] + t0))
                fs.append(False)
            ts.append(0.5 * (t0 + t1))
            fs.append(True)
        if ts:
            t = np.asarray(ts)[:, None]
            points.append(a + t * (b - a))
            flags.append(np.asarray(fs))
        end = hit[n + 1] + 1 if n + 1 < len(hit) else len(c)
        points.append(c[k + 1:end])
        flags.append(inside[k + 1:end])
    return np.concatenate(points), np.concatenate(flags)


def _crossing(region: BaseGeometry, inside: np.ndarray, outside: np.ndarray, iterations: int) -> np.ndarray:
    """The point on the move from ``inside`` to ``outside`` last inside ``region`` (by bisection)."""
    a, b = 0.0, 1.0
    for _ in range(iterations):
        m = 0.5 * (a + b)
        p = inside + m * (outside - inside)
        if shapely.contains_xy(region, p[0], p[1]):
            a = m
        else:
            b = m
    return inside + a * (outside - inside)


def keep_outside(sim: Simulation, boundary: Boundary, radius: float) -> Simulation:
    """``sim`` with the stock outside the roughing tool's cut region (tool ``radius`` [mm]) taken
    as part: it is not to be cut, so it is no excess to remove and nothing unreached."""
    g = sim.grid
    x, y = np.meshgrid(g.xs, g.ys)
    region = boundary.cut_region(radius)
    shapely.prepare(region)
    outside = ~shapely.contains_xy(region, x, y)
    part = np.where(outside, np.maximum(np.where(np.isfinite(sim.part_top), sim.part_top, -np.inf), sim.stock_top),
                    sim.part_top)
    part.setflags(write=False)
    return dataclasses.replace(sim, part_top=part)
