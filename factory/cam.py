"""The CAM half of the plan pipeline: part intake → job, and job ⇄ MCAP.

Used by ``factory toolpath`` and ``factory plan`` (and so by the cell simulation's plans); the
command-line options that fill a :class:`CamRequest` live in :mod:`cli.cam`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh

from cadcam.finishing import FinishingOptions
from cadcam.mesh import PartMesh, load_part
from cadcam.model import Job
from cadcam.plan import PlanOptions, plan_job
from cadcam.roughing import RoughingOptions
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from factory.errors import ToolpathError
from factory.mcaplog import McapLog, read_attachment
from factory.progress import Progress, Stopwatch
from factory.views import job_messages

#: Name of the MCAP attachment that carries the job from ``toolpath`` to ``gcode``.
JOB_ATTACHMENT = "factory.job.json"

Units = Literal["auto", "mm", "inch", "m"]
Origin = Literal["top-front-left", "top-centre"]

# Defaults of the CAM options, shared by `factory toolpath`, `factory plan` and the plans `factory simulate` makes.
MATERIAL = "aluminium"
UNITS: Units = "auto"
ORIGIN: Origin = "top-front-left"
ROUGH_TOOL: int | None = None  # None: chosen from the library by reach and size
FINISH_TOOL: int | None = None
ALLOWANCE = 0.3  # [mm]
SCALLOP = 0.005  # [mm]

@dataclasses.dataclass(frozen=True)
class CamRequest:
    """What to plan and how: the part file, tool library, stock, material, work origin and CAM options.

    ``tools`` None is the bundled library (``fixtures/tools.yaml``); ``stock`` is the stock size
    X, Y, Z [mm], None for the default (part box + 2 mm on the sides, 1 mm on top)."""

    part: Path
    tools: Path | None
    stock: tuple[float, float, float] | None
    material: str
    units: Units
    origin: Origin
    plan: PlanOptions

    @classmethod
    def from_options(cls, part: Path, tools: Path | None, stock: tuple[float, float, float] | None, material: str,
                     units: Units, origin: Origin, rough_tool: int | None, finish_tool: int | None, allowance: float,
                     scallop: float, stepdown: float | None, waterline: bool) -> "CamRequest":
        """The request from the flat option values of ``factory toolpath`` and ``factory plan``."""
        plan = PlanOptions(
            rough_tool=rough_tool,
            finish_tool=finish_tool,
            roughing=RoughingOptions(allowance=allowance, stepdown=stepdown),
            finishing=FinishingOptions(scallop=scallop),
            waterline=waterline,
        )
        if scallop != SCALLOP:  # a scallop asked for on the command line holds on freeform too
            plan = dataclasses.replace(plan, freeform_scallop=scallop)
        return cls(part, tools, stock, material, units, origin, plan)

    @classmethod
    def defaults(cls, part: Path, material: str = MATERIAL, tools: Path | None = None) -> "CamRequest":
        """The request of a command line that gives only the part, material and tool library."""
        return cls.from_options(part, tools, None, material, UNITS, ORIGIN, ROUGH_TOOL, FINISH_TOOL, ALLOWANCE,
                                SCALLOP, None, True)


@dataclasses.dataclass(frozen=True)
class PlannedPart:
    """A computed job with the part it was computed for."""

    job: Job
    loaded: PartMesh
    part_work: trimesh.Trimesh

    def toolpath_picture(self) -> np.ndarray:
        """(H, W, 3) uint8 top view of the toolpaths over the part's faces by kind."""
        from cadcam.faces import classify_faces
        from cadcam.preview import toolpath_image

        return toolpath_image(self.job, faces=classify_faces(self.part_work))


def compute_job(req: CamRequest, progress: Progress | None = None, watch: Stopwatch | None = None) -> PlannedPart:
    """Load, set up and plan one part, timing each stage into ``watch``.

    Raises
    ------
    FactoryError
        The mesh cannot be read or placed, the tool library or material is unknown, an
        operation cannot be computed.
    """
    watch = watch if watch is not None else Stopwatch()
    with watch("load"):
        loaded = load_part(req.part, units=req.units)
        library = load_tool_library(req.tools)
    with watch("setup"):
        setup, part_work = make_setup(
            loaded.mesh,
            stock_size=req.stock,
            origin=req.origin,
            material=req.material,
            mesh_scale=loaded.scale,
            source=str(req.part),
        )
        library.material(req.material)  # unknown material: fail early
    job, timings = plan_job(
        part_work,
        setup,
        library,
        part_name=req.part.stem,
        source_sha256=loaded.sha256,
        options=req.plan,
        progress=progress,
    )
    for stage, seconds in timings.seconds:
        watch.seconds[stage] = seconds
    return PlannedPart(job, loaded, part_work)


def log_job(log: McapLog, planned: PlannedPart, transform_world_to_work: np.ndarray | None = None) -> None:
    """Views of the job for Foxglove, and the job itself as an attachment for ``factory gcode``.

    ``transform_world_to_work``: pose of the work frame in ``world`` [m] (default identity)."""
    part = planned.part_work
    for topic, msg, latched in job_messages(planned.job, np.asarray(part.vertices), np.asarray(part.faces),
                                            transform_world_to_work=transform_world_to_work):
        log.write(topic, msg, 0, latched=latched)
    log.attach(JOB_ATTACHMENT, "application/json", json.dumps(planned.job.to_dict()).encode())


def read_job(path: Path) -> Job:
    """The job a ``factory toolpath`` MCAP carries."""
    data = read_attachment(path, JOB_ATTACHMENT)
    try:
        return Job.from_dict(json.loads(data))
    except (ValueError, KeyError, TypeError) as e:
        raise ToolpathError(f"job attachment is malformed: {e}", source=path) from None


def job_summary(job: Job) -> dict[str, Any]:
    """Per-operation figures for summaries: points and path lengths [mm]."""
    return {
        "part": job.part_name,
        "operations": [
            {"name": op.name, "tool": op.tool.number, "points": int(len(op.points)),
             **{f"{k}_mm": round(v, 1) for k, v in op.lengths().items()}}
            for op in job.operations
        ],
    }

