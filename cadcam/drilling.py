"""Round holes: find them in the part, drill them (spot, then G81 or G83), or helix them to size.

A machinist drills a round hole with a drill of its size rather than pocketing it: a spot
drill centres it, a twist drill takes it to depth in one feed (``G81``) or, deeper than
about three diameters, in pecks that clear the chips (``G83``). A hole no drill in the
library matches, too small for the roughing end mill to enter, is cut to size by helical
interpolation (``G2``/``G3`` with Z) with a smaller flat end mill, after a narrower drill has taken
out its middle where that is quicker.

:func:`find_holes` reads the holes from the mesh: connected bands of vertical faces whose
vertices lie on a circle, facing its axis, open to the top (nothing of the part over the
bore) and closed all round. :func:`plan_holes` matches each with the library and returns
the operations, whose points are the motion a controller makes (what the stock model and
grbl see); drilling operations carry their :class:`~cadcam.model.DrillCycle` for posts
with canned cycles (:func:`cycle_moves` expands one, as LinuxCNC moves it).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import asdict, dataclass, field
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import trimesh

from cadcam.gcode import PECK_CLEARANCE
from cadcam.heightmap import Grid, upper_envelope
from cadcam.model import CuttingData, DrillCycle, Motion, Operation, Setup, Tool
from cadcam.post import PostOptions, operation_move_seconds
from cadcam.restlinks import nearest_tour
from cadcam.tools import ToolLibrary, internal_arc_feed

if TYPE_CHECKING:  # (detection needs no shapely: imported only where a keep-out is used)
    from cadcam.workholding import Region

log = logging.getLogger(__name__)

HoleBottom = Literal["through", "flat", "conical"]


@dataclass(frozen=True)
class Countersink:
    """A cone widening a hole's mouth: ``diameter`` at its top [mm], included ``angle`` [deg], ``top_z`` [mm]."""

    diameter: float
    angle: float
    top_z: float

    def tip_z(self) -> float:
        """Where the cone, continued, meets the hole's axis [mm]: how deep a spot drill of its angle goes."""
        return self.top_z - self.diameter / 2 / math.tan(math.radians(self.angle) / 2)


@dataclass(frozen=True)
class Hole:
    """A cylindrical vertical hole of the part, in work coordinates.

    Attributes
    ----------
    x, y : float
        Axis position [mm].
    diameter : float
        Diameter of the circle through the wall's vertices [mm] (the nominal size).
    inscribed : float
        Diameter of the largest circle inside the wall's facets [mm]: a tool this wide
        cuts nothing of a tessellated wall.
    top_z : float
        Z where the wall starts [mm].
    bottom_z : float
        Z where the wall ends [mm]: the floor of a flat hole, where the cone of a conical
        one starts, the part's underside for a through hole.
    tip_z : float
        Lowest point of the hole [mm]: ``bottom_z`` for flat and through holes, the
        cone's tip for a conical bottom.
    bottom : {"through", "flat", "conical"}
    countersink : Countersink or None
        The cone at its mouth (known from a STEP file's B-rep), cut by the spot drill when its
        angle is the spot drill's; None: none known.
    """

    x: float
    y: float
    diameter: float
    inscribed: float
    top_z: float
    bottom_z: float
    tip_z: float
    bottom: HoleBottom
    countersink: Countersink | None = None

    @property
    def depth(self) -> float:
        """From the top of the wall to the lowest point [mm]."""
        return self.top_z - self.tip_z

    def describe(self) -> str:
        kind = {"through": "through hole", "flat": "flat-bottom hole", "conical": "drilled (conical) hole"}[self.bottom]
        return f"{self.diameter:.2f} mm {kind} at X{self.x:.2f} Y{self.y:.2f}, {self.depth:.2f} mm deep"

    def to_dict(self) -> dict[str, Any]:
        out = {"x": self.x, "y": self.y, "diameter": self.diameter, "top_z": self.top_z,
               "bottom_z": self.bottom_z, "tip_z": self.tip_z, "bottom": self.bottom}
        if self.countersink is not None:
            out["countersink"] = asdict(self.countersink)
        return out


@dataclass(frozen=True)
class DrillingOptions:
    """How round holes are found and cut.

    Attributes
    ----------
    fit_tolerance : float
        The wall's vertices may lie this far off the fitted circle [mm].
    drill_undersize : float
        A drill up to this much narrower than the hole's inscribed diameter drills it to
        size [mm] (a drilled hole comes out a little over the drill's size).
    drill_oversize : float
        A drill up to this much wider than the inscribed diameter still drills it to size
        [mm]: the facets of a tessellated wall lie inside the nominal circle.
    peck_ratio : float
        Holes deeper than this many drill diameters are peck drilled (G83) [D].
    breakthrough : float
        A through hole's drill goes this far past its full diameter below the part [mm], on into
        the holding allowance op 2 faces off (to :data:`POINT_CLEARANCE_MM` over the stock's bottom);
        never below ``Setup.floor_z`` where there is no holding allowance.
    spot : bool
        Spot drill the drilled holes that need it first (when the library has a spot drill; ``spot_depth``),
        but a bore's pilot (``predrill``), which the helix takes to size and place.
    spot_depth : float
        A hole drilled to size is spotted first only where it is deeper than this many drill diameters from
        the stock top [D], or where the spot cuts its countersink: the library's drills are solid carbide, rigid
        and self-centring on the flat stock top, and walk only in deep holes (makers put the depth past which
        they want a spot at 5 to 8 D: Cutting Tool Engineering, June 2012, "Starter kit"; and spotting
        before a carbide drill mostly costs a tool change, or its corners where the spot's cone is narrower
        than its point: CTE, "Get it straight"). 0: every drilled hole.
    spot_share : float
        Diameter of the spot's cone at the surface, as a share of the drill's [1]; below 1
        so the drill removes it all.
    helix_angle : float
        Ramp angle of a helix along its path [deg].
    helix_share : float
        An end mill helixes a hole when the helix's path is at least this share of the
        tool diameter across (the tool must be narrower than ``D / (1 + share)``) [1].
    predrill : bool
        Drill a bore the end mill helixes in one first, with the widest drill the end mill goes
        down inside (:data:`PREDRILL_ROOM`); the helices then start where the drill's point begins,
        each taking a ring of the wall the mill may take at its full flute length
        (:func:`predrilled_radii`). Only where the holes' operations take less time so (tool changes
        counted).
    """

    fit_tolerance: float = 0.02
    drill_undersize: float = 0.05
    drill_oversize: float = 0.016
    peck_ratio: float = 3.0
    breakthrough: float = 0.5
    spot: bool = True
    spot_depth: float = 5.0
    spot_share: float = 0.8
    helix_angle: float = 3.0
    helix_share: float = 0.3
    predrill: bool = True


