"""The stock rack: which blank stands in which slot.

The rack (the cell file's ``rack``) is a grid of ``rows`` x ``columns`` slots at ``pitch`` [m]; a
blank stands centred on its slot, its edges along the slot's axes (:mod:`robotprog.tending`). Two
blanks in two slots stand clear of each other unless they overlap along both axes
(:func:`overlap`): a blank wider than the pitch (the relief's 124 mm blank in the 120 mm pitch)
cannot stand beside another as wide, but can beside a narrow one, or with the slot beside it left
empty.

The operator fills the rack in job order (:func:`next_slot`): each blank takes the first free slot,
row by row, that it fits beside the blanks standing there and that the rack camera sees whole
(``seen``); when none is left the rack is full, and it is refilled (:attr:`RackSlot.load` counts the
fillings). A blank that fits no slot the camera sees, even in an empty rack, is refused with the
reason (:class:`factory.core.errors.CellError`).

Frames and units: the slot frames of :meth:`robotprog.cell.SlotGrid.slot_transform`; metres.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

import numpy as np

from factory.core.errors import CellError
from factory.core.units import MM_PER_M
from robotprog.cell import Box, Pose, SlotGrid


@dataclass(frozen=True)
class RackSlot:
    """Where one blank stands: the scheduler's running slot number ``index``, the rack slot
    (``row``, ``column``), which filling of the rack ``load`` (0: the first), the blank's ``size``
    (3,) [m], and why the free slots before it were ``passed_over`` (:func:`slot_refusal`)."""

    index: int
    row: int
    column: int
    load: int
    size: tuple[float, float, float]
    passed_over: tuple[str, ...] = ()

    @property
    def cell(self) -> tuple[int, int]:
        """(row, column)."""
        return self.row, self.column

    def box(self, grid: SlotGrid, name: str = "rack_blank") -> Box:
        """The blank as a collision box in the world, centred on its slot, bottom at slot height."""
        t = grid.slot_transform(self.row, self.column)
        centre = (t @ np.array([0.0, 0.0, self.size[2] / 2, 1.0]))[:3]
        yaw = float(np.arctan2(t[1, 0], t[0, 0]))
        return Box(f"{name}_r{self.row}c{self.column}", self.size, Pose(tuple(float(v) for v in centre),
                                                                          (0.0, 0.0, yaw)))


def describe_size(size: Sequence[float]) -> str:
    """``124.0 x 84.0 mm`` (its footprint)."""
    return f"{size[0] * MM_PER_M:.1f} x {size[1] * MM_PER_M:.1f} mm"


def overlap(grid: SlotGrid, a: tuple[int, int], size_a: Sequence[float], b: tuple[int, int],
            size_b: Sequence[float]) -> float:
    """How far blanks of ``size_a`` and ``size_b`` (3,) [m] standing centred in slots ``a`` and ``b``
    (row, column) overlap [m]: the smaller of their overlaps along the slot axes (they overlap only
    where they do along both); <= 0 where they stand clear."""
    apart = np.abs(np.array([(b[1] - a[1]) * grid.pitch[0], (b[0] - a[0]) * grid.pitch[1]], dtype=float))
    need = (np.asarray(size_a[:2], dtype=float) + np.asarray(size_b[:2], dtype=float)) / 2
    return float((need - apart).min())


def slot_refusal(grid: SlotGrid, slot: tuple[int, int], size: Sequence[float], standing: Sequence[RackSlot]) -> str:
    """Why a blank of ``size`` (3,) [m] cannot stand in ``slot`` (row, column) beside the blanks
    ``standing`` in the rack ('' when it can)."""
    for s in standing:
        if s.cell == tuple(slot):
            return f"rack slot {tuple(slot)} holds a {describe_size(s.size)} blank already"
        o = overlap(grid, tuple(slot), size, s.cell, s.size)
        if o > 1e-9:
            return (f"a {describe_size(size)} blank does not fit rack slot {tuple(slot)}: it would overlap the "
                    f"{describe_size(s.size)} blank in slot {s.cell} by {o * MM_PER_M:.1f} mm (the rack's pitch is "
                    f"{grid.pitch[0] * MM_PER_M:.0f} x {grid.pitch[1] * MM_PER_M:.0f} mm)")
    return ""


def next_slot(grid: SlotGrid, index: int, size: Sequence[float], standing: Sequence[RackSlot],
              seen: Collection[tuple[int, int]]) -> RackSlot:
    """The slot the blank of the scheduler's slot number ``index``, ``size`` (3,) [m], is put in: the
    first free slot, row by row, of those the camera sees (``seen``, (row, column)), that it fits
    beside the blanks ``standing`` in the rack's current filling; the first such slot of a refilled
    rack when none is left.

    Raises
    ------
    CellError
        The blank fits no slot the camera sees even in an empty rack (``source`` ``rack``).
    """
    size = tuple(float(v) for v in size)
    load = max((s.load for s in standing), default=0)
    now = [s for s in standing if s.load == load]
    order = [(r, c) for r in range(grid.rows) for c in range(grid.columns) if (r, c) in seen]
    passed: list[str] = []
    for slot in order:
        why = slot_refusal(grid, slot, size, now)
        if not why:
            return RackSlot(index, slot[0], slot[1], load, size, tuple(passed))
        if not any(s.cell == slot for s in now):  # a free slot this blank does not fit
            passed.append(why)
    if not now:
        raise CellError(f"the rack camera sees no rack slot that holds a {describe_size(size)} blank whole "
                        f"(it sees {', '.join(map(str, order)) or 'none'})", source="rack")
    return replace(next_slot(grid, index, size, (), seen), load=load + 1)
