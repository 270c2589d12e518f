"""Posted programs run the proven motion (sample stock, random stock, random 15 mm plate stock; the ABB
and KUKA cells on the four samples): controller time within 5 % of the plan on both ways of the
verdict (out-tray, reject bin), the posted path collision-checked, the URScript table the plan's own
samples, every program read by its consumer."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from factory.core.errors import PlanningError
from robotprog.controller import program_duration
from factory.core.resources import FIXTURES
from robotprog.cell import load_cell
from robotprog.collision import collision_world
from robotprog.programs import (LANG_NAME, SERVO_PERIOD_S, VERDICT_AFTER, check_posted_path, post_program,
                                program_name, program_steps, tcp_of)
from robotprog.tending import plan_tending
from robotprog.timing import LIMIT_SLACK
from robotprog.urscript import Branch, ServoJ, flat_steps
from tests.robotprog.parsers import parse_krl, parse_urscript, rapid_errors
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet

_rng = np.random.default_rng(13)
#: Random stock boxes [mm] (x 40..110, y 30..80, z 20..60) besides the samples'.
RANDOM_STOCK = {f"random{k}": tuple(float(v) for v in np.round(_rng.uniform([40, 30, 20], [110, 80, 60]), 1))
                for k in range(2)}
#: and random 15 mm plate stock
RANDOM_STOCK |= {f"plate{k}": (*(float(v) for v in np.round(_rng.uniform([40, 30], [110, 80]), 1)), 15.0)
                 for k in range(2)}
LANG_FILES = {"urscript": "part.script", "rapid": "part.mod", "krl": "part.src"}
#: The sample cell whose arm each language drives (RAPID an ABB, KRL a KUKA, URScript the default UR5).
LANG_CELL = {"urscript": "cell.yaml", "rapid": "cell_abb.yaml", "krl": "cell_kuka.yaml"}
#: Stock the ABB and KUKA cells are planned for: the four samples and a 15 mm plate (each plan
#: takes 10..40 s).
ARM_STOCK = (*sorted(SAMPLE_STOCK), "plate0")


@pytest.fixture(scope="module")
def plans(tending):
    return {name: tending("cell.yaml", sheet(*s)) for name, s in {**SAMPLE_STOCK, **RANDOM_STOCK}.items()}


@pytest.fixture(scope="module")
def arm_cells():
    """lang -> (cell, world, {stock name: plan}) for the ABB and KUKA sample cells."""
    out = {}
    for lang in ("rapid", "krl"):
        c = load_cell(FIXTURES / LANG_CELL[lang])
        w = collision_world(c)
        out[lang] = (c, w, {n: plan_tending(c, sheet(*{**SAMPLE_STOCK, **RANDOM_STOCK}[n]), world=w)
                            for n in ARM_STOCK})
    return out


def _for(lang, name, plans, cell, world, arm_cells):
    """(plan, cell, world) of ``lang``'s sample cell."""
    if lang == "urscript":
        return plans[name], cell, world
    c, w, p = arm_cells[lang]
    return p[name], c, w


@pytest.mark.parametrize("lang, name", [("urscript", n) for n in sorted({**SAMPLE_STOCK, **RANDOM_STOCK})]
                         + [(lang, n) for lang in ("rapid", "krl") for n in ARM_STOCK])
