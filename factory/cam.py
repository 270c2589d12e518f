"""The CAM half of the plan pipeline: part intake → job, and job ⇄ MCAP.

Used by ``factory toolpath`` and ``factory plan`` (and so by the cell simulation's plans); the
command-line options that fill a :class:`CamRequest` live in :mod:`cli.cam`.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh

from cadcam.finishing import FinishingOptions
from cadcam.mesh import PartMesh, load_part
from cadcam.model import Job, Operation, Setup, SoftJaws, ViseJaws
from cadcam.op2 import choose_face_up
from cadcam.plan import PlanOptions, plan_job
from cadcam.relief import (FINISH_ENGAGEMENT, TERRACE_STEPDOWN, Boundary, ReliefOptions, block_margins,
                           machining_surface, own_surface, relief_setup)
from cadcam.roughing import RoughingOptions
from cadcam.setup import StockMargins, orient_setup
from cadcam.tools import ToolLibrary, load_tool_library
from factory.core.errors import ToolpathError
from factory.mcaplog import LogBuffer, McapLog, read_attachment
from factory.core.progress import Progress, Stopwatch
from factory.core.resources import FIXTURES
from factory.core.units import MM_PER_M
from factory.views import job_scene_messages, work_frame_message
from robotprog.cell import Vise, load_cell

log = logging.getLogger(__name__)

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
SCALLOP = 0.005  # [mm] over a relief and on a mesh's faces; a solid's freeform faces take PlanOptions.freeform_scallop
HOLDING: float | None = None  # [mm] None: the vise's grip depth + breakthrough + clearance (cadcam.setup)
CELL = FIXTURES / "cell.yaml"  # whose vise holds the stock


def vise_jaws(vise: Vise) -> ViseJaws:
    """The cell's vise [m] as CAM's :class:`cadcam.model.ViseJaws` [mm]: the one place the cell's metres
    become CAM's millimetres (the pose stays in the cell: CAM places the jaws around the stock, the
    robot places the stock in the vise). Here in the pipeline because neither domain package may see
    the other's type; the stock crosses the other way at :func:`robotprog.frames.setup_sheet_to_cell`."""
    soft = vise.soft_jaws
    return ViseJaws(
        jaw_height=vise.jaw_height * MM_PER_M,
        jaw_width=vise.jaw_width * MM_PER_M,
        jaw_thickness=vise.jaw_thickness * MM_PER_M,
        parallels_height=vise.parallels_height * MM_PER_M,
        opening_min=vise.jaw_opening_min * MM_PER_M,
        opening_max=vise.jaw_opening_max * MM_PER_M,
        soft_jaws=None if soft is None else SoftJaws(soft.kind, soft.depth * MM_PER_M),
    )


