"""The rack camera closes the loop: each blank off its slot's centre is located, its grasp corrected and
proven, or the grasp refused with the reason (``factory simulate --blank-offsets SEED``)."""

from __future__ import annotations

import dataclasses
import json
import math
import sqlite3

import numpy as np
import pytest
from typer.testing import CliRunner

import trimesh

from cli.main import app
from factory.cellcameras import cell_stations
from factory.cellinputs import CellInputs
from factory.core.errors import VisionError
from factory.core.resources import FIXTURES
from factory.mcaplog import read_messages
from factory.rackloop import RackLoop
from factory.simulation import run_cell
from robotprog.cell import load_cell
from robotprog.cellsim import simulate
from robotprog.orders import read_orders
from robotprog.rackpick import CORRECTED_MOVES, BlankScatter, corrected_pick
from tests.cli.expect import simulate_exit
from tests.foxglovecheck import check_foxglove_decodes
from vision.camera import CameraModel
from vision.lit import CONDITIONS, TRAY_ALBEDO
from vision.station import locate_shot


def _orders(folder, part, quantity):
    path = folder / "orders.csv"
    path.write_text(f"part,quantity,material,priority\n{part},{quantity},aluminium,0\n")
    return path


@pytest.fixture(scope="module")
def looped(block_catalog, tmp_path_factory):
    """(JSON of the run, MCAP, record): three blanks off their slots' centres, run with a log and a record."""
    folder, part = block_catalog
    out = tmp_path_factory.mktemp("rackloop")
    mcap, db = out / "cell.mcap", out / "cell.sqlite"
    r = CliRunner().invoke(app, ["simulate", str(_orders(out, part, 3)), "--catalog", str(folder),
                                 "--blank-offsets", "5", "--mcap", str(mcap), "--db", str(db), "--json", "--quiet"])
    doc = json.loads(r.stdout)
    assert r.exit_code == simulate_exit(doc) == 0, r.output
    return doc, mcap, db


def test_every_blank_is_located_and_its_grasp_corrected_and_proven(looped):
    doc, _, _ = looped
    picks = doc["rack_picks"]
    assert doc["summary"]["parts_good"] == 3 and len(picks) == 3
    for p in picks:
        off, loc, corr = p["offset"], p["located"], p["correction"]
        assert p["proven"] and not p["refusal"]
        # a few mm and degrees off, found to a fraction of a mm, and the grasp moved by what was found
        assert 0.05 < math.hypot(off["x_mm"], off["y_mm"]) <= 3.0 * math.sqrt(2) and abs(off["yaw_deg"]) <= 3.0
        assert p["error_mm"] == pytest.approx(math.hypot(loc["x_mm"] - off["x_mm"], loc["y_mm"] - off["y_mm"]),
                                              abs=1e-3)
        # off the camera's axis (it stands over the rack's middle) the small blank's yaw is found to about a
        # degree, within the uncertainty locate reports for it (about 2 deg on its 34 mm)
        assert p["error_mm"] < 0.5 and p["error_mm"] <= p["reported_mm"] and p["error_deg"] <= p["reported_deg"]
        assert p["error_within_reported"] is True
        assert corr == loc
        assert p["fetch_s"] > doc["parts"][0]["process_s"]["fetch_s"] * 0.5
    assert len({(p["offset"]["x_mm"], p["offset"]["y_mm"]) for p in picks}) == 3  # each blank stands its own way
    # each from its own rack slot, row by row, and each seated in the vise within what it tolerates
    assert [p["rack_slot"] for p in picks] == [[0, 0], [0, 1], [0, 2]] and {p["rack_load"] for p in picks} == {0}
    assert all(0 < p["seat_across_mm"] < 3.0 and 0 < p["seat_along_mm"] < 2.0 for p in picks)