def test_controller_runs_the_planned_duration(name, lang, plans, cell, world, arm_cells):
    plan, cell, world = _for(lang, name, plans, cell, world, arm_cells)
    posted = post_program(lang, Path(LANG_FILES[lang]), cell, world, plan)
    assert posted.planned_s == pytest.approx(plan.duration)
    assert 0.95 * plan.duration <= posted.predicted_s <= 1.05 * plan.duration, (posted.predicted_s, plan.duration)
    header = next(iter(posted.texts.values())).splitlines()[:6]
    assert any(f"planned motion {plan.duration:.2f} s, controller {posted.predicted_s:.2f} s" in h for h in header)
    # the number is the timer's on the posted steps, from home
    again = program_duration(posted.steps, np.asarray(cell.robot.home), lang=lang, axis_speed=world.robot.v_max,
                             tcp_of=tcp_of(cell, world.robot))
    assert again == pytest.approx(posted.predicted_s)
    # the reject way: the plan up to the verdict, then the planned reject branch, timed the same way
    k = [m.name for m in plan.moves].index(VERDICT_AFTER)
    planned_reject = sum(m.duration for m in plan.moves[:k + 1] + plan.reject)
    assert posted.planned_reject_s == pytest.approx(planned_reject)
    assert 0.95 * planned_reject <= posted.predicted_reject_s <= 1.05 * planned_reject
    assert any(f"reject branch: planned motion {planned_reject:.2f} s, controller {posted.predicted_reject_s:.2f} s"
               in h for h in header)
    assert sum(isinstance(st, Branch) for st in posted.steps) == 1
    # the consumer reads it (RAPID: rapidchecker takes ~25 s a program, so the arm stock's only, below)
    if lang == "urscript":
        parse_urscript(posted.texts[Path("part.script")])
    elif lang == "krl":
        parse_krl(posted.texts[Path("part.src")], posted.texts[Path("part.dat")])


@pytest.mark.parametrize("name", ARM_STOCK)
def test_rapid_program_passes_rapidchecker(name, arm_cells):
    """Each stock's ABB program passes rapidchecker. rapidchecker reads the bracket's (7-15 s a program); the
    others differ from it only in their numbers and in how many targets they declare and move to, which its
    grammar reads alike (tests.robotprog.parsers.rapid_shape, held by test_parsers), so a program of the
    bracket's shape has its verdict; one of another shape is read by rapidchecker itself."""
    cell, world, plans = arm_cells["rapid"]
    # part.mod, as the module's other tests post it: the bracket's text is then the one the rack pick's
    # test checks too, and rapidchecker reads it once in the run (parsers.rapid_errors)
    posted = post_program("rapid", Path(LANG_FILES["rapid"]), cell, world, plans[name])
    text = posted.texts[Path(LANG_FILES["rapid"])]
    assert "IF DInput(di" in text and "ENDIF" in text
    assert rapid_errors(text, by_shape=True) == []


@pytest.mark.parametrize("lang, name", [(lang, name) for lang in ("rapid", "krl") for name in ARM_STOCK])
def test_arm_plans_are_proven_at_1_khz(lang, name, arm_cells):
    """Every move of the ABB's and the KUKA's plans, the reject branch too, within the URDF's limits and
    collision-free at 1 kHz in the plan's world (the cell, the blanks and tray parts beside the slots)."""
    cell, world, plans = arm_cells[lang]
    plan = plans[name]
    robot = world.robot
    vmax = robot.v_max * cell.motion.speed_scaling
    amax = np.array(cell.motion.acceleration_limits) * cell.motion.speed_scaling
    proven = collision_world(cell, robot, obstacles=plan.obstacles)
    assert plan.reject
    k = [m.name for m in plan.moves].index(VERDICT_AFTER)
    np.testing.assert_allclose(plan.reject[0].waypoints[0], plan.moves[k].q_end, atol=1e-9)
    np.testing.assert_allclose(plan.reject[-1].q_end, cell.robot.home, atol=1e-9)
    for m in plan.moves + plan.reject:
        if m.kind == "gripper":
            continue
        s = m.trajectory.resample(1000.0)
        assert (np.abs(s.qd) <= vmax * (1 + LIMIT_SLACK)).all(), m.name
        assert (np.abs(s.qdd) <= amax * (1 + LIMIT_SLACK)).all(), m.name
        assert (s.q >= robot.q_lower - 1e-9).all() and (s.q <= robot.q_upper + 1e-9).all(), m.name
        assert proven.path_free(s.q, m.held) is None, m.name


