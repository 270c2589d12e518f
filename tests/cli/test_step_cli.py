"""``factory plan PART.step`` end to end with defaults, judged by LinuxCNC's rs274 and verify, and against the plan of
a fine STL of the same part."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("build123d")

from cli.main import app  # noqa: E402
from tests.cadcam.stepparts import (ModelledHole, countersunk_head, pillow_surface, plate, t_slot,  # noqa: E402
                                    two_solids, write_step, write_stl)
from tests.cli.expect import assert_one_line_error  # noqa: E402
from tests.rs274 import run_rs274  # noqa: E402

runner = CliRunner()

#: Through holes at two drill sizes, a drill-point blind hole, a flat-bottom one and an 8 mm bore no drill fits.
HOLES = [ModelledHole(-20, -8, 5.0, None), ModelledHole(-20, 8, 6.8, None), ModelledHole(0, 8, 4.2, 6.0, "conical"),
         ModelledHole(0, -8, 3.3, 5.0, "flat"), ModelledHole(20, 0, 8.0, None)]
HOLE_KINDS = {"spot", "drill", "helix"}


def run(*args):
    return runner.invoke(app, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    """The plate planned from its STEP file and from a fine STL of it, both with the CAM's defaults. Without
    the robot: what this module asserts is the CAM's (intake, holes, operations, both programs, verify), and
    without a robot a plan keeps op 2 as it does when the robot can turn the part over, as it can this
    plate; the robot's half of each plan (most of its time, issue 35) would be checked by nothing here."""
    d = tmp_path_factory.mktemp("stepplan")
    part = plate((60, 40, 12), HOLES)
    out = {}
    for name, path in (("step", write_step(part, d / "plate.step")), ("stl", write_stl(part, d / "plate.stl"))):
        r = run("plan", path, "-o", d / name, "--no-robot")
        assert r.exit_code == 0, r.output
        out[name] = (json.loads((d / name / "plate.plan.json").read_text()), d / name)
        out[f"{name} said"] = " ".join(r.stderr.split())  # rich wraps lines at the terminal's width
    return out


def test_step_plan_states_its_intake_and_exact_holes(plans):
    summary, _ = plans["step"]
    intake = summary["intake"]
    assert intake["format"] == "step" and intake["chordal_deviation_mm"] == pytest.approx(0.0025)
    assert intake["tolerance_mm"] == 0.01 and intake["closed"] and intake["body"] is None
    holes = intake["features"]["holes"]
    assert sorted(h["diameter"] for h in holes) == pytest.approx(sorted(h.diameter for h in HOLES), abs=1e-6)
    assert all(h["source"] == "step" for h in holes)
    sheet = json.loads(Path(summary["setup_sheet"]).read_text())  # the machinist's list: the same
    assert sheet["intake"]["features"]["holes"] == holes
    # the drilling stage got the exact sizes: every hole it lists is one of them
    planned = summary["holes"]
    assert sorted(h["diameter"] for h in planned["holes"]) == pytest.approx(sorted(h.diameter for h in HOLES), abs=1e-6)
    # drills of their size for the through and drill-point holes; the flat-bottom 3.3 and the 8 mm bore helixed
    assert sorted(h["diameter"] for h in planned["drilled"]) == pytest.approx([4.2, 5.0, 6.8], abs=1e-6)
    assert sorted(h["diameter"] for h in planned["helixed"]) == pytest.approx([3.3, 8.0], abs=1e-6)
    assert summary["verify"]["ok"] and summary["verify_op2"] is not None
    assert intake["units"] == "mm" and "plate.step: STEP in mm, " in plans["step said"]
    assert "triangles within 0.0025 mm; 5 round holes read exactly" in plans["step said"]


@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's rs274 is not installed (apt-get install linuxcnc-uspace)")
def test_linuxcnc_accepts_both_programs_of_the_step_part(plans, tmp_path):
    summary, out = plans["step"]
    table = Path(summary["outputs"]["tool_table"])  # the job's own, for both programs
    assert len(summary["setups"]) == 2
    for i, setup in enumerate(summary["setups"]):
        folder = tmp_path / f"op{i + 1}"
        folder.mkdir()
        p = run_rs274(Path(setup["program"]), table, folder, timeout=300)
        assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]


