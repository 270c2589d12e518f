"""factory.plan: the plan pipeline as a library; output sets that appear whole or not at all.

A plan killed (SIGKILL) while writing must leave nothing a later run trips over: the catalog
ignores the set without its summary and plans the part again into the folder it owns.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import signal
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from factory.cam import CamRequest
from factory.catalog import catalog_record, find_entry, sha256_file
from factory.core.errors import PlanningError
from factory.plan import PlanRequest, plan_outputs, plan_part
from factory.core.resources import FIXTURES
from tests.conftest import ROOT, pocket_block
from tests.rs274 import run_rs274
from tests.shared import content, key_of, once


def fast_request(part: Path, robot: bool = True) -> PlanRequest:
    """Coarse CAM and verify: the pipeline's shape, not its finish, is under test here."""
    cam = CamRequest.defaults(part, "aluminium")
    plan = cam.plan
    plan = dataclasses.replace(plan, waterline=False,
                               finishing=dataclasses.replace(plan.finishing, scallop=0.05))
    return PlanRequest(dataclasses.replace(cam, plan=plan), grid=0.5, robot=robot)


@pytest.fixture(scope="module")
def block(tmp_path_factory) -> Path:
    """A block the sample cell's robot can turn over on its flip station (op 1, flip, op 2)."""
    path = tmp_path_factory.mktemp("part") / "block.stl"
    pocket_block(size=(60.0, 40.0, 16.0)).export(path)
    return path


def test_a_part_the_robot_cannot_turn_over_is_op_1_only_unless_op_2_is_asked(tmp_path, caplog):
    # 30 x 20 mm: its holding block does not overhang the flip station's post enough for a side grip
    small = tmp_path / "small.stl"
    pocket_block(size=(30.0, 20.0, 16.0)).export(small)
    with caplog.at_level(logging.WARNING, logger="factory.plan"):
        planned = plan_part(fast_request(small))
    assert planned.op2 is None and planned.ok
    assert "op 1 only, the holding allowance stays: the robot cannot turn the part over" in caplog.text
    assert "program_op2" not in planned.request.outputs(tmp_path)
    with pytest.raises(PlanningError, match="flip station"):
        plan_part(dataclasses.replace(fast_request(small), ops=2))


@pytest.fixture(scope="module")
def heard_planning(block) -> tuple[object, list[tuple[str, int, int]]]:
    """The block planned with the robot (fast CAM), and what its progress callback heard: one plan for the
    module's tests of the plan, of its progress and of a write killed half-way."""
    heard: list[tuple[str, int, int]] = []
    done = plan_part(fast_request(block), progress=lambda stage, n, total: heard.append((stage, n, total)))
    return done, heard


@pytest.fixture(scope="module")
def planned(heard_planning):
    return heard_planning[0]


def test_plan_part_computes_everything_and_writes_nothing(planned, block):
    assert sorted(p.name for p in block.parent.iterdir()) == ["block.stl"]
    assert planned.report.ok and planned.program.total_time > 0
    assert planned.tending is not None and set(planned.tending.programs) == {"block.script"}
    assert planned.setup_sheet.program == "block.nc"
    # two operations: op 2 runs after op 1, in G55, on the part turned over
    assert planned.setup_sheet.next == {"program": "block.op2.nc", "setup_sheet": "block.op2.setup.json"}
    op2 = planned.op2
    assert op2 is not None and op2.setup_sheet.after == {"program": "block.nc", "setup_sheet": "block.setup.json"}
    assert "\nG55\n" in op2.program.text and op2.report.ok and planned.ok


def test_every_stage_shows_as_it_runs_the_robots_planning_too(heard_planning):
    """A progress callback hears every timed stage start and end, in order, the stages that report
    nothing finer (the robot's planning, posting) included: a long plan is never silent."""
    done, heard = heard_planning
    pipeline = ("load", "setup", "post", "cell", "robot plan", "robot program", "verify", "op 2", "op 2 post",
                "op 2 verify")
    assert set(pipeline) <= set(done.seconds)
    for stage in pipeline:
        starts = [i for i, h in enumerate(heard) if h == (stage, 0, 1)]
        ends = [i for i, h in enumerate(heard) if h == (stage, 1, 1)]
        assert starts and ends and starts[0] < ends[-1], (stage, heard)
    # the CAM's own stages report their steps (n of total) as they go
    assert {"roughing", "finishing"} & {h[0] for h in heard if h[2] > 1}


