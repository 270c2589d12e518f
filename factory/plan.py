"""Plan one part end to end: toolpaths, G-code, setup sheet, verify, the robot's load/unload, one MCAP.

This is ``factory plan`` as a library. :func:`plan_part` computes everything and writes nothing;
:meth:`PartPlan.write` writes the output set so that it appears whole or not at all::

    from pathlib import Path
    from factory.plan import PlanRequest, plan_part

    plan = plan_part(PlanRequest.defaults(Path("samples/bracket.stl"), "aluminium"))
    print(plan.report.ok, plan.program.total_time)      # verify verdict, cycle estimate [s]
    summary = plan.write(Path("build/bracket"))         # PART.nc, PART.setup.json, ... PART.plan.json

Crash consistency: the files are written into a hidden staging folder beside the outputs and
renamed into place only when all of them are complete, the summary ``PART.plan.json`` last. The
summary is the commit marker: a set without it was interrupted, and :mod:`factory.catalog`
ignores and repairs it. A staging folder left by a killed run is removed by the next write of
the same part.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from cadcam.model import Job, Operation, Setup
from cadcam.plan import PlanOptions
from cadcam.parallel import Background, processors
from cadcam.op2 import (FLIP_AXIS, WORK_OFFSET, Op2Options, flip_transform, op2_setup_image, op2_sheet_fields,
                        plan_op2)
from cadcam.seam import seam_faults
from cadcam.post import FitAhead, PostOptions, Program, post_process, tool_table_file
from cadcam.preview import setup_image
from cadcam.mesh import PartMesh
from cadcam.relief import Boundary, block_corners
from cadcam.sheet import setup_sheet
from cadcam.stock import Simulation
from cadcam.verify import Fault, VerifyOptions, VerifyReport
from factory.core.atomic import check_writable, write_bytes, write_text
from factory.cam import CamRequest, PlannedPart, compute_job, log_job_scene, log_work_frame
from factory.catalog import catalog_record, sha256_file
from factory.core.errors import FactoryError, PlanningError, SetupError, shown
from factory.mcaplog import LogBuffer, McapLog
from factory.pictures import png_bytes
from factory.refusals import check_op2_grip, check_request, check_setup
from factory.core.progress import Progress, Stopwatch, held_open
from factory.core.resources import FIXTURES
from factory.core.setupsheet import SetupSheet
from factory.robotwork import BackgroundRobot, RobotTask, RobotWork, stock_sheet
from factory.tending import CellPlan, log_cell, log_motion
from factory.verify import (VerifyAhead, log_simulation, report_text, run_verify, run_verify_after,
                            write_verify_outputs)
from robotprog.programs import PostedProgram
from robotprog.visuals import LinkVisual

log = logging.getLogger(__name__)

#: Robot program file ending per language.
PROGRAM_SUFFIX = {"urscript": ".script", "rapid": ".mod", "krl": ".src"}
#: Name of the summary file, the commit marker of an output set, relative to the part's stem.
SUMMARY_SUFFIX = ".plan.json"


def plan_outputs(part: Path, out_dir: Path, robot_lang: str | None = "urscript",
                 ops: int | None = 2, post: str = "linuxcnc") -> dict[str, Path]:
    """Every file ``factory plan`` writes for ``part`` into ``out_dir`` (no robot files for ``None``).

    With ``ops`` 2 (the default) or None (not known yet: all that may be written), op 2's program, setup sheet, verify report and picture, and
    the picture of its setup: ``PART.op2.nc``, ``PART.op2.setup.json``, ... (:mod:`cadcam.op2`).
    For a controller that reads a tool table file (``post`` linuxcnc), the job's: ``PART.tbl``, one for
    both programs."""
    stem = out_dir / part.stem
    outputs = {
        "program": stem.with_suffix(".nc"),
        "setup_sheet": stem.with_suffix(".setup.json"),
        "mcap": stem.with_suffix(".mcap"),
        "verify_json": stem.with_suffix(".verify.json"),
        "verify_png": stem.with_suffix(".verify.png"),
        "toolpath_png": stem.with_suffix(".toolpath.png"),
        "setup_png": stem.with_suffix(".setup.png"),
        "summary": stem.with_suffix(SUMMARY_SUFFIX),
    }
    if ops != 1:
        outputs.update({
            "program_op2": stem.with_suffix(".op2.nc"),
            "setup_sheet_op2": stem.with_suffix(".op2.setup.json"),
            "verify_json_op2": stem.with_suffix(".op2.verify.json"),
            "verify_png_op2": stem.with_suffix(".op2.verify.png"),
            "setup_png_op2": stem.with_suffix(".op2.setup.png"),
        })
    if robot_lang is not None:
        outputs["robot_program"] = stem.with_suffix(PROGRAM_SUFFIX[robot_lang])
        if robot_lang == "krl":
            outputs["robot_program_dat"] = stem.with_suffix(".dat")
    if PostOptions(dialect=post).controller.tool_table is not None:
        outputs["tool_table"] = stem.with_suffix(".tbl")
    return outputs


def program_summary(program: Program, output: Path, sheet_path: Path) -> dict[str, Any]:
    """Figures of a posted program for summaries: lines, cycle estimate [s], per operation lengths [mm]."""
    return {
        "program": str(output),
        "setup_sheet": str(sheet_path),
        "dialect": program.dialect,
        "lines": program.line_count,
        "estimated_cycle_s": round(program.total_time, 1),
        "operations": [
            {"name": e.name, "tool": e.tool_number, "cut_mm": round(e.cut_length, 1),
             "rapid_mm": round(e.rapid_length, 1), "estimated_s": round(e.cut_time + e.rapid_time, 1)}
            for e in program.estimates
        ],
    }


def workholding_summary(setup: Setup, part_bottom: float) -> dict[str, Any]:
    """How op 1 holds the part [mm]: the holding allowance under it, the lowest feed, what stays held,
    and the jaws' top above the stock bottom (None without a vise)."""
    bottom = float(setup.stock_min[2])
    jaws = [b for b in setup.jaws or () if b.name != "parallels"]
    return {
        "holding_mm": round(part_bottom - bottom, 3),
        "floor_z": round(float(setup.floor_z), 3),
        "left_under_part_mm": round(float(setup.floor_z) - bottom, 3),
        "grip_depth_mm": round(max(float(b.hi[2]) for b in jaws) - bottom, 3) if jaws else None,
    }


