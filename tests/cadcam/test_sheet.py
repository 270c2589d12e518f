"""The setup sheet carries the setup and tool table through JSON unchanged, and is a frozen value."""

from __future__ import annotations

import dataclasses
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
from factory.core.setupsheet import SetupSheet
from tests.conftest import pocket_block


@pytest.fixture(scope="module")
def posted():
    setup, part = make_setup(pocket_block(), origin="top-centre", material="brass")
    job = plan_job(part, setup, load_tool_library(), part_name="block",
                      options=PlanOptions(finishing=FinishingOptions(scallop=0.05))).job
    return job, post_process(job, PostOptions())


def test_round_trip(posted):
    job, program = posted
    sheet = json.loads(json.dumps(setup_sheet(job, program, "block.nc").to_json()))
    read = read_setup_sheet(sheet, source="block.setup.json")
    setup, tools = read.setup, read.tools
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
    sheet = json.loads(json.dumps(setup_sheet(job, program, "block.nc").to_json()))
    assert all(t["holder"] and t["shank_diameter"] > 0 for t in sheet["tools"])
    for t in sheet["tools"]:  # a sheet written before holders were recorded
        del t["holder"], t["shank_diameter"]
    tools = read_setup_sheet(sheet).tools
    assert all(t.holder == DEFAULT_HOLDER and t.shank_diameter == t.diameter for t in tools.values())


def test_sheet_reads_back_to_the_same_document(posted):
    """``from_json`` of a written sheet gives the sheet again: equal JSON, equal setup, op 2 fields included."""
    job, program = posted
    sheet = dataclasses.replace(setup_sheet(job, program, "block.nc"), op=2, work_offset="G55",
                                after={"program": "a.nc", "setup_sheet": "a.setup.json"},
                                flip={"axis": "x", "transform_op1_to_op2": [[1.0, 0, 0, 0]] * 4}, face_z=-3.0,
                                holding_mm=4.0, held_in=None)
    text = json.dumps(sheet.to_json(), indent=2)
    again = SetupSheet.from_json(json.loads(text), "block.setup.json")
    assert json.dumps(again.to_json(), indent=2) == text
    assert list(json.loads(text))[-7:] == ["op", "work_offset", "after", "flip", "face_z", "holding_mm", "held_in"]
    assert read_setup_sheet(again).setup.to_dict() == job.setup.to_dict()


def test_sheet_is_frozen(posted):
    """What a stage hands on cannot be changed under it: no field set, no array written, no JSON shared."""
    sheet = setup_sheet(*posted, "block.nc")
    with pytest.raises(dataclasses.FrozenInstanceError):
        sheet.op = 1  # type: ignore[misc]
    with pytest.raises(ValueError):
        sheet.stock_min[0] = 5.0
    doc = sheet.to_json()
    doc["tools"][0]["diameter"] = 99.0
    doc["operations"].clear()
    assert sheet.tools[0]["diameter"] != 99.0 and sheet.operations


@pytest.mark.parametrize("field, junk", [("tools", "T1"), ("operations", 3), ("unreached", [1, 2]),
                                          ("jaws", [{"name": "front jaw", "lo": [0, 0], "hi": [1, 1, 1]}]),
                                          ("transform_mesh_to_work", [[1, 0, 0]]), ("mesh_scale", "big")])
def test_malformed_field_names_its_file(posted, field, junk):
    doc = setup_sheet(*posted, "block.nc").to_json()
    doc[field] = junk
    with pytest.raises(SetupError, match=r"^x.setup.json: malformed setup sheet"):
        SetupSheet.from_json(doc, "x.setup.json")
