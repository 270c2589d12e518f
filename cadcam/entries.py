"""Ramp entries along a finishing path: how a tool gets down to a chain that starts under stock.

A finishing chain (a waterline loop, a raster line) whose first point lies below the stock an
earlier operation left is not entered by feeding straight down: the tool would plunge through
the stock with its centre, where a ball or flat end mill does not cut well (issue 32: entries by
helix or ramp of at most :data:`RAMP_ANGLE`, never a plunge). The tool instead starts on the
stock's top above the chain's first point and descends along the chain itself at the ramp angle
against the horizontal (out and back where the chain falls away under it), following the chain
once the slope meets it. A closed loop is then cut once round from there; an open chain's ramped
stretch is cut back to its start and the chain cut as before. The ramp is cut
at the chain's feed, not the plunge feed: it takes the same finishing skin, at most
:data:`RAMP_ANGLE` deeper per millimetre, so its chip is no thicker than the chain's own.

Only the entry changes: a chain whose start has no stock above it keeps its straight descent
through the air. All heights in millimetres, angles in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cadcam.model import Tool
from cadcam.stock import Simulation, clear_height

#: Steepest descent of an entry into stock [deg]: issue 32's limit for ramps and helices.
RAMP_ANGLE = 3.0
#: Stock above a chain's start thinner than this is none: the straight descent stays [mm].
_FILM = 1e-3
#: Width of the tool's rim [mm] that may cut on the way down: stock that far inside the edge only
#: (a skin on a wall beside the chain) is side milling, not a plunge. The core inside it, whose
#: centre does not cut, must meet no stock on a straight descent.
RIM = 1.0


@dataclass(frozen=True)
class EntryChains:
    """Chains as they are cut, each with the ramp that enters it.

    Attributes
    ----------
    chains : list of (n, 3) float arrays
        CL points [mm]; a ramped chain starts with its ramp, on the stock's top.
    ramp_points : list of int
        Per chain, how many moves after its first point descend on the ramp (0: none).
    """

    chains: list[np.ndarray]
    ramp_points: list[int]


def ramp_entries(chains: list[np.ndarray], stock: Simulation | None, tool: Tool,
                 angle: float = RAMP_ANGLE) -> EntryChains:
    """Give every chain whose first point lies under ``stock`` a ramp entry along itself.

    The ramp starts at the lowest height over the chain's first point where the tool's core
    (all but its :data:`RIM`, at least half its radius) touches none of ``stock``
    (:func:`cadcam.stock.clear_height`, conservative between grid points) and falls at ``angle``
    [deg] along the chain (back and forth along an open one) until it meets it.
    Without a stock model every chain is left as it is.
    """
    if stock is None or not chains:
        return EntryChains(list(chains), [0] * len(chains))
    tan = math.tan(math.radians(angle))
    core = max(tool.radius - RIM, 0.5 * tool.radius)
    tops = clear_height(stock, tool, np.array([c[0, :2] for c in chains]), within=core)
    out: list[np.ndarray] = []
    ramps: list[int] = []
    for c, z_top in zip(chains, tops):
        if len(c) < 2 or not z_top > c[0, 2] + _FILM:
            out.append(c)
            ramps.append(0)
            continue
        chain, n = _ramped(c, float(z_top), tan)
        out.append(chain)
        ramps.append(n)
    return EntryChains(out, ramps)


def _ramped(c: np.ndarray, z_top: float, tan: float) -> tuple[np.ndarray, int]:
    """Chain ``c`` entered from ``z_top`` down a slope ``tan`` along itself; (chain, ramp moves).

    The ramp's own height falls ``tan`` per millimetre walked sideways, whatever the chain under it
    does. A ramp that kept its height over the chain instead would copy the chain's drops: a raster
    stepping straight down off a wall's edge became a straight descent through stock, and on the
    dome 123 of 146 ramps fell steeper than the angle, up to 32 deg.

    The ramp walks out along the chain (round a loop, back and forth along an open chain shorter
    than the ramp) as far as a ramp on a level chain would, ``(z_top - c[0, 2]) / tan``, and back
    the way it came: where the chain falls away under it, it meets the chain on the way back, by
    the chain's start at the latest. A loop is then cut once round from where the ramp met it, in
    its own direction; an open chain is cut from the meeting point back to its start along the
    ramp's way, and then from its start as before.
    """
    closed = bool(np.allclose(c[0], c[-1]))
    seg = np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1)
    length = float(seg.sum())
    rise = z_top - float(c[0, 2])
    if length < 1e-9 or rise <= 0:  # a chain that goes nowhere sideways cannot be ramped along
        return c, 0
    need = rise / tan  # how far the ramp runs on a level chain
    laps = int(math.ceil(need / length)) + 1
    m = len(c) - 1
    if closed:  # round and round: c[m] is c[0]
        idx = np.concatenate([np.arange(m + 1)] + [np.arange(1, m + 1)] * laps)
    else:  # back and forth along the chain
        there, back = np.arange(m + 1), np.arange(m, -1, -1)
        idx = np.concatenate([there] + [(back if k % 2 == 0 else there)[1:] for k in range(laps)])
    walk, s, j = _walked(c, idx, need, m if closed else 0)
    way = np.concatenate([np.arange(j + 1), np.arange(j - 1, -1, -1)])
    along_way = np.concatenate([s[:j + 1], 2.0 * s[j] - s[j - 1::-1]])
    slope = float(c[0, 2]) + (rise - along_way * tan)  # the ramp's height over each point of its way
    # Back at the chain's start the slope is ``rise`` under it: the ramp has met the chain by then.
    i = int(np.argmax(slope <= walk[way, 2]))  # points 0..i-1 of the way lie under the ramp, before the meet
    meet, along = _meet(walk[way[i - 1]], walk[way[i]], along_way[i - 1], along_way[i], float(c[0, 2]), rise, tan)
    down = walk[way[:i]]
    down[:, 2] = slope[:i]
    ramp = np.vstack([down, meet])
    if closed:
        # Once round the loop from where the ramp meets it, in the loop's own direction.
        a, b = idx[way[i - 1]], idx[way[i]]
        lo = min(a, b) if abs(a - b) == 1 else 0  # c[m] to c[1] is the loop's first segment
        end = meet
        if i <= j and s[i] > s[i - 1]:  # met on the way out: where the walk's next ring passes it
            end = np.array([np.interp(along + length, s[i - 1 + m:i + 1 + m], walk[i - 1 + m:i + 1 + m, k])
                            for k in range(3)])
        rest = np.vstack([c[lo + 1:], c[1:lo + 1], end])
    else:
        # Back to the start along the ramp's way at the chain's height, then the chain from its start.
        rest = np.vstack([walk[way[:i]][::-1] if i <= j else walk[way[i:]], c[1:]])
    out = np.vstack([ramp, rest])
    # A slope meeting the chain on a walked point repeats it: no zero-length moves.
    keep = np.concatenate([[True], np.linalg.norm(np.diff(out, axis=0), axis=1) > 1e-9])
    return out[keep], int(keep[:len(ramp)].sum()) - 1


def _walked(c: np.ndarray, idx: np.ndarray, need: float, more: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The first points of the walk ``c[idx]`` (k, 3) [mm], how far along it each lies (k,) [mm], and ``j``: the
    first that lies ``need`` [mm] or more along (0: none), with ``more`` points walked past it (a loop's next lap).

    A raster line is hundreds of points and its ramp a few millimetres of it: the walk is laid out and measured
    only as far as the ramp goes, in prefixes that double. The distances are cumulative sums from the walk's
    start, so each is the number measuring the whole walk gives (issue 35: the whole walk, laps of it, was
    measured for every chain)."""
    n = len(idx)
    size = min(n, 64)
    while True:
        walk = c[idx[:size]]
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(walk[:, :2], axis=0), axis=1))])
        hit = s >= need
        j = int(np.argmax(hit))  # out to the first walked point a level ramp's length along, then back
        if size == n or (hit[j] and j + more < size):
            return walk, s, j
        size = min(n, max(2 * size, j + more + 1 if hit[j] else 0))


def _meet(a: np.ndarray, b: np.ndarray, sa: float, sb: float, base: float, rise: float, tan: float
          ) -> tuple[np.ndarray, float]:
    """Where the slope ``base + rise - s * tan`` meets the walked move ``a``-``b`` (at ``sa``-``sb`` [mm] along
    the walk), which it enters above and leaves on or under; (the point, how far along the walk [mm])."""
    if sb == sa:  # a move straight up or down: the slope meets it at its own height there
        return np.array([b[0], b[1], base + (rise - sa * tan)]), sa
    # Both are straight in s: slope(s) - base = rise - s tan, chain(s) - base = h + k (s - sa). Heights are
    # taken over ``base`` so that on a level chain (h = k = 0) the meet is rise / tan exactly.
    h = a[2] - base
    k = (b[2] - a[2]) / (sb - sa)
    along = (rise - h + k * sa) / (tan + k)
    x, y, z = (np.interp(along, [sa, sb], [a[j], b[j]]) for j in range(3))
    if abs(k) > 1.0:  # on a move steeper than 45 deg the slope's height there is the better conditioned
        z = base + (rise - along * tan)
    return np.array([x, y, z]), along
