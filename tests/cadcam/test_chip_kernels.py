"""cadcam.toolsweep's fused kernels of the chip feeds' cut (issue 35): each gives, to the bit, what the numpy steps
it replaced gave on the same pairs, so the stock, every move's chip and every feed rate stay the same."""

from __future__ import annotations

from unittest import mock

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import cadcam.envelope
from cadcam import toolsweep
from cadcam.engagement import MoveRecord, _across, _plunged, _side_chip, side_chip
from cadcam.envelope import BatchPairs, SpanTops, _Approach, grid_pairs
from tests.cadcam.test_toolsweep import GRID, TOOLS, _segments, moves

tool_moves = st.lists(st.tuples(st.sampled_from(range(len(TOOLS))), moves()), min_size=1, max_size=5)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal shape and values to the bit (NaN where NaN)."""
    return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)


@settings(max_examples=60, deadline=None)
@given(n_moves=st.integers(1, 6), seed=st.integers(0, 2**32 - 1), with_under=st.booleans())
def test_pairs_cut_in_turn_find_what_the_running_minimum_over_points_gives(n_moves, seed, with_under):
    """Pairs move by move, each grid point once a move (as a batch's come), some out of reach (inf), the stock
    with empty columns and, for a flipped stock, a bottom: the pairs that cut, the stock each found and the stock
    left are those of the running minimum over the pairs sorted by point and move
    (:func:`toolsweep.segmented_exclusive_min`, the cut without the shank and holder before)."""
    rng = np.random.default_rng(seed)
    size = 40
    owner = np.concatenate([np.full(k, m) for m, k in enumerate(rng.integers(0, 25, n_moves))]).astype(np.int64)
    flat = np.concatenate([np.sort(rng.choice(size, int((owner == m).sum()), replace=False))
                           for m in range(n_moves)]).astype(np.int64)
    env = np.where(rng.random(len(flat)) < 0.2, np.inf, rng.uniform(-5, 5, len(flat)))
    stock = np.where(rng.random(size) < 0.1, -np.inf, rng.uniform(-3, 5, size))
    under = rng.uniform(-6, 0, size) if with_under else None

    # the sort and the running minimum, as the cut did it
    ref = stock.copy()
    touch = np.flatnonzero(env < ref[flat])
    o, f, e = owner[touch], flat[touch], env[touch]
    order = np.argsort(f * (2 * n_moves + 2) + o * 2 + 1, kind="stable")
    earlier = np.empty(len(f))
    earlier[order] = toolsweep.segmented_exclusive_min(f[order], e[order])
    found = np.minimum(ref[f], earlier)
    if under is not None:
        found[~(found > under[f])] = -np.inf
    cut_ref = np.flatnonzero(found - e > 0.0)
    np.minimum.at(ref, f[cut_ref], e[cut_ref])

    mine = stock.copy()
    cut, before = toolsweep.cut_in_turn(flat, env, mine, mine if under is None else under, under is not None)
    assert np.array_equal(cut, touch[cut_ref])
    assert _same(before, found[cut_ref])
    assert _same(mine, ref)


@settings(max_examples=60, deadline=None)
@given(moves=tool_moves, seed=st.integers(0, 2**32 - 1), cut=st.floats(0.0, 8.0), culled=st.booleans(),
       fall=st.floats(0.0, 3.0), piece=st.sampled_from([1, 3, 16]))
def test_the_pairs_that_can_cut_are_those_of_every_pair_s_approach_filtered(moves, seed, cut, culled, fall, piece):
    """:func:`toolsweep.kept_pairs` (its runs and pieces judged against the tops of the stock, or of the stock
    before it fell, or not at all) gives the pairs, in order, and each one's ``lower, wx, wy, wd`` that
    :func:`grid_pairs` then :meth:`_Approach.of` give, less those out of reach or whose ``lower`` is not under
    the stock (empty columns too), to the bit; and :meth:`BatchPairs.of` takes this way with the tops' bounds."""
    seg, *_ = _segments(moves)
    rng = np.random.default_rng(seed)
    made = 5.0 - cut * rng.random(GRID.size)
    stock = made - fall * (rng.random(GRID.size) < 0.3)
    stock[rng.random(GRID.size) < 0.05] = -np.inf
    tops = SpanTops(made, GRID) if culled else None
    owner, flat, col, row = grid_pairs(seg, GRID)
    a = _Approach.of(GRID.x0 + col * GRID.cell, GRID.y0 + row * GRID.cell, owner, seg)
    keep = np.flatnonzero(a.reach & (a.lower < stock[flat]))
    with mock.patch.object(cadcam.envelope, "_PIECE", piece):
        got_owner, got_flat, got_col, got_row, got = _Approach.kept(seg, GRID, stock, tops)
    for want, have in ((owner, got_owner), (flat, got_flat), (col, got_col), (row, got_row), (a.lower, got.lower),
                       (a.wx, got.wx), (a.wy, got.wy), (a.wd, got.wd)):
        assert _same(have, want[keep])
    assert got.reach.all()
    with mock.patch.object(toolsweep, "kept_pairs", side_effect=toolsweep.kept_pairs) as walked:
        pairs = BatchPairs.of(seg, GRID, None if tops is None else tops.above, cadcam.envelope.grid_pairs, stock)
    assert walked.called and np.array_equal(pairs.flat, flat[keep]) and _same(pairs.approach.lower, a.lower[keep])


@settings(max_examples=60, deadline=None)
@given(moves=tool_moves, seed=st.integers(0, 2**32 - 1))
def test_the_chip_of_pairs_in_one_loop_is_the_chip_of_the_numpy_steps(moves, seed):
    """:func:`cadcam.engagement.side_chip` (one compiled loop) keeps, for each move, the chip of its pairs that
    take more than the film off sideways (moves with a length across, less what a descending move plunges), as
    :func:`_across`, :func:`_plunged` and :func:`_side_chip` read it in turn, to the bit; on descending moves
    the plunge leaves some pairs out."""
    seg, *_ = _segments(moves)
    rng = np.random.default_rng(seed)
    n, s, cell, film = 80, 3, 0.2, 0.02
    o = rng.integers(0, len(seg), n)
    qx, qy = seg.x[o] + rng.uniform(-6, 6, n), seg.y[o] + rng.uniform(-6, 6, n)
    env = seg.z[o] + rng.uniform(-1, 3, n)
    before = env + np.where(rng.random(n) < 0.2, rng.uniform(0, 0.03, n), rng.uniform(0, 4, n))

    ref = MoveRecord(len(seg) + s)
    removed = before - env
    lat, has = _across(seg, o, qx, qy)
    maybe = np.flatnonzero((removed > film) & has)
    sel = maybe[removed[maybe] - _plunged(seg, o[maybe], qx[maybe], qy[maybe], removed[maybe]) > film]
    _side_chip(seg, o[sel], qx[sel], qy[sel], lat[sel], before[sel], env[sel], cell, s, ref)

    mine = MoveRecord(len(seg) + s)
    side_chip(seg, o, s, qx, qy, before, env, cell, mine)
    assert _same(mine.chip, ref.chip)


@settings(max_examples=60, deadline=None)
@given(ny=st.integers(1, 6), nx=st.integers(1, 70), block=st.sampled_from([1, 3, 16]), seed=st.integers(0, 2**32 - 1))
def test_each_block_s_highest_is_numpy_s_max_over_the_padded_row(ny, nx, block, seed):
    """:func:`toolsweep.block_tops`: each run of ``block`` columns' highest (the last run short, empty columns
    -inf, a NaN wins), as ``np.max`` over the rows padded with -inf reads it."""
    rng = np.random.default_rng(seed)
    top = rng.uniform(-5, 5, (ny, nx))
    top[rng.random(top.shape) < 0.2] = -np.inf
    top[rng.random(top.shape) < 0.02] = np.nan
    nb = -(-nx // block)
    padded = np.full((ny, nb * block), -np.inf)
    padded[:, :nx] = top
    assert _same(toolsweep.block_tops(top, block), padded.reshape(ny, nb, block).max(axis=2))
