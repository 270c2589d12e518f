"""Turning the part over between op 1 and op 2 on the flip station, for the three sample arms."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings, strategies as st

from factory.core.errors import CellError, PlanningError
from factory.core.resources import FIXTURES
from robotprog.cell import load_cell, read_cell
from robotprog.collision import collision_world
from robotprog.flip import Piece, turnover
from robotprog.tending import PartBox, plan_tending
from robotprog.timing import LIMIT_SLACK

#: The bracket after op 1 [m, vise frame]: a 100 x 60 x 16 mm part on a 6 mm holding block of
#: the 104 x 64 mm stock.
STOCK_MM = (104, 64, 22)
PART = PartBox(np.array([-0.05, -0.03, 0.006]), np.array([0.05, 0.03, 0.022]))
CELLS = ["cell.yaml", "cell_abb.yaml", "cell_kuka.yaml"]


def sheet(sx: float, sy: float, sz: float) -> dict:
    return {"format": "factory.setup/1", "units": "mm", "work_origin": "top-front-left",
            "stock": {"min": [0, 0, -sz], "max": [sx, sy, 0], "size": [sx, sy, sz]},
            "transform_mesh_to_work": np.eye(4).tolist(), "mesh_scale": 1.0, "tools": []}


@pytest.fixture(scope="module", params=CELLS)
def flipped(request, tending):
    cell = load_cell(FIXTURES / request.param)
    world = collision_world(cell)
    return cell, world, tending(request.param, sheet(*STOCK_MM), part_box=PART, setups=2)


def _tcp(cell, robot, q):
    return cell.robot.base.matrix() @ robot.fk(q) @ cell.gripper.tcp.matrix()


def test_flip_is_collision_free_and_within_limits(flipped):
    cell, world, plan = flipped
    robot = world.robot
    check = collision_world(cell, robot, obstacles=plan.obstacles)
    vmax = robot.v_max * cell.motion.speed_scaling
    amax = np.array(cell.motion.acceleration_limits) * cell.motion.speed_scaling
    phases = [m.name.split(":")[0] for m in plan.moves]
    # load, then the flip, then the unload, each a run of moves from home to home
    assert phases == sorted(phases, key=["load", "flip", "unload"].index) and "flip" in phases
    home = np.array(cell.robot.home)
    q_prev = home
    for m in plan.moves:
        s = m.trajectory.resample(1000.0)
        np.testing.assert_allclose(s.q[0], q_prev, atol=1e-9, err_msg=m.name)
        q_prev = s.q[-1]
        assert (np.abs(s.qd) <= vmax * (1 + LIMIT_SLACK)).all(), m.name
        assert (np.abs(s.qdd) <= amax * (1 + LIMIT_SLACK)).all(), m.name
        assert (s.q >= robot.q_lower - 1e-9).all() and (s.q <= robot.q_upper + 1e-9).all(), m.name
        # every 1 kHz sample, the fingers and the held piece (part and holding block) included
        assert check.path_free(s.q, m.held) is None, m.name
    flip = plan.phase("flip")
    np.testing.assert_allclose(flip[0].waypoints[0], home)
    np.testing.assert_allclose(flip[-1].q_end, home, atol=1e-9)
    assert [m.kind for m in flip].count("gripper") == 6  # part, side grip, turned piece: grip and release each


def test_the_piece_is_turned_over_and_put_back_upside_down(flipped):
    cell, world, plan = flipped
    by = {m.name: m for m in plan.moves}
    grip = by["flip: grip holding block"].transform_world_to_tcp
    lifted = by["flip: lift"].transform_world_to_tcp
    turned = by["flip: turn over"].transform_world_to_tcp
    # gripped from the side (tool axis level), then half a turn about the tool axis
    assert abs(grip[2, 2]) < 1e-6
    np.testing.assert_allclose(turned[:3, 2], lifted[:3, 2], atol=1e-6)
    np.testing.assert_allclose(turned[:3, 1], -lifted[:3, 1], atol=1e-6)
    # held piece: its holding block, under the part before the turn, is above it after
    held = by["flip: turn over"].held
    boxes = {b.name: b for b in held}
    z = {name: (turned @ np.asarray(b.transform_tcp_to_box))[2, 3] for name, b in boxes.items()}
    z0 = {name: (lifted @ np.asarray(b.transform_tcp_to_box))[2, 3] for name, b in boxes.items()}
    assert z0["held_holding_block"] < z0["held_part"] and z["held_holding_block"] > z["held_part"]
    # op 2: in the vise on the part's finished top, centred, the holding block up; unloaded from there
    place = by["flip: place in vise"].transform_world_to_tcp
    vise = cell.vise.pose.matrix()
    np.testing.assert_allclose(place[:2, 3], vise[:2, 3], atol=1e-6)
    assert place[2, 3] > vise[2, 3] + 0.016  # fingers on the block, above the 16 mm part
    np.testing.assert_allclose(plan.part_min, [-0.05, -0.03, 0.0], atol=1e-9)
    np.testing.assert_allclose(plan.part_max, [0.05, 0.03, 0.016], atol=1e-9)
    unload = by["unload: approach part"].transform_world_to_tcp
    assert vise[2, 3] < unload[2, 3] < vise[2, 3] + 0.016


def test_one_setup_plan_has_no_flip(flipped, request, tending):
    cell_file = request.node.callspec.params["flipped"]  # the cell `flipped` was planned in
    plan = tending(cell_file, sheet(*STOCK_MM), part_box=PART)
    assert not plan.phase("flip") and [m.kind for m in plan.moves].count("gripper") == 4


def test_two_setups_need_a_flip_station():
    cell = load_cell(FIXTURES / "cell.yaml")
    with pytest.raises(PlanningError, match="flip_station"):
        plan_tending(dataclasses.replace(cell, flip_station=None), sheet(*STOCK_MM), part_box=PART, setups=2)


@pytest.mark.parametrize("field, value, needle", [
    ("size", [0.03, 0.03], "flip_station.size: expected 3 numbers"),
    ("size", [0.03, -0.03, 0.9], "flip_station.size[1]: must be > 0"),
    ("pose", {"xyz": [0.3, 0.1, 0.45], "rpy": [0.2, 0.0, 0.0]}, "flip_station.pose.rpy: the post must stand upright"),
    ("colour", "red", "flip_station.colour: unknown key"),
])
def test_bad_flip_station_fields_are_one_line_errors(field, value, needle):
    data = yaml.safe_load((FIXTURES / "cell.yaml").read_text(encoding="utf-8"))
    data["flip_station"][field] = value
    with pytest.raises(CellError, match="flip_station") as e:
        read_cell(data, "cell.yaml")
    assert needle in str(e.value) and "\n" not in str(e.value)


boxes = st.tuples(st.floats(-0.1, 0.1), st.floats(-0.1, 0.1), st.floats(0.0, 0.05),
                  st.floats(0.005, 0.1), st.floats(0.005, 0.1), st.floats(0.002, 0.05))


@settings(max_examples=60, deadline=None)
@given(part=boxes, block=st.floats(0.0, 0.02), axis=st.sampled_from([0, 1]))
def test_turning_over_is_rigid_puts_the_top_down_and_twice_is_the_piece(part, block, axis):
    x, y, z0, sx, sy, sz = part
    pmin = np.array([x, y, block])
    pmax = pmin + [sx, sy, sz]
    piece = Piece.after_op1(np.array([x - 0.002, y - 0.002, 0.0]), np.array([x + sx + 0.002, y + sy + 0.002,
                                                                            block + sz]), pmin, pmax)
    turned = piece.turned(axis)
    assert turned.part_min[2] == pytest.approx(0.0, abs=1e-12)  # on the part's finished top
    np.testing.assert_allclose(turned.part_max - turned.part_min, pmax - pmin, atol=1e-12)
    if piece.has_block:
        assert turned.block_min[2] == pytest.approx(sz, abs=1e-12)  # the block on top
    t = turnover(axis, piece.top)
    assert np.linalg.det(t[:3, :3]) == pytest.approx(1.0)  # a turn, not a mirror
    back = turned.turned(axis)
    # turned twice: the piece again, standing on its (now) top, i.e. shifted down by nothing
    np.testing.assert_allclose(back.part_min[:2], pmin[:2], atol=1e-12)
    np.testing.assert_allclose(back.part_max - back.part_min, pmax - pmin, atol=1e-12)


#: The language each sample cell's arm is programmed in.
CELL_LANG = {"ur5": ("urscript", "part.script"), "abb_irb1200_5_90": ("rapid", "part.mod"),
             "kuka_kr6_r900_sixx": ("krl", "part.src")}


def test_the_robot_program_loads_flips_and_reloads_the_part(flipped, tmp_path):
    from robotprog.programs import post_program
    from tests.robotprog.parsers import parse_krl, parse_urscript, rapid_errors

    cell, world, plan = flipped
    lang, name = CELL_LANG[world.robot.name]
    posted = post_program(lang, Path(name), cell, world, plan)  # checks the posted path for collisions
    assert 0.95 * plan.duration <= posted.predicted_s <= 1.05 * plan.duration
    text = posted.texts[Path(name)]
    # every move in order, the machine's cycle before the flip (op 1) and before the unload (op 2)
    marks = [0]
    for m in plan.moves:  # each move's comment after the one before
        marks.append(text.find(m.name, marks[-1] + 1))
        assert marks[-1] > marks[-2], m.name
    marks = marks[1:]
    starts = [k for k in range(len(text)) if text.startswith("machine: start the cycle", k)]
    assert len(starts) == 2
    assert marks[0] < starts[0] < text.find("flip: home to above vise") < starts[1] < text.find(
        "unload: home to above vise")
    if lang == "urscript":
        parse_urscript(text)
    elif lang == "krl":
        parse_krl(text, posted.texts[Path("part.dat")])
    else:
        assert rapid_errors(text) == []


def test_the_plan_mcap_shows_the_flip_and_the_flip_station(flipped, tmp_path):
    from factory.mcaplog import read_messages
    from factory.tending import write_robot_mcap

    cell, world, plan = flipped
    path = tmp_path / "flip.robot.mcap"
    write_robot_mcap(path, cell, world, plan, overwrite=False, inputs={})
    events, boxes = [], []
    for topic, stamp, msg in read_messages(path, ["/robot/events", "/cell/boxes"]):
        if topic == "/robot/events":
            events.append((stamp * 1e-9, msg.data))
        else:
            boxes = [mk.text for mk in msg.markers]
    assert [name for _, name in events] == [m.name for m in plan.moves]
    starts = np.cumsum([0.0] + [m.duration for m in plan.moves])[:-1]
    np.testing.assert_allclose([t for t, _ in events], starts, atol=1e-6)
    assert cell.flip_station.post.name in boxes