@dataclass(frozen=True)
class HolePlan:
    """What :func:`plan_holes` decided.

    Attributes
    ----------
    holes : tuple of Hole
        Every hole found.
    operations : tuple of Operation
        Spot drilling, drilling and helical operations, in cutting order.
    drilled, helixed : tuple of Hole
        Holes taken to depth by a drill (to size, or undersize where ``undersize``) and by a helix.
    predrilled : tuple of Hole
        Helixed holes a narrower drill took the middle of first (``DrillingOptions.predrill``).
    undersize : tuple of Hole
        Drilled holes whose drill is narrower than the hole: rest roughing takes the rest.
    left : tuple of Hole
        Holes left to roughing (it can enter them) or to nothing in the library.
    """

    holes: tuple[Hole, ...]
    operations: tuple[Operation, ...]
    drilled: tuple[Hole, ...]
    helixed: tuple[Hole, ...]
    undersize: tuple[Hole, ...]
    left: tuple[Hole, ...]
    predrilled: tuple[Hole, ...] = ()

    def cut_at(self, z: float):  # -> shapely geometry (imported here only: detection needs no shapely)
        """The XY area [mm] of the holes cut to size (drilled, not undersize, or helixed) down to level ``z`` [mm]
        (a through hole: to the breakthrough below the part, so at every level)."""
        import shapely
        from shapely.geometry import Point

        undersize = set(self.undersize)
        disks = [Point(h.x, h.y).buffer(h.inscribed / 2, quad_segs=16) for h in (*self.drilled, *self.helixed)
                 if h not in undersize and (h.bottom == "through" or h.bottom_z <= z + 1e-9)]
        return shapely.union_all(disks)

    def to_dict(self) -> dict[str, Any]:
        return {k: [h.to_dict() for h in getattr(self, k)]
                for k in ("holes", "drilled", "helixed", "undersize", "left", "predrilled")}


# --------------------------------------------------------------------------- detection

#: A countersink's angle is the spot drill's to this [deg] (an 82 deg inch countersink is not a 90 deg spot).
_SAME_ANGLE = 0.5

#: A face is a wall when its normal is within this of horizontal (sine of the tilt).
_VERTICAL = 1e-3
#: Neighbouring wall facets of one bore turn by less than this [rad] (a 12-gon turns 30 deg).
_MAX_TURN = math.radians(31.0)


def find_holes(part: trimesh.Trimesh, options: DrillingOptions = DrillingOptions()) -> tuple[Hole, ...]:
    """The cylindrical vertical holes of a part in work coordinates, open to the top.

    Parameters
    ----------
    part : trimesh.Trimesh
        Watertight part mesh in work coordinates [mm], outward normals.
    options : DrillingOptions

    Returns
    -------
    tuple of Hole
        Sorted by X, then Y, then top Z. A counterbored hole gives two: the counterbore
        and the bore below it.
    """
    normals = np.asarray(part.face_normals)
    wall = np.abs(normals[:, 2]) < _VERTICAL
    if not wall.any():
        return ()
    adj = np.asarray(part.face_adjacency)
    angles = np.asarray(part.face_adjacency_angles)
    keep = wall[adj[:, 0]] & wall[adj[:, 1]] & (angles < _MAX_TURN)
    groups = trimesh.graph.connected_components(adj[keep], nodes=np.flatnonzero(wall), min_len=3)
    tri = np.asarray(part.triangles)
    found = []
    for faces in groups:
        hole = _hole_from_wall(part, tri, normals, np.asarray(faces), options)
        if hole is not None:
            found.append(hole)
    return tuple(sorted(found, key=lambda h: (round(h.x, 6), round(h.y, 6), -h.top_z)))


