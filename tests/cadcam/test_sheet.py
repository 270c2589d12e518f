"""The setup sheet carries the setup and tool table through JSON unchanged."""

from __future__ import annotations

import json

import pytest

from cadcam.finishing import FinishingOptions
from cadcam.model import DEFAULT_HOLDER
from cadcam.plan import PlanOptions, plan_job
from cadcam.post import PostOptions, post_process
from cadcam.setup import make_setup
from cadcam.sheet import read_setup_sheet, setup_sheet
from cadcam.tools import load_tool_library
from factory.core.errors import SetupError
from tests.conftest import pocket_block


@pytest.fixture(scope="module")
def posted():
    setup, part = make_setup(pocket_block(), origin="top-centre", material="brass")
    job = plan_job(part, setup, load_tool_library(), part_name="block",
                      options=PlanOptions(finishing=FinishingOptions(scallop=0.05))).job
    return job, post_process(job, PostOptions())


def test_round_trip(posted):
    job, program = posted
    sheet = json.loads(json.dumps(setup_sheet(job, program, "block.nc")))
    setup, tools = read_setup_sheet(sheet, source="block.setup.json")
    assert setup.to_dict() == job.setup.to_dict()
    assert tools == {t.number: t for t in job.tools}
    assert sheet["estimated_cycle_s"] == pytest.approx(program.total_time, abs=0.1)
    assert [op["name"] for op in sheet["operations"]] == [op.name for op in job.operations]
    assert sum(op["estimated_s"] for op in sheet["operations"]) <= sheet["estimated_cycle_s"] + 1e-6


@pytest.mark.parametrize("broken", [[], {"format": "other"}, {"format": "factory.setup/1"},
                                    {"format": "factory.setup/1", "stock": {"min": [0, 0]}}])
def test_malformed_sheet_names_its_file(broken):
    with pytest.raises(SetupError, match="x.setup.json"):
        read_setup_sheet(broken, source="x.setup.json")


def test_sheet_carries_holders_and_old_sheets_get_the_default(posted):
    job, program = posted
    sheet = json.loads(json.dumps(setup_sheet(job, program, "block.nc")))
    assert all(t["holder"] and t["shank_diameter"] > 0 for t in sheet["tools"])
    for t in sheet["tools"]:  # a sheet written before holders were recorded
        del t["holder"], t["shank_diameter"]
    _, tools = read_setup_sheet(sheet)
    assert all(t.holder == DEFAULT_HOLDER and t.shank_diameter == t.diameter for t in tools.values())
