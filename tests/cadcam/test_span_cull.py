"""cadcam.stock: the runs of grid points a move provably cannot cut are not paired at all, and the cut is the same to the bit (issue 35)."""

from __future__ import annotations

import contextlib
import os
import threading
from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import cadcam.envelope
import cadcam.model
import cadcam.stock as stock
from cadcam.heightmap import grid_over
from cadcam.stock import cut_stock
from tests.cadcam.test_verify import BALL, BULL, FLAT, LOW_PART, SETUP, STUBBY, TOOLS, C, R, box, moves_strategy, program

#: A part with a sloped top and a step, so moves meet the part and the stock at many heights.
SLOPED = np.concatenate([LOW_PART, box([2, 2, -10], [12, 18, -2]), box([28, 3, -10], [38, 9, -1])])


def _cut(moves, part, cull: bool, tools=TOOLS, threads: str = "1", pair_cull: bool = True):
    """Every array cut_stock returns, with the run cull on or off (``above`` then bounds nothing), with each
    batch's pairs made in the batch itself (``threads`` "1") or ahead in a second thread ("2"), with the pairs
    whose cheap bound stays over the stock dropped where they are made (``pair_cull``) or kept to the envelope
    and every level of the tools' bodies swept (no ceiling)."""
    with contextlib.ExitStack() as patches:
        patches.enter_context(mock.patch.dict(os.environ, {"FACTORY_THREADS": threads}))
        if not cull:
            patches.enter_context(mock.patch.object(stock._SpanTops, "above",
                                                    lambda self, row, first, count: np.full(len(row), np.inf)))
        if not pair_cull:
            real = cadcam.envelope.BatchPairs.of.__func__
            patches.enter_context(mock.patch.object(
                stock.BatchPairs, "of", classmethod(lambda cls, *args: real(cls, *args[:4]))))
            patches.enter_context(mock.patch.object(stock._SpanTops, "highest", lambda self: np.inf))
        c = cut_stock(moves, tools, SETUP, part, 0.5)
    arrays = {"stock_top": c.simulation.stock_top, "removed_volume": c.simulation.removed_volume}
    arrays.update({k: v for k, v in vars(c.met).items() if isinstance(v, np.ndarray)})
    return arrays


def assert_identical(a, b) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].shape == b[k].shape and np.array_equal(a[k], b[k]), k  # to the bit


@settings(max_examples=40, deadline=None)
@given(blocks=moves_strategy, again=st.booleans(), part=st.sampled_from(["low", "sloped"]),
       budget=st.sampled_from([300, 1 << 16]), every=st.sampled_from([1, 16]), block=st.sampled_from([1, 4, 16]),
       piece=st.sampled_from([1, 3, 8, 1 << 20]))
def test_culling_the_runs_a_move_cannot_cut_changes_nothing(blocks, again, part, budget, every, block, piece):
    """Whatever the batches, the tops' staleness and their blocks, and the pieces runs are judged in again:
    the stock, what each move met and removed are the unculled cut's (a program run twice: runs of its second
    pass are culled)."""
    moves = program(blocks + blocks if again else blocks, start=(20, 10, 5))
    tri = LOW_PART if part == "low" else SLOPED
    with mock.patch.object(stock, "_PAIR_BUDGET", budget), mock.patch.object(stock, "_SPAN_TOPS_EVERY", every), \
            mock.patch.object(stock._SpanTops, "_BLOCK", block), mock.patch.object(cadcam.envelope, "_PIECE", piece):
        assert_identical(_cut(moves, tri, cull=True), _cut(moves, tri, cull=False))


@settings(max_examples=30, deadline=None)
@given(blocks=moves_strategy, again=st.booleans(), part=st.sampled_from(["low", "sloped"]),
       budget=st.sampled_from([300, 2000]), every=st.sampled_from([1, 3, 16]))
def test_pairs_made_while_the_batch_before_cuts_change_nothing(blocks, again, part, budget, every):
    """Each batch's pairs made in a second thread from the stock bounds the batch before cut with (staler than
    its own): the stock, what each move met and removed are those of the pairs made in each batch, to the bit."""
    moves = program(blocks + blocks if again else blocks, start=(20, 10, 5))
    tri = LOW_PART if part == "low" else SLOPED
    with mock.patch.object(stock, "_PAIR_BUDGET", budget), mock.patch.object(stock, "_SPAN_TOPS_EVERY", every):
        assert_identical(_cut(moves, tri, cull=True, threads="2"), _cut(moves, tri, cull=True, threads="1"))


