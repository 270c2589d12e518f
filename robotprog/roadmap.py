"""A roadmap of the static cell: joint configurations and the segments between them, proven once.

Every part's trips cross the same cell (home, rack, vise, flip station, out-tray); only the stock,
the part in hand and what stands beside them change. :func:`build_roadmap` samples collision-free
configurations of the cell with the fingers away (seeded, reproducible) and joins each to its
nearest neighbours where the straight joint segment is proven free all along by the continuous
proof of :mod:`robotprog.sweep` at the planner's joint resolution. It is built once per cell file
and kept on disk (:meth:`Roadmap.to_bytes`; the pipeline's cache, :mod:`factory.roadmaps`).

A transfer the straight segment cannot make (:meth:`robotprog.planner.MotionPlanner.transfer`)
asks :meth:`Roadmap.path`: the start and goal are joined to their nearest nodes, and the shortest
path through the graph is checked lazily, edge by edge, in the planner's own world (with the
payload and the obstacles of this part): an edge that touches is dropped and the search runs again
(lazy PRM). The roadmap only finds the path: what is posted is proven exactly as before (the
planner proves the polyline and the timed spline of every transfer all along).

Frames and units: joint space of the cell's robot [rad].
"""

from __future__ import annotations

import heapq
import io
import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np

from factory.core.errors import CellError
from robotprog.cell import Cell
from robotprog.collision import CollisionWorld, collision_world
from robotprog.sweep import swept_motion

log = logging.getLogger(__name__)

#: Format of :meth:`Roadmap.to_bytes`; raise it when the layout or the meaning of the file changes.
ROADMAP_FORMAT = 1


@dataclass(frozen=True)
class RoadmapOptions:
    """How a roadmap is built.

    Attributes
    ----------
    nodes : int
        Collision-free configurations sampled [-] (home is one more).
    neighbours : int
        Nearest nodes each node tries to join by a proven segment [-].
    joint_resolution : float
        Joint step of the continuous proof's first level [rad] (the planner's).
    seed : int
        Seed of the sampler: the same cell and options give the same roadmap.
    max_samples : int
        Samples drawn at most while looking for ``nodes`` free ones [-].
    """

    nodes: int = 150
    neighbours: int = 8
    joint_resolution: float = 0.02
    seed: int = 0
    max_samples: int = 20000