@dataclasses.dataclass(frozen=True)
class PlanRequest:
    """Everything ``factory plan`` needs besides the output folder.

    Attributes
    ----------
    cam : CamRequest
        Part, tools, stock, material and CAM options.
    post : str
        Controller dialect: ``linuxcnc``, ``grbl`` or ``fanuc``.
    arc_tolerance : float
        Arc and line fitting tolerance of the post [mm].
    grid : float
        Verify grid spacing [mm].
    cell : Path
        Robot cell file, used when ``robot`` is true (its vise holds the stock: give the same
        file as ``cam.cell``).
    robot : bool
        Plan loading and unloading with the cell.
    lang : str
        Robot program language: ``urscript``, ``rapid`` or ``krl``.
    ops : int, optional
        2: op 1 from the top, then the part turned over and op 2 facing off the holding
        allowance (:mod:`cadcam.op2`); 1: op 1 only. None (default): 2 for a solid, 1 for a
        relief (cut into the top of a block that is not turned over unless asked).
    """

    cam: CamRequest
    post: str = "linuxcnc"
    arc_tolerance: float = 0.002
    grid: float = 0.2
    cell: Path = FIXTURES / "cell.yaml"
    robot: bool = True
    lang: str = "urscript"
    ops: int | None = None

    @classmethod
    def defaults(cls, part: Path, material: str, cell: Path = FIXTURES / "cell.yaml",
                 tools: Path | None = None) -> "PlanRequest":
        """The plan ``factory plan PART --material M --cell C`` makes with every other option at its default."""
        return cls(CamRequest.defaults(part, material, tools, cell), cell=cell)

    def outputs(self, out_dir: Path) -> dict[str, Path]:
        """Every file :meth:`PartPlan.write` writes into ``out_dir``."""
        return plan_outputs(self.cam.part, out_dir, self.lang if self.robot else None, self.ops, self.post)


@dataclasses.dataclass(frozen=True)
class Tending(CellPlan):
    """The robot's load and unload of one part (the cell, its collision world, the timed plan: a
    :class:`~factory.tending.CellPlan`), the posted robot program (its texts keyed by file name:
    KRL has a ``.src`` and a ``.dat``) and the robot's meshes for the log (None: read when logged)."""

    program: PostedProgram
    visuals: tuple[LinkVisual, ...] | None = None

    @property
    def programs(self) -> dict[str, str]:
        """File name -> text of the robot program."""
        return {path.name: text for path, text in self.program.texts.items()}


@dataclasses.dataclass(frozen=True)
class SecondOp:
    """Op 2 of a plan: the part turned over about the jaw axis, the holding allowance faced off.

    Attributes
    ----------
    job : Job
        In op-2 work coordinates (:func:`cadcam.op2.plan_op2`).
    part_work : trimesh.Trimesh
        The part in op-2 work coordinates [mm].
    program : Program
        Posted in work offset G55.
    setup_sheet : SetupSheet
        ``PART.op2.setup.json``: naming op 1's program and sheet it runs after.
    simulation, report : Simulation, VerifyReport
        Its verify, from op 1's simulated stock turned over.
    """

    job: Job
    part_work: trimesh.Trimesh
    program: Program
    setup_sheet: SetupSheet
    simulation: Simulation
    report: VerifyReport