@pytest.mark.parametrize("lang", ["rapid", "krl"])
def test_programs_carry_the_arms_joint_values_within_its_limits(lang, arm_cells):
    cell, world, plans = arm_cells[lang]
    robot = world.robot
    assert robot.maker == {"rapid": "ABB", "krl": "KUKA"}[lang]
    posted = post_program(lang, Path(LANG_FILES[lang]), cell, world, plans["bracket"])
    if lang == "rapid":
        rows = re.findall(r"jointtarget j\d+ := \[\[([^\]]*)\]", posted.texts[Path("part.mod")])
        deg = np.array([[float(v) for v in r.split(",")] for r in rows])
    else:
        rows = re.findall(r"E6AXIS XJ\d+=\{([^}]*)\}", posted.texts[Path("part.dat")])
        deg = np.array([[float(v) for v in re.findall(r"A\d (-?[\d.]+)", r)] for r in rows])
    assert deg.shape[1] == 6 and len(deg) == posted.targets + 1  # the targets and the move home
    q = np.radians(deg)
    assert (q >= robot.q_lower - 1e-6).all() and (q <= robot.q_upper + 1e-6).all()
    # the posted values are the plan's own joint values (4 decimals of a degree), both ways of the verdict
    moves = [s for s in flat_steps(posted.steps) if hasattr(s, "q")]
    np.testing.assert_allclose(deg, np.degrees([m.q for m in moves]), atol=0.5e-4 + 1e-9)


@pytest.mark.parametrize("lang", ["rapid", "krl"])
def test_a_language_for_another_makers_arm_is_refused(lang, plans, cell, world, arm_cells):
    with pytest.raises(PlanningError, match=f"{LANG_NAME[lang]} needs an? .* arm, the cell has ur5"):
        post_program(lang, Path(LANG_FILES[lang]), cell, world, plans["bracket"])
    other = "krl" if lang == "rapid" else "rapid"
    c, w, p = arm_cells[other]
    with pytest.raises(PlanningError, match=f"{LANG_NAME[lang]} needs"):
        post_program(lang, Path(LANG_FILES[lang]), c, w, p["bracket"])
    with pytest.raises(PlanningError, match="URScript needs a Universal Robots arm"):
        post_program("urscript", Path("part.script"), c, w, p["bracket"])


def test_urscript_table_is_the_proven_trajectory(plans, cell, world):
    plan = plans["bracket"]
    text = post_program("urscript", Path("bracket.script"), cell, world, plan).texts[Path("bracket.script")]
    tables = re.findall(r"^\s+table\d+ = (\[.*\])$", text, re.M)  # in the verdict branch too
    rows = np.concatenate([np.array(eval(t), dtype=float) for t in tables])  # noqa: S307 - our own numbers
    steps = [s for s in flat_steps(program_steps(cell, world, plan, "urscript")) if isinstance(s, ServoJ)]
    assert len(rows) == sum(len(s.targets) for s in steps)
    first = plan.moves[0]
    n = len(steps[0].targets)
    t = np.minimum(np.arange(1, n + 1) * SERVO_PERIOD_S, first.trajectory.duration)
    q, _, _ = first.trajectory.sample(t)
    np.testing.assert_allclose(rows[:n], q, atol=5e-7)
    assert text.count("servoj(") == len(tables)


def test_a_posted_path_into_an_obstacle_is_refused(plans, cell, world):
    plan = plans["bracket"]
    steps = program_steps(cell, world, plan, "rapid")
    rng = np.random.default_rng(1)
    robot = world.robot
    while True:
        bad = robot.q_lower + (robot.q_upper - robot.q_lower) * rng.random(robot.dof)
        if world.in_collision(bad):
            break
    k = next(i for i, s in enumerate(steps) if i > 2 and hasattr(s, "t") and s.t > 0)
    steps[k] = type(steps[k])(tuple(bad), steps[k].a, steps[k].v, steps[k].r, steps[k].t)
    with pytest.raises(PlanningError, match="posted path collides"):
        check_posted_path(world, plan, steps)


def test_program_name():
    assert program_name("bracket") == "bracket"
    assert program_name("3d-part") == "p_3d_part"
    assert program_name("") == "part"


