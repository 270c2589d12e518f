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