@dataclasses.dataclass(frozen=True, eq=False)
class WriteAhead:
    """The outputs of a plan that do not depend on its verification, made while verify runs in its
    process (:func:`write_ahead`) and written by :meth:`PartPlan.write` as they are.

    Attributes
    ----------
    toolpath_png, setup_png : bytes
        Op 1's toolpath and setup pictures.
    job_log, robot_log : LogBuffer
        The log's messages of op 1's job, and of the robot's cell and motion (empty without a robot).
    """

    toolpath_png: bytes
    setup_png: bytes
    job_log: LogBuffer
    robot_log: LogBuffer


@dataclasses.dataclass(frozen=True, eq=False)
class Drawn:
    """What of :class:`WriteAhead` needs no robot (:func:`drawn`): made while verify runs, whether the robot's
    share is planned by then or not.

    Attributes
    ----------
    toolpath_png, setup_png : bytes
        Op 1's toolpath and setup pictures.
    scene : LogBuffer
        The job's views and attachment in the log (:func:`factory.cam.log_job_scene`): all of its log but the
        work frame, which the robot's plan places in the cell.
    """

    toolpath_png: bytes
    setup_png: bytes
    scene: LogBuffer


def drawn(planned: PlannedPart) -> Drawn:
    """:class:`Drawn` of op 1 ``planned``."""
    job = planned.job
    scene = LogBuffer()
    log_job_scene(scene, planned)
    return Drawn(png_bytes(planned.toolpath_picture()),
                 png_bytes(setup_image(job.setup, np.asarray(planned.part_work.triangles), job.part_name)),
                 scene)


def write_ahead(planned: PlannedPart, tending: Tending | None, ahead: Drawn | None = None) -> WriteAhead:
    """:class:`WriteAhead` of op 1 ``planned`` and the robot's ``tending`` (None: no robot), on from what was
    ``ahead`` :func:`drawn` for them (drawn here when None). With a robot the log's work frame sits in the
    cell's vise, and the cell and the robot's motion follow the job in the log."""
    if ahead is None:
        ahead = drawn(planned)
    job_log, robot_log = LogBuffer(), LogBuffer()
    world_work = None
    if tending is not None:
        world_work = tending.cell.vise.pose.matrix() @ tending.plan.stock.transform_vise_to_work
        log_cell(robot_log, tending.cell, tending.world, tending.visuals)
        log_motion(robot_log, tending.world, tending.plan)
    log_work_frame(job_log, world_work)
    ahead.scene.replay(job_log)
    return WriteAhead(ahead.toolpath_png, ahead.setup_png, job_log, robot_log)