def test_programs_drive_the_machine_through_its_io(plans, cell, world, arm_cells):
    io = cell.machine
    texts = {}
    for lang in LANG_FILES:
        plan, c, w = _for(lang, "bracket", plans, cell, world, arm_cells)
        texts[lang] = post_program(lang, Path(LANG_FILES[lang]), c, w, plan).texts
    assert all(arm_cells[lang][0].machine == io for lang in ("rapid", "krl"))
    ur = texts["urscript"][Path("part.script")]
    lines = [ln.strip() for ln in ur.splitlines()]
    seq = [ln for ln in lines if ln.startswith(("while get_standard_digital_in", "set_standard_digital_out"))
           and not ln.startswith("set_standard_digital_out(0,")]
    assert seq == [
        f"while get_standard_digital_in({io.cycle_done}) != True:",
        f"set_standard_digital_out({io.close_door}, False)", f"set_standard_digital_out({io.open_door}, True)",
        f"while get_standard_digital_in({io.door_open}) != True:",
        f"set_standard_digital_out({io.open_door}, False)", f"set_standard_digital_out({io.close_door}, True)",
        f"while get_standard_digital_in({io.door_open}) != False:",
        f"set_standard_digital_out({io.cycle_start}, True)",
        f"while get_standard_digital_in({io.cycle_done}) != False:",
        f"set_standard_digital_out({io.cycle_start}, False)",
        f"while get_standard_digital_in({io.cycle_done}) != True:",
        f"set_standard_digital_out({io.close_door}, False)", f"set_standard_digital_out({io.open_door}, True)",
        f"while get_standard_digital_in({io.door_open}) != True:",
    ]
    # the cycle runs between the load's return home and the unload, with the arm standing
    assert ur.index("# load: return home") < ur.index("# machine: close the door") < ur.index("# unload:")
    # after the retreat from the vise, the verdict: the out-tray way, else the reject bin's
    assert (ur.index(f"# {VERDICT_AFTER}") < ur.index(f"if get_standard_digital_in({io.part_ok}) == True:")
            < ur.index("# unload: transfer to out-tray") < ur.index("  else:") < ur.index("# reject: transfer to bin"))
    mod = texts["rapid"][Path("part.mod")]
    assert f"WaitDI di{io.cycle_done}, 0;" in mod and f"SetDO do{io.cycle_start}, 1;" in mod
    src = texts["krl"][Path("part.src")]
    assert f"WAIT FOR NOT $IN[{io.door_open + 1}]" in src and f"$OUT[{io.close_door + 1}] = TRUE" in src


def test_a_posted_move_that_would_cut_into_an_obstacle_is_posted_finer(arm_cells, monkeypatch):
    """With 0.8 s segments the ABB's first move's polyline cuts into the enclosure; the post halves that
    move's segments until its path (checked by post_program) is free, and still runs the planned time."""
    import robotprog.programs as programs

    cell, world, plans = arm_cells["rapid"]
    plan = plans["bracket"]
    monkeypatch.setattr(programs, "SEGMENT_S", 0.8)
    hit = programs.posted_collision(world, plan, program_steps(cell, world, plan, "rapid"))
    assert hit is not None and hit[0] == 0
    posted = post_program("rapid", Path("part.mod"), cell, world, plan)
    coarse = program_steps(cell, world, plan, "rapid")
    assert posted.targets > sum(1 for s in flat_steps(coarse)[1:] if hasattr(s, "q"))
    assert 0.95 * plan.duration <= posted.predicted_s <= 1.05 * plan.duration


def _matrix(xyz, rot) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rot.as_matrix(), xyz
    return t