def _hole_from_wall(part, tri, normals, faces, options: DrillingOptions) -> Hole | None:
    """The hole a band of wall facets bounds; None when the band is no full round bore."""
    v = tri[faces].reshape(-1, 3)
    xy = v[:, :2]
    # Algebraic circle fit: x^2 + y^2 = 2 a x + 2 b y + c.
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    rhs = (xy * xy).sum(axis=1)
    sol, *_ = np.linalg.lstsq(A, rhs, rcond=None)
    c = sol[:2]
    r2 = sol[2] + c @ c
    if not r2 > 0:
        return None
    r = math.sqrt(r2)
    d = np.hypot(*(xy - c).T)
    if np.abs(d - r).max() > options.fit_tolerance:
        return None
    # Facing the axis (a bore, not a boss), and closed all round.
    mid = tri[faces].mean(axis=1)[:, :2]
    n = normals[faces, :2]
    if ((c - mid) * n).sum(axis=1).min() <= 0:
        return None
    ang = np.sort(np.arctan2(xy[:, 1] - c[1], xy[:, 0] - c[0]))
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * math.pi]))
    if gaps.max() > math.radians(60.0):
        return None
    inscribed = float(((mid - c) * -n).sum(axis=1).min())  # distance from the axis to the nearest facet plane
    top, bottom = float(v[:, 2].max()), float(v[:, 2].min())
    # Nothing of the part over the bore above its bottom: sample the inscribed disk.
    reach = 0.98 * inscribed
    cell = max(reach / 8, 1e-3)
    k = int(math.ceil(reach / cell))
    grid = Grid(x0=float(c[0]) - k * cell, y0=float(c[1]) - k * cell, cell=cell, nx=2 * k + 1, ny=2 * k + 1)
    near = np.all(tri[:, :, :2].min(axis=1) <= c + reach, axis=1) & np.all(tri[:, :, :2].max(axis=1) >= c - reach, axis=1)
    top_map = upper_envelope(tri[near], grid)
    gx, gy = np.meshgrid(grid.xs - c[0], grid.ys - c[1])
    disk = np.hypot(gx, gy) <= reach
    inside = top_map[disk]
    tol = 1e-6 * max(1.0, abs(bottom))
    if np.isfinite(inside).any() and inside[np.isfinite(inside)].max() > bottom + max(tol, 1e-4):
        return None
    centre = top_map[k, k]
    if not np.isfinite(centre):
        kind: HoleBottom = "through"
        tip = bottom
        if np.isfinite(inside).any():
            return None  # part partly under the bore: no simple through hole
    elif centre < bottom - 0.01:
        kind, tip = "conical", float(centre)
    else:
        kind, tip = "flat", bottom
    if top - tip <= 1e-3:
        return None
    return Hole(x=float(c[0]), y=float(c[1]), diameter=2 * r, inscribed=2 * inscribed, top_z=top,
                bottom_z=bottom, tip_z=tip, bottom=kind)


# --------------------------------------------------------------------------- cycles


def cycle_moves(cycle: DrillCycle) -> tuple[np.ndarray, np.ndarray]:
    """The motion of a canned cycle, as LinuxCNC makes it, from the initial level over the first hole.

    Over each hole: rapid across at the higher of the current Z and the retract level, down to
    the R plane, feed to the hole's Z (G83: in pecks of ``peck``, rapid out to R after each
    and back down to :data:`cadcam.gcode.PECK_CLEARANCE` above the last depth), rapid out
    to R (``retract == "r"``, G99) or to the initial level (G98).

    Returns
    -------
    points : (n, 3) float
        Tool tip positions [mm]; ``points[0]`` is the initial level over the first hole.
    motion : (n,) int8
        :class:`Motion` of the move ending at each point (CUT for the feeds).
    """
    r = cycle.r_plane
    clear = r if cycle.retract == "r" else max(cycle.initial_z, r)
    h0 = cycle.holes[0]
    pts: list[tuple[float, float, float]] = [(h0[0], h0[1], cycle.initial_z)]
    mot: list[int] = [Motion.RAPID]

    def go(x: float, y: float, z: float, m: int) -> None:
        if (x, y, z) != pts[-1]:
            pts.append((x, y, z))
            mot.append(m)

    z = cycle.initial_z
    for x, y, bottom in cycle.holes.tolist():
        go(x, y, max(z, clear), Motion.RAPID)
        go(x, y, r, Motion.RAPID)
        if cycle.code == 81:
            go(x, y, bottom, Motion.CUT)
        else:
            depth = r
            while depth > bottom:
                if depth < r:
                    go(x, y, r, Motion.RAPID)
                    go(x, y, depth + PECK_CLEARANCE, Motion.RAPID)
                depth -= cycle.peck
                if depth < bottom + 1e-9:
                    depth = bottom
                go(x, y, depth, Motion.CUT)
        go(x, y, clear, Motion.RAPID)
        z = clear
    return np.array(pts, dtype=np.float64), np.array(mot, dtype=np.int8)


def drill_operation(name: str, kind: str, tool: Tool, cutting: CuttingData, cycle: DrillCycle) -> Operation:
    """A drilling operation: the cycle and its expanded motion."""
    pts, mot = cycle_moves(cycle)
    return Operation(name=name, kind=kind, tool=tool, cutting=cutting, points=pts, motion=mot, cycle=cycle)


