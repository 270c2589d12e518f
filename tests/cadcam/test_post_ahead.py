"""Arc fitting started ahead of posting (:class:`cadcam.post.FitAhead`) gives the program posting alone gives."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import CuttingData, Job, Motion, Operation, Setup, Tool
from cadcam.post import FitAhead, PostOptions, post_process

FLAT = Tool(1, "6 mm flat", "flat", 6.0, 0.0, 20.0, 3, 40.0)
BALL = Tool(4, "3 mm ball", "ball", 3.0, 1.5, 10.0, 2, 30.0)
CUT = CuttingData(spindle_rpm=12000, feed=1200, plunge_feed=300)
SETUP = Setup([0, 0, -20], [80, 60, 0], np.eye(4), safe_z=10.0)


def _op(seed: int, tool: Tool, name: str) -> Operation:
    """A random path of arcs, helices, lines and rapids, as the planner's operations mix them [mm]."""
    rng = np.random.default_rng(seed)
    pts, mot = [np.array([[rng.uniform(5, 75), rng.uniform(5, 55), 5.0]])], [np.array([Motion.RAPID])]
    for _ in range(int(rng.integers(2, 7))):
        kind = int(rng.integers(0, 3))
        last = pts[-1][-1]
        if kind == 0:  # an arc or helix
            r = rng.uniform(0.5, 8.0)
            th = np.linspace(0.0, rng.uniform(-6.0, 6.0), int(rng.integers(8, 120)))[1:]
            c = last[:2] - [r, 0.0]
            z = last[2] - np.linspace(0.0, rng.uniform(0.0, 2.0), len(th))
            p = np.c_[c[0] + r * np.cos(th), c[1] + r * np.sin(th), z]
            m = Motion.PLUNGE if rng.random() < 0.3 else Motion.CUT
        elif kind == 1:  # a wavy line
            k = int(rng.integers(2, 60))
            x = last[0] + np.cumsum(rng.uniform(0.05, 1.0, k))
            p = np.c_[x, last[1] + 0.2 * np.sin(x * rng.uniform(0.1, 3.0)), np.full(k, last[2])]
            m = Motion.CUT
        else:  # a rapid hop
            p = np.array([[last[0], last[1], 5.0], [rng.uniform(5, 75), rng.uniform(5, 55), 5.0],
                          [0.0, 0.0, -rng.uniform(0.0, 3.0)]])
            p[2, :2] = p[1, :2]
            m = Motion.RAPID
        pts.append(p)
        mot.append(np.full(len(p), int(m)))
    return Operation(name, "roughing", tool, CUT, np.vstack(pts), np.concatenate(mot).astype(np.int8))


def _two_processes():
    """Fits in processes of their own, whatever the machine (``FACTORY_THREADS``)."""
    mp = pytest.MonkeyPatch()
    mp.setenv("FACTORY_THREADS", "2")
    return mp


def _moved(op: Operation, k: int) -> Operation:
    """``op`` with cutter location ``k`` moved by a micron: no longer the operation that was fitted."""
    pts = op.points.copy()
    pts[k % len(pts), 0] += 1e-3
    return dataclasses.replace(op, points=pts)


@settings(max_examples=12, deadline=None)
@given(st.lists(st.integers(0, 10_000), min_size=1, max_size=4), st.sets(st.integers(0, 3)), st.integers(0, 500),
       st.booleans())
def test_fits_started_ahead_post_the_same_program(seeds, changed, at, arcs):
    mp = _two_processes()
    ops = [_op(s, FLAT if i % 2 else BALL, f"op {i}") for i, s in enumerate(seeds)]
    options = PostOptions(arcs=arcs)
    ahead = FitAhead(options)
    ahead.offer(ops)
    # the job as the rapid check may leave it: some operations changed after they were offered
    final = [_moved(op, at) if i in changed else op for i, op in enumerate(ops)]
    job = Job(part_name="p", setup=SETUP, operations=tuple(final))
    try:
        posted = post_process(job, options, ahead=ahead)
        for i, op in enumerate(final):
            taken = ahead.take(op, ahead.fit)
            assert (taken is None) == (i in changed)  # a changed operation is fitted anew, never taken
    finally:
        ahead.cancel()
        mp.undo()
    assert posted == post_process(job, options)


def test_a_fit_under_other_options_is_not_taken(monkeypatch):
    monkeypatch.setenv("FACTORY_THREADS", "2")
    op = _op(7, FLAT, "op")
    ahead = FitAhead(PostOptions(arc_tolerance=0.002))
    ahead.offer([op])
    job = Job(part_name="p", setup=SETUP, operations=(op,))
    other = PostOptions(arc_tolerance=0.05)
    try:
        assert ahead.take(op, ahead.fit) is not None
        assert post_process(job, other, ahead=ahead) == post_process(job, other)
    finally:
        ahead.cancel()
    assert post_process(job, PostOptions(arc_tolerance=0.002)).text != post_process(job, other).text
