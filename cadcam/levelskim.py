"""Which roughing level over the top floor to leave to the finishing (issue 32: op 1's time).

A part's top floor 1 mm under the stock top gets a roughing level at its allowance (0.7 mm under
the top) over the whole stock: a full level's path for 0.7 mm, and the facing pass of the finishing
that follows takes the whole 1 mm at the feed it takes 0.3 mm (its engagement allows 1.5). So where all
that level would cut is either that skin or cut by the level below it anyway, it is not cut
(:func:`without_skimmed`, :attr:`cadcam.roughing.RoughingOptions.skim`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
import trimesh
from shapely.geometry.base import BaseGeometry

from cadcam.shadow import part_shadows

#: How far [mm] the tool-centre region of the level under a skimmed one may fall short of it (buffering's
#: chords): the stock so left is within a hundredth of a millimetre of a cut path.
SKIM_TOL = 0.01
#: The widest stock [share of R] that only a skimmed level would have cut may leave for the rest tools: the
#: corners of pockets in the top floor (a square corner's cusp holds a disc of 0.17 (R + allowance) at most;
#: bracket: 0.6 mm^2 each), not a region (plate_bosses: 680 mm^2, 310 of it wider than this).
SKIM_SLIVER = 0.25


def without_skimmed(part: trimesh.Trimesh, levels: np.ndarray, spaces: Sequence[BaseGeometry], top: float,
                    skim: float, allowance: float, radius: float, floor_eps: float
                    ) -> tuple[np.ndarray, Sequence[BaseGeometry]]:
    """The roughing ``levels`` (top down) and their tool-centre regions ``spaces``, less the first level
    where it lies within ``skim`` of the stock ``top`` and all it would cut (its
    tool-centre region ``spaces[0]`` grown by the tool ``radius``) is either over the part's top floor and
    the ``allowance`` round it (the skin the finishing then takes whole, within its engagement) or cut by
    the level below anyway (within ``radius`` of ``spaces[1]``, to :data:`SKIM_TOL`), but for slivers no
    disc of :data:`SKIM_SLIVER` ``radius`` fits in (the inside corners of pockets in the top floor, the rest
    tools' anyway). So no stock beside the top floor waits for a rest tool from the stock top
    (plate_bosses: the gaps between its bosses, which only the top level enters with the roughing tool).
    ``floor_eps``: material this little under a level's allowance is its floor. All [mm]."""
    if not (skim > 0 and len(levels) > 1 and top - float(levels[0]) <= skim + 1e-9):
        return levels, spaces
    floor = part_shadows(part, [float(levels[0]) - allowance - floor_eps])
    covered = shapely.union_all([spaces[1].buffer(radius + SKIM_TOL, quad_segs=8),
                                 *(g.buffer(allowance + SKIM_TOL, quad_segs=8) for g in floor.values())])
    missed = spaces[0].buffer(radius, quad_segs=8).difference(covered)
    return (levels[1:], spaces[1:]) if missed.buffer(-SKIM_SLIVER * radius).is_empty else (levels, spaces)