@settings(max_examples=30, deadline=None)
@given(blocks=moves_strategy, again=st.booleans(), part=st.sampled_from(["low", "sloped"]),
       budget=st.sampled_from([300, 2000, 1 << 16]), threads=st.sampled_from(["1", "2"]))
def test_pairs_dropped_against_the_stock_where_they_are_made_change_nothing(blocks, again, part, budget, threads):
    """The pairs whose cheap bound is at or over the stock (read as the batch before cuts it, in a second
    thread, or as the batch begins) leave before the envelope, and the bodies are swept under the tops'
    highest: the stock, what each move met and removed are those of the cut that takes every pair to the
    envelope and sweeps every level of the bodies, to the bit."""
    moves = program(blocks + blocks if again else blocks, start=(20, 10, 5))
    tri = LOW_PART if part == "low" else SLOPED
    with mock.patch.object(stock, "_PAIR_BUDGET", budget):
        assert_identical(_cut(moves, tri, cull=True, threads=threads),
                         _cut(moves, tri, cull=True, threads=threads, pair_cull=False))


def test_the_pairs_over_the_stock_are_dropped_and_a_wrong_stock_is_caught():
    """The test above can fail: on a pass run twice most pairs the envelope is given are dropped where they
    are made, and a stock read lower than it is (so pairs that cut are dropped) changes the cut."""
    moves = _finishing_twice()
    given_pairs = {True: 0, False: 0}
    real_envelope = cadcam.envelope.BatchPairs.envelope
    real_of = cadcam.envelope.BatchPairs.of.__func__
    for pair_cull in (True, False):
        def counting(self, seg, bound, _cull=pair_cull):
            given_pairs[_cull] += len(self.owner)
            return real_envelope(self, seg, bound)

        with mock.patch.object(stock, "_PAIR_BUDGET", 300), \
                mock.patch.object(stock.BatchPairs, "envelope", counting):
            _cut(moves, SLOPED, cull=True, pair_cull=pair_cull)
    assert given_pairs[True] < 0.8 * given_pairs[False], given_pairs
    whole = _cut(moves, SLOPED, cull=True, pair_cull=False)
    low = classmethod(lambda cls, seg, grid, above, pairs, stock_top: real_of(cls, seg, grid, above, pairs,
                                                                              stock_top - 0.5))
    with mock.patch.object(stock, "_PAIR_BUDGET", 300), mock.patch.object(stock.BatchPairs, "of", low):
        wrong = _cut(moves, SLOPED, cull=True)
    assert not np.array_equal(wrong["stock_top"], whole["stock_top"])


def test_pairs_are_made_ahead_in_a_second_thread_with_two_processors():
    """The test above compares something: with two processors the batches after the first get their pairs
    from the second thread (made with the bounds of the batch before), with one none does."""
    real = cadcam.envelope.BatchPairs.of
    made = {"1": [], "2": []}
    for threads in ("1", "2"):
        def recording(*args, _made=made[threads]):
            _made.append(threading.current_thread() is threading.main_thread())
            return real(*args)

        with mock.patch.object(stock, "_PAIR_BUDGET", 300), \
                mock.patch.object(stock.BatchPairs, "of", staticmethod(recording)):
            _cut(_finishing_twice(), SLOPED, cull=True, threads=threads)
    assert made["1"] and all(made["1"])
    assert made["2"].count(True) == 1 and made["2"].count(False) == len(made["1"]) - 1


def _finishing_twice():
    """A ball finishing pass at one height over the sloped part, then the same pass again: the second cuts nothing."""
    rows = [(C, 2, (x, y, -1.5)) for y in np.arange(2.0, 18.0, 1.0) for x in (2.0, 38.0)]
    return program([(R, 2, (2.0, 2.0, 5.0))] + rows + [(R, 2, (38.0, 18.0, 5.0)), (R, 2, (2.0, 2.0, 5.0))] + rows,
                   start=(20, 10, 5))


