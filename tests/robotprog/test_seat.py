"""The blank's seat in the vise after a corrected pick: the camera's residual error is in the proof."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from factory.core.errors import PlanningError
from robotprog.cell import Box, Pose
from robotprog.grasp import GraspOptions
from robotprog.seat import (CARRIED_MOVES, GRIPS, RELEASED_MOVES, AfterMoves, Residual, Seat, SeatMoves, after_op1,
                            check_seat, open_jaws, prove_after_seat, prove_seat, reach)
from tests.robotprog.test_flip import PART as FLIP_PART, STOCK_MM as FLIP_STOCK_MM, sheet as flip_sheet
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet


@pytest.fixture(scope="module")
def bracket(tending):
    """The plan of the bracket's blank (104 x 64 x 16 mm), and its moves at the vise with the part 2 mm
    inside the stock along the jaws (the default side margin)."""
    plan = tending("cell.yaml", sheet(*SAMPLE_STOCK["bracket"]))
    by = {m.name: m for m in plan.moves}
    return plan, SeatMoves(tuple(by[n].waypoints for n in CARRIED_MOVES),
                           tuple(by[n].waypoints for n in RELEASED_MOVES), np.asarray(plan.stock.size), 0.002)


def test_the_residual_grows_the_blanks_box_by_its_shift_and_its_turn():
    size = np.array([0.104, 0.064, 0.016])
    np.testing.assert_allclose(Residual(0.0005, 0.0).growth(size), [0.0005, 0.0005])
    # turned 1 deg, the 104 x 64 mm box reaches out along x by 32 mm * sin 1 deg less what its 52 mm half
    # shortens, along y by 52 mm * sin 1 deg less what its 32 mm half shortens: the bound is the sine
    t = math.radians(1.0)
    turned = np.array([0.052 * math.cos(t) + 0.032 * math.sin(t) - 0.052, 0.052 * math.sin(t) + 0.032 * math.cos(t) - 0.032])
    grown = Residual(0.0, t).growth(size)
    np.testing.assert_allclose(grown, [0.032 * math.sin(t), 0.052 * math.sin(t)])
    assert (turned <= grown).all() and (grown - turned < 2e-5).all()
    with pytest.raises(PlanningError):
        Residual(-0.001, 0.0)


def test_a_normal_uncertainty_seats_and_the_place_is_proven_with_the_blank_grown(cell, world, bracket):
    plan, moves = bracket
    before = [m.waypoints.copy() for m in plan.moves]
    seat = prove_seat(cell, world.robot, moves, Residual(0.0005, math.radians(0.6)))  # the 640 camera's figures
    assert seat.along == pytest.approx(0.0005 + 0.032 * math.sin(math.radians(0.6)))
    assert seat.across == pytest.approx(0.0005 + 0.052 * math.sin(math.radians(0.6)))
    assert seat.across < seat.place_clearance == cell.vise.place_clearance and seat.along < seat.margin
    assert seat.moves == CARRIED_MOVES + RELEASED_MOVES
    # the proof sweeps the plan's motion again; it does not change it
    assert all(np.array_equal(a, m.waypoints) for a, m in zip(before, plan.moves))


def test_an_uncertainty_over_the_open_jaws_clearance_is_refused_with_the_figures(cell, world, bracket):
    _, moves = bracket
    with pytest.raises(PlanningError) as e:
        prove_seat(cell, world.robot, moves, Residual(0.002, math.radians(1.2)))
    assert e.value.source == "vise.place_clearance"
    assert "may land 3.09 mm off its place across the jaws" in str(e.value)
    assert "the rack camera's +-2.00 mm, +-1.20 deg on the 104.0 x 64.0 mm blank" in str(e.value)
    assert "more than the 3.00 mm the open jaws leave beside it" in str(e.value)


def test_a_shift_along_the_jaws_past_the_parts_margin_in_the_stock_is_refused(cell, bracket):
    _, moves = bracket
    thin = dataclasses.replace(moves, margin_along_jaws=0.0005)
    with pytest.raises(PlanningError, match=r"may sit 0\.84 mm off along the jaws .* more than the 0\.50 mm of stock "
                                            r"beyond the part there: op 1 would cut the part past the stock's end"):
        check_seat(cell, thin, Residual(0.0005, math.radians(0.6)))


def test_the_proof_sweeps_the_place_between_the_open_jaws(cell, world, bracket):
    """Jaws reaching above the fingertips (the fingers close across the blank's 64 mm, beside the jaws)
    make the planned place collide: the jaws are real obstacles of the proof, not only a figure."""
    _, moves = bracket
    tall = dataclasses.replace(cell, vise=dataclasses.replace(cell.vise, jaw_height=cell.vise.jaw_height + 0.02))
    jaws = open_jaws(tall, moves.stock_size)
    assert [j.name for j in jaws] == ["vise_front_jaw_open", "vise_back_jaw_open"]
    # each jaw's inner face stands the clearance beside the blank's side
    assert abs(jaws[1].pose.xyz[0] - tall.vise.pose.xyz[0]) == pytest.approx(
        0.032 + tall.vise.place_clearance + tall.vise.jaw_thickness / 2)
    with pytest.raises(PlanningError, match=r"load: (transfer to|place in) vise: .* collides \(.*jaw_open"):
        prove_seat(tall, world.robot, moves, Residual(0.0, 0.0))


# --- after op 1: the flip and the unload, with what op 1 left of the stock off along the jaws ------

@pytest.fixture(scope="module")
def flipped(tending):
    """The bracket in two setups (a 100 x 60 x 16 mm part on a 6 mm holding block of the 104 x 64 mm
    stock) and what its plan does after op 1."""
    plan = tending("cell.yaml", flip_sheet(*FLIP_STOCK_MM), part_box=FLIP_PART, setups=2)
    moves = AfterMoves(tuple((m.name, m.waypoints) for m in plan.moves if m.name.startswith(("flip:", "unload:"))),
                       plan.stock.stock_min, plan.stock.stock_max, FLIP_PART.low, FLIP_PART.high, 2, 0.009)
    by = {m.name: m for m in plan.moves}
    seat_moves = SeatMoves(tuple(by[n].waypoints for n in CARRIED_MOVES), tuple(by[n].waypoints for n in RELEASED_MOVES),
                           np.asarray(plan.stock.size), 0.002)
    return plan, moves, seat_moves


def _seat(along: float) -> Seat:
    """A seat proven for a blank up to ``along`` [m] off along the jaws (a plain shift)."""
    return Seat(Residual(along, 0.0), along, along, 0.003, 0.002, ())


def test_the_flip_and_the_unload_are_proven_with_the_holding_block_off_along_the_jaws(cell, world, flipped):
    plan, moves, seat_moves = flipped
    before = [m.waypoints.copy() for m in plan.moves]
    seat = prove_seat(cell, world.robot, seat_moves, Residual(0.0005, math.radians(0.6)))  # the 640 camera's figures
    after = prove_after_seat(cell, world.robot, moves, seat)
    assert after.along == seat.along == pytest.approx(0.0005 + 0.032 * math.sin(math.radians(0.6)))
    # every move of the flip (grip, turn-over, re-place) and of the unload, in the plan's order
    assert after.moves == tuple(n for n, _ in moves.moves)
    assert {GRIPS[0], GRIPS[1], GRIPS[2], GRIPS[3], "flip: turn over", "flip: place in vise",
            "unload: transfer to out-tray"} <= set(after.moves)
    assert after.part_off == 0.0  # op 1 cut the part where the plan put it; nothing squared the block up
    assert all(np.array_equal(a, m.waypoints) for a, m in zip(before, plan.moves))


def test_what_op1_leaves_off_along_the_jaws_is_the_stocks_own_faces(cell):
    """A solid part is cut where the plan put it, its holding block sits off with the blank; a
    relief's block (its box the stock's along the jaws) sits off whole."""
    t_vise = cell.vise.pose.matrix()
    stock_min, stock_max = np.array([-0.052, -0.032, 0.0]), np.array([0.052, 0.032, 0.022])
    solid = AfterMoves((), stock_min, stock_max, FLIP_PART.low, FLIP_PART.high, 2, 0.009)
    assert [(b.name, b.off) for b in after_op1(solid, 0.0008, t_vise)] == [("part", 0.0), ("holding_block", 0.0008)]
    # the holding block as it is (the flip's plan grows it by the part's margin in the stock; the proof by the seat's)
    block = after_op1(solid, 0.0008, t_vise)[1]
    np.testing.assert_allclose(block.size, [0.104, 0.064, 0.006])
    relief = AfterMoves((), stock_min, stock_max, stock_min, stock_max, 1)
    assert [(b.name, b.off) for b in after_op1(relief, 0.0008, t_vise)] == [("part", 0.0008)]


def test_the_residual_along_the_jaws_is_what_makes_the_flip_collide(cell, world, flipped):
    """A plate 0.5 mm beyond the stock's end along the jaws, as high as the holding block: the planned
    grip and lift out of the vise clear it (the held piece rides 1 mm in from its faces), the block
    1.8 mm off along the jaws does not. Ignoring the residual would prove it."""
    _, moves, _ = flipped
    t_vise = cell.vise.pose.matrix()
    end = t_vise @ np.array([float(moves.stock_max[0]) + 0.0005 + 0.001, 0.0, 0.003, 1.0])
    plate = Box("end_plate", (0.002, 0.064, 0.006), Pose(tuple(float(v) for v in end[:3]),
                                                          (0.0, 0.0, math.atan2(t_vise[1, 0], t_vise[0, 0]))))
    walled = dataclasses.replace(cell, enclosure=dataclasses.replace(cell.enclosure,
                                                                       walls=cell.enclosure.walls + (plate,)))
    assert prove_after_seat(walled, world.robot, moves, _seat(0.0)).along == 0.0
    with pytest.raises(PlanningError, match=r"flip: grip part: with the piece off by up to 1\.80 mm along "
                                            r"the jaws .* collides \(.*end_plate"):
        prove_after_seat(walled, world.robot, moves, _seat(0.0018))


def test_op2s_facing_ramps_must_not_meet_a_block_off_along_the_jaws_with_the_tools_centre(cell, world, flipped):
    _, moves, _ = flipped
    tight = dataclasses.replace(moves, facing_reach=0.0005)  # a facing that lets the block reach 0.5 mm
    with pytest.raises(PlanningError, match=r"op 2: the holding block may reach 0\.84 mm further along the jaws than "
                                            r"planned, op 2's facing ramps meet it with the tool's centre past 0\.50 mm"):
        prove_after_seat(cell, world.robot, tight, _seat(0.00084))
    assert prove_after_seat(cell, world.robot, tight, _seat(0.0004)).along == 0.0004


def test_the_side_grip_keeps_its_depth_with_the_block_off_along_its_tool_axis(cell, world, flipped):
    """The flip grips the holding block from its end, the tool axis along the jaws: a block off that
    way takes the grip's depth; the shallowest grip accepted must still hold."""
    _, moves, _ = flipped
    shallow = GraspOptions(min_grip_depth=0.0145)  # the plan's side grip reaches 15 mm in
    with pytest.raises(PlanningError, match=r"flip: grip holding block: the fingers reach 15\.00 mm into the "
                                            r"holding_block as planned, 14\.16 mm where it sits 0\.84 mm off"):
        prove_after_seat(cell, world.robot, moves, _seat(0.00084), grasp=shallow)
    prove_after_seat(cell, world.robot, moves, _seat(0.0004), grasp=shallow)


@given(st.floats(0, 0.003), st.floats(0, 2 * math.pi), st.floats(-0.05, 0.05), st.floats(0.02, 0.15),
       st.floats(0.02, 0.15))
def test_one_poses_reach_lies_within_the_growth_of_every_pose_within_its_shift_and_turn(shift, way, turn, sx, sy):
    size = np.array([sx, sy, 0.02])
    error = shift * np.array([math.cos(way), math.sin(way)])
    true = reach(size, error, turn)
    assert (true <= Residual(shift, abs(turn)).growth(size) + 1e-12).all()
    # a shift along one axis and no turn reaches exactly that far along it
    np.testing.assert_allclose(reach(size, np.array([shift, 0.0]), 0.0), [shift, 0.0], atol=1e-15)