def helix_operation(hole: Hole, tool: Tool, cutting: CuttingData, start_z: float, bottom_z: float,
                    options: DrillingOptions, clear_z: float, predrilled: tuple[float, float] | None = None
                    ) -> Operation:
    """Helical interpolation of a hole to its inscribed size with an end mill.

    Climb milling (counter-clockwise inside a bore, spindle clockwise): down a helix from ``start_z``
    to ``bottom_z`` [mm], a full circle there to cut the ramp's last turn level, to the centre and
    straight up to ``clear_z``. A helix wider than the tool leaves a pin standing in the middle, which
    the move to the centre would take at full width over the whole depth (:func:`helix_radii`):
    narrower helices clear the middle first, each back up to ``start_z`` inside the bore it cut.
    Its pitch and feed are :func:`helix_pitch` and :func:`helix_cutting` (``cutting``: the tool's
    cutting data in the material).

    ``predrilled``: (``from_z``, ``drilled`` [mm]): a drill of radius ``drilled`` took the middle out down to
    ``from_z`` (at its full diameter, at least the tool's and :data:`PREDRILL_ROOM` wider): the tool goes
    down its axis by rapid, out to the first helix on a half circle (no straight move into the wall),
    and each helix (:func:`predrilled_radii`) starts there at ``from_z``, the next one reached the same
    way from where the last ended, after a rapid back up inside the bore it cut. A bore of one helix from
    solid only.
    """
    radii = helix_radii(hole.inscribed / 2 - tool.radius - 0.002, tool.radius)  # a hair inside the facets
    from_z = None if predrilled is None else predrilled[0]
    if predrilled is not None:
        if len(radii) > 1:
            raise ValueError("a predrilled bore is one the end mill helixes in one turn round")
        radii = predrilled_radii(predrilled[1], radii[0], tool)
    pts_parts, mot_parts = [], []
    top = start_z if from_z is None else from_z
    start = 0.0  # where the helix begins round the bore [rad]
    for k, rh in enumerate(radii):
        if from_z is not None:  # from the axis or the last helix's end, a half circle out to this one
            inner = 0.0 if k == 0 else radii[k - 1]
            if k == 0:  # down the drilled hole's axis
                pts_parts.append(np.array([[hole.x, hole.y, start_z], [hole.x, hole.y, from_z]]))
                mot_parts.append([Motion.RAPID, Motion.RAPID])
            else:  # back up inside the bore the last helix cut
                pts_parts.append(_on_circle(hole, inner, start, from_z)[None])
                mot_parts.append([Motion.RAPID])
            lead = _lead_out(hole, inner, rh, start, from_z)
            pts_parts.append(lead[:-1])
            mot_parts.append(np.full(len(lead) - 1, Motion.CUT))
        pitch = helix_pitch(rh, tool, options.helix_angle)
        turns = max((top - bottom_z) / pitch, 0.0)
        per_turn = 72
        n = max(int(math.ceil(turns * per_turn)), 1)
        theta = start + np.linspace(0.0, 2 * math.pi * turns, n + 1)
        z = np.linspace(top, bottom_z, n + 1)
        helix = np.column_stack([hole.x + rh * np.cos(theta), hole.y + rh * np.sin(theta), z])
        last = theta[-1]
        ring_t = last + np.linspace(0.0, 2 * math.pi, per_turn + 1)[1:]
        ring = np.column_stack([hole.x + rh * np.cos(ring_t), hole.y + rh * np.sin(ring_t),
                                np.full(per_turn, bottom_z)])
        pts_parts += [helix, ring]
        # The first helix starts by a rapid; a wider one after a narrower at the feed, from above its bore.
        mot_parts += [[Motion.RAPID if k == 0 and from_z is None else Motion.CUT], np.full(n, Motion.PLUNGE),
                      np.full(per_turn, Motion.CUT)]
        start = float(ring_t[-1]) if from_z is not None else 0.0
        if k + 1 < len(radii) and from_z is None:
            pts_parts.append(np.array([[ring[-1, 0], ring[-1, 1], start_z]]))
            mot_parts.append([Motion.RAPID])
    out = np.array([[hole.x, hole.y, bottom_z], [hole.x, hole.y, clear_z]])
    pts = np.concatenate([*pts_parts, out])
    mot = np.concatenate([*mot_parts, [Motion.CUT, Motion.RAPID]])
    # a predrilled hole whose drill went as deep as the helix has no turns to make: no zero-length moves
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts, mot = pts[keep], mot[keep]
    return Operation(name=f"helix {hole.diameter:.2f} mm bore", kind="helix", tool=tool,
                     cutting=helix_cutting(cutting, tool, radii), points=pts, motion=mot.astype(np.int8))


def _on_circle(hole: Hole, radius: float, angle: float, z: float) -> np.ndarray:
    """The point ``radius`` [mm] from the hole's axis at ``angle`` [rad] round it, at height ``z`` [mm]."""
    return np.array([hole.x + radius * math.cos(angle), hole.y + radius * math.sin(angle), z])


def _lead_out(hole: Hole, inner: float, outer: float, angle: float, z: float) -> np.ndarray:
    """A half circle at height ``z`` from ``inner`` out to ``outer`` [mm] from the hole's axis, along the
    radius at ``angle`` [rad], meeting the circle of ``outer`` tangentially, counter-clockwise (climb milling):
    (18, 3) points, the last on that circle."""
    u = np.array([math.cos(angle), math.sin(angle)])
    v = np.array([-u[1], u[0]])
    a = np.linspace(math.pi, 2 * math.pi, 19)[1:]
    mid, half = (inner + outer) / 2, (outer - inner) / 2
    xy = np.array([hole.x, hole.y]) + np.outer(mid + half * np.cos(a), u) + np.outer(half * np.sin(a), v)
    return np.column_stack([xy, np.full(len(a), z)])


def predrilled_radii(drilled: float, outer: float, tool: Tool) -> tuple[float, ...]:
    """Radii of the helices [mm] that take a hole drilled to radius ``drilled`` out to a helix of radius ``outer``.

    Each takes a ring of the wall at most :data:`_RING_SHARE` of the tool's deep radial limit wide by its
    engagement (:func:`ring_engagement`; the wall's whole height is a side cut at the flutes' length):
    the widest such ring each time, the last one out to ``outer``.
    """
    limit = _RING_SHARE * tool.deep_radial_limit
    radii: list[float] = []
    inner = drilled
    while ring_engagement(outer + tool.radius, inner, tool.radius) > limit and len(radii) < 16:
        lo, hi = max(inner - tool.radius, 0.0), outer
        for _ in range(60):  # the widest helix whose ring stays within the limit
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ring_engagement(mid + tool.radius, inner, tool.radius) <= limit else (lo, mid)
        radii.append(lo)
        inner = lo + tool.radius
    return (*radii, outer)