def _corrected_targets(lang: str, texts: dict) -> tuple[np.ndarray, tuple[float, float], list[np.ndarray]]:
    """Read from a posted program's text the rack slot (4, 4), the pitch (x, y) it steps by to the
    slot the blank stands in, and the corrected straight moves' targets (4, 4) in the slot's frame
    (URScript: in the controller's base frame), in metres."""
    from scipy.spatial.transform import Rotation as R

    def nums(s):
        return [float(v) for v in re.findall(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", s)]

    if lang == "urscript":
        text = next(iter(texts.values()))
        slot = nums(re.search(r"rack_slot = p\[([^\]]*)\]", text).group(1))
        pitch = nums(re.search(r"rack_there = pose_trans\(rack_slot, p\[rack_column \* ([^,]*), rack_row \* ([^,]*),",
                               text).group(0).split("p[", 1)[1])
        moves = [nums(m) for m in re.findall(r"movel\(pose_trans\(rack_corr, p\[([^\]]*)\]\)", text)]
        return (_matrix(slot[:3], R.from_rotvec(slot[3:])), (pitch[0], pitch[1]),
                [_matrix(m[:3], R.from_rotvec(m[3:])) for m in moves])
    if lang == "rapid":
        text = next(iter(texts.values()))
        m = re.search(r"CONST pose pRackSlot := \[\[([^\]]*)\],\[([^\]]*)\]\]", text)
        u = nums(m.group(1)) + nums(m.group(2))
        step = re.search(r"PoseMult\(pRackSlot, \[\[nRackColumn \* ([^,]*), nRackRow \* ([^,]*), 0\]", text)
        names = re.findall(r"MoveL (p\d+), \w+, \w+, tGripper\\WObj:=wRack;", text)
        pts = {n: nums(v) for n, v in re.findall(r"CONST robtarget (p\d+) := \[\[([^\]]*\],\[[^\]]*)\]", text)}

        def pose(v):  # [mm] and quaternion w, x, y, z
            return _matrix(np.array(v[:3]) / 1000.0, R.from_quat([v[4], v[5], v[6], v[3]]))
        return pose(u), (float(step.group(1)) / 1000.0, float(step.group(2)) / 1000.0), [pose(pts[n]) for n in names]
    src, dat = texts[Path("part.src")], texts[Path("part.dat")]

    def frame(v):  # X, Y, Z [mm], A, B, C [deg] (Z, Y', X'')
        return _matrix(np.array(v[:3]) / 1000.0, R.from_euler("ZYX", v[3:6], degrees=True))
    slot = frame(nums(re.search(r"DECL FRAME RACK_SLOT=\{([^}]*)\}", dat).group(1)))
    px = float(re.search(r"RACK_STEP\.X = RACK_COLUMN \* (\S+)", src).group(1)) / 1000.0
    py = float(re.search(r"RACK_STEP\.Y = RACK_ROW \* (\S+)", src).group(1)) / 1000.0
    base = "$BASE = RACK_SLOT : RACK_STEP : RACK_CORR"
    after = src[src.index(base):src.index("$BASE = $NULLFRAME", src.index(base))]
    names = re.findall(r"LIN (XP\d+)", after)
    pts = {n: nums(v)[:6] for n, v in re.findall(r"DECL E6POS (XP\d+)=\{([^}]*)\}", dat)}
    return slot, (px, py), [frame(pts[n]) for n in names]


@pytest.mark.parametrize("lang", ["urscript", "rapid", "krl"])
def test_the_pick_at_the_rack_takes_the_correction_at_run_time(lang, plans, cell, world, arm_cells):
    """Each language reads the rack camera's correction from the cell's controller (URScript: RTDE input
    registers; RAPID: a PERS work object's object frame; KRL: a global FRAME) and moves the grasp by it:
    read back from the program's text and composed as that controller does, a correction of (x, y,
    yaw) puts each corrected target where the proven corrected pick goes (slot * offset * slot^-1 * target)."""
    from robotprog.rackpick import SlotOffset
    from robotprog.urscript import TRANSFORM_BASE_LINK_TO_UR_BASE, MoveL, ReadCorrection

    plan, c, w = _for(lang, "bracket", plans, cell, world, arm_cells)
    program = Path(LANG_FILES[lang])
    posted = post_program(lang, program, c, w, plan)
    steps = flat_steps(list(posted.steps))
    (read,) = [s for s in steps if isinstance(s, ReadCorrection)]
    nominal = [np.asarray(s.pose) for s in steps if isinstance(s, MoveL) and s.corrected]
    assert len(nominal) == 3  # over the blank, down to it, back up
    texts = posted.texts
    if lang == "urscript":
        text = texts[program]
        assert all(f"read_input_float_register({n})" in text for n in range(3)) and "halt" in text
        assert all(f"read_input_integer_register({n})" in text for n in range(2))
        parse_urscript(text)
    elif lang == "rapid":
        assert "PERS wobjdata wRack" in texts[program] and rapid_errors(texts[program]) == []
        assert "PERS num nRackRow" in texts[program] and "PERS num nRackColumn" in texts[program]
    else:
        assert "DECL GLOBAL FRAME RACK_CORR=" in texts[program.with_suffix(".dat")]
        assert "DECL GLOBAL INT RACK_ROW=0" in texts[program.with_suffix(".dat")]
        parse_krl(texts[program], texts[program.with_suffix(".dat")])
    slot, pitch, targets = _corrected_targets(lang, texts)
    assert len(targets) == 3
    assert read.grid == (c.rack.rows, c.rack.columns) and pitch == pytest.approx(c.rack.pitch, abs=1e-9)
    offset = SlotOffset(0.0021, -0.0013, np.radians(2.4))
    d = offset.transform(np.eye(4))  # the offset in the slot's own frame
    to_ur = np.linalg.inv(TRANSFORM_BASE_LINK_TO_UR_BASE)
    base_slot = np.asarray(read.slot)
    for row, column in ((0, 0), (c.rack.rows - 1, c.rack.columns - 1)):  # the plan's slot and the farthest
        step = np.eye(4)
        step[:2, 3] = column * pitch[0], row * pitch[1]  # as the program steps to the slot it reads
        there = read.there(row, column)
        np.testing.assert_allclose(there, np.linalg.inv(c.robot.base.matrix()) @ c.rack.slot_transform(row, column),
                                   atol=1e-9)
        for target, want in zip(targets, nominal):
            # base_link, as the cell proves the pick from that slot (robotprog.rackpick.corrected_pick)
            expected = offset.transform(there) @ there @ np.linalg.inv(base_slot) @ want
            if lang == "urscript":  # rack_corr = slot * step * offset * slot^-1, then pose_trans(rack_corr, target)
                got = np.linalg.inv(to_ur) @ (slot @ step @ d @ np.linalg.inv(slot) @ target)
            else:  # RAPID's uframe (slot * step) * oframe * robtarget; KRL's RACK_SLOT : RACK_STEP : RACK_CORR
                got = slot @ step @ d @ target
            np.testing.assert_allclose(got[:3, 3], expected[:3, 3], atol=2e-6)
            np.testing.assert_allclose(got[:3, :3], expected[:3, :3], atol=1e-5)
    # the bounds the program stops beyond: the slot's room and the camera's error, a few degrees
    assert 0.002 < read.bounds[0] < 0.03 and 0.002 < read.bounds[1] < 0.03 and read.bounds[2] == np.radians(5.0)


def test_a_servo_stream_in_the_proven_room_is_free(plans, cell, world):
    """The planner proves room around each timed path for the chords of its servo samples, and the
    post takes the stream as proven by it: the bound covers the stream (each target the path's own
    sample), and the polyline through the targets, proven on its own, is free; in another world
    than the plan's the stream is proven again."""
    from robotprog.programs import _servo_in_tube, posted_collision
    from robotprog.sweep import swept_motion

    plan = plans["bracket"]
    steps = program_steps(cell, world, plan, "urscript")
    per_move, moves = [], plan.moves + plan.reject
    for st in flat_steps(steps):
        if type(st).__name__ == "Comment":
            per_move.append([])
        elif per_move:
            per_move[-1].append(st)
    proven = collision_world(cell, world.robot, obstacles=plan.obstacles)
    sweep = swept_motion(proven, 0.02)
    covered = 0
    for mv, posted in zip(moves, per_move):
        if mv.kind == "gripper" or not _servo_in_tube(mv, posted):
            continue
        covered += 1
        assert (mv.trajectory.chord_deviation(SERVO_PERIOD_S) <= mv.tube).all()
        qs = np.vstack([mv.waypoints[:1], posted[0].targets])
        assert sweep.polyline_contact(qs, mv.held) is None
    assert covered >= len([m for m in plan.moves if m.kind != "gripper"]) - 4
    assert posted_collision(proven, plan, steps, planned_world=True) is None
    # in a world the plan was not proven in every stream is proven as posted (the cell alone: free too)
    assert posted_collision(world, plan, steps) is None