def test_the_log_and_the_record_carry_each_offset_located_pose_and_correction(looped):
    doc, mcap, db = looped
    picks = doc["rack_picks"]
    logged = [m for _, _, m in read_messages(mcap, ["/cell/rack_pick"])]
    assert len(logged) == len(picks)
    for msg, p in zip(logged, picks):
        (status,) = msg.status
        values = {kv.key: kv.value for kv in status.values}
        assert status.name == "cell/rack_pick" and values["proven"] == "yes"
        for name in ("offset", "located", "correction"):
            assert float(values[f"{name}_x_mm"]) == pytest.approx(p[name]["x_mm"], abs=1e-3)
            assert float(values[f"{name}_yaw_deg"]) == pytest.approx(p[name]["yaw_deg"], abs=1e-3)
    # the corrected fetch is logged as it moved: its joint states end where the plan's retreat ends,
    # after the camera's picture of the blank where it stood
    assert sum(1 for _ in read_messages(mcap, ["/camera/image/compressed"])) >= len(picks)
    with sqlite3.connect(db) as c:
        said = [m for (m,) in c.execute("SELECT message FROM job_state WHERE event = 'fetched' ORDER BY seq")]
    assert len(said) == 3 and all("grasp corrected by" in m and "located" in m and "blank offset" in m for m in said)
    counts = check_foxglove_decodes(mcap)
    assert counts["/cell/rack_pick"] == len(picks)


def test_a_blank_not_located_confidently_stops_the_robot_and_no_grasp_is_attempted(block_catalog, tmp_path):
    """First the blank is picked as it should be: the corrected moves, timed as the fetch. Then with fingers
    opened only 0.4 mm beyond the blank, less room than the camera's reported uncertainty, every picture
    is refused: the robot stops with a stock_not_found fault and the reason, and never reaches for it."""
    folder, part = block_catalog
    orders = read_orders(_orders(tmp_path, part, 1))
    run = run_cell(orders, CellInputs(catalog=folder, blank_offsets=2))
    (picked,) = run.picks
    assert tuple(m.name for m in picked.pick.moves) == CORRECTED_MOVES
    fetch = next(a for a in run.result.activities if a.action == "fetch")
    assert fetch.pick == 0 and fetch.end - fetch.start == pytest.approx(picked.fetch_s)
    planned = next(iter(run.ready.values())).blank.planned
    np.testing.assert_allclose(picked.pick.moves[-1].q_end, planned.q_lifted, atol=1e-9)
    fingers = dataclasses.replace(run.cell.gripper.fingers, clearance=0.0004)
    tight = dataclasses.replace(run.cell, gripper=dataclasses.replace(run.cell.gripper, fingers=fingers))
    loop = RackLoop(tight, run.world.robot, run.stations, {k: v.blank for k, v in run.ready.items()},
                    BlankScatter(seed=2))
    result = simulate(orders, {k: v.process for k, v in run.ready.items()}, picks=loop)
    assert loop.picks and all(p.pick is None and "located too loosely" in p.refusal for p in loop.picks)
    assert not [a for a in result.activities if a.resource == "robot" and a.action in ("fetch", "missed_grasp")]
    faults = [e for e in result.log if e.event == "stock_not_found"]
    assert len(faults) == len(loop.picks) and all("the open fingers allow 0.20 mm" in e.message for e in faults)
    assert result.outcomes[0].outcome == "failed"
    # the first refused picture is of the same blank the run above picked, found where it was found then
    assert loop.picks[0].offset == run.picks[0].offset
    np.testing.assert_allclose([loop.picks[0].located.dx, loop.picks[0].located.dy],
                               [run.picks[0].located.dx, run.picks[0].located.dy], atol=1e-9)