@dataclasses.dataclass(frozen=True)
class CamRequest:
    """What to plan and how: the part file, tool library, stock, material, work origin and CAM options.

    ``tools`` None is the bundled library (``fixtures/tools.yaml``); ``stock`` is the stock size
    X, Y, Z [mm], None for the default (part box + 2 mm on the sides, 1 mm on top, the holding
    allowance below); ``holding`` the holding allowance under the part [mm], None for the
    default of :func:`cadcam.setup.default_holding`; ``cell`` the cell file whose vise holds
    the stock (None: no vise, nothing checked against jaws); ``relief`` applies when the mesh is
    an open surface (:mod:`cadcam.relief`): floor and boundary mode; ``body`` picks the solid
    (1-based) of a STEP file with several; ``rapid_cell`` the grid [mm] every rapid is checked on
    (``plan_job``'s, finer when :func:`factory.plan.plan_part` plans again after a rapid in stock);
    ``set_aside`` the tool numbers the plan may not use (a re-plan after that tool failed verify)."""

    part: Path
    tools: Path | None
    stock: tuple[float, float, float] | None
    material: str
    units: Units
    origin: Origin
    plan: PlanOptions
    holding: float | None = HOLDING
    cell: Path | None = CELL
    relief: ReliefOptions = ReliefOptions()
    body: int | None = None
    rapid_cell: float = 0.5
    set_aside: tuple[int, ...] = ()

    @classmethod
    def from_options(cls, part: Path, tools: Path | None, stock: tuple[float, float, float] | None, material: str,
                     units: Units, origin: Origin, rough_tool: int | None, finish_tool: int | None, allowance: float,
                     scallop: float | None, stepdown: float | None, waterline: bool, holding: float | None = HOLDING,
                     cell: Path | None = CELL, relief: ReliefOptions = ReliefOptions(),
                     body: int | None = None) -> "CamRequest":
        """The request from the flat option values of ``factory toolpath`` and ``factory plan``; ``scallop``
        [mm] None keeps each surface's default, a value holds everywhere, freeform faces included."""
        plan = PlanOptions(
            rough_tool=rough_tool,
            finish_tool=finish_tool,
            roughing=RoughingOptions(allowance=allowance, stepdown=stepdown),
            finishing=FinishingOptions(scallop=SCALLOP if scallop is None else scallop),
            waterline=waterline,
        )
        if scallop is not None:  # asked for on the command line, even at the default's value: it holds on freeform too
            plan = dataclasses.replace(plan, freeform_scallop=scallop)
        return cls(part, tools, stock, material, units, origin, plan, holding, cell, relief, body)

    @classmethod
    def defaults(cls, part: Path, material: str = MATERIAL, tools: Path | None = None,
                 cell: Path | None = CELL) -> "CamRequest":
        """The request of a command line that gives only the part, material, tool library and cell."""
        return cls.from_options(part, tools, None, material, UNITS, ORIGIN, ROUGH_TOOL, FINISH_TOOL, ALLOWANCE,
                                None, None, True, HOLDING, cell)

    def library(self) -> ToolLibrary:
        """The tool library of :attr:`tools`, without the tools :attr:`set_aside`.

        Raises
        ------
        ToolError
            The library file cannot be read or is malformed.
        """
        library = load_tool_library(self.tools)
        if not self.set_aside:
            return library
        return dataclasses.replace(library, tools=tuple(t for t in library.tools if t.number not in self.set_aside))

    def jaws(self) -> ViseJaws | None:
        """The vise of :attr:`cell` in millimetres, None without a cell.

        Raises
        ------
        CellError
            The cell file cannot be read or is malformed.
        """
        return None if self.cell is None else vise_jaws(load_cell(self.cell, check_robot=False).vise)

    def gripped(self) -> float | None:
        """The widest blank [mm] the gripper of :attr:`cell` opens its fingers' clearance beside
        (:func:`robotprog.grasp.finger_room`), None without a cell.

        Raises
        ------
        CellError
            The cell file cannot be read or is malformed.
        """
        if self.cell is None:
            return None
        gripper = load_cell(self.cell, check_robot=False).gripper
        return (gripper.opening_max - 2 * gripper.fingers.clearance) * MM_PER_M


@dataclasses.dataclass(frozen=True)
class PlannedPart:
    """A computed job with the part it was computed for (for a relief, the surface it was machined
    against, :func:`cadcam.relief.machining_surface`, and the boundary the tools kept within)."""

    job: Job
    loaded: PartMesh
    part_work: trimesh.Trimesh
    boundary: Boundary | None = None

    def toolpath_picture(self) -> np.ndarray:
        """(H, W, 3) uint8 top view of the toolpaths over the part's faces by kind (a relief's own
        faces: the base plane its machining surface lays round it spans far past the stock)."""
        from cadcam.faces import classify_faces
        from cadcam.preview import toolpath_image

        part = self.part_work if self.boundary is None else own_surface(self.part_work)
        return toolpath_image(self.job, faces=classify_faces(part))


