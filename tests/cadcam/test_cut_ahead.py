"""cadcam.cutahead: a program's first moves cut ahead (cut_ahead, in another process meanwhile) and the cut resumed
from there is the cut made in one go, to the bit; a state that is not the program's beginning is not used (issue 35)."""

from __future__ import annotations

import dataclasses
from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import cadcam.stock as stock
from cadcam.cutahead import cut_ahead
from cadcam.stock import cut_stock
from tests.cadcam.test_span_cull import SLOPED, assert_identical
from tests.cadcam.test_verify import LOW_PART, SETUP, TOOLS, C, R, moves_strategy, program

START = (20, 10, 5)


def _arrays(cut) -> dict[str, np.ndarray]:
    """Every array a cut returns: the stock, what each move removed and met, the moves as swept."""
    out = {"stock_top": cut.simulation.stock_top, "removed_volume": cut.simulation.removed_volume,
           "starts": cut.starts, "swept": cut.swept}
    out.update({k: v for k, v in vars(cut.met).items() if isinstance(v, np.ndarray)})
    out.update({"seg_" + f.name: getattr(cut.segments, f.name) for f in dataclasses.fields(stock.Segments)})
    return out


class _Batches:
    """Counts the batches cut (to tell a resumed cut from one made from the first move)."""

    def __init__(self):
        self.n = 0
        self.real = stock._run_batch

    def __call__(self, *args, **kwargs):
        self.n += 1
        return self.real(*args, **kwargs)


def _cut(moves, part, resume=None):
    batches = _Batches()
    with mock.patch.object(stock, "_run_batch", batches):
        cut = cut_stock(moves, TOOLS, SETUP, part, 0.5, resume=resume)
    return _arrays(cut), batches.n


#: A tail the program known so far ends with (the end of a program posted from its first operations):
#: up to the safe height and away, which the whole program does not do.
TAIL = [(R, 2, (1.0, 1.0, 5.0)), (C, 2, (1.0, 19.0, -3.0))]


@settings(max_examples=40, deadline=None)
@given(first=moves_strategy, rest=moves_strategy, part=st.sampled_from(["low", "sloped"]),
       every=st.sampled_from([1, 3, 16]), steps=st.integers(1, 3), tail=st.booleans())
def test_resuming_a_cut_made_ahead_is_the_cut_made_in_one_go(first, rest, part, every, steps, tail):
    """Whatever the batches (one move or a few each), the stock bounds' schedule and however many steps the
    cut ahead was made in, with or without moves after the ones known: the cut resumed from it is the plain
    one, and it did resume (fewer batches)."""
    tri = LOW_PART if part == "low" else SLOPED
    whole = program(first + rest, start=START)
    with mock.patch.object(stock, "_PAIR_BUDGET", 300), mock.patch.object(stock, "_SPAN_TOPS_EVERY", every):
        plain, n_plain = _cut(whole, tri)
        state = None
        for k in range(1, steps + 1):  # the first moves known in steps, each cut on from the last
            known = first[:max(1, len(first) * k // steps)]
            ahead = program(known + (TAIL if tail else []), start=START)
            state = cut_ahead(ahead, TOOLS, SETUP, tri, 0.5, before=len(known) + 1, resume=state)
        resumed, n_resumed = _cut(whole, tri, resume=state)
    assert_identical(resumed, plain)
    if state is not None:
        assert state.moves <= len(first)  # nothing of the tail was taken
        assert n_resumed == n_plain - (len(state.bounds) - 1)  # the batches made ahead were not cut again


@settings(max_examples=40, deadline=None)
@given(first=moves_strategy, rest=moves_strategy, part=st.sampled_from(["low", "sloped"]),
       changed=st.integers(0, 11), by=st.sampled_from([0.25, -0.5, 3.0]), what=st.sampled_from(["move", "tool"]))
def test_a_cut_ahead_of_moves_that_then_changed_is_not_used(first, rest, part, changed, by, what):
    """The speculation invalidated: one of the first moves changed before the whole program was known (the
    rapid check slowed it, a coordinate was rounded otherwise, another tool took it). The cut is still the
    plain one, and it was not resumed from a state holding the changed move."""
    tri = LOW_PART if part == "low" else SLOPED
    k = changed % len(first)
    m, t, (x, y, z) = first[k]
    edited = list(first)
    edited[k] = (m, t, (x, y, z + by)) if what == "move" else (m, 3 if t != 3 else 2, (x, y, z))
    whole = program(edited + rest, start=START)
    with mock.patch.object(stock, "_PAIR_BUDGET", 300):
        state = cut_ahead(program(first + TAIL, start=START), TOOLS, SETUP, tri, 0.5, before=len(first) + 1)
        plain, n_plain = _cut(whole, tri)
        resumed, n_resumed = _cut(whole, tri, resume=state)
    assert_identical(resumed, plain)
    if state is not None and state.moves > k:  # the state holds the changed move: not resumed from it
        assert n_resumed == n_plain


def test_a_state_of_another_part_or_stock_is_not_used_and_the_check_can_fail():
    """The same moves into another part are another cut: the state is refused. And the tests above can
    fail: a state whose stock is not what its moves leave, resumed from, changes the cut."""
    blocks = [(R, 1, (2.0, 2.0, 5.0)), (C, 1, (2.0, 2.0, -3.0)), (C, 1, (38.0, 2.0, -3.0)), (C, 1, (38.0, 18.0, -3.0)),
              (C, 2, (2.0, 18.0, -2.0)), (C, 2, (2.0, 10.0, -4.0)), (C, 2, (30.0, 10.0, -4.5))]
    whole = program(blocks, start=START)
    with mock.patch.object(stock, "_PAIR_BUDGET", 300):
        state = cut_ahead(program(blocks[:5] + TAIL, start=START), TOOLS, SETUP, LOW_PART, 0.5, before=6)
        assert state is not None and len(state.bounds) > 2
        plain_low, n_low = _cut(whole, LOW_PART)
        plain_sloped, n_sloped = _cut(whole, SLOPED)
        resumed, n = _cut(whole, SLOPED, resume=state)  # cut ahead into the other part
        assert_identical(resumed, plain_sloped)
        assert n == n_sloped
        wrong = dataclasses.replace(state, stock=state.stock + 0.3)  # material the moves did not leave
        resumed, n = _cut(whole, LOW_PART, resume=wrong)
    assert n < n_low  # resumed: its key and moves are the program's
    assert not np.array_equal(resumed["stock_top"], plain_low["stock_top"])