@dataclasses.dataclass(frozen=True)
class PartPlan:
    """A planned part, computed and not yet written (see :func:`plan_part`).

    Attributes
    ----------
    request : PlanRequest
    planned : PlannedPart
        The CAM job with the part mesh it was computed for.
    program : Program
        The posted G-code and its time estimate.
    setup_sheet : SetupSheet
        The setup sheet (``PART.setup.json``).
    tending : Tending or None
        The robot's load and unload, None when planned without a robot.
    simulation : Simulation
        The verify material-removal simulation of the program.
    report : VerifyReport
        Its verdict: gouges, remaining stock, rapid crashes.
    seconds : dict
        Wall time per stage [s].
    op2 : SecondOp or None
        Op 2, None when planned with ``ops=1``.
    replanned : tuple of str
        Why each earlier plan of this part was thrown away (its first verify fault), in order;
        empty when the first plan passed verify (:func:`plan_part`).
    """

    request: PlanRequest
    planned: PlannedPart
    program: Program
    setup_sheet: SetupSheet
    tending: Tending | None
    simulation: Simulation
    report: VerifyReport
    seconds: dict[str, float]
    op2: SecondOp | None = None
    replanned: tuple[str, ...] = ()
    ahead: WriteAhead | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def ok(self) -> bool:
        """Both operations verified: no gouge, no rapid into stock, no other fault."""
        return self.report.ok and (self.op2 is None or self.op2.report.ok)

    def summary(self, out_dir: Path) -> dict[str, Any]:
        """The ``PART.plan.json`` document of this plan written into ``out_dir``."""
        req, job, tending = self.request, self.planned.job, self.tending
        outputs = req.outputs(out_dir)
        tools_path = req.cam.tools or FIXTURES / "tools.yaml"
        return {
            "part": str(req.cam.part),
            "catalog": catalog_record(self.planned.loaded.sha256, req.cam.material,
                                      sha256_file(req.cell) if tending is not None else None,
                                      sha256_file(tools_path)),
            "triangles": int(len(self.planned.loaded.mesh.faces)),
            "repairs": list(self.planned.loaded.repairs),
            **self.planned.loaded.intake_summary(),  # a STEP part: unit, chordal deviation, exact features
            # an open surface machined from above (cadcam.relief): what was found, floor, boundary
            **({"relief": job.parameters["relief"]} if "relief" in job.parameters else {}),
            "stock_mm": job.setup.stock_size.round(3).tolist(),
            "workholding": workholding_summary(job.setup, np.asarray(self.planned.part_work.bounds)[0][2]),
            **program_summary(self.program, outputs["program"], outputs["setup_sheet"]),
            # what no tool in the library reaches: left in place, and finishing stays out of it [mm]
            "unreached": list(job.parameters.get("unreached", [])),
            "rapids": job.parameters.get("rapids"),
            # round holes found, and which were drilled, helixed, or left to roughing (cadcam.drilling)
            "holes": job.parameters.get("holes", {}),
            # verify.ok: every operation verified; the figures are op 1's, op 2's under verify_op2
            "verify": {**self.report.to_dict(), "ok": self.ok},
            "verify_op2": None if self.op2 is None else self.op2.report.to_dict(),
            "setups": self._setups(outputs),
            "robot": None if tending is None else {
                "cell": tending.cell.name, "robot": tending.world.robot.name,
                "motion_s": round(tending.plan.duration, 3),
                "program_s": round(tending.program.predicted_s, 3), "program_targets": tending.program.targets,
                "moves": [{"name": n, "duration_s": round(d, 3)} for n, d in tending.plan.durations],
                # the program's reject branch after the verdict (none: it does not branch)
                "reject_moves": [] if tending.program.planned_reject_s is None else
                [{"name": m.name, "duration_s": round(m.duration, 3)} for m in tending.plan.reject]},
            # the verify faults that made the plan be made again, more conservatively (only when it was)
            **({"replanned": list(self.replanned)} if self.replanned else {}),
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
            "outputs": {k: str(v) for k, v in outputs.items()},
        }

    def _setups(self, outputs: dict[str, Path]) -> list[dict[str, Any]]:
        """One entry per operation, in running order: program, sheet, work offset, cycle estimate [s]."""
        out = [{"op": 1, "program": str(outputs["program"]), "setup_sheet": str(outputs["setup_sheet"]),
                "work_offset": "G54", "estimated_cycle_s": round(self.program.total_time, 1),
                "verify_ok": self.report.ok}]
        if self.op2 is not None:
            out.append({"op": 2, "program": str(outputs["program_op2"]),
                        "setup_sheet": str(outputs["setup_sheet_op2"]), "work_offset": "G55",
                        "estimated_cycle_s": round(self.op2.program.total_time, 1),
                        "verify_ok": self.op2.report.ok, "flip_axis": FLIP_AXIS,
                        "face_z": round(float(self.op2.job.parameters["face_z"]), 4),
                        "operations": [{"name": e.name, "tool": e.tool_number,
                                        "estimated_s": round(e.cut_time + e.rapid_time, 1)}
                                       for e in self.op2.program.estimates],
                        "unreached": list(self.op2.job.parameters.get("unreached", [])),
                        # after a depth split: where op 1's and op 2's walls meet, and the step [mm]
                        **({"seams": self.op2.job.parameters["seams"]} if "seams" in self.op2.job.parameters
                           else {})})
        return out

    def write(self, out_dir: Path, *, overwrite: bool = False, progress: Progress | None = None) -> dict[str, Any]:
        """Write every output into ``out_dir`` as one set, the summary last; returns the summary.

        ``progress`` shows the stage ``write`` (the pictures and the MCAP) as it starts and ends.

        Raises
        ------
        OutputExistsError
            An output exists and ``overwrite`` is false (checked before anything is written).
        """
        final = self.request.outputs(out_dir)
        for p in final.values():
            check_writable(p, overwrite)
        watch = Stopwatch(progress)
        with watch("write"), _staging(out_dir, self.request.cam.part.stem) as stage:
            self._write_files(self.request.outputs(stage))
            for p in final.values():  # a file that appeared meanwhile is not clobbered
                check_writable(p, overwrite)
            seconds = dict(self.seconds)
            for name, path in final.items():
                if name != "summary":
                    os.replace(stage / path.name, path)
        seconds.update(watch.seconds)
        summary = dataclasses.replace(self, seconds=seconds).summary(out_dir)
        write_text(final["summary"], json.dumps(summary, indent=2) + "\n", overwrite=overwrite)
        return summary

    def _write_files(self, outputs: dict[str, Path]) -> None:
        """Every output but the summary, into a fresh folder."""
        req, planned, tending = self.request, self.planned, self.tending
        job = planned.job
        write_text(outputs["setup_sheet"], json.dumps(self.setup_sheet.to_json(), indent=2) + "\n")
        write_text(outputs["program"], self.program.text)
        if "tool_table" in outputs:  # one for op 1's and op 2's programs: both number the library's tools alike
            tools = [*job.tools, *(self.op2.job.tools if self.op2 is not None else ())]
            write_text(outputs["tool_table"], tool_table_file(PostOptions(dialect=req.post), tools) or "")
        write_verify_outputs(self.simulation, self.report, png=outputs["verify_png"], json_path=outputs["verify_json"],
                             mcap=None, overwrite=False, inputs={},
                             relief=None if planned.boundary is None else np.asarray(planned.part_work.triangles))
        ahead = self.ahead if self.ahead is not None else write_ahead(planned, tending)
        write_bytes(outputs["toolpath_png"], ahead.toolpath_png)
        write_bytes(outputs["setup_png"], ahead.setup_png)
        if self.op2 is not None:
            op2 = self.op2
            write_text(outputs["setup_sheet_op2"], json.dumps(op2.setup_sheet.to_json(), indent=2) + "\n")
            write_text(outputs["program_op2"], op2.program.text)
            write_verify_outputs(op2.simulation, op2.report, png=outputs["verify_png_op2"],
                                 json_path=outputs["verify_json_op2"], mcap=None, overwrite=False, inputs={})
            write_bytes(outputs["setup_png_op2"], png_bytes(op2_setup_image(op2.job, op2.part_work)))
        inputs = {str(req.cam.part): planned.loaded.sha256}
        parameters = dict(job.parameters)
        if tending is not None:
            inputs[str(req.cell)] = sha256_file(req.cell)
            parameters["robot"] = {"cell": tending.cell.name, "robot": tending.world.robot.name,
                                   "durations_s": {n: round(d, 4) for n, d in tending.plan.durations},
                                   "program_duration_s": round(tending.program.predicted_s, 4)}
            for name, text in tending.programs.items():
                write_text(outputs["summary"].parent / name, text)
        # One log of the whole plan: with a robot, the work frame sits in the cell's vise.
        with McapLog(outputs["mcap"], stage="plan", inputs=inputs, parameters=parameters) as m:
            ahead.job_log.replay(m)
            log_simulation(m, self.simulation)
            ahead.robot_log.replay(m)