def test_piped_output_is_never_wrapped(capsys):
    """stderr to a pipe or a log: a long summary stays one line (rich would wrap it at 80 columns)."""
    from cli.common import stderr

    line = "verify OK: max gouge 0.0000 mm, stock over the 0.4 mm grid max 0.010 / mean 0.003 / p95 0.005 mm, 0 rapid crash(es)"
    stderr.print(line, highlight=False, markup=False)
    assert capsys.readouterr().err == line + "\n"


def test_every_stage_of_the_work_is_timed(planned, block, monkeypatch):
    """What a plan reports per stage is all its work (the workflow's overhead figure is what is left):
    the robot program's posting and the CAM's tool choice and face classes included, and a stage
    that ran several times (the stock model) counted every time."""
    assert {"load", "setup", "tools and faces", "roughing", "stock model", "rapid check", "post", "robot plan",
            "robot program", "verify", "op 2", "op 2 verify"} <= set(planned.seconds)
    import factory.cam
    from cadcam.plan import PlanJobResult, PlanTimings
    from factory.core.progress import Stopwatch

    real = factory.cam.plan_job

    def stock_modelled_twice(*args, **kwargs):
        job = real(*args, **kwargs).job
        return PlanJobResult(job, PlanTimings((("stock model", 1.0), ("roughing", 0.5), ("stock model", 2.0))))

    monkeypatch.setattr(factory.cam, "plan_job", stock_modelled_twice)
    watch = Stopwatch()
    factory.cam.compute_job(fast_request(block, robot=False).cam, watch=watch)
    assert watch.seconds["stock model"] == 3.0 and watch.seconds["roughing"] == 0.5


def test_a_stage_begun_inside_another_counts_its_seconds_once():
    """The roadmap a robot plan asks for on its way is timed as its own stage, not twice."""
    from factory.core import progress

    clock = iter([0.0, 1.0, 4.0, 6.0, 10.0, 11.0])  # robot plan 0-6 with roadmap 1-4 inside; then post 10-11
    heard: list[tuple[str, int, int]] = []
    watch = progress.Stopwatch(lambda *report: heard.append(report), clock=lambda: next(clock))
    with watch("robot plan"):
        with watch("roadmap"):
            pass
    with watch("post"):
        pass
    assert watch.seconds == {"roadmap": 3.0, "robot plan": 3.0, "post": 1.0}
    assert heard == [("robot plan", 0, 1), ("roadmap", 0, 1), ("roadmap", 1, 1), ("robot plan", 1, 1),
                     ("post", 0, 1), ("post", 1, 1)]


def test_write_makes_the_whole_set_and_no_staging_is_left(planned, tmp_path, tmp_path_factory):
    summary = planned.write(tmp_path)
    outputs = plan_outputs(planned.request.cam.part, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in outputs.values())
    assert json.loads(outputs["summary"].read_text()) == summary
    assert summary["outputs"] == {k: str(v) for k, v in outputs.items()}
    setups = summary["setups"]
    assert [s["op"] for s in setups] == [1, 2] and [s["work_offset"] for s in setups] == ["G54", "G55"]
    assert setups[0]["program"] == str(outputs["program"]) and setups[1]["program"] == str(outputs["program_op2"])
    assert all(s["estimated_cycle_s"] > 0 for s in setups) and summary["verify"]["ok"]
    assert "write" in summary["seconds"]
    # one tool table for both programs: LinuxCNC runs each with it (a tool it lacks stops the run)
    if shutil.which("rs274"):
        home = tmp_path_factory.mktemp("rs274")  # rs274 leaves its table's copy in its HOME
        for program in (outputs["program"], outputs["program_op2"]):
            p = run_rs274(program, outputs["tool_table"], home)
            assert p.returncode == 0, (program.name, p.stdout[-1500:], p.stderr[-1500:])
    with pytest.raises(Exception, match="exists"):
        planned.write(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in outputs.values())