def compute_job(req: CamRequest, progress: Progress | None = None, watch: Stopwatch | None = None,
                check_setup: Callable[[Setup, trimesh.Trimesh | None], None] | None = None,
                on_setup: Callable[[Setup, PartMesh, Boundary | None, trimesh.Trimesh], None] | None = None,
                on_operations: Callable[[list[Operation], Setup], None] | None = None,
                on_planned: Callable[[list[Operation], Setup], None] | None = None) -> PlannedPart:
    """Load, set up and plan one part, timing each stage into ``watch``.

    ``check_setup`` is called with the setup and the part in work coordinates [mm] (None for a
    relief) before the toolpaths are computed, to refuse early what a later stage would refuse
    only after that work. ``on_setup`` is called once with the setup chosen, the part as loaded and
    a relief's boundary (None for a solid) and the part the toolpaths are planned against (work
    coordinates [mm]) before the toolpaths are computed, to start work that needs no toolpath (the
    robot's), or that needs the part placed (verify's). ``on_operations`` is :func:`cadcam.plan.plan_job`'s: told of the
    operations as they are planned, to start work on them meanwhile (their arc fitting); ``on_planned``
    its too: told of them all, before the rapid check.

    Raises
    ------
    FactoryError
        The mesh cannot be read or placed, the tool library or material is unknown, an
        operation cannot be computed.
    """
    watch = watch if watch is not None else Stopwatch()
    with watch("load"):
        loaded = load_part(req.part, units=req.units, body=req.body)
        library = req.library()
        jaws = req.jaws()
    if loaded.step is not None:
        _report_step_features(loaded, library, req.part)
    boundary = None
    with watch("setup"):
        library.material(req.material)  # unknown material: fail early
        if loaded.surface is None:  # turned about Z when only that fits the vise and the gripper
            def place(mesh: trimesh.Trimesh) -> tuple[Setup, trimesh.Trimesh]:
                return orient_setup(mesh, fits=check_setup, stock_size=req.stock,
                                    margins=StockMargins(bottom=req.holding), jaws=jaws, origin=req.origin,
                                    material=req.material, mesh_scale=loaded.scale, source=str(req.part))

            if req.plan.rough_tool is None and req.plan.finish_tool is None:
                # deeper than the tools reach: the face up first that leaves the least unreached (op 1 and op 2)
                setup, part_work = choose_face_up(loaded.mesh, place, library)
            else:
                setup, part_work = place(loaded.mesh)
        else:
            log.info("%s: %s", req.part, loaded.surface.describe())
            margins = block_margins(loaded.surface, StockMargins(bottom=req.holding), req.gripped())
            setup, surface_work, boundary = relief_setup(
                loaded.mesh, loaded.surface, req.relief, stock_size=req.stock,
                margins=margins, jaws=jaws, origin=req.origin,
                material=req.material, mesh_scale=loaded.scale, source=str(req.part))
            part_work = machining_surface(surface_work, setup)
            if check_setup is not None:
                check_setup(setup, None)  # a relief leaves in its block: no part of its own to grip
    if on_setup is not None:
        on_setup(setup, loaded, boundary, part_work)
    options = req.plan
    if boundary is not None:  # shallow nearly everywhere: finer terraces, finishing engages less
        options = dataclasses.replace(options, finish_engagement=min(options.finish_engagement, FINISH_ENGAGEMENT),
                                      terrace_stepdown=min(options.terrace_stepdown, TERRACE_STEPDOWN))
    exact_holes = None
    if loaded.step is not None and loaded.surface is None and not loaded.step.features.freeform:
        # the B-rep's holes, not the mesh's guess; with free-form faces, which may be bores, the mesh's
        exact_holes = loaded.step.features.holes_in_work(setup.transform_mesh_to_work, loaded.step.chordal_deviation)
    planned = plan_job(
        part_work,
        setup,
        library,
        part_name=req.part.stem,
        source_sha256=loaded.sha256,
        options=options,
        progress=progress,
        boundary=boundary,
        holes=exact_holes,
        rapid_cell=req.rapid_cell,
        on_operations=on_operations,
        on_planned=on_planned,
    )
    job = planned.job
    if not job.operations:  # nothing to cut: say so here, not as an empty job a later stage refuses
        what = ("surfaces only, no solid, and no tool cuts them from above" if loaded.surface is not None
                else "no tool cuts anything of it")
        raise ToolpathError(f"nothing to machine: {what}", source=req.part)
    if boundary is not None and loaded.surface is not None:
        relief = {"found": loaded.surface.describe(), **loaded.surface.to_dict(), **req.relief.to_dict(),
                  "boundary": boundary.to_dict()}
        job = dataclasses.replace(job, parameters={**job.parameters, "relief": relief})
    intake = loaded.sheet_record()
    if intake is not None:  # a STEP part: verify, the robot and the cell read it again as planned
        job = dataclasses.replace(job, parameters={**job.parameters, "intake": intake})
    for stage, seconds in planned.timings.seconds:  # a stage that ran more than once (the stock model) adds up
        watch.seconds[stage] = watch.seconds.get(stage, 0.0) + seconds
    return PlannedPart(job, loaded, part_work, boundary)