#: Each re-plan after a failed verify scales the roughing stepdown, the terrace stepdown and the
#: finishing engagement of the first plan by the next of these: thinner cuts for every tool.
REPLAN_SCALES = (0.5, 0.25)


def plan_part(request: PlanRequest, progress: Progress | None = None) -> PartPlan:
    """Plan a part: CAM, post, setup sheet, robot load/unload and program, verify. Writes nothing.

    A plan that verify fails is never the first answer: the failing operation is planned again with
    thinner cuts (:func:`conservative`, at each of :data:`REPLAN_SCALES`) and its rapids checked on
    verify's grid (``CamRequest.rapid_cell``) until one passes: op 2 alone, from op 1's verified
    stock, when op 1 passed; the whole part when op 1 failed (op 2 starts from what op 1 leaves). When the
    thinnest cuts fail too, once more without the faulting tool (:func:`_with_the_next_tool`); at once when
    that fault is the tool's holder (:func:`_holder_at_fault`), which thinner cuts cannot move. Only the
    last is returned failed (``ok`` False), naming its faults. What each re-plan was for is in
    ``replanned``.

    Raises
    ------
    FactoryError
        Any stage's error: a bad mesh, an unknown tool or material, an unreachable part, a cell
        the robot cannot tend.
    """
    plan = _plan_once(request, progress)
    why: list[str] = []
    for scale in REPLAN_SCALES:
        if plan.ok or _holder_at_fault(plan):
            break
        fault = _first_fault(plan)
        why.append(fault)
        op2_only = plan.report.ok and plan.op2 is not None
        log.warning("%s: verify failed (%s): planning again%s with stepdowns and finishing engagement x%g",
                    request.cam.part, fault, " (op 2 only)" if op2_only else "", scale)
        failing = plan.op2.job if op2_only else plan.planned.job
        # the rapids checked on verify's own grid too: what it saw in stock, the check sees
        cam = dataclasses.replace(request.cam, plan=conservative(request.cam.plan, failing, scale),
                                  rapid_cell=min(request.cam.rapid_cell, request.grid))
        plan = _replan_op2(plan, cam, progress) if op2_only else _plan_once(dataclasses.replace(request, cam=cam),
                                                                            progress)
    if not plan.ok:
        plan = _with_the_next_tool(plan, request, progress, why)
    return dataclasses.replace(plan, replanned=tuple(why))


def _holder_at_fault(plan: PartPlan) -> bool:
    """Whether the fault :func:`_with_the_next_tool` acts on is a tool's shank or holder meeting the stock or
    the part: thinner cuts leave the holder as low beside the same stock, so only the next tool can help."""
    fault = _tool_fault(plan)
    return fault is not None and fault.kind == "holder"


def _op2_only(plan: PartPlan) -> bool:
    """Whether only op 2 failed verify (op 1 passed), so a re-plan is op 2's alone."""
    return plan.report.ok and plan.op2 is not None


def _tool_fault(plan: PartPlan) -> Fault | None:
    """The first fault naming a tool in the operation a re-plan acts on (:func:`_op2_only`), None if none does."""
    report = plan.op2.report if _op2_only(plan) else plan.report
    return next((f for f in report.faults if f.tool), None)


