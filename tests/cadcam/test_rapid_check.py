"""The planner's check of its own rapids reads only rapids and jaws: what it computes, and what it no longer does."""

from __future__ import annotations

import numpy as np
import pytest

import cadcam.stock
import cadcam.verify
from cadcam.model import CuttingData, Motion, Operation, ProgramMoves
from cadcam.rest import safe_rapids
from cadcam.verify import VerifyOptions, rapid_check, simulate
from tests.cadcam.test_workholding import FLAT, PART, SETUP, STUBBY, TOOLS

R, C = Motion.RAPID, Motion.CUT


def _random_program(seed: int) -> ProgramMoves:
    """Rapids and cuts wandering over, into and beside the stock (and into the jaws, some of them)."""
    rng = np.random.default_rng(seed)
    n = 60
    pts = np.column_stack([rng.uniform(-8, 48, n), rng.uniform(-6, 26, n), rng.uniform(-12, 4, n)])
    pts[0] = [20, 10, 20]
    motion = np.where(rng.random(n) < 0.4, R, C).astype(np.int8)
    motion[0] = R
    tool = np.where(np.arange(n) < n // 2, 1, 2).astype(np.int32)
    return ProgramMoves(points=pts, motion=motion, tool=tool, feed=np.where(motion == R, np.nan, 800.0),
                        line=np.arange(n, dtype=np.int32))


@pytest.mark.parametrize("seed", range(4))
def test_rapid_check_finds_what_verify_finds_for_rapids_and_jaws(seed):
    moves = _random_program(seed)
    full = simulate(moves, TOOLS, SETUP, PART, VerifyOptions(cell=0.5, engagement_resolution=None))
    found = rapid_check(moves, TOOLS, SETUP, PART, 0.5)
    assert found.rapid_crashes == full.report.rapid_crashes
    assert found.jaw_faults == tuple(f for f in full.report.faults if f.kind == "jaws")
    np.testing.assert_array_equal(found.simulation.stock_top, full.simulation.stock_top)
    np.testing.assert_array_equal(found.simulation.part_top, full.simulation.part_top)
    assert found.rapid_crashes and (seed > 0 or found.jaw_faults)  # the examples hold something to find


def _counted(monkeypatch, module, name: str) -> list[int]:
    calls = [0]
    real = getattr(module, name)

    def counting(*args, **kwargs):
        calls[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counting)
    return calls


def test_the_planners_rapid_check_measures_no_engagement_contacts_or_stock_left(monkeypatch):
    """Undoing the saving (safe_rapids through the whole verify) makes these counts non-zero."""
    engagement = _counted(monkeypatch, cadcam.stock, "engaged_depth")
    body = _counted(monkeypatch, cadcam.stock._Body, "pairs")
    report = _counted(monkeypatch, cadcam.verify, "_report")
    judge = _counted(monkeypatch, cadcam.verify, "_judge")
    cut = CuttingData(10000, 800, 300)
    slot = Operation("slot", "roughing", FLAT, cut,
                     np.array([[5, 10, 5], [5, 10, -3], [35, 10, -3], [35, 10, 5]], float), np.array([R, C, C, R], np.int8))
    low = Operation("low", "roughing", STUBBY, cut, np.array([[20, 5, -4], [30, 5, -4]], float),
                    np.array([R, C], np.int8))
    ops, checked, fixed = safe_rapids([slot, low], SETUP, PART)
    assert fixed == 1  # the descent into the second operation touched the stock and was made safe
    assert engagement[0] == body[0] == report[0] == judge[0] == 0
    simulate(cadcam.stock.operation_moves(ops), TOOLS, SETUP, PART, VerifyOptions(cell=0.5))
    assert engagement[0] > 0 and body[0] > 0 and report[0] == judge[0] == 1  # the counters do count