@dataclass(frozen=True, eq=False)
class Roadmap:
    """Proven-free configurations of the static cell and the proven segments between them.

    Attributes
    ----------
    nodes : (n, dof) float
        Configurations [rad], read-only; node 0 is the cell's home.
    edges : (m, 2) int
        Node index pairs ``i < j`` whose straight joint segment is proven free with nothing held.
    """

    nodes: np.ndarray
    edges: np.ndarray

    def __post_init__(self) -> None:
        for a in (self.nodes, self.edges):
            a.setflags(write=False)

    def to_bytes(self) -> bytes:
        """The roadmap as an ``.npz`` file's bytes (with :data:`ROADMAP_FORMAT`)."""
        buf = io.BytesIO()
        np.savez(buf, format=np.array(ROADMAP_FORMAT), nodes=self.nodes, edges=self.edges)
        return buf.getvalue()

    @staticmethod
    def from_bytes(data: bytes, dof: int, source: str | None = None) -> "Roadmap":
        """The roadmap of :meth:`to_bytes` for a robot of ``dof`` joints.

        Raises
        ------
        CellError
            Not a roadmap of this format, or not for ``dof`` joints.
        """
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                fmt, nodes, edges = int(z["format"]), np.array(z["nodes"], dtype=float), np.array(z["edges"])
        except (OSError, ValueError, KeyError, EOFError) as e:
            raise CellError(f"not a roadmap file: {e}", source=source) from None
        if fmt != ROADMAP_FORMAT:
            raise CellError(f"roadmap format {fmt}, expected {ROADMAP_FORMAT}", source=source)
        if nodes.ndim != 2 or nodes.shape[1] != dof or not np.isfinite(nodes).all():
            raise CellError(f"roadmap nodes must be (n, {dof}) finite angles, got {nodes.shape}", source=source)
        if edges.size and (edges.ndim != 2 or edges.shape[1] != 2 or edges.min() < 0 or edges.max() >= len(nodes)):
            raise CellError("roadmap edges must be pairs of node indices", source=source)
        return Roadmap(nodes, edges.reshape(-1, 2).astype(np.int64))

    def path(self, q_a: np.ndarray, q_b: np.ndarray, edge_free: Callable[[np.ndarray, np.ndarray], bool],
             connect: int = 10, max_checks: int = 200) -> np.ndarray | None:
        """The shortest path (n, dof) [rad] from ``q_a`` to ``q_b`` through the roadmap whose every
        segment ``edge_free`` accepts, or ``None``.

        ``q_a`` and ``q_b`` are joined to their ``connect`` nearest nodes; the search is lazy: the
        shortest candidate's segments are checked in order, one that ``edge_free`` refuses is
        dropped, and the search runs again, ``max_checks`` checks at most. Edge lengths are the
        largest joint step [rad] (the slowest joint's travel sets a transfer's time).
        """
        n = len(self.nodes)
        if n == 0:
            return None
        start, goal = n, n + 1
        pts = np.vstack([self.nodes, q_a, q_b])
        adj: dict[int, set[int]] = {i: set() for i in range(n + 2)}
        for i, j in self.edges:
            adj[int(i)].add(int(j))
            adj[int(j)].add(int(i))
        for end in (start, goal):
            d = np.abs(self.nodes - pts[end]).max(axis=1)
            for i in np.argsort(d, kind="stable")[:connect]:
                adj[end].add(int(i))
                adj[int(i)].add(end)
        checked: set[tuple[int, int]] = set()
        checks = 0
        while checks < max_checks:
            route = _shortest(pts, adj, start, goal)
            if route is None:
                return None
            for a, b in zip(route[:-1], route[1:]):
                key = (min(a, b), max(a, b))
                if key in checked:
                    continue
                checks += 1
                if not edge_free(pts[a], pts[b]):
                    adj[a].discard(b)
                    adj[b].discard(a)
                    break
                checked.add(key)
            else:
                return pts[route]
        return None


class RoadmapOnDemand:
    """A cell's roadmap got (read from the cache or built) the first time a transfer asks it for a path.

    Building a cell's roadmap takes minutes; a plan that fails on a grasp or an unreachable pose, which
    it finds before any transfer, fails without waiting for it, and a plan whose transfers are all
    straight never needs it. ``get`` returns the roadmap, or None where there is none to be had; it is
    called once, and the copies of a planner (:meth:`robotprog.planner.MotionPlanner.among`) share it.
    """

    def __init__(self, get: Callable[[], Roadmap | None]) -> None:
        self._get: Callable[[], Roadmap | None] | None = get
        self._roadmap: Roadmap | None = None

    def path(self, q_a: np.ndarray, q_b: np.ndarray, edge_free: Callable[[np.ndarray, np.ndarray], bool],
             connect: int = 10, max_checks: int = 200) -> np.ndarray | None:
        """:meth:`Roadmap.path` on the roadmap, got now if no transfer asked before; None without one."""
        if self._get is not None:
            get, self._get = self._get, None
            self._roadmap = get()
        if self._roadmap is None:
            return None
        return self._roadmap.path(q_a, q_b, edge_free, connect, max_checks)


