"""Load/unload planning in the default cell for the sample parts' stock sizes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factory.core.errors import CellError, PlanningError
from robotprog.cell import Pose
from robotprog.tending import PartBox, TendingOptions, part_box_in_vise, plan_tending
from robotprog.timing import LIMIT_SLACK

#: Stock sizes [mm] of the sample parts (samples/make_samples.py with the default allowances).
SAMPLE_STOCK = {
    "bracket": (104, 64, 16),
    "plate_bosses": (94, 74, 21),
    "dome_mould": (94, 74, 31),
    "stepped_wall": (104, 54, 31),
}


def sheet(sx: float, sy: float, sz: float) -> dict:
    return {
        "format": "factory.setup/1",
        "units": "mm",
        "work_origin": "top-front-left",
        "stock": {"min": [0, 0, -sz], "max": [sx, sy, 0], "size": [sx, sy, sz]},
        "transform_mesh_to_work": np.eye(4).tolist(),
        "mesh_scale": 1.0,
        "tools": [],
    }




@pytest.fixture(scope="module")
def plans(tending):
    return {name: tending("cell.yaml", sheet(*s)) for name, s in SAMPLE_STOCK.items()}


def _tcp(cell, robot, q):
    return cell.robot.base.matrix() @ robot.fk(q) @ cell.gripper.tcp.matrix()


@pytest.mark.parametrize("name", sorted(SAMPLE_STOCK))
def test_plan_within_limits_reaches_targets_and_is_collision_free(name, plans, cell, world):
    plan = plans[name]
    robot = world.robot
    vmax = robot.v_max * cell.motion.speed_scaling
    amax = np.array(cell.motion.acceleration_limits) * cell.motion.speed_scaling
    home = np.array(cell.robot.home)
    assert [m.kind for m in plan.moves].count("gripper") == 4
    np.testing.assert_allclose(plan.moves[0].waypoints[0], home)
    np.testing.assert_allclose(plan.moves[-1].q_end, home, atol=1e-9)
    q_prev = home
    for m in plan.moves:
        s = m.trajectory.resample(1000.0)
        # Moves chain: each starts where the previous ended.
        np.testing.assert_allclose(s.q[0], q_prev, atol=1e-9, err_msg=m.name)
        q_prev = s.q[-1]
        assert (np.abs(s.qd) <= vmax * (1 + LIMIT_SLACK)).all(), m.name
        assert (np.abs(s.qdd) <= amax * (1 + LIMIT_SLACK)).all(), m.name
        assert (s.q >= robot.q_lower - 1e-9).all() and (s.q <= robot.q_upper + 1e-9).all(), m.name
        end = _tcp(cell, robot, s.q[-1])
        np.testing.assert_allclose(end[:3, 3], m.transform_world_to_tcp[:3, 3], atol=1e-4, err_msg=m.name)
        assert world.path_free(s.q, m.held) is None, m.name  # every 1 kHz sample
        assert world.path_free(m.waypoints, m.held) is None, m.name
        if m.kind == "linear":
            # Straight TCP line: every sample within 1 mm of the segment, tool pointing down.
            a = _tcp(cell, robot, m.waypoints[0])[:3, 3]
            b = end[:3, 3]
            # Approach and retreat are vertical lines of the approach height.
            np.testing.assert_allclose(np.abs(b - a), [0.0, 0.0, TendingOptions().planner.approach_height], atol=1e-4)
            for q in s.q[::25]:
                p = _tcp(cell, robot, q)
                u = np.clip(np.dot(p[:3, 3] - a, b - a) / np.dot(b - a, b - a), 0, 1)
                assert np.linalg.norm(p[:3, 3] - (a + u * (b - a))) < 1e-3, m.name
                assert p[2, 2] < -0.999, m.name
        if m.kind == "gripper":
            assert m.duration == cell.gripper.io.settle_s
            assert m.outputs in (cell.gripper.io.grip, cell.gripper.io.release)
    assert plan.duration == pytest.approx(sum(d for _, d in plan.durations))


@pytest.mark.parametrize("name", sorted(SAMPLE_STOCK))
def test_grasp_and_place_poses(name, plans, cell, world):
    plan = plans[name]
    sx, sy, sz = (v / 1000 for v in SAMPLE_STOCK[name])
    by_name = {m.name: m for m in plan.moves}
    slot = cell.rack.slot_transform(0, 0)
    grasp = by_name["load: approach stock"].transform_world_to_tcp
    # Centred on the stock in the slot, fingers within its height, closing across the narrow side.
    np.testing.assert_allclose(grasp[:2, 3], slot[:2, 3], atol=1e-6)
    assert slot[2, 3] < grasp[2, 3] < slot[2, 3] + sz
    assert abs(abs(grasp[:3, 1] @ slot[:3, 1]) - 1) < 1e-6  # sy is the narrow side of every sample
    vise = cell.vise.pose.matrix()
    place = by_name["load: place in vise"].transform_world_to_tcp
    np.testing.assert_allclose(place[:2, 3], vise[:2, 3], atol=1e-6)
    assert vise[2, 3] < place[2, 3] < vise[2, 3] + sz
    tray = by_name["unload: place in out-tray"].transform_world_to_tcp
    np.testing.assert_allclose(tray[:2, 3], cell.out_tray.slot_transform(0, 0)[:2, 3], atol=1e-6)
    assert sy <= cell.gripper.opening_max


def test_stock_wider_than_gripper_names_the_field(cell, world):
    with pytest.raises(PlanningError) as e:
        plan_tending(cell, sheet(120, 100, 20), world=world)
    assert e.value.source == "gripper.opening.max" or "gripper.opening.max" in str(e.value)


def test_stock_too_wide_for_vise(cell, world):
    with pytest.raises(CellError, match="vise.jaw_opening"):
        plan_tending(cell, sheet(250, 230, 20), world=world)


def test_unreachable_rack_slot_names_the_field(cell, world):
    far = dataclasses.replace(cell, rack=dataclasses.replace(cell.rack, pose=Pose((1.6, -1.2, 0.8))))
    with pytest.raises(PlanningError, match="rack.pose"):
        plan_tending(far, sheet(104, 64, 16), world=world)


def test_missing_slot(cell, world):
    with pytest.raises(CellError, match="rack"):
        plan_tending(cell, sheet(104, 64, 16), world=world, options=TendingOptions(rack_slot=(5, 0)))


def test_part_box_from_mesh_sits_in_stock(cell, world):
    from robotprog.frames import setup_sheet_to_cell

    stock = setup_sheet_to_cell(sheet(100, 60, 20))
    verts = np.array([[5.0, 5.0, -20.0], [95.0, 55.0, -4.0]])  # part in work coords (identity mesh→work)
    box = part_box_in_vise(stock, verts)
    np.testing.assert_allclose(box.low, [-0.045, -0.025, 0.0], atol=1e-12)
    np.testing.assert_allclose(box.high, [0.045, 0.025, 0.016], atol=1e-12)
    plan = plan_tending(cell, sheet(100, 60, 20), part_box=box, world=world)
    grip = {m.name: m for m in plan.moves}["unload: approach part"].transform_world_to_tcp
    assert grip[2, 3] < cell.vise.pose.matrix()[2, 3] + 0.016
    # 4 mm tall: the fingertips, kept 2 mm above the parallels, reach 2 mm below its top (3 needed).
    thin = part_box_in_vise(stock, np.array([[5.0, 5.0, -20.0], [95.0, 55.0, -16.0]]))
    with pytest.raises(PlanningError, match="too thin to grip") as e:
        plan_tending(cell, sheet(100, 60, 20), part_box=thin, world=world)
    assert e.value.source == "gripper.fingers"


def test_smallest_stock_the_default_gripper_takes_is_6_mm(cell, world):
    # 3 mm of grip with the fingertips 2 mm above the rack: 6 mm; 5.9 mm leaves 2.95 mm
    assert len(plan_tending(cell, sheet(104, 64, 6.0), world=world).moves) == 18
    with pytest.raises(PlanningError, match="5.9 mm tall is too thin to grip"):
        plan_tending(cell, sheet(104, 64, 5.9), world=world)


@pytest.mark.parametrize("height", [10.0, 15.0])
def test_plate_stock_is_gripped_from_above_in_rack_vise_and_tray(height, cell, world):
    plan = plan_tending(cell, sheet(104, 64, height), world=world)
    grips = {m.name: m.transform_world_to_tcp for m in plan.moves}
    z_rack = cell.rack.slot_transform(0, 0)[2, 3]
    z_vise = cell.vise.pose.matrix()[2, 3]
    z_tray = cell.out_tray.slot_transform(0, 0)[2, 3]
    for name, z in (("load: approach stock", z_rack), ("load: place in vise", z_vise),
                    ("unload: place in out-tray", z_tray)):
        depth = z + height / 1000.0 - grips[name][2, 3]  # fingertips below the box's top [m]
        assert 0.003 - 1e-9 <= depth <= height / 2000.0 + 1e-9, (name, depth)
    # the fingers and the blanks beside the picked one are in the proof
    assert {b.name for b in plan.obstacles} >= {"rack_blank_r0c1", "rack_blank_r1c0", "tray_part_r0c1"}
    for m in plan.moves:
        assert any(getattr(b, "name", "") == "finger" for b in m.held), m.name
    # the reject move is planned: from above the vise, over the bin, let go, home
    assert [m.name for m in plan.reject] == ["reject: transfer to bin", "reject: release part", "reject: return home"]
    start = {m.name: m for m in plan.moves}["unload: retreat from vise"].q_end
    np.testing.assert_allclose(plan.reject[0].waypoints[0], start)
    np.testing.assert_allclose(plan.reject[-1].q_end, cell.robot.home, atol=1e-9)
    drop = plan.reject[1].transform_world_to_tcp
    bin_ = cell.reject_bin
    assert np.abs(drop[:2, 3] - np.array(bin_.pose.xyz[:2])).max() < 1e-6
    assert drop[2, 3] > bin_.pose.xyz[2] + bin_.size[2] / 2
    robot = world.robot
    vmax = robot.v_max * cell.motion.speed_scaling
    amax = np.array(cell.motion.acceleration_limits) * cell.motion.speed_scaling
    for m in plan.reject[::2]:
        smp = m.trajectory.resample(1000.0)
        assert (np.abs(smp.qd) <= vmax * (1 + LIMIT_SLACK)).all() and (np.abs(smp.qdd) <= amax * (1 + LIMIT_SLACK)).all()


def test_blanks_beside_the_picked_one_are_obstacles(cell, world):
    import dataclasses

    from robotprog.cell import SlotGrid

    # rows 70 mm apart: a 60 mm blank leaves 10 mm to its neighbour, less than a finger and its clearance
    tight = dataclasses.replace(cell, rack=SlotGrid(cell.rack.pose, 2, 3, (0.12, 0.07)))
    with pytest.raises(PlanningError, match="finger <-> rack_blank_r1c0"):
        plan_tending(tight, sheet(104, 60, 30), world=world)


def test_a_part_in_one_setup_leaves_on_its_holding_block_and_stands_on_it_in_the_tray(cell, tending):
    """Op 1 alone leaves the part on the stock under it: the unload carries that block under the part
    (it rode unseen before, and was set down through the tray) and stands it on the tray slot."""
    stock = sheet(104, 64, 22)
    box = PartBox(np.array([-0.05, -0.03, 0.006]), np.array([0.05, 0.03, 0.022]))  # 100 x 60 x 16 on a 6 mm block
    plan = tending("cell.yaml", stock, part_box=box)  # the same plan as tests/robotprog/test_flip.py's one setup
    place = {m.name: m for m in plan.moves}["unload: place in out-tray"]
    held = {h.name: h for h in place.held}
    assert {"finger", "held_part", "held_holding_block"} <= set(held)
    tcp = place.transform_world_to_tcp
    block = tcp @ np.asarray(held["held_holding_block"].transform_tcp_to_box)
    part = tcp @ np.asarray(held["held_part"].transform_tcp_to_box)
    slot_z = cell.out_tray.slot_transform(0, 0)[2, 3]
    assert block[2, 3] - 0.003 == pytest.approx(slot_z, abs=1e-9)  # the 6 mm block's bottom on the slot
    assert part[2, 3] - 0.008 == pytest.approx(slot_z + 0.006, abs=1e-9)  # the part on the block
    np.testing.assert_allclose(held["held_holding_block"].size, [0.104, 0.064, 0.006])