def test_the_cull_drops_pairs_and_a_wrong_bound_is_caught():
    """The test above can fail: the cull does drop pairs here, and tops that claim the stock lower than it
    is (so runs it does cut are dropped) change the cut."""
    moves = _finishing_twice()
    counted = []
    real = cadcam.envelope.grid_pairs

    def counting(seg, grid, above=None):
        out = real(seg, grid, above)
        if above is not None:  # the cutter's pairs and the body's
            counted.append(len(out[0]))
        return out

    with mock.patch.object(stock, "_PAIR_BUDGET", 300), mock.patch.object(stock, "_SPAN_TOPS_EVERY", 1):
        with mock.patch.object(stock, "grid_pairs", counting):
            culled = _cut(moves, SLOPED, cull=True)
            n_culled, counted[:] = sum(counted), []
            whole = _cut(moves, SLOPED, cull=False)
            n_whole = sum(counted)
        assert_identical(culled, whole)
        assert n_culled < 0.85 * n_whole, (n_culled, n_whole)  # runs of the second pass are dropped
        with mock.patch.object(stock._SpanTops, "above", lambda self, row, first, count: np.full(len(row), -np.inf)):
            wrong = _cut(moves, SLOPED, cull=True)
    assert not np.array_equal(wrong["stock_top"], whole["stock_top"])


def test_a_holder_swept_low_beside_tall_stock_meets_it_as_unculled_and_pairs_only_near_it():
    """The shank and holder are culled too (where they stay over the stock and the part, which they meet): the
    10 mm end mill faces the stock's right side 3 mm down; a short tool (16 mm holder 8 mm over its tip) cuts a
    narrow pocket 1 mm a level down to 9 mm on the left, its holder on the whole stock round it, then feeds
    9.5 mm deep beside the part's low box under the faced side: the contacts are the unculled ones to the bit,
    and far fewer body pairs are made (the holder stays over the faced stock)."""
    face = [(C, 4, (x, y, -3.0)) for y in (0.0, 5.0, 10.0, 15.0, 20.0) for x in (14.0, 40.0)]
    pocket = [(C, 5, (x, 10.0, -z)) for z in np.arange(1.0, 10.0) for x in (3.0, 6.0, 3.0)]
    floor = [(C, 5, (x, y, -9.5)) for y in (2.0, 18.0) for x in (24.0, 38.0, 24.0)]
    moves = program([(R, 4, (14.0, 0.0, 2.0))] + face + [(R, 4, (40.0, 20.0, 2.0)), (R, 5, (3.0, 10.0, 2.0))] + pocket
                    + [(R, 5, (3.0, 10.0, 2.0)), (R, 5, (24.0, 2.0, 2.0))] + floor, start=(20, 10, 5))
    tools = {**TOOLS, 5: STUBBY}
    counted = []
    real = stock.grid_pairs

    def counting(seg, grid, above=None):
        out = real(seg, grid, above)
        if np.any(seg.radius >= STUBBY.holder[0].diameter / 2 - 1e-9):  # the body's (the cutters are narrower)
            counted.append(len(out[0]))
        return out

    with mock.patch.object(stock, "_PAIR_BUDGET", 300), mock.patch.object(stock, "_SPAN_TOPS_EVERY", 1), \
            mock.patch.object(stock, "grid_pairs", counting):
        culled = _cut(moves, LOW_PART, cull=True, tools=tools)
        n_culled, counted[:] = sum(counted), []
        whole = _cut(moves, LOW_PART, cull=False, tools=tools)
        n_whole = sum(counted)
    assert_identical(culled, whole)
    assert whole["contact"].max() == 1.0  # the holder came 9 - 8 mm down onto the stock round the pocket
    assert n_culled < 0.7 * n_whole, (n_culled, n_whole)


def test_judging_runs_again_in_pieces_drops_pairs_the_whole_runs_keep():
    """A run's pieces (``envelope._PIECE`` columns) are judged on their own stretch of stock and their own
    distance from the move: in the second ball pass (moves along X, where a run's ends are far from the move)
    they drop pairs the whole runs keep, and the cut is the same to the bit."""
    moves = _finishing_twice()
    counted = []
    real = cadcam.envelope.grid_pairs

    def counting(seg, grid, above=None):
        out = real(seg, grid, above)
        if above is not None:
            counted.append(len(out[0]))
        return out

    with mock.patch.object(stock, "_PAIR_BUDGET", 300), mock.patch.object(stock, "_SPAN_TOPS_EVERY", 1), \
            mock.patch.object(stock, "grid_pairs", counting):
        pieces = _cut(moves, SLOPED, cull=True)
        n_pieces, counted[:] = sum(counted), []
        with mock.patch.object(cadcam.envelope, "_PIECE", 1 << 20):  # one piece a run: runs judged whole
            runs = _cut(moves, SLOPED, cull=True)
        n_runs = sum(counted)
    assert_identical(pieces, runs)
    assert n_pieces < 0.9 * n_runs, (n_pieces, n_runs)


