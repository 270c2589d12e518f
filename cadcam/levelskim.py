"""Which roughing level over the top floor to leave to the finishing (issue 32: op 1's time).

A part's top floor 1 mm under the stock top gets a roughing level at its allowance (0.7 mm under
the top) over the whole stock: a full level's path for 0.7 mm, and the facing pass of the finishing
that follows takes the whole 1 mm at the feed it takes 0.3 mm (its engagement allows 1.5). So where all
that level would cut is either that skin or cut by the level below it anyway, it is not cut
(:func:`without_skimmed`, :attr:`cadcam.roughing.RoughingOptions.skim`).

The same holds inside the part: a floor's level 1 mm above the next one (plate_bosses: its counterbores'
floors at -6 mm, its locating boss at -7) is a full level's path for 1 mm. Where the level below may take
the stock from the last level cut over its whole region in one step (no deeper than the stepdown), the
level in between is cut only where the one below cannot reach: round the floor it exists for
(:func:`local_levels`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

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
    skin = top_skin(part, levels, top, skim, allowance, floor_eps)
    if skin is None or len(levels) < 2:
        return levels, spaces
    covered = shapely.union_all([spaces[1].buffer(radius + SKIM_TOL, quad_segs=8), skin])
    missed = spaces[0].buffer(radius, quad_segs=8).difference(covered)
    return (levels[1:], spaces[1:]) if missed.buffer(-SKIM_SLIVER * radius).is_empty else (levels, spaces)


def top_skin(part: trimesh.Trimesh, levels: np.ndarray, top: float, skim: float, allowance: float,
             floor_eps: float) -> BaseGeometry | None:
    """The XY area [mm] of the skin over the part's top floor that the finishing takes whole: the floor under the
    first of the roughing ``levels`` (top down) grown by the ``allowance`` (and :data:`SKIM_TOL`), where that
    level lies within ``skim`` of the stock ``top``; None where it does not (no level is skimmed). ``floor_eps``:
    material this little under a level's allowance is its floor. All [mm]."""
    if not (skim > 0 and len(levels) > 0 and top - float(levels[0]) <= skim + 1e-9):
        return None
    floor = part_shadows(part, [float(levels[0]) - allowance - floor_eps])
    return shapely.union_all([g.buffer(allowance + SKIM_TOL, quad_segs=8) for g in floor.values()])


#: A level is cut locally (:func:`local_levels`) only where that leaves at most this share of its region's area:
#: a local region is cut from the last whole level, so it pays only where it is much smaller.
LOCAL_SHARE = 0.5


@dataclass(frozen=True)
class LevelReach:
    """The roughing levels' tool-centre regions once some are cut locally (:func:`local_levels`).

    ``spaces``: per level, the region to clear (a local level's: only round what the next whole level
    cannot reach); ``floor_above``: per level, the height [mm] down to which the stock over its region is
    known to be cut before it (the last whole level's, the stock top above the first); ``local``: per
    level, whether it is cut locally."""

    spaces: tuple[BaseGeometry, ...]
    floor_above: tuple[float, ...]
    local: tuple[bool, ...]


def local_levels(levels: np.ndarray, spaces: Sequence[BaseGeometry], top: float, stepdown: float, radius: float,
                 taken: Callable[[int], BaseGeometry | None] | None = None, skin: BaseGeometry | None = None
                 ) -> LevelReach:
    """Which roughing ``levels`` (top down, [mm]) to cut only where the next whole level cannot reach.

    A level ``k`` is local when the next whole level ``j`` below it lies no more than ``stepdown`` [mm] under
    the last whole level above it (or the stock ``top``): ``j`` then takes the stock over its whole region in
    one step, within the depth any level may take at full width, and ``k`` need clear only the stock within
    the tool ``radius`` of its region ``spaces[k]`` that is not within ``radius`` of ``spaces[j]`` (to
    :data:`SKIM_TOL`: the floors and bosses ``j``'s shadow keeps it from), with every tool centre within
    ``radius`` of that stock, and the areas deep cuts take from the next level down (``taken(k + 1)``: a deep cut
    starts from the floor of the level above its band, so that floor is cut over it). Only where the local region
    is at most :data:`LOCAL_SHARE` of the level's. The last level is always whole.

    ``skin`` (:func:`top_skin`, None: none): the XY area [mm] of the top floor's skin, which the finishing takes
    whole; a local first level leaves it, and the slivers beside it no disc of :data:`SKIM_SLIVER` ``radius``
    fits in (the rest tools'), as :func:`without_skimmed` does: it cuts only the stock round the top floor that
    no level below reaches (plate_bosses: the gaps between its bosses, not the bosses' tops)."""
    n = len(levels)
    out, floor_above, local = list(spaces), [float(top)] * n, [False] * n
    hi, k = float(top), 0
    while k < n:
        j = k  # the deepest level the stock over the last whole one may be taken down to in one step
        while j + 1 < n and hi - float(levels[j + 1]) <= stepdown + 1e-9:
            j += 1
        floor_above[k] = hi
        if j > k:
            reach = spaces[j].buffer(radius + SKIM_TOL, quad_segs=8)
            missed = spaces[k].buffer(radius, quad_segs=8).difference(reach)
            if k == 0 and skin is not None:
                sliver = SKIM_SLIVER * radius
                missed = missed.difference(skin).buffer(-sliver, quad_segs=8).buffer(sliver, quad_segs=8)
            deep = taken(k + 1) if taken is not None else None  # a deep cut starting under it starts from its floor
            keep = missed.buffer(radius + SKIM_TOL, quad_segs=8)
            if deep is not None:
                keep = keep.union(deep.buffer(radius + SKIM_TOL, quad_segs=8))
            region = spaces[k].intersection(keep)
            if region.area <= LOCAL_SHARE * spaces[k].area:
                out[k], local[k] = region, True
                k += 1
                continue
        hi = float(levels[k])  # a whole level: what lies under it is taken from its floor
        k += 1
    return LevelReach(spaces=tuple(out), floor_above=tuple(floor_above), local=tuple(local))
