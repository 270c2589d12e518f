"""The stock rack: which blank stands in which slot, and the refusals where one does not fit."""

from __future__ import annotations

import pytest

from factory.core.errors import CellError
from robotprog.rack import RackSlot, next_slot, overlap, slot_refusal

BRACKET, RELIEF, DOME = (0.104, 0.064, 0.016), (0.124, 0.084, 0.02), (0.094, 0.074, 0.031)


def _all(cell):
    return frozenset((r, c) for r in range(cell.rack.rows) for c in range(cell.rack.columns))


def test_blanks_clear_each_other_unless_they_overlap_along_both_axes(cell):
    grid = cell.rack  # 2 x 3 slots at 120 x 100 mm
    assert overlap(grid, (0, 0), RELIEF, (0, 1), RELIEF) == pytest.approx(0.004)  # 124 mm in a 120 mm pitch
    assert overlap(grid, (0, 0), RELIEF, (0, 1), BRACKET) == pytest.approx(-0.006)  # (124 + 104) / 2 < 120
    assert overlap(grid, (0, 0), RELIEF, (1, 0), RELIEF) < 0 and overlap(grid, (0, 0), RELIEF, (1, 1), RELIEF) < 0


def test_the_rack_is_filled_row_by_row_where_each_blank_fits_and_refilled_when_full(cell):
    placed: list[RackSlot] = []
    for i, size in enumerate((BRACKET, RELIEF, RELIEF, DOME, RELIEF, RELIEF, BRACKET)):
        placed.append(next_slot(cell.rack, i, size, placed, _all(cell)))
    assert [(s.cell, s.load) for s in placed] == [
        ((0, 0), 0), ((0, 1), 0),  # the relief's blank stands beside the narrower bracket's
        ((1, 0), 0),  # not beside the other relief in (0, 1): the next row
        ((0, 2), 0),  # the dome's 94 mm beside the relief's 124 mm: 109 mm of the 120 mm pitch
        ((1, 2), 0),  # (1, 1) would stand between two reliefs
        ((0, 0), 1), ((0, 1), 1)]  # nothing left for a relief: the rack is refilled
    assert placed[-1].index == 6 and placed[-1].size == BRACKET
    # each says why it passed a free slot over
    assert placed[2].passed_over == ("a 124.0 x 84.0 mm blank does not fit rack slot (0, 2): it would overlap the "
                                     "124.0 x 84.0 mm blank in slot (0, 1) by 4.0 mm (the rack's pitch is 120 x 100 mm)",)
    assert placed[4].passed_over[0].startswith("a 124.0 x 84.0 mm blank does not fit rack slot (1, 1)")
    assert placed[0].passed_over == placed[3].passed_over == ()


def test_a_blank_that_does_not_fit_a_slot_is_refused_with_the_figures(cell):
    beside = [RackSlot(0, 0, 0, 0, RELIEF)]
    assert slot_refusal(cell.rack, (0, 1), RELIEF, beside) == (
        "a 124.0 x 84.0 mm blank does not fit rack slot (0, 1): it would overlap the 124.0 x 84.0 mm blank in "
        "slot (0, 0) by 4.0 mm (the rack's pitch is 120 x 100 mm)")
    assert slot_refusal(cell.rack, (0, 0), BRACKET, beside) == "rack slot (0, 0) holds a 124.0 x 84.0 mm blank already"
    assert slot_refusal(cell.rack, (0, 1), BRACKET, beside) == ""


def test_only_the_slots_the_camera_sees_are_filled_and_a_blank_it_sees_nowhere_is_refused(cell):
    middle = frozenset({(0, 1), (1, 1)})
    placed: list[RackSlot] = []
    for i in range(3):
        placed.append(next_slot(cell.rack, i, RELIEF, placed, middle))
    assert [(s.cell, s.load) for s in placed] == [((0, 1), 0), ((1, 1), 0), ((0, 1), 1)]
    with pytest.raises(CellError, match=r"the rack camera sees no rack slot that holds a 124\.0 x 84\.0 mm blank "
                                        r"whole \(it sees none\)"):
        next_slot(cell.rack, 0, RELIEF, (), frozenset())