def _killed_write(planned, out: Path, when: str) -> None:
    """``planned`` written to ``out`` by a forked copy of this process that dies by SIGKILL at a chosen point
    of the write phase: while the files are staged (after the first one), or while they are renamed into
    place (after the second). Forked, so it writes the module's plan as planned (planning it again in a
    fresh process made the same plan, minutes of it; the plan holds the robot's world, which does not pickle)."""
    import factory.plan as fp

    pid = os.fork()
    if pid == 0:  # the child: its patches and its death are its own
        try:
            calls = [0]

            def dying(real):
                def call(*args, **kwargs):
                    real(*args, **kwargs)
                    calls[0] += 1
                    if calls[0] == 2:
                        os.kill(os.getpid(), signal.SIGKILL)
                return call

            if when == "staging":
                fp.write_text = dying(fp.write_text)
            else:
                fp.os.replace = dying(os.replace)
            planned.write(out)
        finally:
            os._exit(1)  # not killed where it should have been: the parent's assertion says so
    _, status = os.waitpid(pid, 0)
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, status


@pytest.mark.parametrize("when", ["staging", "renaming"])
def test_a_plan_killed_while_writing_poisons_nothing(block, planned, tmp_path, when):
    """kill -9 in the write phase, into the catalog's own folder for the part; then `factory
    simulate` finds no plan there, plans the part again over the leftovers, and runs the order."""
    catalog = tmp_path / "catalog"
    key = catalog_record(sha256_file(block), "aluminium", sha256_file(FIXTURES / "cell.yaml"),
                         sha256_file(FIXTURES / "tools.yaml"))["key"]
    folder = catalog / f"block-aluminium-{key[:8]}"
    _killed_write(planned, folder, when)
    assert not (folder / "block.plan.json").exists()
    assert any(folder.iterdir())  # it died with something written
    assert find_entry(catalog, key) is None

    orders = tmp_path / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{block},1,aluminium,0\n")
    r = CliRunner().invoke(app, ["simulate", str(orders), "--catalog", str(catalog), "--json", "--quiet"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    assert [o["outcome"] for o in doc["orders"]] == ["done"], doc["orders"]
    assert find_entry(catalog, key) is not None
    assert not [p for p in folder.iterdir() if p.name.startswith(".")], "staging or temp files left behind"


def test_a_plain_plan_after_a_killed_one_starts_clean(planned, tmp_path):
    """Staging left by a dead process is removed by the next write of the part."""
    out = tmp_path / "out"
    _killed_write(planned, out, "staging")
    assert [p for p in out.iterdir() if p.name.startswith(".block.plan-")]
    planned.write(out, overwrite=True)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_readme_python_example_runs(tmp_path, monkeypatch):
    """The README's "From Python" example, as written, with its output folder under tmp_path."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme.split("## From Python", 1)[1]
    code = section.split("```python\n", 1)[1].split("```", 1)[0]
    monkeypatch.chdir(ROOT)
    code = code.replace('Path("build/', f'Path("{tmp_path}/')
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert (tmp_path / "bracket" / "bracket.plan.json").is_file()


def test_the_tool_table_is_an_output_only_for_a_controller_that_reads_one(tmp_path):
    part = tmp_path / "block.stl"
    assert plan_outputs(part, tmp_path)["tool_table"] == tmp_path / "block.tbl"  # LinuxCNC, the default post
    for post in ("grbl", "fanuc"):
        assert "tool_table" not in plan_outputs(part, tmp_path, post=post)
        assert "tool_table" not in dataclasses.replace(fast_request(part), post=post).outputs(tmp_path)


def _planned_once(real):
    """``real`` (factory.plan._plan_once) with each request planned once in the run: the re-plan tests below
    fault plans of the same block with the same requests (the defaults, then each of REPLAN_SCALES' thinner
    cuts), and a plan depends on nothing but its request, the part's and the cell's content and the processors
    it may use. Each call gets its own copy (:func:`tests.shared.once`), so each test judges a plan of its own."""
    def plan(request, progress=None):
        if progress is not None:
            return real(request, progress)
        key = key_of(repr(request), content(request.cam.part), content(request.cam.cell),
                     os.environ.get("FACTORY_THREADS"))
        return once("factory_plan_once", key, lambda: real(request))
    return plan


def _with_fault(plan, message: str, tool: int = 3, kind: str = "buried"):
    """``plan`` as if op 1's verify had found ``tool`` at fault (``kind``: buried by default)."""
    from cadcam.verify import Fault

    fault = Fault(kind, tool, (10,), 1.2, 1.0, (1.0, 2.0, -3.0), message)
    return dataclasses.replace(plan, report=dataclasses.replace(plan.report, faults=(fault,)))


def _faulted_while_cutting(real, tool: int, message: str, kind: str = "buried"):
    """``real`` planning, with each plan that cuts with ``tool`` faulted (:func:`_with_fault`); also what each
    plan was asked (its CamRequest) and the tools it used, in order."""
    asked, used = [], []

    def plan(request, progress=None):
        asked.append(request.cam)
        planned = real(request, progress)
        used.append({t.number for t in planned.planned.job.tools})
        return _with_fault(planned, message, tool=tool, kind=kind) if tool in used[-1] else planned
    return plan, asked, used


def test_a_plan_verify_fails_is_made_again_with_thinner_cuts_before_any_is_handed_over(block, monkeypatch, caplog):
    import factory.plan

    real = _planned_once(factory.plan._plan_once)
    asked = []

    def first_fails(request, progress=None):
        asked.append(request.cam)
        plan = real(request, progress)
        return _with_fault(plan, "T3 engages 1.2 mm, limit 1 mm") if len(asked) == 1 else plan

    monkeypatch.setattr(factory.plan, "_plan_once", first_fails)
    request = dataclasses.replace(fast_request(block, robot=False), ops=1)
    with caplog.at_level(logging.WARNING, logger="factory.plan"):
        planned = plan_part(request)
    assert planned.ok and planned.replanned == ("op 1: T3 engages 1.2 mm, limit 1 mm",)
    assert "verify failed (op 1: T3 engages 1.2 mm, limit 1 mm): planning again" in caplog.text
    first, again = asked
    assert (first.rapid_cell, again.rapid_cell) == (0.5, request.grid)  # the rapids on verify's grid
    first, again = first.plan, again.plan
    rough = next(t for t in planned.planned.job.tools if t.number == planned.planned.job.parameters["rough_tool"])
    assert again.roughing.stepdown == pytest.approx(0.5 * min(0.5 * rough.diameter, rough.flute_length))
    assert again.finish_engagement == pytest.approx(0.5 * first.finish_engagement)
    assert again.terrace_stepdown == pytest.approx(0.5 * first.terrace_stepdown)
    assert planned.summary(Path("out"))["replanned"] == ["op 1: T3 engages 1.2 mm, limit 1 mm"]


def test_only_when_every_re_plan_fails_is_the_failed_plan_returned(block, monkeypatch):
    import factory.plan

    real = _planned_once(factory.plan._plan_once)
    calls = []

    def always_fails(request, progress=None):
        calls.append(request.cam.plan.finish_engagement)
        return _with_fault(real(request, progress), f"fault {len(calls)}")

    monkeypatch.setattr(factory.plan, "_plan_once", always_fails)
    planned = plan_part(dataclasses.replace(fast_request(block, robot=False), ops=1))
    # the first plan, one per thinner scale, then one without the faulting tool (T3), with the first's cuts
    assert not planned.ok and len(calls) == 1 + len(factory.plan.REPLAN_SCALES) + 1
    assert calls[1:-1] == pytest.approx([calls[0] * s for s in factory.plan.REPLAN_SCALES])
    assert calls[-1] == pytest.approx(calls[0])
    assert planned.replanned == ("op 1: fault 1", "op 1: fault 2", "op 1: fault 3")


def test_when_thinner_cuts_fail_too_the_next_tool_is_tried_before_giving_up(block, monkeypatch, caplog):
    """A tool whose every plan fails verify (whatever the cuts) is set aside: the planner takes the next
    tool for its work, and that plan, which passes, is handed over (not exit 3)."""
    import factory.plan

    fails_while_t1_cuts, asked, used = _faulted_while_cutting(_planned_once(factory.plan._plan_once), 1,
                                                              "T1 engages 1.2 mm, limit 1 mm")
    monkeypatch.setattr(factory.plan, "_plan_once", fails_while_t1_cuts)
    with caplog.at_level(logging.WARNING, logger="factory.plan"):
        planned = plan_part(dataclasses.replace(fast_request(block, robot=False), ops=1))
    assert 1 in used[0]  # the defaults finish the block's flats and walls with T1: the test is not vacuous
    assert planned.ok and len(asked) == 1 + len(factory.plan.REPLAN_SCALES) + 1
    assert [c.set_aside for c in asked] == [()] * (1 + len(factory.plan.REPLAN_SCALES)) + [(1,)]
    assert 1 not in used[-1] and used[-1] == {t.number for t in planned.planned.job.tools}
    assert len(planned.replanned) == 3 and "planning again without T1" in caplog.text


def test_a_holder_fault_goes_straight_to_the_next_tool(block, monkeypatch, caplog):
    """Thinner cuts leave a tool's holder as low beside the same stock: a plan whose holder verify finds in
    the stock is planned again at once without that tool, not first with each of REPLAN_SCALES' cuts."""
    import factory.plan

    holder_hits_while_t1_cuts, asked, used = _faulted_while_cutting(
        _planned_once(factory.plan._plan_once), 1, "T1's holder 2.30 mm into the stock", kind="holder")
    monkeypatch.setattr(factory.plan, "_plan_once", holder_hits_while_t1_cuts)
    with caplog.at_level(logging.WARNING, logger="factory.plan"):
        planned = plan_part(dataclasses.replace(fast_request(block, robot=False), ops=1))
    assert 1 in used[0]  # the defaults cut with T1: the test is not vacuous
    assert [c.set_aside for c in asked] == [(), (1,)]  # no plan with thinner cuts between
    assert asked[1].plan == asked[0].plan  # the first plan's cuts, without T1
    assert planned.ok and 1 not in used[-1] and planned.replanned == ("op 1: T1's holder 2.30 mm into the stock",)
    assert "planning again without T1" in caplog.text and "stepdowns and finishing engagement" not in caplog.text


def test_when_only_op_2_fails_verify_only_op_2_is_planned_again(block, monkeypatch, caplog):
    """Op 1 passed: it is kept (planned once) and op 2 alone is planned again with thinner cuts,
    from op 1's verified stock."""
    import factory.plan
    from cadcam.verify import Fault

    once, op2 = factory.plan._plan_once, factory.plan._plan_op2
    ones, twos = [], []

    def count_once(request, progress=None):
        ones.append(request.cam)
        return once(request, progress)

    def first_op2_fails(req, planned, op1_sim, outputs, progress, watch, op1_report):
        twos.append((req.cam.plan, op1_sim, op1_report))
        second = op2(req, planned, op1_sim, outputs, progress, watch, op1_report)
        if len(twos) > 1:
            return second
        fault = Fault("buried", 3, (10,), 1.2, 1.0, (1.0, 2.0, -3.0), "T3 engages 1.2 mm, limit 1 mm")
        return dataclasses.replace(second, report=dataclasses.replace(second.report, faults=(fault,)))

    monkeypatch.setattr(factory.plan, "_plan_once", count_once)
    monkeypatch.setattr(factory.plan, "_plan_op2", first_op2_fails)
    with caplog.at_level(logging.WARNING, logger="factory.plan"):
        planned = plan_part(dataclasses.replace(fast_request(block, robot=False), ops=2))
    assert len(ones) == 1 and len(twos) == 2  # op 1 planned once, op 2 twice
    assert planned.ok and planned.replanned == ("op 2: T3 engages 1.2 mm, limit 1 mm",)
    assert "planning again (op 2 only)" in caplog.text
    (first, stock1, report1), (again, stock2, report2) = twos
    assert stock1 is stock2 is planned.simulation  # from op 1's verified stock, op 1 kept
    assert report1 is report2 is planned.report  # and op 2's verdict carries what op 1 left
    assert again.finish_engagement == pytest.approx(0.5 * first.finish_engagement)
    assert planned.op2 is not None and planned.op2.report.ok


def _written(out: Path) -> dict[str, object]:
    """Every output in ``out`` but the summary (its wall times): bytes with the folder named, or for the
    MCAP each message's channel, log time and payload in order."""
    from mcap.reader import make_reader

    files: dict[str, object] = {}
    for path in sorted(out.iterdir()):
        if path.name.endswith(".plan.json"):
            continue
        if path.suffix == ".mcap":
            with path.open("rb") as f:
                files[path.name] = [(c.topic, m.log_time, m.data)
                                    for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
        else:
            files[path.name] = path.read_bytes().replace(str(out).encode(), b"<OUT>")
    return files


@pytest.mark.parametrize("robot", [False, True])
def test_the_pictures_drawn_while_verify_runs_are_those_drawn_when_written(block, tmp_path, monkeypatch, robot):
    """The pictures and the log's views of the job are drawn in a second process while verify runs (two
    processors; with a robot, whether its own process has planned its share by then or not), or when the plan is
    written (one; with a robot, after verify): the same bytes either way (issue 35)."""
    request = dataclasses.replace(fast_request(block, robot=robot), ops=1)
    written = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("FACTORY_THREADS", threads)
        plan = plan_part(request)
        drawn_meanwhile = threads == "2"
        assert (plan.ahead is not None) == (drawn_meanwhile or robot)
        assert ("pictures and log" in plan.seconds) == drawn_meanwhile
        assert ("pictures" in plan.seconds) == (robot and not drawn_meanwhile)
        plan.write(tmp_path / threads)
        written[threads] = _written(tmp_path / threads)
    assert {"verify_png", "toolpath_png", "setup_png", "mcap"} <= set(request.outputs(tmp_path))
    assert written["1"] == written["2"]
    # the log holds what was drawn ahead (the job's part and toolpath) and what verify found
    topics = {topic for name, messages in written["2"].items() if name.endswith(".mcap") for topic, _, _ in messages}
    assert {"/cam/part", "/cam/toolpath", "/verify/stock"} <= topics


def test_verify_begun_ahead_on_an_idle_processor_writes_what_one_processor_writes(block, tmp_path, monkeypatch):
    """Where the machine leaves a processor idle (cadcam.parallel.IdleMeter), op 1's verify is begun in rounds while
    the later operations are planned, and verify goes on from the last round: every output the same bytes as the
    plan on one processor, where nothing is begun ahead (issue 35)."""
    import factory.verify

    request = dataclasses.replace(fast_request(block, robot=False), ops=1)
    monkeypatch.setattr(factory.verify.IdleMeter, "idle", lambda self, own=0.0: 2.0)
    monkeypatch.setattr(factory.verify, "OVERTAKE_BELOW", 0.0)  # each round waited for, however loaded the machine
    resumed = []
    real_state = factory.verify.VerifyAhead.state

    def state(self, operations):
        out = real_state(self, operations)
        resumed.append(out)
        return out

    monkeypatch.setattr(factory.verify.VerifyAhead, "state", state)
    written = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("FACTORY_THREADS", threads)
        resumed.clear()
        plan_part(request).write(tmp_path / threads)
        written[threads] = _written(tmp_path / threads)
        assert (resumed[-1] is not None) == (threads == "2")  # verify went on from a round's cut
    assert written["1"] == written["2"]


@pytest.mark.parametrize("robot", [False, True])
def test_the_pictures_are_drawn_beside_the_wait_for_the_last_round_of_verify_ahead(block, monkeypatch, robot):
    """On two processors the pictures and the log's views of the job are begun in their process before the plan
    waits for the last round of verify begun ahead, with a robot or without: that wait leaves the plan's own
    process idle, and the drawing needs neither the post, verify nor the robot's plan (issue 35)."""
    import factory.plan
    import factory.verify

    import factory.robotwork

    monkeypatch.setenv("FACTORY_THREADS", "2")
    real_work = factory.robotwork.robot_work

    def slow_work(*args):  # the robot still planning when the plan begins to wait
        time.sleep(3.0)
        return real_work(*args)

    monkeypatch.setattr(factory.robotwork, "robot_work", slow_work)
    begun: list[str] = []
    at_the_wait: list[list[str]] = []

    class Recorded(factory.plan.Background):
        def __init__(self, fn, *args):
            begun.append(fn.__name__)
            super().__init__(fn, *args)

    real_state = factory.verify.VerifyAhead.state

    def state(self, operations):
        at_the_wait.append(list(begun))
        return real_state(self, operations)

    monkeypatch.setattr(factory.plan, "Background", Recorded)
    monkeypatch.setattr(factory.verify.VerifyAhead, "state", state)
    plan = plan_part(dataclasses.replace(fast_request(block, robot=robot), ops=1))
    assert at_the_wait == [["drawn"]]  # drawing when the plan began to wait, and drawn once
    assert plan.ahead is not None and "pictures and log" in plan.seconds and "pictures" not in plan.seconds
    assert (plan.tending is not None) == robot