def test_a_blank_whose_seat_in_the_vise_is_not_proven_is_not_picked(block_catalog, tmp_path):
    """The located pose's uncertainty is the blank's residual in the vise after the corrected pick. The
    picked blank's seat was proven for it (the place swept with the blank grown by it, between the open
    jaws), without changing the pick; with the jaws opened only 0.3 mm beside the blank, less than that
    residual, every picture is refused with the figures and no grasp is attempted."""
    folder, part = block_catalog
    orders = read_orders(_orders(tmp_path, part, 1))
    run = run_cell(orders, CellInputs(catalog=folder, blank_offsets=2))
    (picked,) = run.picks
    seat = picked.seat
    assert seat is not None and seat.residual.shift == pytest.approx(picked.sigma_mm / 1e3)
    assert 0 < seat.across < seat.place_clearance == run.cell.vise.place_clearance and 0 < seat.along < seat.margin
    assert "seat in the vise proven for" in picked.message() and picked.to_dict()["seat_across_mm"] > 0
    blanks = {k: v.blank for k, v in run.ready.items()}
    planned = next(iter(blanks.values())).planned
    again = corrected_pick(run.cell, run.world.robot, planned, picked.located, picked.offset, slot=picked.rack.cell)
    assert [m.name for m in again.moves] == [m.name for m in picked.pick.moves]
    for a, b in zip(again.moves, picked.pick.moves):  # the seat's proof left the pick as it was
        np.testing.assert_allclose(a.waypoints, b.waypoints, atol=1e-12)
    vise = dataclasses.replace(run.cell.vise, place_clearance=0.0003)
    loop = RackLoop(dataclasses.replace(run.cell, vise=vise), run.world.robot, run.stations, blanks, BlankScatter(seed=2))
    result = simulate(orders, {k: v.process for k, v in run.ready.items()}, picks=loop)
    assert loop.picks and all(p.pick is None and p.seat is None for p in loop.picks)
    assert not [a for a in result.activities if a.resource == "robot" and a.action in ("fetch", "missed_grasp")]
    faults = [e for e in result.log if e.event == "stock_not_found"]
    assert faults and all("the blank's seat in the vise is not proven" in e.message and
                          "more than the 0.30 mm the open jaws leave beside it" in e.message for e in faults)


def test_the_rack_camera_in_real_light_locates_the_blank_and_the_grasp_is_corrected(block_catalog, tmp_path):
    """``rack_light``: the rack camera's picture is taken in real light (vision.lit: aluminium, shadows,
    exposure, noise), not exactly; the blank is still located to a fraction of a millimetre and its
    pick corrected and proven."""
    folder, part = block_catalog
    orders = read_orders(_orders(tmp_path, part, 1))
    lit = run_cell(orders, CellInputs(catalog=folder, blank_offsets=2, rack_light="diffuse"))
    (shot,) = lit.picks
    assert shot.pick is not None and not shot.refusal and tuple(m.name for m in shot.pick.moves) == CORRECTED_MOVES
    assert 0.05e-3 < shot.offset.shift_m and shot.error.shift_m < 0.5e-3
    # within what locate reports: off the camera's axis the small blank's yaw is found to a degree or two
    assert shot.error.shift_m * 1e3 <= shot.sigma_mm and abs(math.degrees(shot.error.dyaw)) <= shot.sigma_deg


def test_the_rack_floor_shows_a_blank_under_a_low_light():
    """Straight under the rack camera a blank shows its top only, no side. Under a low key light its
    top and a floor as grey as the out-tray's take the same light and differ by their albedo alone:
    the lit sides do not show, and the blank is refused with the reason. Against the rack's dark
    floor every side shows, and the same blank in the same light is located to a fraction of a mm."""
    rack = cell_stations(load_cell(FIXTURES / "cell.yaml"), CameraModel.read(FIXTURES / "camera.yaml")).rack
    blank = trimesh.creation.box((104.0, 64.0, 22.5))  # the bracket's stock [mm]
    blank.apply_translation(np.array([104.0, 64.0, 22.5]) / 2)
    x, y = rack.camera_pose[:2, 3]
    pose = (x + 0.002, y - 0.001, math.radians(1.5))
    args = (np.asarray(blank.vertices), np.asarray(blank.faces), pose)
    shot = locate_shot(rack, *args, seed=0, light=CONDITIONS["low_angle"])
    assert shot.passed and shot.error_mm < 0.3
    grey = dataclasses.replace(rack, surface_albedo=TRAY_ALBEDO)
    with pytest.raises(VisionError, match="outline is not there"):
        locate_shot(grey, *args, seed=0, light=CONDITIONS["low_angle"])