def helix_pitch(radius: float, tool: Tool, angle: float) -> float:
    """Depth a bore's helix of ``radius`` [mm] (its centre line) descends per turn [mm].

    The ramp rule (``angle`` [deg] along the centre line, :data:`cadcam.entries.RAMP_ANGLE`),
    and no deeper than the tool's full-width depth (:attr:`~cadcam.model.Tool.full_width_limit`): a
    helix from solid cuts its bottom turn at full width, and Sandvik Coromant sets the pitch of
    circular ramping by the cutter's largest depth of cut (*Heat resistant super alloys* application
    guide, "Circular ramping from solid"). At least 2 % of D, so that a helix near the axis ends.
    """
    pitch = 2 * math.pi * radius * math.tan(math.radians(angle))
    return max(min(pitch, tool.full_width_limit), 0.02 * tool.diameter)


def helix_cutting(cutting: CuttingData, tool: Tool, radii: tuple[float, ...]) -> CuttingData:
    """The feed of a bore's helices [mm/min]: the tool's cutting feed at its edge, at the centre line.

    A helix is a ramp, and ramping is fed as slot milling (Dormer Pramet, milling catalogue
    2021-2022, "Ramping": "when choosing the feed speed, we advise following the recommendation
    given for slot milling"), so the edge takes the library's chip load ``cutting.feed``; the
    controller feeds the centre line, slower on an internal arc (:func:`cadcam.tools.internal_arc_feed`,
    Dh = 2 (r + R)), and the narrowest helix sets the operation's feed. No chip-thinning rise: a
    bore's helix from solid cuts at full width (each wider helix takes 1.5 R more, over D/2).
    The helices, their last circle and the move to the centre all run at it; the spindle is ``cutting``'s.
    """
    feed = min(internal_arc_feed(cutting.feed, tool.diameter, 2 * (r + tool.radius)) for r in radii)
    feed = round(feed, 1)
    return dataclasses.replace(cutting, feed=feed, plunge_feed=feed)


def helix_radii(outer: float, tool_radius: float) -> tuple[float, ...]:
    """Radii of the helices [mm] that take a bore out to a helix of radius ``outer`` and leave no pin.

    A helix of radius ``r`` cuts the ring from ``r - R`` to ``r + R`` (``R`` the tool radius), so
    one wider than the tool leaves a pin of radius ``r - R`` in the middle. Narrower helices come
    first, each at most 1.5 R inside the next (the rings overlap by half a radius), the innermost
    within the tool radius. A bore the tool helixes in one leaves no pin: one radius.
    """
    radii = [outer]
    while radii[0] > tool_radius * (1 + 1e-9):
        radii.insert(0, max(radii[0] - 1.5 * tool_radius, 0.5 * tool_radius))
    return tuple(radii)


# --------------------------------------------------------------------------- planning


def _floor(setup: Setup) -> float:
    """Lowest a tool tip may go [mm]: ``Setup.floor_z`` where the setup has one, else the stock bottom."""
    floor = getattr(setup, "floor_z", None)
    return float(setup.stock_min[2]) if floor is None else float(floor)


#: A through hole's drill point stays this far above the stock's bottom [mm] (the parallels are under it).
POINT_CLEARANCE_MM = 1.0


def _point_floor(setup: Setup, floor: float) -> float:
    """Lowest a through hole's drill point may go [mm]: on into the holding allowance under the part, which
    op 2 faces off, to :data:`POINT_CLEARANCE_MM` over the stock's bottom; ``floor`` where there is none."""
    return min(floor, float(setup.stock_min[2]) + POINT_CLEARANCE_MM)


def _drill_tip(hole: Hole, drill: Tool, options: DrillingOptions, floor: float, point_floor: float) -> float:
    """Lowest the drill's tip goes in ``hole`` [mm], its cone never below the hole's bottom; a through hole's
    never below ``point_floor`` (:func:`_point_floor`), other holes' never below ``floor``."""
    if hole.bottom == "through":
        # The point goes on below the part, so the full diameter breaks through: held at the floor, it would
        # leave a cone of stock in the hole that a rest tool then digs out at full width (issue 34's
        # counterbored plate: the 6 mm end mill 2.9 mm wide below its full-width depth).
        return max(hole.bottom_z - drill.point_length - options.breakthrough, point_floor)
    # Flat: tip on the floor. Conical: the tip of the hole's cone, unless that is steeper
    # than the drill's, whose cone then meets the wall's bottom edge first.
    return max(hole.tip_z, hole.bottom_z - drill.point_slope * drill.radius, floor)


def _reaches(tool: Tool, top: float, tip: float) -> bool:
    """Flutes and stick-out both longer than the depth from the stock top to the tip."""
    return tool.flute_length >= top - tip and tool.length > top - tip