def _with_the_next_tool(plan: PartPlan, request: PlanRequest, progress: Progress | None, why: list[str]) -> PartPlan:
    """After thinner cuts failed too: the operation planned again with the faulting tool set aside, so the
    planner takes the next one (narrower, or longer reach) or leaves the region it cannot cut and reports it
    unreached. ``plan`` itself when the fault names no tool, a tool the user named, or when the library
    without it cannot plan the part (a tool role no other tool fills); the fault appended to ``why``
    when it is planned again."""
    op2_only = _op2_only(plan)
    fault = _tool_fault(plan)
    tool = 0 if fault is None else fault.tool
    named = (request.cam.plan.rough_tool, request.cam.plan.finish_tool)
    if not tool or tool in named:
        return plan
    fault = _first_fault(plan)
    cam = dataclasses.replace(request.cam, set_aside=(*request.cam.set_aside, tool),
                              rapid_cell=min(request.cam.rapid_cell, request.grid))
    log.warning("%s: verify failed (%s) with thinner cuts too: planning again%s without T%d", request.cam.part,
                fault, " (op 2 only)" if op2_only else "", tool)
    try:
        again = _replan_op2(plan, cam, progress) if op2_only else _plan_once(dataclasses.replace(request, cam=cam),
                                                                             progress)
    except FactoryError as e:
        log.warning("%s: without T%d the part cannot be planned (%s): the plan with it stands", request.cam.part,
                    tool, e.message)
        return plan
    why.append(fault)
    return again


def conservative(options: PlanOptions, job: Job, scale: float) -> PlanOptions:
    """``options`` with thinner cuts: the roughing stepdown (the job's roughing tool's default when not
    given, :class:`cadcam.roughing.RoughingOptions`), the terrace stepdown and the finishing engagement
    [mm] scaled by ``scale`` in (0, 1)."""
    rough = next((t for t in job.tools if t.number == job.parameters.get("rough_tool")), None)
    stepdown = options.roughing.stepdown
    if stepdown is None and rough is not None:
        stepdown = rough.level_stepdown
    roughing = dataclasses.replace(options.roughing, stepdown=None if stepdown is None else stepdown * scale)
    return dataclasses.replace(options, roughing=roughing, terrace_stepdown=options.terrace_stepdown * scale,
                               finish_engagement=options.finish_engagement * scale)


def _first_fault(plan: PartPlan) -> str:
    """The first verify fault of the plan's first failing operation, as one clause."""
    for label, report in (("op 1", plan.report), ("op 2", None if plan.op2 is None else plan.op2.report)):
        if report is not None and not report.ok:
            faults = list(report.faults)
            return f"{label}: {faults[0].message}" if faults else f"{label}: {report_text(report).splitlines()[0]}"
    return "verify passed"


def _plan_once(request: PlanRequest, progress: Progress | None = None) -> PartPlan:
    """:func:`plan_part` without the re-plans."""
    req = request
    if req.lang not in PROGRAM_SUFFIX:
        raise PlanningError(f"unknown robot program language {shown(req.lang)}: expected {', '.join(PROGRAM_SUFFIX)}",
                            source="lang")
    if req.ops not in (None, 1, 2):
        raise PlanningError(f"ops must be 1 or 2, got {shown(req.ops)}", source="ops")
    post_options = PostOptions(dialect=req.post, arc_tolerance=req.arc_tolerance)  # refused before the CAM work
    processors()  # and a bad FACTORY_THREADS
    robot_cell = req.cell if req.robot else None
    check_request(robot_cell, req.lang)  # the cell, its robot and the program language
    watch = Stopwatch(progress)  # every stage shows, the robot's planning too
    jaws = req.cam.jaws() if req.ops != 1 else None  # op 2 will hold the part turned over in them

    def refuse_early(setup: Setup, part_work: trimesh.Trimesh | None) -> None:
        check_setup(setup, req.grid, req.cam.part, robot_cell, part_work, req.cam.units, req.cam.tools)
        check_op2_grip(setup, part_work, jaws, req.cam.part, req.cam.tools)

    robot: BackgroundRobot | None = None
    # Each operation's arcs are fitted as soon as it is planned, as the rapid check will hand it to the
    # post (every operation from and to the safe height); posting takes a fit only for an operation that is
    # still that one (:class:`cadcam.post.FitAhead`). Verify of the first operations begins meanwhile, where
    # a processor is idle, fitting them itself (:class:`factory.verify.VerifyAhead`, made once the part is placed).
    ahead = FitAhead(post_options)
    verify_ahead: VerifyAhead | None = None

    def placed(setup: Setup, loaded: PartMesh, boundary: Boundary | None, part_work: trimesh.Trimesh) -> None:
        """Verify begun ahead from here on; the robot's share planned in a second process meanwhile
        (:mod:`factory.robotwork`)."""
        nonlocal robot, verify_ahead
        verify_ahead = VerifyAhead(ahead, post_options, _verify_options(req, boundary is not None),
                                   np.asarray(part_work.triangles), req.cam.part.stem, loaded.sha256)
        if not req.robot:
            return
        ops = req.ops if req.ops is not None else 1 if boundary is not None else 2
        outputs = dataclasses.replace(req, ops=ops).outputs(Path("."))
        # a relief leaves in its block: the robot holds the block
        vertices = (block_corners(setup) if boundary is not None
                    else np.asarray(loaded.mesh.vertices) / float(setup.mesh_scale))
        robot = BackgroundRobot(RobotTask(req.cell, stock_sheet(setup), str(outputs["setup_sheet"]), vertices, ops,
                                          req.ops is None, req.lang, outputs["robot_program"]), watch)

    def planning(operations: list[Operation], setup: Setup) -> None:  # (the part is placed before any is planned)
        verify_ahead.offer(operations, setup)

    def all_planned(operations: list[Operation], setup: Setup) -> None:
        verify_ahead.offer_all(operations, setup)

    try:
        return _plan_with(req, progress, watch, post_options,
                          compute_job(req.cam, progress, watch, check_setup=refuse_early, on_setup=placed,
                                      on_operations=planning, on_planned=all_planned),
                          robot, ahead, verify_ahead)
    finally:
        ahead.cancel()  # none left fitting for a plan that failed (taken: nothing to end)
        if verify_ahead is not None:
            verify_ahead.cancel()
        if robot is not None:
            robot.cancel()  # no robot left planning for a plan that failed (taken: nothing to end)