def test_step_and_its_fine_stl_plan_the_same_operations(plans):
    step, _ = plans["step"]
    stl, _ = plans["stl"]

    def milling(summary):
        return [(op["name"], op["tool"]) for op in summary["operations"] if not op["name"].split()[0] in
                ("spot", "drill", "peck", "helix")]

    assert milling(step) == milling(stl)
    assert len(step["holes"]["holes"]) == len(stl["holes"]["holes"]) == len(HOLES)
    # the mesh guesses the same holes, a hair off; the STEP part's are exact
    for a, b in zip(step["holes"]["holes"], stl["holes"]["holes"]):
        assert abs(a["diameter"] - b["diameter"]) < 0.01 and a["bottom"] == b["bottom"]
    assert "intake" not in stl


def test_two_solids_need_a_body(tmp_path):
    path = write_step(two_solids(), tmp_path / "two.step")
    r = run("toolpath", path, "-o", tmp_path / "two.mcap")
    assert_one_line_error(r, str(path), "2 solids", "--body N")
    assert not (tmp_path / "two.mcap").exists()
    r = run("toolpath", path, "-o", tmp_path / "two.mcap", "--body", "2", "--quiet", "--scallop", "0.02")
    assert r.exit_code == 0, r.output


def test_surfaces_no_tool_cuts_are_one_line_not_an_empty_job(tmp_path, monkeypatch):
    """Issue 29: a surfaces-only file the relief path plans nothing for (a public spline cage did) is refused in one
    line by ``toolpath``, not written as an empty job that ``plan`` refuses only later."""
    import dataclasses

    import factory.cam

    real = factory.cam.plan_job

    def nothing_cut(*args, **kwargs):
        planned = real(*args, **kwargs)
        return dataclasses.replace(planned, job=dataclasses.replace(planned.job, operations=()))

    monkeypatch.setattr(factory.cam, "plan_job", nothing_cut)
    path = write_step(pillow_surface(), tmp_path / "sheet.step")
    r = run("toolpath", path, "-o", tmp_path / "sheet.mcap", "--scallop", "0.05")
    assert_one_line_error(r, str(path), "nothing to machine", "surfaces only")
    assert not (tmp_path / "sheet.mcap").exists()


def test_tight_inside_corners_are_reported_before_the_toolpaths(tmp_path, caplog):
    from build123d import Align, Axis, Box, fillet

    block = Box(40, 30, 8, align=(Align.CENTER, Align.CENTER, Align.MAX))
    pocket = Box(20, 14, 4, align=(Align.CENTER, Align.CENTER, Align.MAX))
    path = write_step(block - fillet(pocket.edges().filter_by(Axis.Z), 0.5), tmp_path / "pocket.step")
    r = run("toolpath", path, "-o", tmp_path / "pocket.mcap", "--scallop", "0.02")
    assert r.exit_code == 0, r.output
    said = [rec.getMessage() for rec in caplog.records if rec.levelname == "WARNING"]
    corners = [i for i, line in enumerate(said) if "inside corner" in line]
    assert len(corners) == 4 and corners == list(range(4)), said  # the first warnings, before roughing's
    assert all("R0.500" in said[i] and "the smallest end mill is 2 mm (T6): left with R1" in said[i] for i in corners)


