"""Ramp entries along a finishing path: how a tool gets down to a chain that starts under stock.

A finishing chain (a waterline loop, a raster line) whose first point lies below the stock an
earlier operation left is not entered by feeding straight down: the tool would plunge through
the stock with its centre, where a ball or flat end mill does not cut well (issue 32: entries by
helix or ramp of at most :data:`RAMP_ANGLE`, never a plunge). The tool instead starts on the
stock's top above the chain's first point and descends along the chain itself at the ramp angle,
following the chain once the slope meets it. A closed loop is then cut once round from there; an
open chain's ramped stretch is cut back to its start and the chain cut as before. The ramp is cut
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
    """Chain ``c`` entered from ``z_top`` down a slope ``tan`` along itself; (chain, ramp moves)."""
    closed = bool(np.allclose(c[0], c[-1]))
    seg = np.linalg.norm(np.diff(c[:, :2], axis=0), axis=1)
    length = float(seg.sum())
    if length < 1e-9:  # a chain that goes nowhere sideways cannot be ramped along
        return c, 0
    rise = z_top - float(c[0, 2])
    need = rise / tan  # how far along the chain the ramp runs
    laps = int(math.ceil(need / length)) + 1
    if closed:
        walk = np.vstack([c] + [c[1:]] * laps)
    else:  # back and forth along the chain
        there, back = c, c[::-1]
        walk = np.vstack([c] + [(back if k % 2 == 0 else there)[1:] for k in range(laps)])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(walk[:, :2], axis=0), axis=1))])
    i = int(np.searchsorted(s, need, side="right"))  # walked points 0..i-1 lie before the meet
    meet = _at(walk, s, need)
    # The ramp's height over the chain falls at the ramp angle: on a chain that itself falls (a
    # raster down a slope) the tool goes down into the stock no steeper than the angle.
    down = walk[:i].copy()
    down[:, 2] += rise - s[:i] * tan
    ramp = np.vstack([down, meet])
    if closed:
        # Once round the loop from where the ramp meets it: the walk repeats every ring.
        ahead = walk[i:][s[i:] < need + length - 1e-9]
        end = _at(walk, s, need + length)
        rest = np.vstack([ahead, end])
    else:
        # Back over the ramped stretch at the chain's height, then the chain from its start.
        rest = np.vstack([walk[:i][::-1], c[1:]])
    out = np.vstack([ramp, rest])
    # A slope meeting the chain on a walked point repeats it: no zero-length moves.
    keep = np.concatenate([[True], np.linalg.norm(np.diff(out, axis=0), axis=1) > 1e-9])
    return out[keep], int(keep[:len(ramp)].sum()) - 1


def _at(walk: np.ndarray, s: np.ndarray, where: float) -> np.ndarray:
    """The walked point ``where`` [mm] along the walk (``s`` its cumulative lengths)."""
    return np.array([np.interp(where, s, walk[:, k]) for k in range(3)])
