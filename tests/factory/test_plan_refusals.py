"""What ``factory plan`` refuses, it refuses before the CAM work: one FactoryError, one error line."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import trimesh
from typer.testing import CliRunner

import factory.cam
from cadcam.setup import make_setup
from cadcam.stock import check_grid_size
from cli.main import app
from factory.core.errors import FactoryError, GcodeError, PlanningError, VerifyError
from factory.plan import PlanRequest, plan_part
from tests.cli.expect import assert_one_line_error
from tests.conftest import pocket_block

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()


@pytest.fixture
def no_cam(monkeypatch):
    """Fail the test if the toolpaths are computed."""
    def refuse(*args, **kwargs):
        raise AssertionError("the CAM work ran before the refusal")

    monkeypatch.setattr(factory.cam, "plan_job", refuse)


@pytest.fixture
def part(tmp_path) -> Path:
    path = tmp_path / "block.stl"
    pocket_block(size=(100.0, 70.0, 20.0), pocket=(40.0, 30.0, 5.0)).export(path)
    return path


def test_unknown_robot_language_is_a_planning_error(part, no_cam):
    request = dataclasses.replace(PlanRequest.defaults(part, "aluminium"), lang="cobol")
    with pytest.raises(PlanningError, match="unknown robot program language 'cobol': expected urscript, rapid, krl"):
        plan_part(request)


def test_unknown_dialect_is_refused_before_the_cam_work(part, no_cam):
    request = dataclasses.replace(PlanRequest.defaults(part, "aluminium"), post="heidenhain")
    with pytest.raises(GcodeError, match="unknown dialect 'heidenhain'"):
        plan_part(request)


def test_a_verify_grid_too_fine_is_refused_with_the_figure_before_the_cam_work(part, tmp_path, no_cam):
    out = tmp_path / "out"
    r = runner.invoke(app, ["plan", str(part), "-o", str(out), "--grid", "0.01"])
    # the stock is the part's box plus its margins; the cells are counted over its footprint
    assert_one_line_error(r, str(part), "verify grid cells at 0.01 mm", "(limit 60,000,000)", "coarser grid")
    assert not out.exists()
    with pytest.raises(FactoryError):
        plan_part(dataclasses.replace(PlanRequest.defaults(part, "aluminium"), grid=0.01))


def test_the_grid_limit_is_the_one_verify_applies(part):
    setup, _ = make_setup(trimesh.load(part), stock_size=(100.0, 70.0, 40.0), material="aluminium")
    check_grid_size(setup, 0.0125)  # 8000 x 5600: 44.8 M cells
    with pytest.raises(VerifyError, match="71,431,242 verify grid cells at 0.0099 mm over the 100 x 70 mm stock"):
        check_grid_size(setup, 0.0099)  # 10102 x 7071


@pytest.fixture
def no_cam_stage(monkeypatch):
    """Fail the test if any CAM stage starts (the part is not even loaded)."""
    import factory.plan

    def refuse(*args, **kwargs):
        raise AssertionError("a CAM stage started before the refusal")

    monkeypatch.setattr(factory.plan, "compute_job", refuse)


@pytest.mark.parametrize(("lang", "cell", "fixes"), [
    ("rapid", "cell.yaml", ["--cell fixtures/cell_abb.yaml", "--lang urscript"]),
    ("krl", "cell_abb.yaml", ["--cell fixtures/cell_kuka.yaml", "--lang rapid"]),
    ("urscript", "cell_kuka.yaml", ["--cell fixtures/cell.yaml", "--lang krl"]),
])
def test_a_language_for_another_arm_is_refused_before_any_cam_stage_and_names_the_fix(
        lang, cell, fixes, part, tmp_path, no_cam_stage, monkeypatch):
    monkeypatch.chdir(ROOT)  # the fixes are shown as a user in the checkout types them
    out = tmp_path / "out"
    args = ["plan", str(part), "-o", str(out), "--lang", lang]
    if cell != "cell.yaml":  # the default cell is the UR5's
        args += ["--cell", f"fixtures/{cell}"]
    r = runner.invoke(app, args)
    assert_one_line_error(r, f"fixtures/{cell}: robot.model:", " needs ", *fixes)
    assert not out.exists()


def test_the_language_of_the_arm_passes_the_early_checks(part):
    from factory.refusals import check_request

    for lang, cell in (("urscript", "cell.yaml"), ("rapid", "cell_abb.yaml"), ("krl", "cell_kuka.yaml")):
        check_request(ROOT / "fixtures" / cell, lang)
    # without the robot, the language is not the cell's business
    check_request(None, "rapid")


def test_a_cell_with_an_unknown_robot_is_refused_before_any_cam_stage(part, tmp_path, no_cam_stage):
    cell = tmp_path / "cell.yaml"
    cell.write_text((ROOT / "fixtures" / "cell.yaml").read_text().replace("model: ur5", "model: ur99"))
    r = runner.invoke(app, ["plan", str(part), "-o", str(tmp_path / "out"), "--cell", str(cell)])
    assert_one_line_error(r, "unknown robot 'ur99'")


def test_a_stock_the_gripper_cannot_hold_is_refused_before_the_toolpaths(tmp_path, no_cam):
    # 90 x 95 mm: the stock (2 mm each side) fits the jaws (223.5 mm) either way but not the fingers (85 mm)
    wide = tmp_path / "wide.stl"
    pocket_block(size=(90.0, 95.0, 20.0), pocket=(20.0, 40.0, 5.0)).export(wide)
    out = tmp_path / "out"
    r = runner.invoke(app, ["plan", str(wide), "-o", str(out)])
    assert_one_line_error(r, "fits the cell in no orientation: as given, ",
                          "gripper.opening.max: stock 99.0 mm wide exceeds the gripper opening 85.0 mm",
                          "turned 90 degrees about Z, ", "stock 94.0 mm wide exceeds", "--stock", "--cell")
    assert not out.exists()
    # without the robot nothing holds the stock but the vise: the plan goes on to the toolpaths
    with pytest.raises(AssertionError, match="the CAM work ran"):
        plan_part(dataclasses.replace(PlanRequest.defaults(wide, "aluminium"), robot=False))


def test_a_stock_heavier_than_the_robot_carries_is_refused_with_the_figures_before_the_toolpaths(tmp_path, no_cam):
    # 150 x 76 x 61 mm of steel: 695,400 mm^3 at 7.85 g/cm^3 = 5.46 kg, over the UR5's 5 kg less its
    # 0.925 kg gripper (4.075 kg); the same block in aluminium (2.81 g/cm^3: 1.95 kg) goes on to the CAM work
    heavy = tmp_path / "heavy.stl"
    pocket_block(size=(146.0, 72.0, 53.5), pocket=(40.0, 30.0, 5.0)).export(heavy)
    out = tmp_path / "out"
    r = runner.invoke(app, ["plan", str(heavy), "-o", str(out), "--material", "steel"])
    assert_one_line_error(r, "robot.payload: stock 150.0 x 76.0 x 61.0 mm of steel (7.85 g/cm³) weighs 5.46 kg, "
                          "over the 4.08 kg the robot carries (5 kg payload less the 0.925 kg gripper)", "--stock",
                          "--cell")
    assert not out.exists()
    with pytest.raises(AssertionError, match="the CAM work ran"):
        plan_part(PlanRequest.defaults(heavy, "aluminium"))
    with pytest.raises(AssertionError, match="the CAM work ran"):  # no robot: nothing to carry it
        plan_part(dataclasses.replace(PlanRequest.defaults(heavy, "steel"), robot=False))


@pytest.fixture
def inch_part(tmp_path) -> Path:
    """A 2 x 1.5 x 0.8 inch block in an STL, which states no unit: read as mm under --units auto."""
    path = tmp_path / "inch.stl"
    trimesh.creation.box(extents=(2.0, 1.5, 0.8)).export(path)
    return path


def test_an_inch_part_read_as_mm_is_refused_before_the_toolpaths_with_the_units_hint(inch_part, tmp_path, no_cam):
    out = tmp_path / "out"
    r = runner.invoke(app, ["plan", str(inch_part), "-o", str(out)])
    assert_one_line_error(r, f"{inch_part}: part 0.8 mm tall is too thin to grip",
                          "; if the file is in inches, give --units inch")
    assert not out.exists()
    # units said: mm gives no hint (the user knows); inch passes the checks, on to the toolpaths
    r = runner.invoke(app, ["plan", str(inch_part), "-o", str(out), "--units", "mm"])
    assert_one_line_error(r, "part 0.8 mm tall is too thin to grip")
    assert "--units" not in r.output
    with pytest.raises(AssertionError, match="the CAM work ran"):
        plan_part(dataclasses.replace(PlanRequest.defaults(inch_part, "aluminium"), cam=dataclasses.replace(
            PlanRequest.defaults(inch_part, "aluminium").cam, units="inch")))


def test_the_inch_hint_only_when_the_units_were_guessed_and_inches_help():
    from cadcam.mesh import inch_hint

    assert inch_hint(2.0, "auto", 1.0) == "if the file is in inches, give --units inch"
    assert inch_hint(2.0, "mm", 1.0) is None  # said mm
    assert inch_hint(2.0, "auto", 25.4) is None  # the file stated its unit
    assert inch_hint(100.0, "auto", 1.0) is None  # 2.5 m in inches: no ordinary part either
