"""The part process the cell simulation runs on, taken from a plan's robot motion and summary."""

from __future__ import annotations

import numpy as np
import pytest

from factory.core.errors import CellError
from factory.cellcameras import Shot
from factory.simulation import RobotMotion, op2_of, part_process
from robotprog.cellsim import simulate
from robotprog.orders import Order

SHOTS = {"locate": Shot(b"", [], 0.05, True), "inspect": Shot(b"", [], 0.07, True)}


def _motion(phases: list[tuple[str, list[tuple[str, float]]]]) -> RobotMotion:
    moves, t = [], 0.0
    for phase, steps in phases:
        for name, d in steps:
            moves.append((f"{phase}: {name}", t, t + d))
            t += d
    ts = np.linspace(0.0, t, 50)
    return RobotMotion(tuple(moves), ts, np.zeros((50, 6)))


LOAD = ("load", [("home to above rack", 2.0), ("approach stock", 0.5), ("grip stock", 0.4),
                 ("retreat from rack", 0.5), ("transfer to vise", 3.0), ("return home", 2.0)])
FLIP = ("flip", [("home to above vise", 2.5), ("turn over", 1.5), ("return home", 3.0)])
UNLOAD = ("unload", [("home to above vise", 2.0), ("return home", 4.0)])


def test_one_setup_plan_has_no_flip():
    proc = part_process(_motion([LOAD, UNLOAD]), 300.0, SHOTS)
    assert proc.setups == 1 and proc.flip_s == 0.0 and proc.op2_machining_s is None
    assert proc.fetch_s == pytest.approx(3.4) and proc.load_s == pytest.approx(5.0)
    assert proc.unload_s == pytest.approx(6.0)


def test_two_setups_take_the_flip_from_the_motion_and_op2_from_the_summary():
    summary = {"setups": [{"op": 1, "program": "a.nc", "estimated_cycle_s": 300.0},
                          {"op": 2, "program": "a.op2.nc", "estimated_cycle_s": 95.5}]}
    op2 = op2_of(summary)
    proc = part_process(_motion([LOAD, FLIP, UNLOAD]), 300.0, SHOTS, op2["estimated_cycle_s"])
    assert proc.setups == 2 and proc.flip_s == pytest.approx(7.0) and proc.op2_machining_s == 95.5
    assert proc.unload_s == pytest.approx(6.0) and proc.load_s == pytest.approx(5.0)
    assert proc.cycle_s == pytest.approx(proc.locate_s + 3.4 + 5.0 + 300.0 + 7.0 + 95.5 + 6.0)
    result = simulate([Order("o1", "a.stl", 2, "aluminium", 0)], {"a.stl": proc})
    acts = [(a.action, a.op, round(a.end - a.start, 6)) for a in result.activities
            if a.job == 1 and a.action in ("cut", "flip")]
    assert acts == [("cut", 1, 300.0), ("flip", None, 7.0), ("cut", 2, 95.5)]
    assert op2_of({"setups": summary["setups"][:1]}) is None and op2_of({}) is None


def test_setups_and_motion_must_agree():
    with pytest.raises(CellError, match="does not turn the part over"):
        part_process(_motion([LOAD, UNLOAD]), 300.0, SHOTS, 90.0)
    with pytest.raises(CellError, match="one setup"):
        part_process(_motion([LOAD, FLIP, UNLOAD]), 300.0, SHOTS)


def test_the_cameras_see_an_inch_part_at_its_size_in_mm(tmp_path):
    """The part a setup sheet was made for is read in mm once: an inch part is not scaled by 25.4 again."""
    import trimesh

    from cadcam.model import Setup
    from factory.core.setupsheet import SetupSheet
    from factory.simulation import seen_part

    path = tmp_path / "block.stl"
    trimesh.creation.box((2.0, 1.5, 0.8)).export(path)  # inches
    setup = Setup(stock_min=(0, 0, -25), stock_max=(55, 42, 0), transform_mesh_to_work=np.eye(4), mesh_scale=25.4)
    sheet = SetupSheet(stock_min=setup.stock_min, stock_max=setup.stock_max, transform_mesh_to_work=np.eye(4),
                       tools=(), mesh_scale=25.4)
    seen = seen_part(path, setup, sheet, "block.setup.json")
    assert np.allclose(seen.extents, (50.8, 38.1, 20.32))


def test_robot_states_written_as_cdr_are_the_bytes_of_the_messages_a_live_sink_gets():
    """The robot's joint states and link transforms, packed straight into their CDR with the
    links' poses converted a whole move at once, are byte for byte the messages (built one by
    one, as before) that sinks serialising themselves get, at every state of a motion."""
    from factory.core.resources import FIXTURES
    from factory.rosmsgs import serialize_cdr
    from factory.tending import RobotStateLog
    from robotprog.cell import load_cell
    from robotprog.collision import collision_world

    world = collision_world(load_cell(FIXTURES / "cell.yaml"))

    class Recorder:
        def __init__(self):
            self.pairs = []

        def write_cdr(self, topic, typename, data, log_time_ns, make=None, *, latched=False):
            msg = make()
            self.pairs.append((topic, typename, data, msg.__msgtype__, serialize_cdr(msg, msg.__msgtype__)))

    sink = Recorder()
    states = RobotStateLog(sink, world)
    rng = np.random.default_rng(3)
    lower, upper = world.robot.model.lowerPositionLimit, world.robot.model.upperPositionLimit
    q = rng.uniform(np.maximum(lower, -np.pi), np.minimum(upper, np.pi), size=(12, len(lower)))
    poses = states.links.poses(q)
    for i, qi in enumerate(q):
        states.write(qi, rng.normal(size=len(qi)), 10**9 * i + 7, poses[i] if i % 2 else None)
    assert [p[0] for p in sink.pairs] == ["/joint_states", "/tf"] * len(q)
    assert len(states.links.names) > 3
    for topic, typename, data, made_type, made in sink.pairs:
        assert (typename, data) == (made_type, made), topic
