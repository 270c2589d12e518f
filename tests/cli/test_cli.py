"""The `factory` command driven through typer's CliRunner on temp files."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from cli.main import app
from factory.plan import plan_outputs
from tests.cli.expect import assert_one_line_error
from tests.conftest import SAMPLES
from tests.rs274 import run_rs274

runner = CliRunner()
FAST = ["--scallop", "0.02", "--quiet"]


def run(*args: str):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def chain(tmp_path_factory) -> dict[str, Path]:
    """toolpath → gcode → verify on the pocket block, once for the module."""
    from tests.conftest import pocket_block

    d = tmp_path_factory.mktemp("chain")
    part = d / "block.stl"
    pocket_block().export(part)
    tp = d / "block.toolpath.mcap"
    r = run("toolpath", part, "-o", tp, "--png", d / "block.toolpath.png", *FAST)
    assert r.exit_code == 0, r.output
    nc = d / "block.nc"
    r = run("gcode", tp, "-o", nc, "--quiet")
    assert r.exit_code == 0, r.output
    return {"part": part, "toolpath": tp, "nc": nc, "setup": d / "block.setup.json", "table": d / "block.tbl", "dir": d}


def test_chain_writes_program_and_setup_sheet(chain):
    assert (chain["dir"] / "block.toolpath.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = chain["nc"].read_text()
    assert "G21" in text and "M30" in text
    sheet = json.loads(chain["setup"].read_text())
    assert sheet["format"] == "factory.setup/1"
    assert sheet["units"] == "mm"
    # the tools the planner chose by reach and fit are the ones listed, each used by an operation
    assert {t["number"] for t in sheet["tools"]} == {op["tool"] for op in sheet["operations"]}
    assert sheet["estimated_cycle_s"] > 0
    assert all(op["estimated_s"] > 0 for op in sheet["operations"])


def test_verify_passes_and_writes_reports(chain):
    d = chain["dir"]
    r = run("verify", chain["nc"], "--setup", chain["setup"], "--part", chain["part"],
            "-o", d / "v.json", "--png", d / "v.png", "--mcap", d / "v.mcap", "--quiet")
    assert r.exit_code == 0, r.output
    report = json.loads((d / "v.json").read_text())
    assert report["max_gouge"] <= 0.01
    assert report["rapid_crashes"] == []
    assert (d / "v.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (d / "v.mcap").stat().st_size > 0


def test_verify_fails_with_exit_3_on_a_gouging_program(chain, tmp_path):
    # Lower every Z by 1 mm: the program now cuts into the part.
    import re

    text = chain["nc"].read_text()
    lowered = re.sub(r"Z(-?\d+\.?\d*)", lambda m: f"Z{float(m.group(1)) - 1.0:.4f}", text)
    bad = tmp_path / "deep.nc"
    bad.write_text(lowered)
    r = run("verify", bad, "--setup", chain["setup"], "--part", chain["part"], "--json", "--quiet")
    assert r.exit_code == 3
    assert json.loads(r.stdout)["max_gouge"] > 0.5


def test_gcode_writes_the_jobs_tool_table_for_linuxcnc(chain):
    """PART.tbl beside PART.nc: one line per tool of the setup sheet, its figures as the sheet gives them."""
    sheet = json.loads(chain["setup"].read_text())
    lines = chain["table"].read_text().splitlines()
    assert lines == [f"T{t['number']} P{t['number']} D{t['diameter']:g} Z{t['length']:g} ;{t['name'][:39]}"
                     for t in sorted(sheet["tools"], key=lambda t: t["number"])]


@pytest.mark.parametrize("post", ["grbl", "fanuc"])
def test_gcode_writes_no_tool_table_for_controllers_that_read_none(chain, tmp_path, post):
    nc = tmp_path / "block.nc"
    r = run("gcode", chain["toolpath"], "-o", nc, "--post", post, "--json", "--quiet")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["block.nc", "block.setup.json"]
    assert "tool_table" not in json.loads(r.stdout)


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 is not installed (apt-get install linuxcnc-uspace)")
def test_linuxcnc_accepts_the_program(chain, tmp_path):
    """rs274 -t PART.tbl PART.nc: the program with the table `factory gcode` wrote beside it."""
    p = run_rs274(chain["nc"], chain["table"], tmp_path, timeout=120)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]


def test_outputs_are_not_overwritten_without_asking(chain):
    before = chain["nc"].read_bytes()
    r = run("gcode", chain["toolpath"], "-o", chain["nc"], "--quiet")
    assert_one_line_error(r, str(chain["nc"]), "--overwrite")
    assert chain["nc"].read_bytes() == before


def test_plan_writes_everything(tmp_path):
    from tests.conftest import pocket_block

    part = tmp_path / "block.stl"
    pocket_block(size=(30.0, 20.0, 16.0)).export(part)  # 17 mm of stock: tall enough to grip
    out = tmp_path / "out"
    r = run("plan", part, "-o", out, "--json", "--scallop", "0.02", "--quiet")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    for key in ("program", "setup_sheet", "mcap", "verify_json", "verify_png", "toolpath_png", "setup_png", "summary",
                "robot_program", "tool_table"):
        assert Path(summary["outputs"][key]).is_file(), key
    if shutil.which("rs274"):  # the program runs with the job's tool table beside it
        p = run_rs274(Path(summary["outputs"]["program"]), Path(summary["outputs"]["tool_table"]), tmp_path)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    # this block is too small for the robot to turn over: op 1 only (tests/factory/test_plan.py)
    assert set(summary["outputs"]) == set(plan_outputs(part, out, ops=len(summary["setups"])))
    # one MCAP of the whole plan: CAM, verify and robot, with the work frame in the cell's vise
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(summary["outputs"]["mcap"], "rb") as f:
        msgs = list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
    topics = {ch.topic for _, ch, _, _ in msgs}
    assert {"/cam/toolpath", "/verify/stock", "/robot_description", "/joint_states", "/tf"} <= topics
    static = [t for _, ch, _, m in msgs if ch.topic == "/tf_static" for t in m.transforms]
    work = next(t for t in static if t.child_frame_id == "work")
    vise = next(t for t in static if t.child_frame_id == "vise")
    assert work.header.frame_id == "world"
    # the stock's top face (work z = 0) is above the vise's parallels
    assert work.transform.translation.z > vise.transform.translation.z
    assert abs(work.transform.translation.x - vise.transform.translation.x) < 0.1
    script = Path(summary["outputs"]["robot_program"]).read_text()
    assert "movej(" in script and "set_standard_digital_out(" in script
    assert summary["robot"]["motion_s"] > 0
    assert summary["robot"]["program_s"] == pytest.approx(summary["robot"]["motion_s"], rel=0.05)
    assert summary["verify"]["max_gouge"] <= 0.01
    assert set(summary["seconds"]) >= {"load", "roughing", "post", "verify"}
    # a block of flats and walls: finished by flat end mills, no ball raster
    assert any(k.startswith("flats+walls") for k in summary["seconds"]) and "raster" not in summary["seconds"]


def test_gcode_rejects_a_file_that_is_not_mcap(tmp_path):
    bogus = tmp_path / "x.toolpath.mcap"
    bogus.write_text("hello")
    out = tmp_path / "x.nc"
    r = run("gcode", bogus, "-o", out)
    assert_one_line_error(r, str(bogus))
    assert not out.exists()


def _box_stl(path: Path, size=(20.0, 20.0, 10.0)) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(size)
    mesh.export(path)
    return mesh


def bad_empty(p: Path) -> None:
    p.write_bytes(b"")


def bad_truncated(p: Path) -> None:
    _box_stl(p)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) - 70])


def bad_nan(p: Path) -> None:
    mesh = trimesh.creation.box((20, 20, 10))
    v = mesh.vertices.copy()
    v[0, 0] = np.nan
    data = bytearray(b"\0" * 80 + struct.pack("<I", len(mesh.faces)))
    for f in mesh.faces:
        data += struct.pack("<3f", 0, 0, 0) + struct.pack("<9f", *v[f].ravel()) + b"\0\0"
    p.write_bytes(bytes(data))


def bad_open(p: Path) -> None:
    # A tube without its end caps: holes far too big to patch (a missing box side gets repaired).
    tube = trimesh.creation.cylinder(radius=10, height=20, sections=32)
    walls = np.abs(tube.face_normals[:, 2]) < 0.5
    trimesh.Trimesh(tube.vertices, tube.faces[walls], process=False).export(p)


def bad_units(p: Path) -> None:
    _box_stl(p, (0.05, 0.04, 0.02))


@pytest.mark.parametrize("make_bad", [bad_empty, bad_truncated, bad_nan, bad_open, bad_units],
                         ids=lambda f: f.__name__)
@pytest.mark.parametrize("command", ["toolpath", "plan"])
def test_bad_part_gives_one_line_error_and_no_output(tmp_path, make_bad, command):
    part = tmp_path / "bad.stl"
    make_bad(part)
    out = tmp_path / "out"
    if command == "toolpath":
        r = run("toolpath", part, "-o", out / "bad.toolpath.mcap", "--quiet")
    else:
        r = run("plan", part, "-o", out, "--quiet")
    assert_one_line_error(r, str(part))
    assert not out.exists() or not any(out.iterdir())


def test_a_bad_thread_count_is_refused_before_the_work(tmp_path, monkeypatch):
    """FACTORY_THREADS (the workflow's per-job share) is checked before any planning, by name."""
    monkeypatch.setenv("FACTORY_THREADS", "all")
    out = tmp_path / "out"
    r = run("plan", SAMPLES / "bracket.stl", "-o", out, "--quiet")
    assert_one_line_error(r, "FACTORY_THREADS", "'all'")
    assert not out.exists()


def test_part_bigger_than_the_stock_given(small_part, tmp_path):
    out = tmp_path / "x.mcap"
    r = run("toolpath", small_part, "-o", out, "--stock", "20,20,20", "--quiet")
    assert_one_line_error(r)
    assert not out.exists()


@pytest.mark.parametrize("stock", ["20,abc", "inf,100,30", "nan,100,30", "2000,2000,31", "100000,100000,31"])
def test_malformed_or_unbounded_stock_option_is_a_usage_error(small_part, tmp_path, stock):
    r = runner.invoke(app, ["toolpath", str(small_part), "-o", str(tmp_path / "x.mcap"), "--stock", stock])
    assert r.exit_code == 2 and "--stock" in r.output


def test_help_shows_units():
    r = runner.invoke(app, ["verify", "--help"])
    assert r.exit_code == 0
    assert "[mm]" in r.output


def test_plan_without_robot_writes_no_robot_files(small_part, tmp_path):
    out = tmp_path / "out"
    r = run("plan", small_part, "-o", out, "--no-robot", "--scallop", "0.05", "--quiet")
    assert r.exit_code == 0, r.output
    assert not list(out.glob("*.script"))
    assert (out / "block.nc").is_file() and (out / "block.op2.nc").is_file()  # both operations


def test_plan_ops_1_writes_op_1_only(small_part, tmp_path):
    out = tmp_path / "out"
    r = run("plan", small_part, "-o", out, "--no-robot", "--ops", "1", "--scallop", "0.05", "--json", "--quiet")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert not list(out.glob("*.op2.*")) and "program_op2" not in summary["outputs"]
    assert [s["op"] for s in summary["setups"]] == [1] and summary["verify_op2"] is None
    r = run("plan", small_part, "-o", out, "--no-robot", "--ops", "3", "--quiet")
    assert r.exit_code == 2


def test_plan_in_a_pipe_shows_each_stage_as_it_starts_and_ends(small_part, tmp_path):
    """stderr is no terminal here (no bars): each stage still shows, the CAM's inner ones and the rapid check too."""
    from cli.common import STAGE_LINE

    r = run("plan", small_part, "-o", tmp_path / "out", "--no-robot", "--ops", "1", "--scallop", "0.05")
    assert r.exit_code == 0, r.output
    lines = r.stderr.splitlines()
    staged = [ln for ln in lines if STAGE_LINE.match(ln)]
    started = [ln.split("] ", 1)[1][:-len(" ...")] for ln in staged if ln.endswith(" ...")]
    ended = [ln.split("] ", 1)[1].rsplit(" done in ", 1)[0] for ln in staged if " done in " in ln]
    assert started[:2] == ["load", "setup"] and {"roughing", "rapid check", "post", "verify"} <= set(started)
    assert sorted(started) == sorted(ended)  # every stage that started ended, once
    seconds = [float(ln[1:].split(" s]")[0]) for ln in staged]
    assert seconds == sorted(seconds) and lines[:len(staged)] == staged  # in order, before the summary
    assert "block.stl" in lines[len(staged)]


def _stage_lines(monkeypatch, after: float):
    """A :class:`cli.common.StageLines` that prints into a string (its second value) instead of stderr."""
    import io

    from rich.console import Console

    import cli.common

    said = io.StringIO()
    monkeypatch.setattr(cli.common, "stderr", Console(file=said, soft_wrap=True))
    return cli.common.StageLines(after), said


def test_stage_lines_held_back_print_in_order_when_the_command_succeeds(monkeypatch):
    from cli.common import STAGE_LINE
    from factory.core.progress import Stopwatch

    lines, said = _stage_lines(monkeypatch, after=3600.0)
    watch = Stopwatch(lines)
    for name in ("load", "setup"):
        with watch(name):
            pass
    assert said.getvalue() == ""  # held back: the command has not run its first seconds
    lines.close(failed=False)
    shown = said.getvalue().splitlines()
    assert [ln.split("] ", 1)[1] for ln in shown][::2] == ["load ...", "setup ..."]
    assert len(shown) == 4 and all(STAGE_LINE.match(ln) for ln in shown) and "load done in" in shown[1]


def test_a_quick_failure_shows_no_stage_and_a_failed_stage_never_says_done(monkeypatch):
    from factory.core.errors import FactoryError
    from factory.core.progress import Stopwatch

    lines, said = _stage_lines(monkeypatch, after=3600.0)
    watch = Stopwatch(lines)
    with watch("load"):
        pass
    with pytest.raises(FactoryError), watch("setup"):
        raise FactoryError("part.stl: fits the cell in no orientation")
    lines.close(failed=True)
    assert said.getvalue() == ""
    # once the lines show (here at once), a stage that failed shows its start and no end
    lines, said = _stage_lines(monkeypatch, after=0.0)
    lines._timer.join()  # the release has happened: no waiting on the clock
    watch = Stopwatch(lines)
    with pytest.raises(FactoryError), watch("setup"):
        raise FactoryError("part.stl: fits the cell in no orientation")
    lines.close(failed=True)
    assert [ln.split("] ", 1)[1] for ln in said.getvalue().splitlines()] == ["setup ..."]


def test_plan_with_a_broken_cell_writes_nothing(small_part, tmp_path):
    from factory.core.resources import FIXTURES

    cell = tmp_path / "cell.yaml"
    cell.write_text((FIXTURES / "cell.yaml").read_text().replace("gripper:", "griper:", 1))
    out = tmp_path / "out"
    r = run("plan", small_part, "-o", out, "--cell", cell, "--scallop", "0.05", "--quiet")
    assert_one_line_error(r, str(cell))
    assert not out.exists() or not any(out.iterdir())


def test_simulate_plans_exactly_what_plan_does_with_its_defaults():
    """A part missing from the catalog is planned as `factory plan PART` would: same options."""
    import inspect

    from cli import cam
    from cli.plan import plan
    from factory.plan import PlanRequest

    defaults = {k: p.default for k, p in inspect.signature(plan).parameters.items()
                if p.default is not inspect.Parameter.empty}
    part = Path("p.stl")
    from_cli = PlanRequest(cam.cam_request(
        part, defaults["tools"], defaults["stock"], defaults["material"], defaults["units"], defaults["origin"],
        defaults["rough_tool"], defaults["finish_tool"], defaults["allowance"], defaults["scallop"],
        defaults["stepdown"], defaults["waterline"], defaults["holding"], defaults["robot_cell"]), post=defaults["post"], arc_tolerance=defaults["arc_tolerance"],
        grid=defaults["grid"], cell=defaults["robot_cell"], robot=defaults["robot"], lang=defaults["lang"])
    assert PlanRequest.defaults(part, defaults["material"]) == from_cli


@pytest.mark.parametrize("given, finishing, freeform", [
    (None, 0.005, 0.01),  # each surface keeps its own default
    (0.005, 0.005, 0.005),  # asked for at the default's value: it still holds on a solid's freeform faces
    (0.02, 0.02, 0.02),
])
def test_a_scallop_on_the_command_line_holds_everywhere(given, finishing, freeform):
    from cli import cam

    request = cam.cam_request(Path("p.stl"), None, None, "aluminium", "auto", "top-front-left", None, None, 0.3,
                              given, None, True)
    assert (request.plan.finishing.scallop, request.plan.freeform_scallop) == (finishing, freeform)


@pytest.mark.parametrize("args, needles", [
    (["--holding", "2"], ["holding allowance 2 mm leaves 1.5 mm under the part", "--holding 6.5"]),
    (["--holding", "6"], ["below the jaws' grip depth 5 mm", "--holding 6.5"]),
    (["--stock", "40,30,12"], ["needs stock 16.500 mm tall, stock is 12.000 mm"]),
    # too wide across the jaws either way (turned about Z, 40 x 230 would fit: cadcam.setup.orient_setup)
    (["--stock", "230,230,30"], ["stock 230.0 mm wide (Y) does not fit the vise opening 0..223.5 mm"]),
])
def test_stock_the_vise_cannot_hold_is_one_line_with_its_figures(small_part, tmp_path, args, needles):
    out = tmp_path / "out"
    for command in (["plan", small_part, "-o", out], ["toolpath", small_part, "-o", tmp_path / "t.mcap"]):
        assert_one_line_error(run(*command, *args, "--quiet"), str(small_part), *needles)
    assert not out.exists() or not any(out.iterdir())