@settings(max_examples=60, deadline=None)
@given(moves=st.lists(st.tuples(st.floats(2, 38), st.floats(2, 18), st.floats(-6, 0), st.floats(2, 38), st.floats(2, 18),
                                st.floats(-6, 0), st.sampled_from([0, 1, 2, 3])), min_size=1, max_size=6),
       heights=st.lists(st.floats(-6, 1), min_size=4, max_size=4), fall=st.floats(0, 6))
def test_pairs_made_against_a_stock_give_pair_envelopes_against_any_lower_one(moves, heights, fall):
    """Pairs made against a stock, their envelopes worked out then (a bull-nose's bisection with the steps of
    all of them), cut against the stock fallen since: each is :func:`pair_envelope`'s value to the bit (the
    bisection done again where the pairs left need fewer steps), and those dropped have none."""
    tools = [FLAT, BALL, BULL, cadcam.model.Tool(7, "drill", "drill", 6.0, 0.0, 20.0, 2, 40.0, point_angle=118.0)]
    p0 = np.array([m[:3] for m in moves])
    p1 = np.array([m[3:6] for m in moves])
    used = [tools[m[6]] for m in moves]
    seg = cadcam.envelope.Segments.between(p0, p1, [t.radius for t in used], [float(t.corner_radius) for t in used],
                                          cone=[t.point_slope for t in used])
    grid = grid_over(np.array([0.0, 0.0, -10.0]), np.array([40.0, 20.0, 0.0]), 0.5)
    xs = grid.x0 + np.arange(grid.ny * grid.nx) % grid.nx * grid.cell
    made = np.interp(xs, [0.0, 13.0, 26.0, 40.0], heights)  # a stock of four slopes
    now = made - fall * (np.arange(len(made)) % 3 == 0)  # cut down since, here and there
    pairs = cadcam.envelope.BatchPairs.of(seg, grid, None, None, made)
    owner, flat, col, row = cadcam.envelope.grid_pairs(seg, grid)
    whole = cadcam.envelope.pair_envelope(grid.x0 + col * grid.cell, grid.y0 + row * grid.cell, owner, seg, now[flat])
    kept = {(int(o), int(f)): v for o, f, v in zip(pairs.owner, pairs.flat, pairs.envelope(seg, now[pairs.flat]))}
    for o, f, v in zip(owner.tolist(), flat.tolist(), whole):
        assert kept.get((o, f), np.inf) == v or (np.isnan(v) and np.isnan(kept[(o, f)]))
    assert len(kept) <= len(owner)


def test_a_bisection_left_with_shorter_stretches_takes_fewer_steps_as_before():
    """The test above meets both cases: here the long sloped bull-nose move's pairs are all below the stock
    now (cut down to -10 mm) but the short one's, so the pairs left take fewer steps than those made did, and
    their values are still pair_envelope's (the bisection done again)."""
    p0, p1 = np.array([[5.0, 10.0, -1.0], [20.0, 5.0, -1.0]]), np.array([[35.0, 10.0, -5.0], [20.5, 5.0, -1.2]])
    seg = cadcam.envelope.Segments.between(p0, p1, [BULL.radius] * 2, [BULL.corner_radius] * 2)
    grid = grid_over(np.array([0.0, 0.0, -10.0]), np.array([40.0, 20.0, 0.0]), 0.5)
    made = np.zeros(grid.ny * grid.nx)
    now = np.where(grid.y0 + np.arange(len(made)) // grid.nx * grid.cell < 7.0, 0.0, -10.0)
    pairs = cadcam.envelope.BatchPairs.of(seg, grid, None, None, made)
    left = np.flatnonzero(pairs.bisect & (pairs.approach.lower < now[pairs.flat]))
    assert 0 < len(left) < pairs.bisect.sum() and cadcam.envelope._bisect_steps(pairs.lengths[left]) < pairs.steps
    expected = cadcam.envelope.pair_envelope(grid.x0 + pairs.col * grid.cell, grid.y0 + pairs.row * grid.cell,
                                             pairs.owner, seg, now[pairs.flat])
    assert np.array_equal(pairs.envelope(seg, now[pairs.flat]), expected)
    assert np.isfinite(expected[left]).all()