def plan_holes(
    part: trimesh.Trimesh,
    setup: Setup,
    library: ToolLibrary,
    rough_tool: Tool,
    options: DrillingOptions = DrillingOptions(),
    rough_min_helix: float | None = None,
    allowance: float = 0.0,
    holes: tuple[Hole, ...] | None = None,
    within: Region | None = None,
) -> HolePlan:
    """Find the part's round holes and the operations that cut them, before roughing.

    Per hole, in this order of preference:

    1. through or conical-bottom hole, a drill of its size (within ``drill_undersize`` /
       ``drill_oversize`` of the inscribed diameter) that reaches: spot and drill it;
    2. the roughing tool can enter it (``D - 2 allowance - d_rough >= rough_min_helix``):
       left to roughing;
    3. a flat end mill can helix it (narrower than ``D / (1 + helix_share)``, reaching):
       helix it to size (a flat floor stays flat); a through or flat-bottom bore it helixes in one,
       after the widest drill it goes down inside (``DrillingOptions.predrill``) where the holes'
       operations take less time so by the program's clock (:func:`cadcam.post.operation_move_seconds`, tool
       changes at ``PostOptions.tool_change_time``) than with helices from solid;
    4. a drill of its size (a flat-bottom hole no end mill fits): drill, tip on the floor;
       the corner the point leaves goes to rest roughing;
    5. the widest drill narrower than the hole that reaches (through and conical holes):
       drill undersize, rest roughing takes the rest;
    6. nothing: left (the plan's unreached report names the stock left there).

    Drilling happens first, into the uncut block: drills enter at the stock top, the R
    plane is ``setup.clearance`` above it, the cycle starts at ``setup.safe_z`` and
    retracts to R between holes (G99). Holes deeper than ``peck_ratio`` drill diameters
    from R are peck drilled (G83, Q from the library's drilling data).

    Parameters
    ----------
    rough_tool : Tool
        The roughing end mill, to tell which holes it can enter.
    rough_min_helix : float, optional
        Narrowest helix the roughing enters with [mm]; default ``0.3 d_rough``.
    allowance : float
        Stock roughing leaves on walls [mm].
    holes : tuple of Hole, optional
        The holes, exact, when the part came with them (a STEP file's B-rep,
        :mod:`cadcam.features`); None: found in the mesh (:func:`find_holes`).
    within : callable, optional
        ``within(radius)``: where a tool of that radius [mm] may put its axis (the jaws' keep-out,
        :func:`cadcam.workholding.jaw_keepout`). A drill or helix that would leave it is not used:
        the hole goes to the next method, else is left (and its stock reported as unreached).
    """
    holes = find_holes(part, options) if holes is None else holes
    if not holes:
        return HolePlan((), (), (), (), (), ())
    mat = setup.material
    top = float(setup.stock_max[2])
    floor = _floor(setup)
    r_plane = top + float(setup.clearance)
    initial = max(float(setup.safe_z), r_plane)
    drills = library.drills(mat)
    spots = library.spot_drills(mat) if options.spot else ()
    # a long-reach end mill (slower) only for a hole no standard one reaches
    mills = sorted((t for t in library.tools if t.shape == "flat"),
                   key=lambda t: (library.feed_factor(t) < 1.0, -t.diameter, t.number))
    min_helix = 0.3 * rough_tool.diameter if rough_min_helix is None else rough_min_helix
    fits = _fits(within, spots[:1])
    origin = np.array([float(setup.stock_min[0]), float(setup.stock_min[1])])

    def operations(methods: _Methods) -> list[Operation]:
        ops: list[Operation] = []
        spotted = _to_spot(methods, spots[0], library, top, options.spot_depth) if spots else {}
        if spotted:
            ops.append(_spot_operation(spotted, spots[0], library, mat, top, r_plane, initial, origin, options))
        ops += _drill_operations(methods.drilled, library, mat, r_plane, initial, origin, options)
        for h, mill in sorted(methods.helixed, key=lambda hm: (-hm[1].diameter, hm[0].x, hm[0].y)):
            bottom = max(h.bottom_z - (options.breakthrough if h.bottom == "through" else 0.0), floor)
            ops.append(helix_operation(h, mill, library.cutting_data(mill, mat), r_plane, bottom, options, initial,
                                       methods.predrilled.get(h)))
        return ops

    point_floor = _point_floor(setup, floor)
    chosen = _choose_methods(holes, drills, mills, rough_tool, min_helix, allowance, top, floor, point_floor,
                             options, fits)
    ops = operations(chosen)
    if chosen.predrilled:  # drilling first pays only for enough metal: else the helices from solid
        plain = _choose_methods(holes, drills, mills, rough_tool, min_helix, allowance, top, floor, point_floor,
                                dataclasses.replace(options, predrill=False), fits)
        plain_ops = operations(plain)
        if _seconds(plain_ops) <= _seconds(ops):
            chosen, ops = plain, plain_ops
    drilled, helixed = chosen.drilled, chosen.helixed
    spotted = {h for hs in _to_spot(chosen, spots[0], library, top, options.spot_depth).values() for h, _ in hs
               if _spots_countersink(spots[0], h.countersink)} if spots else set()
    for h in holes:
        log.debug("hole: %s", h.describe())
        if h.countersink is not None and h not in spotted:
            log.warning("%s: its countersink %.2f mm x %g deg is left: only a spot drill of its angle, on a "
                        "drilled hole, cuts it", h.describe(), h.countersink.diameter, h.countersink.angle)
    log.info("%d round holes: %d drilled (%d undersize), %d helixed (%d predrilled), %d left to roughing or "
             "unreached", len(holes), sum(len(v) for v in drilled.values()) - len(chosen.predrilled),
             len(chosen.undersize), len(helixed), len(chosen.predrilled), len(chosen.left))
    return HolePlan(
        holes=holes, operations=tuple(ops),
        drilled=tuple(h for hs in drilled.values() for h, _ in hs if h not in chosen.predrilled),
        helixed=tuple(h for h, _ in helixed), undersize=tuple(chosen.undersize), left=tuple(chosen.left),
        predrilled=tuple(h for h, _ in helixed if h in chosen.predrilled),
    )