def _verify_options(req: PlanRequest, relief: bool) -> VerifyOptions:
    """How op 1 is verified: on the request's grid, stock left for op 2 where it follows (a relief stays in
    its block, right way up, unless asked)."""
    ops = req.ops if req.ops is not None else 1 if relief else 2
    return VerifyOptions(cell=req.grid, op2_follows=ops == 2, relief=relief)


def _plan_with(req: PlanRequest, progress: Progress | None, watch: Stopwatch, post_options: PostOptions,
               planned: PlannedPart, robot: BackgroundRobot | None, ahead: FitAhead | None = None,
               verify_ahead: VerifyAhead | None = None) -> PartPlan:
    """:func:`_plan_once` after the toolpaths: post, verify (on from what ``verify_ahead`` cut meanwhile),
    op 2. With a robot, all of it runs here while the robot's share is planned in its process (which reads
    the robot's meshes for the log too): this share is the longer."""
    job = planned.job
    options = _verify_options(req, planned.boundary is not None)
    if req.ops is None:  # a relief stays in its block, right way up, unless asked
        req = dataclasses.replace(req, ops=1 if planned.boundary is not None else 2)
    outputs = req.outputs(Path("."))
    # The pictures and the log's views of the job depend on neither the post, verify nor the robot: they are drawn
    # in a second process from here on (issue 35: they were most of the `write` stage), beside the wait for the
    # last round of verify ahead (this process idles there), verify and op 2, and the robot's planning if it
    # has not ended (one processor: drawn here, with a robot after verify, else when written).
    drawing = Background(drawn, planned) if processors() > 1 else None
    try:
        with watch("verify ahead"):  # a round under way fits operations the post needs: waited for first
            resume = verify_ahead.state(job.operations) if verify_ahead is not None else None
            # the last round's whole program, where it is this job's: neither posted nor parsed again
            posted = verify_ahead.posted(job) if verify_ahead is not None else None
        with watch("post"):
            program = post_process(job, post_options, ahead=ahead) if posted is None else posted[0]
            sheet = dataclasses.replace(setup_sheet(job, program, outputs["program"].name), op=1, work_offset="G54")
        with watch("verify"):
            verified = run_verify(program.text, str(outputs["program"]), job.setup, {t.number: t for t in job.tools},
                                  np.asarray(planned.part_work.triangles), options, held_open(progress),
                                  operations=sheet.operations, resume=resume,
                                  moves=None if posted is None else posted[1])
        op2 = op2_error = None
        if req.ops == 2:
            try:
                op2 = _plan_op2(req, planned, verified.simulation, outputs, progress, watch, verified.report)
            except FactoryError as e:
                if robot is None:
                    raise
                op2_error = e  # stands only if the robot turns the part over: its answer decides
        tending = drawn_ahead = None
        if robot is not None:
            work = robot.result(sheet)  # its errors after verify's and op 2's
            if drawing is None:
                with watch("pictures"):
                    pictures = drawn(planned)
            if work.dropped_op2 is not None:
                # Not asked for two operations, and the robot cannot turn this part over on the cell's
                # flip station: op 1 alone, said loudly (the holding allowance stays on the part).
                log.warning("%s: op 1 only, the holding allowance stays: the robot cannot turn the part over: %s",
                            req.cam.part, work.dropped_op2)
                req, op2, op2_error = dataclasses.replace(req, ops=1), None, None
                outputs = req.outputs(Path("."))
            if op2_error is not None:
                raise op2_error
            tending = _tending(robot, work)
            if drawing is None:
                with watch("log"):
                    drawn_ahead = write_ahead(planned, tending, pictures)
    except BaseException:
        if drawing is not None:
            drawing.cancel()  # no drawing left running for a plan that failed
        raise
    if drawing is not None:
        with watch("pictures and log"):  # the wait for the second process, if it is still drawing; the robot's
            drawn_ahead = write_ahead(planned, tending, drawing.result())  # cell and motion are a few ms
    if op2 is not None:
        sheet = dataclasses.replace(sheet, next={"program": outputs["program_op2"].name,
                                                 "setup_sheet": outputs["setup_sheet_op2"].name})
    return PartPlan(req, planned, program, sheet, tending, verified.simulation, verified.report,
                    dict(watch.seconds), op2, ahead=drawn_ahead)


