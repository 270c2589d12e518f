"""cadcam.model: an operation's feeds in the job's JSON (the plan's log attachment, ``factory gcode``'s input)."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import CuttingData, Motion, Operation, Tool

MILL = Tool(2, "10 mm flat", "flat", 10.0, 0.0, 30.0, 3, 50.0)


@settings(max_examples=60, deadline=None)
@given(feeds=st.lists(st.one_of(st.just(float("nan")), st.floats(0.0, 1e5, allow_nan=False),
                                st.sampled_from([0.05, 0.15, 0.25, 1.45, 2.675, 1234.55, 999.95])),
                      min_size=2, max_size=40))
def test_each_feed_is_written_rounded_to_a_tenth_and_a_rapids_as_null(feeds):
    """A feed [mm/min] is Python's ``round(f, 1)`` of the float (its exact binary value rounded, not numpy's
    ``np.round``), a move without one (NaN: a rapid) null; the job reads them back."""
    n = len(feeds)
    op = Operation("op", "finishing", MILL, CuttingData(10000.0, 1500.0, 500.0, 0.05),
                   np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]),
                   np.full(n, Motion.CUT, dtype=np.int8), feeds=np.array(feeds, dtype=np.float64))
    written = op.to_dict()["feeds"]
    assert written == [None if np.isnan(f) else round(float(f), 1) for f in np.array(feeds)]
    assert all(w is None or type(w) is float for w in written)
    again = Operation.from_dict(json.loads(json.dumps(op.to_dict())))
    assert np.array_equal(np.isnan(again.feeds), np.isnan(op.feeds))
