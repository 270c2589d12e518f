"""How deep a program cut into the part, grid point by grid point, as :mod:`cadcam.verify` judges it.

Depths and lengths in millimetres.
"""

from __future__ import annotations

import math

import numpy as np

from cadcam.heightmap import Grid, upper_envelope_at
from cadcam.stock import Simulation


def gouge_depths(sim: Simulation, tri: np.ndarray, covered: np.ndarray, rem: np.ndarray,
                 tolerance: float) -> np.ndarray:
    """How deep the program cut into the part at each ``covered`` grid point [mm] (negative: stock left over it),
    ``rem`` the stock over the part there.

    Only cuts deeper than the tolerance can fail the verdict; those are measured against the part within the
    tolerance sideways too (:func:`_lowest_part_near`). Where no part lies that near in some direction, the
    cut is a nick of a wall's edge however deep: no gouge, also where the column was cut through (the stock's
    ``-inf`` against the look's ``-inf``, which as NaN would have hidden every real gouge from the argmax).
    """
    deep = np.flatnonzero(rem < -tolerance)
    gouge = -rem
    if len(deep) and tolerance > 0:
        cells = np.flatnonzero(covered.reshape(-1))[deep]
        low = _lowest_part_near(tri, sim.grid, sim.part_top.reshape(-1)[cells], cells, tolerance)
        with np.errstate(invalid="ignore"):  # -inf - -inf, replaced
            gouge[deep] = np.where(np.isneginf(low), -np.inf, low - sim.stock_top.reshape(-1)[cells])
    return gouge


#: Directions [rad] in which :func:`_lowest_part_near` looks sideways: within 22.5 deg of
#: any wall normal, so a wall nicked less than ``cos(22.5 deg) = 0.92`` times the reach is
#: always seen past.
_SIDEWAYS = np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False)


def _lowest_part_near(tri: np.ndarray, grid: Grid, part_top: np.ndarray, cells: np.ndarray, reach: float) -> np.ndarray:
    """Lowest part top at, and ``reach`` [mm] sideways of, some grid points [mm].

    Why: on a vertical wall the part top jumps, so a tool that passes within the path
    tolerance of the wall (finishing touches walls by design, and the post-processor's
    line and arc fit may move the path ``arc_tolerance`` either way) takes a grid point
    lying a hair inside the wall down to the tool's side: a cut of the wall's full height
    at that point, though the tool reached only microns into the part. Measured against
    the lowest part top within ``reach`` sideways, such a nick counts for what it is, while
    a cut deeper into the part than ``reach`` in every direction keeps its full depth
    (floors, and walls cut into by more than the tolerance).

    Parameters
    ----------
    tri : (m, 3, 3) float
        Part triangles [mm].
    grid : Grid
    part_top : (k,) float
        Upper envelope of the part at those points [mm].
    cells : (k,) int
        Flat indices of the grid points (row-major, ``(ny, nx)``).
    reach : float
        How far to look sideways [mm].

    Returns
    -------
    (k,) float
        ``-inf`` where no part lies under some point looked at.
    """
    jj, ii = np.divmod(cells, grid.nx)
    i0, j0 = int(ii.min()), int(jj.min())
    low = np.asarray(part_top, dtype=np.float64).copy()
    for angle in _SIDEWAYS:
        # The grid points' bounding box, shifted; read at the points only (they are few: walls nicked).
        shifted = Grid(
            x0=grid.x0 + i0 * grid.cell + reach * math.cos(angle),
            y0=grid.y0 + j0 * grid.cell + reach * math.sin(angle),
            cell=grid.cell, nx=int(ii.max()) - i0 + 1, ny=int(jj.max()) - j0 + 1,
        )
        low = np.minimum(low, upper_envelope_at(tri, shifted, (jj - j0) * shifted.nx + (ii - i0)))
    return low
