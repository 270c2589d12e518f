"""The setup sheet of a posted job, and the setup and tool table a sheet describes (CAM's side, mm).

The format itself, ``factory.setup/1``, is :class:`factory.core.setupsheet.SetupSheet`: the robot
reads the same file (:func:`robotprog.frames.setup_sheet_to_cell`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from cadcam.model import FixtureBox, Job, Setup, Tool
from cadcam.post import Program
from factory.core.errors import SetupError, clipped
from factory.core.setupsheet import FORMAT, SetupSheet

__all__ = ["FORMAT", "SetupSheet", "read_setup_sheet", "setup_sheet"]


def setup_sheet(job: Job, program: Program, program_name: str) -> SetupSheet:
    """The setup sheet of ``job`` as posted to ``program`` (named ``program_name``) [mm]."""
    s = job.setup
    estimates = {e.name: e for e in program.estimates}
    operations = []
    for op in job.operations:
        e = estimates.get(op.name)
        operations.append(
            {
                "name": op.name,
                "kind": op.kind,
                "tool": op.tool.number,
                "spindle_rpm": round(op.cutting.spindle_rpm),
                "feed_mm_min": round(op.cutting.feed, 1),
                "plunge_feed_mm_min": round(op.cutting.plunge_feed, 1),
                # the library's feed per tooth the tool's chip is held to (factory verify)
                **({"chip_load_mm": op.cutting.chip_load} if op.cutting.chip_load is not None else {}),
                "allowance_mm": op.allowance,
                "cut_mm": round(e.cut_length, 1) if e else None,
                "rapid_mm": round(e.rapid_length, 1) if e else None,
                "estimated_s": round(e.cut_time + e.rapid_time, 1) if e else None,
            }
        )
    return SetupSheet(
        part=job.part_name,
        program=program_name,
        dialect=program.dialect,
        source_sha256=job.source_sha256,
        work_origin=s.origin,
        material=s.material,
        stock_min=s.stock_min,
        stock_max=s.stock_max,
        transform_mesh_to_work=s.transform_mesh_to_work,
        mesh_scale=s.mesh_scale,
        safe_z=s.safe_z,
        clearance=s.clearance,
        floor_z=s.floor_z,
        jaws=None if s.jaws is None else tuple(b.to_dict() for b in s.jaws),
        tools=tuple(t.to_dict() for t in job.tools),
        operations=tuple(operations),
        estimated_cycle_s=round(program.total_time, 1),
        gcode_lines=program.line_count,
        unreached=tuple(job.parameters.get("unreached", [])),
        # a relief (cadcam.relief): what was found, its floor and the boundary the tools kept within
        relief=job.parameters.get("relief"),
        intake=job.parameters.get("intake"),  # a STEP part: its unit, solid and tessellation tolerance
    )


@dataclass(frozen=True)
class SheetSetup:
    """What a setup sheet gives back: the sheet itself, the setup it describes, and its tool table by number."""

    sheet: SetupSheet
    setup: Setup
    tools: Mapping[int, Tool]


def read_setup_sheet(data: SetupSheet | Any, source: str | None = None) -> SheetSetup:
    """The setup and tool table a setup sheet describes: a :class:`SetupSheet`, or its JSON document.

    Raises
    ------
    SetupError
        Not a ``factory.setup/1`` document, or a field is missing or malformed.
    """
    sheet = data if isinstance(data, SetupSheet) else SetupSheet.from_json(data, source)
    try:
        setup = Setup(
            stock_min=sheet.stock_min,
            stock_max=sheet.stock_max,
            transform_mesh_to_work=sheet.transform_mesh_to_work,
            mesh_scale=sheet.mesh_scale,
            origin=sheet.work_origin,  # type: ignore[arg-type]
            material=sheet.material,
            safe_z=sheet.safe_z,
            clearance=sheet.clearance,
            floor_z=sheet.floor_z,
            jaws=None if sheet.jaws is None else tuple(FixtureBox.from_dict(dict(b)) for b in sheet.jaws),
        )
        tools = {int(t["number"]): Tool.from_dict(dict(t)) for t in sheet.tools}
    except (KeyError, TypeError, ValueError) as e:
        raise SetupError(f"malformed setup sheet: {type(e).__name__}: {clipped(str(e))}", source=source) from None
    return SheetSetup(sheet, setup, tools)
