"""`factory simulate`: orders through the cell from a catalog of plans, one MCAP, a Foxglove layout.

A small pocketed block is planned once per run (fast CAM options) into a catalog; the
simulation must find it there by its key, run every order to an outcome, and log motion that a
real robot could make (inside the joint limits, no jumps) to an MCAP that rosbag2's readers take.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from mcap.reader import make_reader
from typer.testing import CliRunner

from cli.main import app
from factory.mcaplog import read_messages
from factory.core.resources import FIXTURES
from robotprog.cell import load_cell
from robotprog.robots import load_robot
from tests.cli.expect import assert_one_line_error, simulate_exit
from tests.conftest import copy_block_catalog
from tests.mcapcheck import check_rosbag2_mcap

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def catalog(shared_work, tmp_path_factory) -> tuple[Path, Path]:
    """(catalog folder, part): a 30x20x16 mm pocketed block planned with fast options, the module's own copy
    of the run's one plan (:func:`tests.conftest.copy_block_catalog`: the block and options it planned)."""
    return copy_block_catalog(tmp_path_factory.mktemp("sim"))


def _orders(folder: Path, rows: list[str]) -> Path:
    path = folder / "orders.csv"
    path.write_text("part,quantity,material,priority\n" + "\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def run_ok(catalog, tmp_path_factory):
    """A run with good, missing, unknown-material and implausible parts, with its JSON and MCAP."""
    folder, part = catalog
    out = tmp_path_factory.mktemp("run")
    huge = out / "huge.stl"
    trimesh.creation.box((3000.0, 2000.0, 500.0)).export(huge)
    orders = _orders(out, [f"{part},2,aluminium,1", "missing.stl,1,aluminium,0", f"{part},1,unobtainium,0",
                           f"{huge},1,aluminium,0", f"{part},1,aluminium,0"])
    mcap = out / "cell.mcap"
    r = run("simulate", orders, "--catalog", folder, "--mcap", mcap, "--png", out / "cell.png", "--json", "--quiet")
    assert r.exit_code == 3, r.output  # done, with findings: three orders failed, everything written
    assert (out / "cell.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return json.loads(r.stdout), mcap, orders


def test_every_order_ends_with_an_outcome_and_the_rest_run(run_ok):
    doc, _, _ = run_ok
    by_id = {o["order"]: o for o in doc["orders"]}
    assert by_id["o1"]["outcome"] == "done" and by_id["o1"]["good"] == 2
    assert by_id["o5"]["outcome"] == "done" and by_id["o5"]["good"] == 1
    assert by_id["o2"]["outcome"] == "failed" and "not found" in by_id["o2"]["reason"]
    assert by_id["o3"]["outcome"] == "failed" and "unobtainium" in by_id["o3"]["reason"]
    assert by_id["o4"]["outcome"] == "failed" and "huge.stl" in by_id["o4"]["reason"]
    s = doc["summary"]
    assert s["parts_good"] == 3 and s["orders"] == {"done": 2, "rejected": 0, "failed": 3}
    assert s["faults"] == {} and 0 < s["robot_utilisation"] < 1 and 0 < s["machine_utilisation"] < 1
    # the plan came from the catalog, not planned again
    block = next(p for p in doc["parts"] if p["material"] == "aluminium" and p["part"].endswith("block.stl"))
    assert block["planned_now"] is False


def test_durations_come_from_the_plan(run_ok, catalog):
    doc, _, _ = run_ok
    folder, _ = catalog
    plan = json.loads((folder / "block.plan.json").read_text())
    block = next(p for p in doc["parts"] if "process_s" in p)["process_s"]
    moves = {m["name"]: m["duration_s"] for m in plan["robot"]["moves"]}
    assert block["machining_s"] == pytest.approx(plan["estimated_cycle_s"], abs=0.06)
    assert block["fetch_s"] + block["load_s"] == pytest.approx(sum(d for n, d in moves.items()
                                                                   if n.startswith("load:")), abs=0.05)
    assert block["unload_s"] == pytest.approx(sum(d for n, d in moves.items() if n.startswith("unload:")), abs=0.05)
    assert 0.1 < block["locate_s"] < 5 and 0.1 < block["inspect_s"] < 5
    # three parts, one after the other: pick, load, cut, unload each
    cycle = sum(block[k] for k in ("locate_s", "fetch_s", "load_s", "machining_s", "unload_s"))
    assert doc["summary"]["makespan_s"] == pytest.approx(3 * cycle + block["inspect_s"], rel=1e-3)


def test_mcap_meets_rosbag2_requirements_and_layout_names_its_topics(run_ok):
    doc, mcap, _ = run_ok
    counts = check_rosbag2_mcap(mcap)
    for topic in ("/robot_description", "/tf", "/tf_static", "/joint_states", "/machine/toolpath", "/machine/stock",
                  "/camera/image/compressed", "/cell/state", "/cell/robot", "/cell/machine", "/cell/orders",
                  "/rosout"):
        assert counts.get(topic, 0) > 0, topic
    assert mcap.stat().st_size < 100e6
    layout = json.loads(mcap.with_suffix(".layout.json").read_text())
    text = json.dumps(layout)
    assert "/robot_description" in text and "/camera/image/compressed" in text
    # every camera step left a picture: 3 locates + 3 inspections
    assert counts["/camera/image/compressed"] == 6


def test_the_log_is_written_in_log_time(run_ok, catalog, tmp_path):
    # streamed, not sorted at the end: a player (and the live view) gets every message in time order,
    # also when faults rerun steps and the summary's rounded makespan precedes the last entries
    folder, part = catalog
    orders = _orders(tmp_path, [f"{part},3,aluminium,0", f"{part},2,aluminium,1"])
    mcap = tmp_path / "faults.mcap"
    r = run("simulate", orders, "--catalog", folder, "--faults", "3", "--mcap", mcap, "--json", "--quiet")
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    for path in (run_ok[1], mcap):
        with open(path, "rb") as f:
            times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
        assert len(times) > 1000 and times == sorted(times)


def test_every_logged_marker_is_stamped_when_it_was_logged(run_ok):
    _, mcap, _ = run_ok
    msgs = read_messages(mcap, ["/machine/toolpath", "/machine/stock"])
    assert len({t for topic, t, _ in msgs if topic == "/machine/toolpath"}) >= 3  # a toolpath per load
    for _, t, m in msgs:
        for mk in m.markers:
            assert mk.header.stamp.sec * 10**9 + mk.header.stamp.nanosec == t


def test_logged_robot_motion_is_continuous_and_inside_the_limits(run_ok):
    _, mcap, _ = run_ok
    cell = load_cell(FIXTURES / "cell.yaml")
    robot = load_robot(cell.robot.model)
    states = [(t * 1e-9, np.asarray(m.position)) for _, t, m in read_messages(mcap, ["/joint_states"])]
    t = np.array([s[0] for s in states])
    q = np.array([s[1] for s in states])
    assert np.all(np.diff(t) >= 0)
    assert np.all(q >= robot.q_lower - 1e-6) and np.all(q <= robot.q_upper + 1e-6)
    # no jumps: between samples no joint moves faster than its velocity limit allows
    dt = np.diff(t)
    step = np.abs(np.diff(q, axis=0))
    assert np.all(step <= robot.v_max * cell.motion.speed_scaling * dt[:, None] * 1.05 + 1e-6)
    # the robot starts and ends at home
    np.testing.assert_allclose(q[0], cell.robot.home, atol=1e-6)
    np.testing.assert_allclose(q[-1], cell.robot.home, atol=1e-3)


def test_robot_rate_thins_the_robot_states_and_leaves_every_other_topic_as_it_was(run_ok, tmp_path):
    doc, full, orders = run_ok
    mcap = tmp_path / "thin.mcap"
    r = run("simulate", orders, "--catalog", Path(doc["parts"][0]["plan"]).parent.parent, "--mcap", mcap,
            "--robot-rate", "1", "--json", "--quiet")
    assert r.exit_code == 3, r.output  # the run_ok orders: three fail
    thin = json.loads(r.stdout)["mcap"]["messages"]
    counts = doc["mcap"]["messages"]
    # one state per simulated second (and each move's ends) instead of 25
    assert 0 < thin["/joint_states"] < counts["/joint_states"] / 5
    assert {k: v for k, v in thin.items() if k != "/joint_states"} == \
        {k: v for k, v in counts.items() if k != "/joint_states"}
    states = [(t, np.asarray(m.position)) for _, t, m in read_messages(mcap, ["/joint_states"])]
    assert all(b[0] >= a[0] for a, b in zip(states, states[1:]))
    # the robot still starts and ends at home
    home = load_cell(FIXTURES / "cell.yaml").robot.home
    np.testing.assert_allclose(states[0][1], home, atol=1e-6)
    np.testing.assert_allclose(states[-1][1], home, atol=1e-3)
    r = run("simulate", orders, "--catalog", Path(doc["parts"][0]["plan"]).parent.parent, "--robot-rate", "0")
    assert r.exit_code == 2


def test_tool_follows_the_program_inside_the_stock(run_ok, catalog):
    _, mcap, _ = run_ok
    folder, _ = catalog
    sheet = json.loads((folder / "block.setup.json").read_text())
    lo, hi = np.array(sheet["stock"]["min"]) / 1000, np.array(sheet["stock"]["max"]) / 1000
    tool = [tf.transform.translation for _, _, m in read_messages(mcap, ["/tf"]) for tf in m.transforms
            if tf.child_frame_id == "tool"]
    xyz = np.array([[p.x, p.y, p.z] for p in tool])
    assert len(xyz) > 10
    # the tool tip stays over the stock's footprint (plus a tool radius and lead-in) and cuts below its top
    assert np.all(xyz[:, :2] >= lo[:2] - 0.02) and np.all(xyz[:, :2] <= hi[:2] + 0.02)
    assert xyz[:, 2].min() < hi[2] and xyz[:, 2].min() >= lo[2] - 1e-6


def test_faults_are_recovered_or_reported(catalog, tmp_path):
    folder, part = catalog
    orders = _orders(tmp_path, [f"{part},4,aluminium,0", f"{part},3,aluminium,1"])
    mcap = tmp_path / "faults.mcap"
    r = run("simulate", orders, "--catalog", folder, "--faults", "7", "--mcap", mcap, "--json", "--quiet")
    doc = json.loads(r.stdout)
    assert r.exit_code == simulate_exit(doc), r.output
    s = doc["summary"]
    assert sum(s["faults"].values()) == s["recoveries"] + s["failures"] > 0
    assert all(o["outcome"] in ("done", "rejected", "failed") and o["reason"] for o in doc["orders"])
    again = run("simulate", orders, "--catalog", folder, "--faults", "7", "--json", "--quiet")
    assert json.loads(again.stdout)["summary"] == s  # same seed, same run
    levels = [m.level for _, _, m in read_messages(mcap, ["/rosout"])]
    assert max(levels) >= 30  # faults are logged as warnings (or errors)


def test_a_missing_part_is_planned_into_the_catalog_once(tmp_path):
    part = tmp_path / "cube.stl"
    trimesh.creation.box((24.0, 18.0, 20.0)).export(part)
    orders = _orders(tmp_path, [f"{part},1,aluminium,0"])
    catalog = tmp_path / "catalog"
    first = run("simulate", orders, "--catalog", catalog, "--json", "--quiet")
    assert first.exit_code == 0, first.output
    assert json.loads(first.stdout)["parts"][0]["planned_now"] is True
    plans = sorted(catalog.rglob("*.plan.json"))
    assert len(plans) == 1 and sorted(catalog.rglob("*.camera.json"))
    second = run("simulate", orders, "--catalog", catalog, "--json", "--quiet")
    assert json.loads(second.stdout)["parts"][0]["planned_now"] is False
    assert sorted(catalog.rglob("*.plan.json")) == plans
    assert json.loads(second.stdout)["summary"] == json.loads(first.stdout)["summary"]
    # a changed mesh is a new key: planned again beside the old plan, which is kept
    trimesh.creation.box((24.0, 18.0, 19.0)).export(part)
    third = run("simulate", orders, "--catalog", catalog, "--json", "--quiet")
    assert json.loads(third.stdout)["parts"][0]["planned_now"] is True
    assert len(list(catalog.rglob("*.plan.json"))) == 2


@pytest.mark.parametrize("text, needle", [
    ("orders: [{part: a.stl, quantity: zero, material: steel}]", "quantity"),
    ("orders: [{part: a.stl, quantity: 1}]", "material"),
    ("orders:\n  - {part: a.stl, quantity: 1, material: steel\n", "YAML"),
    ("parts: []", "orders"),
])
def test_a_malformed_orders_file_stops_before_anything_runs(tmp_path, text, needle):
    orders = tmp_path / "orders.yaml"
    orders.write_text(text)
    mcap = tmp_path / "out.mcap"
    r = run("simulate", orders, "--catalog", tmp_path / "catalog", "--mcap", mcap)
    assert_one_line_error(r, str(orders), needle)
    assert not mcap.exists() and not (tmp_path / "catalog").exists()


def test_an_existing_log_is_not_overwritten(run_ok):
    _, mcap, orders = run_ok
    before = mcap.read_bytes()
    r = run("simulate", orders, "--mcap", mcap)
    assert_one_line_error(r, str(mcap), "--overwrite")
    assert mcap.read_bytes() == before


def test_the_command_is_glue_the_library_call_makes_the_same_run(run_ok, catalog, tmp_path):
    """The README's ``simulate_orders`` example, on this module's orders and catalog: the same orders,
    figures, parts and MCAP messages as the command made."""
    from factory.core.errors import FactoryError
    from factory.cellinputs import CellInputs
    from factory.production import SimulateRequest, simulate_orders

    doc, full, orders = run_ok
    folder, _ = catalog
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    code = readme.split("## From Python", 1)[1].split("```python\n")[2].split("```", 1)[0]
    for old, new in (('Path("samples/orders.yaml")', f'Path("{orders}")'),
                     ('catalog=Path("build")', f'catalog=Path("{folder}")'), ('Path("build/', f'Path("{tmp_path}/')):
        assert old in code, old
        code = code.replace(old, new)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    done = namespace["done"]
    same = done.summary
    for key in ("orders", "summary", "parts"):
        assert same[key] == doc[key], key
    assert same["mcap"]["messages"] == doc["mcap"]["messages"] and (tmp_path / "cell.layout.json").exists()
    assert (tmp_path / "cell.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ours = [t for _, t, _ in read_messages(tmp_path / "cell.mcap", ["/joint_states"])]
    assert ours == [t for _, t, _ in read_messages(full, ["/joint_states"])]
    with pytest.raises(FactoryError, match="fault rate needs a seed"):
        simulate_orders(SimulateRequest(orders, CellInputs(catalog=folder, fault_rate=0.5)))
