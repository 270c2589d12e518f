"""Continuous collision proof of a joint motion: every configuration between the checked ones.

A discrete check (every 0.02 rad) says nothing about what happens between two samples: a gripper
corner sweeping past a wall can touch it for a few milliseconds and be free again at the next
sample. :class:`SweptMotion` proves a whole segment instead, by conservative advancement with
margins.

Bound on motion
---------------
A point ``p`` of a body on joint ``k`` moves at ``|v| <= sum_j |qd_j| r_j(p)``, ``r_j`` its distance
to the axis of revolute joint ``j`` on the chain from the base to ``k`` (1 for a prismatic joint).
``r_j`` is bounded for every configuration by the chain's geometry: the distance of the next joint's
origin to the axis, the lengths of the joint offsets beyond it, and the farthest corner of the body's
bounding box from its own joint. Integrated along a segment on which every joint moves one way
(monotone), each point of the body moves at most ``L . |dq|`` [m], ``L`` (dof,) [m/rad]. For a pair
of bodies the relative motion counts only the joints on one body's chain and not the other's (for
the arm against the cell: the arm body's whole chain; the gripper against the upper arm: the joints
in between). The bodies riding on the TCP (fingers, held box) get the flange's chain.

Proof
-----
If a pair is at least ``m`` apart at both ends of a segment and the segment moves it by at most
``2 m``, no configuration between touches: a configuration a fraction of the way along is at most
``L . |dq_a|`` from one end and ``L . |dq_b|`` from the other, and the two add up to ``L . |dq|``.
The distance ``>= m`` is asked of coal as a collision query with ``security_margin = m`` (about as
fast as a plain collision query, much faster than a distance query on meshes), pair by pair, the boxes
riding on the TCP included (:meth:`robotprog.collision.CollisionWorld.riding`). Between two meshes a
margin wider than :data:`WIDE_MARGIN_M` is asked as coal's distance query instead, the same predicate
(``distance >= m``): with a margin that wide the collision query visits most pairs of the two meshes'
triangles (20-120 ms for the UR5's base and wrist at the coarsest level, against 0.6 ms). Where many pairs are
asked, a pair whose broad-phase bound (:class:`robotprog.collision.PairBounds`, never more than the
distance) is already beyond ``m`` passes without a query. Margins come in
levels: level ``k`` covers segments of effective joint step ``step * 2**-k`` (``step`` the planner's
joint resolution; a pair's margin ``step * 2**-k * sum(L) / 2``). A segment whose ends are not free
at its level is halved (at the mid-parameter of the path: halves of a monotone segment are
monotone), down to :attr:`SweptMotion.finest_level`; then the motion is taken to touch.
In free space segments longer than ``step`` are proven at once with larger margins (negative levels).

Room around a path
------------------
Asked for a tube ``t`` (dof,) [rad], each pair's margin grows by ``rates . t``: a stretch whose
ends clear a pair by ``m + rates . t`` and that moves it by at most ``2 m`` keeps it at least
``rates . t`` apart all along, so every configuration within ``t`` of the path, joint by joint, is
free too (a straight joint segment of travel at most ``t`` moves the pair by at most ``rates . t``).
The planner proves its timed spline so, with room for the chords between its servo samples
(:meth:`robotprog.timing.Trajectory.chord_deviation`); the posted servo stream is then proven by
that bound, without queries of its own (:func:`robotprog.programs.posted_collision`).

A cubic path (the timed spline) is cut at its breakpoints and at the turning points of every joint,
so that each piece is monotone; a polyline's straight segments already are.
A run of several pieces travels, joint by joint, the sum of its pieces' ``|dq|``; each point moves
at most ``L`` times that, so a run is proven from its two ends like one piece of that travel, and
split at its middle given parameter where it is not (a posted program's thousands of servo
targets, a TCP line's samples: mostly a few checks instead of one per sample).

Units: metres, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import coal
import numpy as np
import pinocchio as pin

from factory.core.errors import CellError
from robotprog.collision import BROAD_PHASE_SLACK, CollisionWorld, PairBounds, Payload, _riding, pair_name

#: Coarsest margin level: segments of up to ``step * 2**-COARSEST_LEVEL`` are proven in one piece [-].
COARSEST_LEVEL = -3
#: Finest margin level: at ``step * 2**-FINEST_LEVEL`` a segment that is still not proven touches [-].
FINEST_LEVEL = 12
#: From this level on, a segment not yet proven has its ends checked at the finest level too [-].
EXACT_AFTER = 4
#: Up to this many collision pairs are asked of coal one by one; more, all at once [-].
PAIRS_ONE_BY_ONE = 24
#: Collision checks one blended corner's proof may spend before it counts as touching [-].
CORNER_CHECKS = 2000
#: Between two meshes a security margin wider than this [m] is asked as a distance query (module
#: docstring): coal's collision query with a margin is about 10 us below it, milliseconds above.
WIDE_MARGIN_M = 0.12


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the axis-aligned box [lo, hi]."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


@dataclass(frozen=True, eq=False)
class _Chain:
    """Per joint of the model (index v): axis in its own frame, its parent, its offset."""

    parents: tuple[int, ...]
    axes: np.ndarray          # (njoints, 3); zero for the universe
    prismatic: np.ndarray     # (njoints,) bool
    offsets: np.ndarray       # (njoints, 3): joint origin in its parent's frame [m]
    idx_v: tuple[int, ...]
    nv: int

    def ancestors(self, k: int) -> list[int]:
        """Joints from ``k`` down to the first above the universe (k itself first)."""
        out = []
        while k != 0:
            out.append(k)
            k = self.parents[k]
        return out

    def coefficients(self, k: int, corners: np.ndarray) -> np.ndarray:
        """(nv,) bound [m/rad] on the speed of any point of a body on joint ``k`` whose bounding
        corners in joint ``k``'s frame are ``corners`` (n, 3) [m], per unit joint speed."""
        out = np.zeros(self.nv)
        chain = self.ancestors(k)
        rho = float(np.linalg.norm(corners, axis=1).max())
        # beyond: bound on the distance from the origin of the joint after chain[i] (towards the
        # body) to any point of the body, whatever the joints in between do
        beyond = rho
        for i, j in enumerate(chain):
            a = self.axes[j]
            if self.prismatic[j]:
                r = 1.0
            elif i == 0:
                r = float(np.linalg.norm(corners - np.outer(corners @ a, a), axis=1).max())
            else:
                child = chain[i - 1]
                t = self.offsets[child]
                r = float(np.linalg.norm(t - (t @ a) * a)) + beyond
            out[self.idx_v[j]] = r
            if i > 0:
                beyond += float(np.linalg.norm(self.offsets[chain[i - 1]]))
        return out


