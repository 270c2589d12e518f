"""The blank's seat in the vise after a corrected pick: the camera's residual error is in the proof."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from factory.core.errors import PlanningError
from robotprog.seat import CARRIED_MOVES, RELEASED_MOVES, Residual, SeatMoves, check_seat, open_jaws, prove_seat
from robotprog.tending import plan_tending
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet


@pytest.fixture(scope="module")
def bracket(cell, world):
    """The plan of the bracket's blank (104 x 64 x 16 mm), and its moves at the vise with the part 2 mm
    inside the stock along the jaws (the default side margin)."""
    plan = plan_tending(cell, sheet(*SAMPLE_STOCK["bracket"]), world=world)
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