def _shortest(pts: np.ndarray, adj: dict[int, set[int]], start: int, goal: int) -> list[int] | None:
    """Dijkstra from ``start`` to ``goal``; edge length the largest joint step [rad]."""
    dist = {start: 0.0}
    prev: dict[int, int] = {}
    heap = [(0.0, start)]
    done: set[int] = set()
    while heap:
        d, u = heapq.heappop(heap)
        if u in done:
            continue
        if u == goal:
            route = [u]
            while route[-1] != start:
                route.append(prev[route[-1]])
            return route[::-1]
        done.add(u)
        for v in sorted(adj[u]):
            nd = d + float(np.abs(pts[v] - pts[u]).max())
            if nd < dist.get(v, np.inf):
                dist[v], prev[v] = nd, u
                heapq.heappush(heap, (nd, v))
    return None


def build_roadmap(home: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                  state_free: Callable[[np.ndarray], bool],
                  segment_free: Callable[[np.ndarray, np.ndarray], bool],
                  options: RoadmapOptions = RoadmapOptions(),
                  progress: Callable[[int, int], None] | None = None) -> Roadmap:
    """Sample ``options.nodes`` configurations in [``lower``, ``upper``] (dof,) [rad] that
    ``state_free`` accepts, and join each to its ``options.neighbours`` nearest where
    ``segment_free`` (the continuous proof) accepts the straight joint segment.

    ``progress(done, total)`` is called as the segments are proven.

    Raises
    ------
    CellError
        ``home`` is not free, or fewer than two free configurations in ``max_samples`` draws.
    """
    home = np.asarray(home, dtype=float)
    if not state_free(home):
        raise CellError("the robot's home configuration is in collision", source="robot.home")
    rng = np.random.default_rng(options.seed)
    nodes = [home]
    for _ in range(options.max_samples):
        if len(nodes) > options.nodes:
            break
        q = lower + (upper - lower) * rng.random(len(home))
        if state_free(q):
            nodes.append(q)
    if len(nodes) < 2:
        raise CellError(f"no free configuration in {options.max_samples} samples of the joint box", source="robot")
    pts = np.array(nodes)
    pairs: set[tuple[int, int]] = set()
    for i in range(len(pts)):
        d = np.abs(pts - pts[i]).max(axis=1)
        for j in np.argsort(d, kind="stable")[1:options.neighbours + 1]:
            pairs.add((min(i, int(j)), max(i, int(j))))
    todo = sorted(pairs)
    edges = []
    for k, (i, j) in enumerate(todo):
        if segment_free(pts[i], pts[j]):
            edges.append((i, j))
        if progress is not None:
            progress(k + 1, len(todo))
    log.info("roadmap: %d nodes, %d of %d segments proven free", len(pts), len(edges), len(todo))
    return Roadmap(pts, np.array(edges, dtype=np.int64).reshape(-1, 2))


def cell_roadmap(cell: Cell, world: CollisionWorld, options: RoadmapOptions = RoadmapOptions(),
                 progress: Callable[[int, int], None] | None = None) -> Roadmap:
    """The roadmap of ``cell``'s static boxes (door open, nothing held), ``world``'s robot model
    reused: nodes in the planner's joint box (:attr:`robotprog.planner.MotionPlanner.lo`, ``hi``),
    segments proven with :meth:`robotprog.sweep.SweptMotion.polyline_contact`.

    Raises
    ------
    CellError
        As :func:`build_roadmap`.
    """
    static = collision_world(cell, world.robot)
    sweep = swept_motion(static, options.joint_resolution)
    robot = static.robot
    home = np.asarray(cell.robot.home, dtype=float)
    lower, upper = joint_box(robot.q_lower, robot.q_upper, home)
    return build_roadmap(home, lower, upper, lambda q: not static.in_collision(q),
                         lambda a, b: sweep.polyline_contact(np.array([a, b])) is None, options, progress)


def joint_box(q_lower: np.ndarray, q_upper: np.ndarray, home: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint box transfers search [rad]: the joint limits, at most half a turn from ``home``."""
    home = np.asarray(home, dtype=float)
    return np.maximum(q_lower, home - np.pi), np.minimum(q_upper, home + np.pi)