def _chain(model: pin.Model) -> _Chain:
    data = model.createData()
    q0 = pin.neutral(model)
    pin.computeJointJacobians(model, data, q0)
    axes = np.zeros((model.njoints, 3))
    prismatic = np.zeros(model.njoints, dtype=bool)
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.nv != 1 or jm.nq != 1:
            raise CellError(f"joint {model.names[j]}: only 1-dof revolute or prismatic joints are supported")
        twist = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.LOCAL)[:, jm.idx_v]
        lin, ang = twist[:3], twist[3:]
        if np.linalg.norm(ang) > 1e-9:
            axes[j] = ang / np.linalg.norm(ang)
        else:
            prismatic[j] = True
            axes[j] = lin / np.linalg.norm(lin)
    offsets = np.array([model.jointPlacements[j].translation for j in range(model.njoints)])
    return _Chain(tuple(int(p) for p in model.parents), axes, prismatic, offsets,
                  tuple(int(model.joints[j].idx_v) if j else -1 for j in range(model.njoints)), model.nv)


@dataclass(frozen=True, eq=False)
class _Rider:
    """The checks of one payload: its geometry (:meth:`CollisionWorld.riding`) and its broad phase,
    every pair's closing rates [m/rad] (npairs, nv), those that can close (``live`` rows, with their
    row sums ``scale``), each pair's two bodies (lower index first), whether both are meshes, one
    geometry data buffer, and per margin level its margins (npairs,) [m], the same by pair of bodies
    and the pairs asked by distance (:func:`_wide`) (made once; one buffer whose margins are set per
    check, as a buffer per level costs a megabyte each)."""

    geometry: pin.GeometryModel
    bounds: PairBounds
    rates: np.ndarray
    live: np.ndarray
    scale: np.ndarray
    pair_bodies: tuple[np.ndarray, np.ndarray]
    meshes: np.ndarray
    data: pin.GeometryData
    levels: dict = field(default_factory=dict)
    #: the level whose margins ``data`` holds (None: others)
    holds: list = field(default_factory=lambda: [None])


