"""The setup sheet: what the machinist (and later stages) need to run a program.

``PART.setup.json`` sits beside ``PART.nc``. Other stages (verify, the robot planner,
outside checkers) read it instead of the G-code. Format ``factory.setup/1``::

    {
      "format": "factory.setup/1",
      "part": "bracket", "program": "bracket.nc", "dialect": "linuxcnc",
      "source_sha256": "…",              # of the part mesh file
      "units": "mm",
      "work_origin": "top-front-left",   # X0 Y0 Z0 on the stock
      "material": "aluminium",
      "stock": {"min": [x, y, z], "max": [x, y, z], "size": [x, y, z]},   # work coordinates [mm]
      "transform_mesh_to_work": [[4×4]],  # mesh file coordinates (scaled to mm) → work [mm]
      "mesh_scale": 1.0,                  # mesh file units → mm
      "safe_z": 5.0,                      # retract height [mm]
      "floor_z": -22.5,                   # lowest feed [mm]: part bottom minus the breakthrough
      "jaws": [{"name": "front jaw", "lo": [x, y, z], "hi": [x, y, z]}, …],   # vise boxes [mm, work];
                                          # null: workholding unknown (older sheets)
      "tools": [{"number": 1, "name": …, "shape": "flat", "diameter": 6.0,
                 "corner_radius": 0.0, "flute_length": 18.0, "flutes": 3, "length": 30.0,
                 "shank_diameter": 6.0,       # body between flutes and holder [mm]
                 "holder": [{"diameter": 22.0, "length": 10.0, "top_diameter": 28.0}, …]}],
                                              # from the gauge line up [mm]; sheets without
                                              # them read as cadcam.model.DEFAULT_HOLDER
      "operations": [{"name": "rough z-level", "kind": "roughing", "tool": 1,
                      "spindle_rpm": …, "feed_mm_min": …, "allowance_mm": …,
                      "cut_mm": …, "rapid_mm": …, "estimated_s": …}],
      "estimated_cycle_s": …,
      "unreached": [{"x": …, "y": …, "size_x": …, "size_y": …, "depth": …, "z_bottom": …}]
    }

``unreached`` lists stock no tool in the library could reach [mm, work coordinates]: the
program leaves it, finishing does not enter it (see :func:`cadcam.rest.unreached`).
"""

from __future__ import annotations

from typing import Any

from cadcam.model import Job, Setup, Tool
from cadcam.post import Program
from factory.core.errors import SetupError, clipped

FORMAT = "factory.setup/1"


def setup_sheet(job: Job, program: Program, program_name: str) -> dict[str, Any]:
    """The setup sheet of ``job`` as posted to ``program`` (JSON-ready)."""
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
                "allowance_mm": op.allowance,
                "cut_mm": round(e.cut_length, 1) if e else None,
                "rapid_mm": round(e.rapid_length, 1) if e else None,
                "estimated_s": round(e.cut_time + e.rapid_time, 1) if e else None,
            }
        )
    return {
        "format": FORMAT,
        "part": job.part_name,
        "program": program_name,
        "dialect": program.dialect,
        "source_sha256": job.source_sha256,
        "units": "mm",
        "work_origin": s.origin,
        "material": s.material,
        "stock": {"min": s.stock_min.tolist(), "max": s.stock_max.tolist(), "size": s.stock_size.tolist()},
        "transform_mesh_to_work": s.transform_mesh_to_work.tolist(),
        "mesh_scale": s.mesh_scale,
        "safe_z": s.safe_z,
        "clearance": s.clearance,
        # workholding: the lowest feed, and the vise's jaws and parallels as boxes [mm, work]
        "floor_z": s.floor_z,
        "jaws": None if s.jaws is None else [b.to_dict() for b in s.jaws],
        "tools": [t.to_dict() for t in job.tools],
        "operations": operations,
        "estimated_cycle_s": round(program.total_time, 1),
        "gcode_lines": program.line_count,
        "unreached": list(job.parameters.get("unreached", [])),
        # a relief (cadcam.relief): what was found, its floor and the boundary the tools kept within
        **({"relief": job.parameters["relief"]} if "relief" in job.parameters else {}),
    }


def read_setup_sheet(data: Any, source: str | None = None) -> tuple[Setup, dict[int, Tool]]:
    """The setup and tool table a setup sheet describes.

    Raises
    ------
    SetupError
        Not a ``factory.setup/1`` document, or a field is missing or malformed.
    """
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise SetupError(f"not a factory setup sheet (expected format {FORMAT!r})", source=source)
    try:
        # The sheet names two fields for readers outside factory; the rest are Setup's own.
        setup = Setup.from_dict(
            {**data, "stock_min": data["stock"]["min"], "stock_max": data["stock"]["max"],
             "origin": data.get("work_origin", "top-front-left")}
        )
        tools = {int(t["number"]): Tool.from_dict(t) for t in data["tools"]}
    except (KeyError, TypeError, ValueError) as e:
        raise SetupError(f"malformed setup sheet: {type(e).__name__}: {clipped(str(e))}", source=source) from None
    return setup, tools
