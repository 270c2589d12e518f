"""The lowest tip height that clears a stock model, compiled: :func:`cadcam.stock.clear_height`'s pairs.

:func:`cadcam.stock.clear_height` asks, for every tool axis, every grid point within the tool's reach (a disc
of a few hundred offsets): numpy made each (axis, offset) pair's index, distance, profile height and candidate
height as temporaries of the whole batch, and those temporaries were the call's cost (the raster's air moves and
engagement clip, the terraces' entries and links: issue 35). Here one axis at a time runs over the same offsets
with the same formulas, in the same order of operations (no fast-math: nothing contracted or reordered), so each
height is the same number to the bit. All lengths in mm.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def clear_heights(x: np.ndarray, y: np.ndarray, i0: np.ndarray, j0: np.ndarray, di: np.ndarray, dj: np.ndarray,
                  top: np.ndarray, x0: float, y0: float, cell: float, slack: float, reach: float, radius: float,
                  corner: float, point_slope: float, out: np.ndarray) -> None:
    """``out[n]``: the highest ``top[j, i] - h`` over the grid points ``(i0[n] + di, j0[n] + dj)`` on the grid
    and within ``reach`` of the axis ``(x[n], y[n])``, ``h`` the tool's profile height (:meth:`Tool.profile_height`,
    ``point_slope`` a drill's, else ``radius`` and ``corner``) at the distance less ``slack``, clipped to
    ``0..radius``; ``-inf`` where there is none.

    x, y : (n,) float, the axes; i0, j0 : (n,) int, the grid point each rounds to; di, dj : (k,) int, the offsets
    asked, in order; top : (ny, nx) float, the stock's top on the grid of ``cell`` from ``(x0, y0)``.
    """
    ny, nx = top.shape
    flat = radius - corner
    for n in range(len(x)):
        best = -np.inf
        for k in range(len(di)):
            i = i0[n] + di[k]
            j = j0[n] + dj[k]
            if i < 0 or i >= nx or j < 0 or j >= ny:
                continue
            r = math.hypot(x0 + i * cell - x[n], y0 + j * cell - y[n])
            if not r <= reach:
                continue
            q = r - slack  # np.clip(r - slack, 0, radius): the maximum, then the minimum
            q = q if q > 0.0 else 0.0
            q = q if q < radius else radius
            if point_slope > 0.0:
                h = q * point_slope
            else:
                d = q - flat
                d = d if d > 0.0 else 0.0
                s = corner * corner - d * d
                h = corner - math.sqrt(s if s > 0.0 else 0.0)
            v = top[j, i] - h
            best = best if best > v else v  # as numpy's maximum: the second on a tie
        out[n] = best