@dataclass(frozen=True, eq=False)
class SweptMotion:
    """Proves joint motions collision-free between their samples. Build with :func:`swept_motion`.

    Not thread-safe (one Pinocchio data buffer, like its :class:`CollisionWorld`).

    Attributes
    ----------
    world : CollisionWorld
    step : float
        Effective joint step of level 0 [rad] (the planner's joint resolution).
    pair_rates : (npairs, nv) float
        Bound on how fast each collision pair of ``world.geometry`` closes per unit joint speed [m/rad].
    finest_level : int
        Levels of halving before a segment still not proven counts as touching.
    """

    world: CollisionWorld
    step: float
    pair_rates: np.ndarray
    finest_level: int = FINEST_LEVEL
    _chain: _Chain = field(repr=False, default=None)
    _flange_joint: int = field(repr=False, default=0)
    _flange_placement: np.ndarray = field(repr=False, default=None)
    _link_rates: dict = field(repr=False, default_factory=dict)
    _riders: dict = field(repr=False, default_factory=dict)

    # --- margins ---------------------------------------------------------------------------

    def _gdata(self, rider: _Rider, level: int,
               tube: np.ndarray | None = None) -> tuple[pin.GeometryData, np.ndarray, np.ndarray | None]:
        """``rider``'s geometry data with its pair requests at level ``level``'s margins, the margins
        (npairs,) [m] and the pairs asked by distance (:func:`_wide`); with ``tube`` (nv,) [rad], each
        pair's margin grown by its closing rates times ``tube`` (:meth:`first_contact`)."""
        key = level if tube is None else (level, tube.tobytes())
        got = rider.levels.get(key)
        if got is None:
            margins = self._margins(rider.rates, self.step * 2.0 ** -level)
            if tube is not None:
                margins = margins + rider.rates @ tube * (1 + 1e-6)
                # one tube at a time is kept (a move's): the others' margins go
                for old in [k for k in rider.levels if isinstance(k, tuple) and k[1] != key[1]]:
                    del rider.levels[old]
            by_bodies = np.zeros((rider.geometry.ngeoms, rider.geometry.ngeoms))
            by_bodies[rider.pair_bodies[0], rider.pair_bodies[1]] = margins
            got = rider.levels[key] = (by_bodies, margins, _wide(rider.meshes, margins))
        if rider.holds[0] != key:
            rider.data.setSecurityMargins(rider.geometry, got[0], True, False)
            rider.holds[0] = key
        return rider.data, got[1], got[2]

    @staticmethod
    def _margins(rates: np.ndarray, h: float) -> np.ndarray:
        # half the motion of a segment of effective step h, a hair more so that equality is free
        return h * rates.sum(axis=1) / 2 * (1 + 1e-6) + 1e-9

    def _rider(self, held: Payload) -> _Rider:
        """The checks of ``held``: the world's pairs, then each box riding on the TCP against the arm
        links (rates: the joints between them) and the static boxes (the flange's whole chain)."""
        key = _riding(held)
        got = self._riders.get(key)
        if got is not None:
            return got
        w = self.world
        if not key:
            geometry, bounds, rows = w.geometry, w._bounds, [self.pair_rates]
        else:
            riding = w.riding(key)
            geometry, bounds, rows = riding.geometry, riding.bounds, [self.pair_rates]
            mine = set(self._chain.ancestors(self._flange_joint))
            for box, t_flange_box in zip(riding.boxes, riding.placements):
                size = np.asarray(box.size) - 2 * box.clearance
                corners = _box_corners(-size / 2, size / 2) @ t_flange_box[:3, :3].T + t_flange_box[:3, 3]
                corners = corners @ self._flange_placement[:3, :3].T + self._flange_placement[:3, 3]
                c = self._chain.coefficients(self._flange_joint, corners)
                for _, i in w._arm_links:
                    theirs = set(self._chain.ancestors(w.geometry.geometryObjects[i].parentJoint))
                    rows.append((c * self._mask(mine - theirs) + self._link_rates[i] * self._mask(theirs - mine))[None])
                rows.append(np.tile(c, (len(w._static_ids), 1)))
        rates = np.vstack(rows)
        rates.setflags(write=False)
        scale = rates.sum(axis=1)
        live = scale > 0
        first = np.array([p.first for p in geometry.collisionPairs], dtype=np.int64)
        second = np.array([p.second for p in geometry.collisionPairs], dtype=np.int64)
        # each pair's two bodies, the lower index first (how Pinocchio reads a margin per pair of bodies)
        bodies = (np.minimum(first, second), np.maximum(first, second))
        objects = geometry.geometryObjects
        meshes = np.array([isinstance(objects[int(a)].geometry, coal.BVHModelBase)
                           and isinstance(objects[int(b)].geometry, coal.BVHModelBase) for a, b in zip(first, second)],
                          dtype=bool)
        got = self._riders[key] = _Rider(geometry, bounds, rates, rates[live], scale[live], bodies, meshes,
                                         pin.GeometryData(geometry))
        return got

    def _level(self, travel: np.ndarray, rider: _Rider) -> int:
        """The margin level that covers a segment of joint travel ``travel`` (nv,) [rad] from its ends."""
        e = float(np.max(rider.live @ np.abs(travel) / rider.scale)) if len(rider.scale) else 0.0
        return self.finest_level if e <= 0 else min(self.finest_level, math.floor(math.log2(self.step / e)))

    def _mask(self, joints) -> np.ndarray:
        m = np.zeros(self._chain.nv)
        for j in joints:
            m[self._chain.idx_v[j]] = 1.0
        return m

    # --- checks ----------------------------------------------------------------------------

    def _place(self, q: np.ndarray, rider: _Rider, gd: pin.GeometryData) -> None:
        w = self.world
        model = w.robot.model
        pin.forwardKinematics(model, w._data, q)
        pin.updateGeometryPlacements(model, w._data, rider.geometry, gd)

    def _free_within(self, q: np.ndarray, d: np.ndarray, rider: _Rider) -> str | None:
        """``None`` when every configuration within ``d`` (nv,) [rad] of ``q``, joint by joint, is
        free, else the pair: each pair's margin is its own closing rates times ``d``."""
        gd = rider.data
        rider.holds[0] = None  # its margins are this check's
        margins = rider.rates @ d * (1 + 1e-6) + 1e-9
        wide = _wide(rider.meshes, margins)
        self._place(q, rider, gd)
        for k in np.flatnonzero(rider.bounds.lower(self.world._data) <= margins + BROAD_PHASE_SLACK):
            gd.collisionRequests[int(k)].security_margin = float(margins[k])
            if _within(rider.geometry, gd, int(k), margins, wide):
                return pair_name(rider.geometry, int(k))
        return None

    def _failing(self, q: np.ndarray, level: int, checks: np.ndarray,
                 rider: _Rider, tube: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Which pairs of ``checks`` (k,) int fail at ``q`` by level ``level``'s margins (grown by
        ``tube``): (k,) bool failing or not known to pass, and (k,) bool known."""
        gd, margins, wide = self._gdata(rider, level, tube)
        self._place(q, rider, gd)
        hits = np.zeros(len(checks), dtype=bool)
        known = np.ones(len(checks), dtype=bool)
        near = np.arange(len(checks))
        if len(checks) > PAIRS_ONE_BY_ONE:
            # the pairs the broad phase keeps farther apart than their margins pass; the rest ask coal
            near = near[rider.bounds.lower(self.world._data)[checks] <= margins[checks] + BROAD_PHASE_SLACK]
        g = rider.geometry
        if len(near) > PAIRS_ONE_BY_ONE:
            # many near ones (a coarse level): stop at the first that fails (one within a coarse
            # level's margin of a mesh is slow to settle); those after it are not known
            for n, i in enumerate(near):
                if _within(g, gd, int(checks[i]), margins, wide):
                    hits[near[n:]] = True
                    known[near[n + 1:]] = False
                    break
        else:
            hits[near] = [_within(g, gd, int(checks[i]), margins, wide) for i in near]
        return hits, known

    def first_contact(self, path: Callable[[np.ndarray], np.ndarray], s: np.ndarray,
                      held: Payload = None, tube: np.ndarray | None = None) -> tuple[float, str] | None:
        """The first stretch of ``path`` not proven free, or ``None`` when all of it is.

        With ``tube`` every configuration within ``tube`` of the path, joint by joint, is proven
        free too: each pair's margin is grown by its closing rates times ``tube``. A stretch whose
        ends clear a pair by ``m + rates . tube`` and that moves it by at most ``2 m`` keeps it at
        least ``rates . tube`` apart all along (module docstring), and a configuration within
        ``tube`` of one on the stretch is at most that much closer.

        Parameters
        ----------
        path : callable
            ``path(s)`` (k,) -> (k, dof) joint configurations [rad] at path parameters ``s``.
        s : (n,) float
            Increasing path parameters; between two of them every joint must move one way
            (:func:`monotone_breaks` for a cubic spline, the vertices for a polyline).
        held : Payload
            What rides on the TCP.
        tube : (dof,) float, optional
            Room [rad] proven around the path, joint by joint (default none).

        Returns
        -------
        (float, str) or None
            The path parameter where the unproven stretch ends and the pair nearest there.
        """
        s = np.asarray(s, dtype=float)
        tube = None if tube is None else np.ascontiguousarray(tube, dtype=float)
        qs = np.asarray(path(s), dtype=float).reshape(len(s), -1)
        rider = self._rider(held)
        # The checks: each collision pair, the cell's and the boxes' riding on the TCP. A pair that
        # passes at both ends of a stretch is proven on all of it, so the halves of a stretch not
        # proven ask only the pairs that failed at its ends.
        npairs = len(rider.geometry.collisionPairs)
        everything = np.ones(npairs, dtype=bool)
        # per sample and pair: highest level known to fail, lowest known to pass
        state: dict[int, tuple[np.ndarray, np.ndarray]] = {}

        def failing(key: int, q: np.ndarray, level: int, checks: np.ndarray) -> np.ndarray:
            """The pairs of ``checks`` (npairs,) bool that ``q`` fails at ``level``, as a mask."""
            st = state.get(key)
            if st is None:
                st = state[key] = (np.full(npairs, COARSEST_LEVEL - 1), np.full(npairs, self.finest_level + 1))
            fail, free = st
            out = checks & (level <= fail)
            todo = np.flatnonzero(checks & (level < free) & ~out)
            if len(todo):
                hits, known = self._failing(q, level, todo, rider, tube)
                free[todo[~hits]] = level
                fail[todo[hits & known]] = level
                out[todo[hits]] = True
            return out

        def name(failed: np.ndarray) -> str:
            return pair_name(rider.geometry, int(np.argmax(failed)))

        def ends(ka: int, qa: np.ndarray, kb: int, qb: np.ndarray, level: int,
                 checks: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
            """The pairs not proven on a stretch from its ends at ``level``, and those failing at the
            first end that fails (to name a contact), or None."""
            fa = failing(ka, qa, level, checks)
            fb = failing(kb, qb, level, checks & ~fa)
            a, b = fa.any(), fb.any()
            if not a and not b:
                return fa, None
            return fa | fb, fa if a else fb

        if len(s) == 1:
            failed = failing(0, qs[0], self.finest_level, everything)
            return None if not failed.any() else (float(s[0]), name(failed))
        # Joint travel along the path up to each given parameter (n, dof) [rad]: between two given
        # parameters every joint moves one way, so a run of pieces travels the difference. A run is
        # proven from its two ends like one piece (module docstring: the bound holds for the
        # travel, whichever way the joints turn); a run that is not is split at its middle
        # parameter, down to single pieces, which are halved as before.
        travel = np.vstack([np.zeros((1, qs.shape[1])), np.cumsum(np.abs(np.diff(qs, axis=0)), axis=0)])
        counter = [len(s)]
        # (key a, s a, q a, key b, s b, q b, whether both ends are given parameters (their keys are
        # their indices into s), the pairs not yet proven on the stretch)
        stack = [(0, float(s[0]), qs[0], len(s) - 1, float(s[-1]), qs[-1], True, everything)]
        while stack:
            ka, sa, qa, kb, sb, qb, given, live = stack.pop()
            if given and kb - ka > 1:  # a run of several given pieces
                level = self._level(travel[kb] - travel[ka], rider)
                if level >= COARSEST_LEVEL:
                    live, _ = ends(ka, qa, kb, qb, level, live)
                    if not live.any():
                        continue
                km = (ka + kb) // 2
                stack.append((km, float(s[km]), qs[km], kb, sb, qb, True, live))
                stack.append((ka, sa, qa, km, float(s[km]), qs[km], True, live))
                continue
            level = self._level(qb - qa, rider)
            if level >= COARSEST_LEVEL:
                live, hit = ends(ka, qa, kb, qb, level, live)
                if hit is None:
                    continue
                if level >= self.finest_level or sb - sa <= 1e-12 * max(1.0, abs(sb)):
                    return sb, name(hit)
                if level >= EXACT_AFTER:
                    # still close after a few halvings: if an end touches outright, stop narrowing down
                    for k, sk, qk in ((ka, sa, qa), (kb, sb, qb)):
                        touch = failing(k, qk, self.finest_level, live)
                        if touch.any():
                            return sk, name(touch)
            sm = 0.5 * (sa + sb)
            qm = np.asarray(path(np.array([sm])), dtype=float).reshape(-1)
            km = counter[0]
            counter[0] += 1
            stack.append((km, sm, qm, kb, sb, qb, False, live))
            stack.append((ka, sa, qa, km, sm, qm, False, live))
        return None

    def polyline_contact(self, qs: np.ndarray, held: Payload = None) -> tuple[float, str] | None:
        """:meth:`first_contact` of the straight joint segments through ``qs`` (n, dof) [rad];
        the parameter is the fractional waypoint index."""
        qs = np.asarray(qs, dtype=float)
        n = len(qs)

        def path(s: np.ndarray) -> np.ndarray:
            i = np.clip(np.floor(s).astype(int), 0, max(n - 2, 0))
            f = (s - i)[:, None]
            return qs[i] if n == 1 else qs[i] + f * (qs[np.minimum(i + 1, n - 1)] - qs[i])

        return self.first_contact(path, np.arange(n, dtype=float), held)

    def corner_contact(self, a: np.ndarray, c: np.ndarray, b: np.ndarray, held: Payload = None,
                       max_checks: int = CORNER_CHECKS) -> str | None:
        """Proves the triangle ``a``, ``c``, ``b`` of joint space [rad] free, or names a pair near it.

        A controller blending from segment ``a``-``c`` into ``c``-``b`` drives a convex combination
        of the two (a parabolic or Bezier blend), inside this triangle. A configuration ``g`` clear
        of each pair by that pair's closing rates times ``d`` holds every configuration within ``d``
        of it, joint by joint, free: the triangle is proven at its centroid, else as four triangles
        of half its size, down to the finest level's reach or ``max_checks`` collision checks.

        Returns
        -------
        str or None
            None when every point of the triangle is free, else the pair nearest where the proof
            stopped (a touch, or the check budget spent close to something).
        """
        rider = self._rider(held)
        # a triangle this small [rad] (the finest level's joint step) still not clear touches
        finest = self.step * 2.0 ** -self.finest_level
        stack = [(np.asarray(a, dtype=float), np.asarray(c, dtype=float), np.asarray(b, dtype=float))]
        checks = 0
        while stack:
            p = np.stack(stack.pop())
            g = p.mean(axis=0)
            d = np.abs(p - g).max(axis=0)
            hit = self._free_within(g, d, rider)
            checks += 1
            if hit is None:
                continue
            if float(np.max(rider.live @ d / rider.scale)) <= finest or checks >= max_checks:
                return hit
            m01, m12, m20 = (p[0] + p[1]) / 2, (p[1] + p[2]) / 2, (p[2] + p[0]) / 2
            stack += [(p[0], m01, m20), (m01, p[1], m12), (m20, m12, p[2]), (m01, m12, m20)]
        return None


def _wide(meshes: np.ndarray, margins: np.ndarray) -> np.ndarray | None:
    """(npairs,) bool: the pairs of two meshes whose margin [m] is wider than :data:`WIDE_MARGIN_M`
    (asked by distance, :func:`_within`), or None when there is none."""
    wide = meshes & (margins > WIDE_MARGIN_M)
    return wide if wide.any() else None


def _within(g: pin.GeometryModel, gd: pin.GeometryData, k: int, margins: np.ndarray, wide: np.ndarray | None) -> bool:
    """Whether pair ``k`` is closer than its margin ``margins[k]`` [m] (set in ``gd``'s request): coal's
    collision query with that security margin, or for a pair of ``wide`` its distance query (the same
    predicate; the collision query with a wide margin between meshes visits most of their triangle pairs)."""
    if wide is not None and wide[k]:
        return pin.computeDistance(g, gd, k).min_distance < margins[k]
    return pin.computeCollision(g, gd, k)


def monotone_breaks(breakpoints: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """Path parameters cutting a cubic spline into pieces on which every joint moves one way.

    Parameters
    ----------
    breakpoints : (p+1,) float
    coefficients : (4, p, dof) float
        ``scipy.interpolate.PPoly`` layout (highest power first).

    Returns
    -------
    (k,) float
        The breakpoints and every turning point of every joint inside a piece, sorted.
    """
    x = np.asarray(breakpoints, dtype=float)
    c = np.asarray(coefficients, dtype=float)
    h = np.diff(x)[:, None]
    # q'(t) = 3 c0 t^2 + 2 c1 t + c2 on [0, h]
    a, b, cc = 3 * c[0], 2 * c[1], c[2]
    roots = []
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = b * b - 4 * a * cc
        sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
        quad = np.abs(a) > 1e-12 * (np.abs(b) + np.abs(cc) + 1e-300)
        for r in ((-b + sq) / (2 * a), (-b - sq) / (2 * a)):
            roots.append(np.where(quad, r, np.nan))
        roots.append(np.where(~quad & (np.abs(b) > 0), -cc / b, np.nan))
    r = np.stack(roots)  # (3, p, dof)
    inside = np.isfinite(r) & (r > 0) & (r < h[None])
    base = np.broadcast_to(x[:-1][None, :, None], r.shape)
    return np.unique(np.concatenate([x, (base + r)[inside]]))


def swept_motion(world: CollisionWorld, step: float) -> SweptMotion:
    """The continuous checker of ``world`` for a planner of joint resolution ``step`` [rad].

    Raises
    ------
    CellError
        The robot has a joint that is not a 1-dof revolute or prismatic joint.
    """
    model = world.robot.model
    chain = _chain(model)
    gm = world.geometry
    link_rates = {}
    chains = {}
    for i, g in enumerate(gm.geometryObjects):
        k = g.parentJoint
        chains[i] = set(chain.ancestors(k))
        if k == 0:
            link_rates[i] = np.zeros(chain.nv)
            continue
        geo = g.geometry
        geo.computeLocalAABB()
        box = geo.aabb_local
        corners = _box_corners(np.asarray(box.min_), np.asarray(box.max_))
        m = g.placement.homogeneous
        link_rates[i] = chain.coefficients(k, corners @ m[:3, :3].T + m[:3, 3])
    rates = np.zeros((len(gm.collisionPairs), chain.nv))
    for p, pair in enumerate(gm.collisionPairs):
        a, b = pair.first, pair.second
        for x, y in ((a, b), (b, a)):
            for j in chains[x] - chains[y]:
                rates[p, chain.idx_v[j]] += link_rates[x][chain.idx_v[j]]
    rates.setflags(write=False)
    fr = model.frames[world._flange_id]
    return SweptMotion(world, float(step), rates, FINEST_LEVEL, chain, int(fr.parentJoint),
                       fr.placement.homogeneous, link_rates)