def test_a_rack_light_needs_blank_offsets_and_a_known_light(block_catalog, tmp_path):
    """Refused in one line before any work: a light without blanks off their slots, or an unknown light."""
    folder, part = block_catalog
    orders = _orders(tmp_path, part, 1)
    for extra, said in ((["--rack-light", "diffuse"], "needs blank offsets"),
                        (["--blank-offsets", "1", "--rack-light", "sunset"], "unknown rack light 'sunset'")):
        r = CliRunner().invoke(app, ["simulate", str(orders), "--catalog", str(folder), "--quiet", *extra])
        assert r.exit_code != 0 and said in r.output, r.output
        assert len(r.output.strip().splitlines()) == 1


def test_each_pick_says_whether_the_blank_as_it_truly_came_lay_within_its_proven_seat():
    """The seat is proven for the reported uncertainty; the simulation knows the camera's true error and
    says, per blank, whether the blank truly landed within what was proven (a real cell cannot)."""
    from factory.rackloop import RackPick
    from robotprog.rack import RackSlot
    from robotprog.rackpick import SlotOffset
    from robotprog.seat import Residual, Seat

    size = (0.104, 0.064, 0.016)
    seat = Seat(Residual(0.0005, math.radians(0.6)), 0.00104, 0.00084, 0.003, 0.002, ())
    offset = SlotOffset(0.001, -0.002, math.radians(1.0))

    def pick(err_x, err_y, err_deg):
        located = SlotOffset(offset.dx + err_x, offset.dy + err_y, offset.dyaw + math.radians(err_deg))
        return RackPick(0, 1, 0, 0, offset, located, 0.5, 0.6, "", None, 1.0, b"", None, seat, RackSlot(0, 0, 0, 0, size))

    within = pick(0.0003, 0.0, 0.1)
    reach = within.true_reach()
    # 0.30 mm along the jaws plus what 0.1 deg swings the 32 mm half-side out; across, the 52 mm half-side's swing
    assert reach[0] == pytest.approx(0.0003 + 0.032 * math.sin(math.radians(0.1)) + 0.052 * (math.cos(math.radians(0.1)) - 1), abs=2e-6)
    assert within.seat_holds() is True and within.to_dict()["seat_holds"] is True
    beyond = pick(0.0, 0.0012, 0.0)  # 1.2 mm across the jaws: the seat was proven for 1.04 mm
    assert beyond.seat_holds() is False
    assert beyond.to_dict()["seat_true_across_mm"] == pytest.approx(1.2, abs=0.02)
    assert "beyond what its seat was proven for, the reported uncertainty did not hold" in beyond.message()


def test_the_facings_reach_is_its_pass_ends_clearance_plus_the_tools_radius():
    """How far a holding block seated off along the jaws may reach before a facing ramp meets it with
    the end mill's centre (robotprog.seat's op 2 figure)."""
    from cadcam.model import Tool
    from cadcam.model import Setup
    from cadcam.op2 import facing_gap
    from factory.rackloop import facing_reach

    setup = Setup(stock_min=[0, 0, -20], stock_max=[104, 64, 0], transform_mesh_to_work=np.eye(4))
    mill = Tool(number=14, name="16 mm flat", shape="flat", diameter=16.0, corner_radius=0.0, flute_length=30.0, flutes=3,
                length=60.0)
    ops = ({"kind": "facing", "tool": 14}, {"kind": "rest", "tool": 3})
    assert facing_gap(setup) == 1.0 and facing_reach(setup, ops, {14: mill}) == 9.0
    assert facing_reach(setup, ops[1:], {14: mill}) is None