def _report_step_features(loaded: PartMesh, library, part: Path) -> None:
    """Say, before any toolpath work, what of a STEP part's exact features this setup cannot cut.

    Holes off the Z axis or covered from above, and faces that look down with the part under them
    (undercuts), need another setup; an inside corner tighter
    than the library's narrowest flat or bull-nose end mill is left with that tool's radius.
    """
    step = loaded.step
    log.info("%s: STEP in %s, %d B-rep faces tessellated to %d triangles at a chordal deviation of %g mm",
             part, step.unit, step.brep_faces, len(step.faces), step.chordal_deviation)
    if step.features.freeform:
        log.info("%s: %d free-form B-rep faces, which may be bores: the holes are found in the mesh", part,
                 step.features.freeform)
    for hole in step.features.elsewhere:
        log.warning("%s: %s", part, hole.describe())
    for face in step.features.undercuts:
        log.warning("%s: %s", part, face.describe())
    mills = [t for t in library.tools if t.shape in ("flat", "bull") and not t.is_drill]
    if mills:
        smallest = min(mills, key=lambda t: t.diameter)
        for corner in step.features.unreachable_corners(smallest.radius):
            log.warning("%s: %s: the smallest end mill is %g mm (T%d): left with R%g", part, corner.describe(),
                        smallest.diameter, smallest.number, smallest.radius)


def log_job(log: McapLog | LogBuffer, planned: PlannedPart,
            transform_world_to_work: np.ndarray | None = None) -> None:
    """Views of the job for Foxglove, and the job itself as an attachment for ``factory gcode``: the work frame
    (:func:`log_work_frame`), then the rest (:func:`log_job_scene`).

    ``transform_world_to_work``: pose of the work frame in ``world`` [m] (default identity)."""
    log_work_frame(log, transform_world_to_work)
    log_job_scene(log, planned)


def log_work_frame(log: McapLog | LogBuffer, transform_world_to_work: np.ndarray | None = None) -> None:
    """The first message of :func:`log_job`: the work frame's pose in ``world`` [m] (default identity)."""
    topic, message, latched = work_frame_message(transform_world_to_work)
    log.write_cdr(topic, message.typename, message.cdr, 0, message.make, latched=latched)


def log_job_scene(log: McapLog | LogBuffer, planned: PlannedPart) -> None:
    """:func:`log_job` after the work frame: the toolpath, part and stock views and the job's attachment, which
    need no robot (the robot places the work frame)."""
    part = planned.part_work
    for topic, message, latched in job_scene_messages(planned.job, np.asarray(part.vertices),
                                                      np.asarray(part.faces)):
        log.write_cdr(topic, message.typename, message.cdr, 0, message.make, latched=latched)
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