@dataclass
class _Methods:
    """How :func:`plan_holes` takes each hole, in the order the holes were found.

    ``drilled``: drill number -> (hole, tip height [mm]), to size or undersize, predrilled ones too;
    ``helixed``: (hole, flat end mill); ``undersize``: drilled with a narrower drill (rest roughing
    takes the rest); ``left``: to roughing or to nothing in the library; ``predrilled``: helixed
    hole -> (where its drill's full diameter ends, the drill's radius) [mm]: the helices' start.
    """

    drilled: dict[int, list[tuple[Hole, float]]] = field(default_factory=dict)
    helixed: list[tuple[Hole, Tool]] = field(default_factory=list)
    undersize: list[Hole] = field(default_factory=list)
    left: list[Hole] = field(default_factory=list)
    predrilled: dict[Hole, tuple[float, float]] = field(default_factory=dict)


def _choose_methods(holes: tuple[Hole, ...], drills: tuple[Tool, ...], mills: list[Tool], rough_tool: Tool,
                    min_helix: float, allowance: float, top: float, floor: float, point_floor: float,
                    options: DrillingOptions, fits: Callable[[Hole, Tool], bool] = lambda h, t: True) -> _Methods:
    """Each hole's method, in :func:`plan_holes`' order of preference (``top``: stock top, ``floor``:
    lowest a tool may go, ``point_floor``: lowest a through hole's drill point may go (:func:`_drill_tip`),
    ``min_helix``: narrowest helix the roughing enters with, ``allowance``: stock roughing leaves on walls,
    all [mm]; ``mills``: flat end mills, the standard ones widest first, then
    the long-reach ones; ``fits(hole, tool)``: the tool may cut that hole where it lies, :func:`_fits`)."""

    def exact(h: Hole, tip_of) -> Tool | None:
        for t in sorted(drills, key=lambda t: -t.diameter):
            if h.inscribed - options.drill_undersize <= t.diameter <= h.inscribed + options.drill_oversize \
                    and _reaches(t, top, tip_of(t)) and fits(h, t):
                return t
        return None

    def helix_mill(h: Hole) -> Tool | None:
        bottom = max(h.bottom_z - (options.breakthrough if h.bottom == "through" else 0.0), floor)
        for t in mills:
            if t.diameter * (1 + options.helix_share) <= h.inscribed and _reaches(t, top, bottom) and fits(h, t):
                return t
        return None

    def predrill(h: Hole, mill: Tool, tip_of) -> Tool | None:
        """The widest drill the mill goes down inside (the helices take the wall in rings, :func:`predrilled_radii`)."""
        if not options.predrill or h.bottom == "conical" or h.inscribed / 2 - mill.radius > mill.radius:
            return None
        ok = [t for t in drills if mill.diameter + 2 * PREDRILL_ROOM <= t.diameter < h.inscribed - options.drill_undersize
              and _reaches(t, top, tip_of(t)) and fits(h, t)]
        return max(ok, key=lambda t: (t.diameter, -t.number), default=None)

    out = _Methods()
    for h in holes:
        def tip(t: Tool, h=h) -> float:
            deep = _drill_tip(h, t, options, floor, point_floor)  # a drill too short for it stops at the floor
            return deep if _reaches(t, top, deep) else _drill_tip(h, t, options, floor, floor)
        d = exact(h, tip)
        mill = helix_mill(h)
        if d is not None and h.bottom != "flat":
            out.drilled.setdefault(d.number, []).append((h, tip(d)))
        elif h.inscribed - 2 * allowance - rough_tool.diameter >= min_helix:
            out.left.append(h)
        elif mill is not None:
            out.helixed.append((h, mill))
            pre = predrill(h, mill, tip)
            if pre is not None:
                out.drilled.setdefault(pre.number, []).append((h, tip(pre)))
                out.predrilled[h] = (tip(pre) + pre.point_length, pre.radius)
        elif d is not None:
            out.drilled.setdefault(d.number, []).append((h, tip(d)))
        else:
            under = [t for t in drills if t.diameter < h.inscribed - options.drill_undersize
                     and h.bottom != "flat" and _reaches(t, top, tip(t)) and fits(h, t)]
            if under:
                t = max(under, key=lambda t: t.diameter)
                out.drilled.setdefault(t.number, []).append((h, tip(t)))
                out.undersize.append(h)
            else:
                out.left.append(h)
    return out


def _fits(within: Region | None, spots: tuple[Tool, ...] = ()) -> Callable[[Hole, Tool], bool]:
    """``fits(hole, tool)``: every axis position of ``tool`` in ``hole`` (a disc of the hole's radius
    less the tool's about its centre) lies where ``within(tool radius)`` allows, and for a drill the
    same for the ``spots`` that spot it first; always, without ``within``."""
    if within is None:
        return lambda h, t: True
    from shapely.geometry import Point

    def one(h: Hole, t: Tool) -> bool:
        orbit = h.inscribed / 2 - float(t.radius)  # a drill's is about nothing: its axis is the centre
        axis = Point(h.x, h.y).buffer(orbit, quad_segs=16) if orbit > 1e-9 else Point(h.x, h.y)
        return bool(within(float(t.radius)).covers(axis))

    return lambda h, t: one(h, t) and (not t.is_drill or all(one(h, s) for s in spots))


#: Radial room [mm] an end mill keeps from a predrilled hole's wall on its way down the hole's axis by rapid.
PREDRILL_ROOM = 0.5
#: Share of the end mill's deep radial limit a predrilled bore's wall may load it to: verify measures the
#: engagement on its grid, a little over the exact figure.
_RING_SHARE = 0.9