def test_a_picked_solid_in_centimetres_is_verified_and_unloaded_as_planned(tmp_path):
    """``--body`` and the file's unit go into the setup sheet; verify and the robot read the file again with them."""
    path = write_step(two_solids(), tmp_path / "two.step", unit="CM")
    out = tmp_path / "out"
    r = run("plan", path, "--body", "2", "--ops", "1", "--no-robot", "--scallop", "0.02", "-o", out, "--quiet")
    assert r.exit_code == 0, r.output
    sheet = json.loads((out / "two.setup.json").read_text())
    assert sheet["mesh_scale"] == 10.0
    assert sheet["intake"] == {"format": "step", "unit": "CENTIMETRE", "scale": 10.0, "body": 2, "tolerance_mm": 0.01,
                               "features": sheet["intake"]["features"]}
    assert [f["z"] for f in sheet["intake"]["features"]["flats"]] == [0.0, -15.0]
    assert sheet["stock"]["size"][2] > 15.0  # the 20 x 20 x 15 mm solid, not the 40 x 30 x 10 one
    for tolerance in ("0.01", "0.05"):  # verify's tolerance is the tessellation's
        r = run("verify", out / "two.nc", "--setup", out / "two.setup.json", "--part", path, "--tolerance", tolerance,
                "--quiet")
        assert r.exit_code == 0, r.output
    r = run("robot", "fixtures/cell.yaml", "--setup", out / "two.setup.json", "--part", path, "-o",
            tmp_path / "two.robot.mcap", "--quiet")
    assert r.exit_code == 0, r.output


def test_a_step_part_is_read_again_as_its_sheet_says(tmp_path):
    from cadcam.mesh import load_planned_part
    from factory.core.errors import SetupError

    path = write_step(two_solids(), tmp_path / "two.step", unit="CM")
    intake = {"format": "step", "unit": "CENTIMETRE", "scale": 10.0, "body": 2, "tolerance_mm": 0.01}
    loaded = load_planned_part(path, 10.0, intake)
    assert np.allclose(loaded.mesh.extents, (20, 20, 15), atol=1e-6) and loaded.step.body == 2
    assert loaded.step.chordal_deviation == pytest.approx(0.0025)
    assert load_planned_part(path, 10.0, intake, tolerance=0.04).step.chordal_deviation == pytest.approx(0.01)
    assert load_planned_part(path, 10.0, intake, tolerance=0.0).step.chordal_deviation == pytest.approx(0.0025)
    with pytest.raises(SetupError, match="CENTIMETRE .*mesh_scale is 1: not the part the program was made for"):
        load_planned_part(path, 1.0, intake, source="two.setup.json")


def test_a_part_op_2_must_cut_in_its_jaws_is_refused_before_any_toolpath(tmp_path, monkeypatch):
    """The public M6 countersunk screw was refused by verify (T1 runs into the back jaw) after 8 minutes of CAM work:
    the cone under its head looks down, and turned over for op 2 the jaws hold the head."""
    import factory.cam

    def no_toolpaths(*args, **kwargs):
        raise AssertionError("toolpaths were computed before the refusal")

    monkeypatch.setattr(factory.cam, "plan_job", no_toolpaths)
    path = write_step(countersunk_head(), tmp_path / "screw.step")
    r = run("plan", path, "-o", tmp_path / "out")
    assert_one_line_error(r, "screw.step: op 2 holds the turned-over part", "mm deep in the jaws",
                          "in op 1, 0.17 mm from a jaw at Y", "closer than the 2 mm end mill's radius",
                          "plan op 1 only (--ops 1)", code=r.exit_code or 1)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_undercuts_are_reported_before_any_toolpath(tmp_path, monkeypatch, caplog):
    """A T-slot's lips look down over its floor: each is said with its place and direction before the toolpaths."""
    import factory.cam

    class Stopped(Exception):
        pass

    def stop(*args, **kwargs):
        raise Stopped

    monkeypatch.setattr(factory.cam, "plan_job", stop)
    path = write_step(t_slot(), tmp_path / "tslot.step")
    with pytest.raises(Stopped):
        run("toolpath", path, "-o", tmp_path / "tslot.mcap")
    said = [rec.getMessage() for rec in caplog.records if rec.levelname == "WARNING" and "undercut" in rec.getMessage()]
    assert len(said) == 2, said
    for line, y in zip(sorted(said), ("-6.500", "6.500")):
        assert "tslot.step: undercut face" in line and f"at X0.000 Y{y} Z-8.000 facing (0.000, 0.000, -1.000)" in line
        assert "300.0 mm^2" in line and "needs another setup or a 4th axis" in line
