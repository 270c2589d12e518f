"""cadcam.stock: the planner's stock model cut on from what earlier operations left is the stock cutting them all leaves."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cadcam.op2 import flip_part, flip_transform, op2_setup
from cadcam.stock import OperationsCut, flip_stock, stock_after, stock_after_flipped
from tests.cadcam.test_plan import sample_op1
from tests.cadcam.test_rapid_check import _counted


@pytest.fixture(scope="module")
def bracket():
    """The sample bracket's op 1: helixed holes, roughing, flats and walls (several operations, two tools)."""
    _, part_work, job = sample_op1("bracket")  # planned once in the run, tests/cadcam/test_plan.py's too
    return part_work, job


def assert_same_stock(a, b) -> None:
    assert a.grid == b.grid and a.stock_bottom == b.stock_bottom and a.floor_z == b.floor_z
    for name in ("stock_top", "part_top", "stock_under", "removed_volume"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.shape == y.shape and np.array_equal(x, y), name  # to the bit, -inf where -inf


@pytest.mark.parametrize("cell", [0.5, 0.3])
def test_cutting_on_from_the_first_operations_leaves_the_stock_cutting_all_of_them_leaves(bracket, cell):
    part_work, job = bracket
    ops, tri = list(job.operations), np.asarray(part_work.triangles)
    assert len(ops) >= 3
    whole = stock_after(ops, job.setup, tri, cell)
    for k in range(1, len(ops)):
        first = OperationsCut(tuple(ops[:k]), stock_after(ops[:k], job.setup, tri, cell))
        assert_same_stock(stock_after(ops, job.setup, tri, cell, earlier=first), whole)
    # in steps, each model cut on from the one before, as the planner makes them
    earlier = None
    for k in range(1, len(ops) + 1):
        earlier = OperationsCut(tuple(ops[:k]), stock_after(ops[:k], job.setup, tri, cell, earlier=earlier))
    assert_same_stock(earlier.simulation, whole)


def test_the_planners_model_is_the_measured_cut_without_measuring_engagement_or_the_body(bracket, monkeypatch):
    """The stock model is cut_stock's measured stock to the bit, and measures nothing beside the cut (issue 35)."""
    import cadcam.stock

    part_work, job = bracket
    ops, tri = list(job.operations), np.asarray(part_work.triangles)
    tools = {op.tool.number: op.tool for op in ops}
    measured = cadcam.stock.cut_stock(cadcam.stock.operation_moves(ops), tools, job.setup, tri, 0.5)
    assert measured.met.depth.max() > 0  # the measured cut does measure engagement
    engagement = _counted(monkeypatch, cadcam.stock, "engaged_depth")
    body = _counted(monkeypatch, cadcam.stock._Body, "pairs")
    assert_same_stock(stock_after(ops, job.setup, tri, 0.5), measured.simulation)
    earlier = OperationsCut(tuple(ops[:1]), stock_after(ops[:1], job.setup, tri, 0.5))
    assert_same_stock(stock_after(ops, job.setup, tri, 0.5, earlier=earlier), measured.simulation)
    assert engagement[0] == body[0] == 0


def test_an_earlier_stock_that_does_not_hold_the_first_operations_is_not_cut_on(bracket):
    part_work, job = bracket
    ops, tri = list(job.operations), np.asarray(part_work.triangles)
    whole = stock_after(ops, job.setup, tri)
    other = dataclasses.replace(ops[0], points=ops[0].points + [0.0, 0.0, -1.0])  # the same op moved: another op
    for earlier in (OperationsCut((other,), stock_after([other], job.setup, tri)),  # not these operations
                    OperationsCut(tuple(ops[:1]), stock_after(ops[:1], job.setup, tri, 0.3))):  # another grid
        assert_same_stock(stock_after(ops, job.setup, tri, earlier=earlier), whole)


def test_op_2_cut_on_from_its_first_operations_as_from_op_1s_stock_turned_over(bracket):
    part_work, job = bracket
    ops = list(job.operations)
    setup2 = op2_setup(job.setup)
    tri2 = np.asarray(flip_part(part_work, job.setup).triangles)
    start = flip_stock(stock_after(ops, job.setup, np.asarray(part_work.triangles), 0.5), flip_transform(job.setup),
                       setup2)
    # op 1's operations run again on the turned-over stock: cutting, as the checks need, not sense
    moved = [dataclasses.replace(op, points=op.points - [0.0, 0.0, 3.0]) for op in ops]
    whole = stock_after_flipped(moved, setup2, tri2, start, 0.5)
    assert whole.stock_under is not None and (whole.stock_top < start.top).any()
    for k in range(1, len(moved)):
        first = OperationsCut(tuple(moved[:k]), stock_after_flipped(moved[:k], setup2, tri2, start, 0.5))
        assert_same_stock(stock_after_flipped(moved, setup2, tri2, start, 0.5, earlier=first), whole)