def ring_engagement(hole_radius: float, drilled_radius: float, tool_radius: float) -> float:
    """Radial engagement [mm] of an end mill circling inside a bore, cutting it out from ``drilled_radius`` to
    ``hole_radius`` [mm]: ``R (1 - cos b)``, ``b`` the angle at the tool's centre from the bore's radius
    out to where the tool's edge crosses the drilled wall (on an internal arc more than the wall's width)."""
    rh = hole_radius - tool_radius
    if drilled_radius >= hole_radius:
        return 0.0
    if rh <= 0.0:
        return 2 * tool_radius
    cos_b = (drilled_radius ** 2 - rh ** 2 - tool_radius ** 2) / (2 * rh * tool_radius)
    return tool_radius * (1.0 - max(-1.0, min(1.0, cos_b)))


def _seconds(ops: list[Operation], post: PostOptions = PostOptions()) -> float:
    """What ``ops`` take by the program's clock [s] (:func:`cadcam.post.operation_move_seconds`), each change of
    tool counted."""
    total, tool = 0.0, None
    for op in ops:
        if op.tool.number != tool:
            total, tool = total + post.tool_change_time, op.tool.number
        total += float(operation_move_seconds(op, post.rapid_rate).sum())
    return total


def _spot_operation(drilled: dict[int, list[tuple[Hole, float]]], spot: Tool, library: ToolLibrary, mat: str,
                    top: float, r_plane: float, initial: float, origin: np.ndarray,
                    options: DrillingOptions) -> Operation:
    """One G81 spot drilling every hole a drill takes, in a nearest-neighbour tour from ``origin``,
    each spot ``spot_share`` of its drill wide (at most the spot drill's size) [mm]."""
    targets = [(h, library.tool(n)) for n, hs in drilled.items() for h, _ in hs]
    xy = np.array([[h.x, h.y] for h, _ in targets])
    order = nearest_tour(xy, origin)
    rows = []
    for i in order:
        h, drill = targets[i]
        if _spots_countersink(spot, h.countersink):  # the spot drill's cone is the countersink's: cut it to size
            rows.append((h.x, h.y, h.countersink.tip_z()))
            continue
        spot_d = min(options.spot_share * drill.diameter, spot.diameter)
        rows.append((h.x, h.y, top - spot.point_slope * spot_d / 2))
    cycle = DrillCycle(code=81, holes=np.array(rows), r_plane=r_plane, peck=0.0, retract="r", initial_z=initial)
    return drill_operation("spot drill", "spot", spot, library.cutting_data(spot, mat), cycle)


def _to_spot(methods: _Methods, spot: Tool, library: ToolLibrary, top: float, spot_depth: float
             ) -> dict[int, list[tuple[Hole, float]]]:
    """The drilled holes to spot (drill number -> (hole, tip height [mm])): those whose countersink the spot cuts,
    and those drilled to size deeper than ``spot_depth`` drill diameters under the stock ``top`` [mm]
    (:attr:`DrillingOptions.spot_depth`). A spot holds a drill's point where the hole must be, which a solid
    carbide drill keeps by itself in a shallower hole (plate_bosses' three holes, 2.5 D: 10 s); a bore's pilot
    never needs one: its place is the helix's, which takes its wall all round (a ring well inside the end mill's
    radial limit, :func:`predrilled_radii`), so the spot would cost a tool change for nothing the part keeps (the
    bracket's five bores: 12 s)."""
    def needs(n: int, h: Hole, tip: float) -> bool:
        if _spots_countersink(spot, h.countersink):
            return True
        return h not in methods.predrilled and top - tip > spot_depth * library.tool(n).diameter

    out = {n: [(h, tip) for h, tip in hs if needs(n, h, tip)] for n, hs in methods.drilled.items()}
    return {n: hs for n, hs in out.items() if hs}


def _spots_countersink(spot: Tool, countersink: Countersink | None) -> bool:
    """The spot drill cuts ``countersink`` to size: the same included angle, and at least as wide."""
    return countersink is not None and abs(spot.point_angle - countersink.angle) <= _SAME_ANGLE \
        and countersink.diameter <= spot.diameter


def _drill_operations(drilled: dict[int, list[tuple[Hole, float]]], library: ToolLibrary, mat: str,
                      r_plane: float, initial: float, origin: np.ndarray,
                      options: DrillingOptions) -> list[Operation]:
    """The drilling cycles, smallest drill first: per drill a G81 for the shallow holes and a G83
    for those deeper than ``peck_ratio`` diameters from the R plane, each a nearest-neighbour tour."""
    ops = []
    for number in sorted(drilled, key=lambda n: library.tool(n).diameter):
        drill = library.tool(number)
        rows_by_code: dict[int, list[tuple[float, float, float]]] = {}
        for h, tip_z in drilled[number]:
            code = 83 if r_plane - tip_z > options.peck_ratio * drill.diameter else 81
            rows_by_code.setdefault(code, []).append((h.x, h.y, tip_z))
        for code in sorted(rows_by_code):
            rows = np.array(rows_by_code[code])
            rows = rows[nearest_tour(rows[:, :2], origin)]
            peck = library.peck_depth(drill, mat) if code == 83 else 0.0
            cycle = DrillCycle(code=code, holes=rows, r_plane=r_plane, peck=peck, retract="r", initial_z=initial)
            name = f"{'peck ' if code == 83 else ''}drill {drill.diameter:g} mm"
            ops.append(drill_operation(name, "drill", drill, library.cutting_data(drill, mat), cycle))
    return ops
