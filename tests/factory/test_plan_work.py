"""factory.plan does each piece of CAM work once: no operation is cut into the same stock model twice."""

from __future__ import annotations

import dataclasses
import hashlib
from collections import Counter

import cadcam.heightmap
import cadcam.stock
from cadcam.stock import Simulation, operation_moves
from factory.plan import PlanRequest, plan_part
from tests.conftest import SAMPLES


def test_op_1_is_cut_into_each_stock_model_once_in_a_plan(monkeypatch):
    # The planner models the stock after every few operations it adds (on the planning grid, and on a
    # finer one for flats and walls): each model cuts on from the last one on its grid, so over the plan
    # each of op 1's moves is cut once per grid. Simulating op 1 from the block for each model cut the
    # first operations again every time.
    cut_stock = cadcam.stock.cut_stock
    cut: Counter[tuple[float, bool]] = Counter()  # moves cut per (grid cell [mm], op 1)

    def counted(moves, tools, setup, part_triangles, cell, **kwargs):
        start = kwargs.get("start")
        op1 = start is None or (isinstance(start, Simulation) and start.stock_under is None)
        cut[cell, op1] += len(moves.points) - 1
        return cut_stock(moves, tools, setup, part_triangles, cell, **kwargs)

    monkeypatch.setattr(cadcam.stock, "cut_stock", counted)  # the stock models' calls (cadcam.stock.stock_after)
    plan = plan_part(dataclasses.replace(PlanRequest.defaults(SAMPLES / "bracket.stl", "aluminium"), robot=False))
    assert plan.ok and plan.op2 is not None
    op1 = {cell: n for (cell, first), n in cut.items() if first}
    assert op1 and 0.5 in op1, cut  # the planning grid's models were counted
    # op 1's moves as the planner's operations run them (the rapid check adds a few rapids; never fewer)
    moves = len(operation_moves(plan.planned.job.operations).points) - 1
    for cell, n in op1.items():
        assert n <= moves, f"op 1's {moves} moves cut {n} times into the {cell} mm stock models"


def test_a_plan_rasterises_each_part_on_each_grid_once(monkeypatch):
    # Choosing tools, the stock models, the rapid check, verify, op 2's model and its verify all want
    # the part's upper envelope, mostly on the same few grids (cadcam.heightmap.upper_envelope).
    rasterised = cadcam.heightmap._rasterised
    seen: Counter[tuple[bytes, cadcam.heightmap.Grid]] = Counter()

    def counted(tri, grid):
        seen[hashlib.sha1(tri.tobytes()).digest(), grid] += 1
        return rasterised(tri, grid)

    cadcam.heightmap._ENVELOPES.forget()  # none kept from earlier tests
    monkeypatch.setattr(cadcam.heightmap, "_rasterised", counted)
    plan_part(dataclasses.replace(PlanRequest.defaults(SAMPLES / "bracket.stl", "aluminium"), robot=False))
    # tools, models, op 1, op 2, the holes, verify's sideways looks (the rapid check no longer looks: it
    # sweeps only rapids, cadcam.verify.rapid_check): enough grids that "each once" says something
    assert len(seen) > 6
    again = {grid: n for (_, grid), n in seen.items() if n > 1}
    assert not again, again