def _tending(robot: BackgroundRobot, work: RobotWork) -> Tending:
    """The robot's load and unload from its finished ``work``, in its cell."""
    return Tending(robot.cell, robot.world, work.plan, work.program, work.visuals)


def _replan_op2(plan: PartPlan, cam: CamRequest, progress: Progress | None) -> PartPlan:
    """``plan`` with op 2 planned again with ``cam``'s options, from op 1's verified stock (op 1, its
    program, its robot program and its verdict kept); its wall times added to the plan's [s]."""
    req = dataclasses.replace(plan.request, cam=cam)
    watch = Stopwatch(progress)
    op2 = _plan_op2(req, plan.planned, plan.simulation, req.outputs(Path(".")), progress, watch, plan.report)
    seconds = dict(plan.seconds)
    for stage, s in watch.seconds.items():
        seconds[stage] = seconds.get(stage, 0.0) + s
    return dataclasses.replace(plan, request=req, op2=op2, seconds=seconds)


def _plan_op2(req: PlanRequest, planned: PlannedPart, op1_sim: Simulation, outputs: dict[str, Path],
              progress: Progress | None, watch: Stopwatch, op1_report: VerifyReport | None = None) -> SecondOp:
    """Op 2 planned, posted in G55 and verified from op 1's simulated stock turned over (with what op 1
    left on the part, ``op1_report``'s, that op 2 leaves too)."""
    job1 = planned.job
    with watch("op 2"):
        library = req.cam.library()
        # Op 1's verify simulation is op 2's starting stock: op 1 is not simulated again unless the bottom
        # has features to rest rough (planned on the coarser planning grid).
        try:
            job2, part2 = plan_op2(planned.part_work, job1, library, options=Op2Options(plan=req.cam.plan),
                                   op1_stock=op1_sim, jaws=req.cam.jaws())
        except SetupError as e:  # the part cannot be held for op 2: the part is what is wrong
            raise e.with_source(req.cam.part) from None
    with watch("op 2 post"):
        program2 = post_process(job2, PostOptions(dialect=req.post, arc_tolerance=req.arc_tolerance,
                                                  work_offset=WORK_OFFSET[2], program_number=1002))
        sheet2 = dataclasses.replace(setup_sheet(job2, program2, outputs["program_op2"].name),
                                     intake=job1.parameters.get("intake"),
                                     **op2_sheet_fields(job2, outputs["program"].name, outputs["setup_sheet"].name))
    with watch("op 2 verify"):
        verified2 = run_verify_after(op1_sim, flip_transform(job1.setup), program2.text,
                                         str(outputs["program_op2"]), job2.setup, {t.number: t for t in job2.tools},
                                         np.asarray(part2.triangles), VerifyOptions(cell=req.grid), progress,
                                         operations=sheet2.operations, op1=op1_report)
    # where op 2's walls meet op 1's (a depth split): a step over the tolerance fails op 2 as a fault does
    report2 = verified2.report
    if seam_faults(job2):
        report2 = dataclasses.replace(report2, faults=report2.faults + seam_faults(job2))
    return SecondOp(job2, part2, program2, sheet2, verified2.simulation, report2)


@contextlib.contextmanager
def _staging(out_dir: Path, stem: str):  # type: ignore[no-untyped-def]
    """A fresh hidden folder in ``out_dir`` for one part's output set, removed on the way out.

    The folder is named after this process, so a later run can tell a folder whose writer was
    killed (its process is gone) from one still being written, and remove it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    prefix = f".{stem}.plan-"
    for old in out_dir.glob(prefix + "*"):
        pid = old.name[len(prefix):].split(".")[0]
        if old.is_dir() and pid.isdigit() and not _alive(int(pid)):
            log.info("removing %s, left by an interrupted run", old)
            shutil.rmtree(old, ignore_errors=True)
    stage = Path(tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}.", dir=out_dir))
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
