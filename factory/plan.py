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

from cadcam.post import PostOptions, Program, post_process
from cadcam.preview import toolpath_image
from cadcam.sheet import setup_sheet
from cadcam.verify import Simulation, VerifyOptions, VerifyReport
from factory.atomic import check_writable, write_bytes, write_text
from factory.cam import CamRequest, PlannedPart, compute_job, log_job
from factory.catalog import catalog_record, sha256_file
from factory.mcaplog import McapLog
from factory.pictures import png_bytes
from factory.progress import Progress, Stopwatch
from factory.resources import FIXTURES
from factory.tending import log_tending, plan_cell
from factory.verify import log_simulation, run_verify, write_verify_outputs
from robotprog.cell import Cell
from robotprog.collision import CollisionWorld
from robotprog.programs import PostedProgram, post_program
from robotprog.tending import TendingPlan

log = logging.getLogger(__name__)

#: Robot program file ending per language.
PROGRAM_SUFFIX = {"urscript": ".script", "rapid": ".mod", "krl": ".src"}
#: Name of the summary file, the commit marker of an output set, relative to the part's stem.
SUMMARY_SUFFIX = ".plan.json"


def plan_outputs(part: Path, out_dir: Path, robot_lang: str | None = "urscript") -> dict[str, Path]:
    """Every file ``factory plan`` writes for ``part`` into ``out_dir`` (no robot files for ``None``)."""
    stem = out_dir / part.stem
    outputs = {
        "program": stem.with_suffix(".nc"),
        "setup_sheet": stem.with_suffix(".setup.json"),
        "mcap": stem.with_suffix(".mcap"),
        "verify_json": stem.with_suffix(".verify.json"),
        "verify_png": stem.with_suffix(".verify.png"),
        "toolpath_png": stem.with_suffix(".toolpath.png"),
        "summary": stem.with_suffix(SUMMARY_SUFFIX),
    }
    if robot_lang is not None:
        outputs["robot_program"] = stem.with_suffix(PROGRAM_SUFFIX[robot_lang])
        if robot_lang == "krl":
            outputs["robot_program_dat"] = stem.with_suffix(".dat")
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
    """

    cam: CamRequest
    post: str = "linuxcnc"
    arc_tolerance: float = 0.002
    grid: float = 0.2
    cell: Path = FIXTURES / "cell.yaml"
    robot: bool = True
    lang: str = "urscript"

    @classmethod
    def defaults(cls, part: Path, material: str, cell: Path = FIXTURES / "cell.yaml",
                 tools: Path | None = None) -> "PlanRequest":
        """The plan ``factory plan PART --material M --cell C`` makes with every other option at its default."""
        return cls(CamRequest.defaults(part, material, tools, cell), cell=cell)

    def outputs(self, out_dir: Path) -> dict[str, Path]:
        """Every file :meth:`PartPlan.write` writes into ``out_dir``."""
        return plan_outputs(self.cam.part, out_dir, self.lang if self.robot else None)


@dataclasses.dataclass(frozen=True)
class Tending:
    """The robot's load and unload of one part: the cell, its collision world, the timed plan,
    and the posted robot program (its texts keyed by file name: KRL has a ``.src`` and a ``.dat``)."""

    cell: Cell
    world: CollisionWorld
    plan: TendingPlan
    program: PostedProgram

    @property
    def programs(self) -> dict[str, str]:
        """File name -> text of the robot program."""
        return {path.name: text for path, text in self.program.texts.items()}


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
    setup_sheet : dict
        The setup sheet document (``PART.setup.json``).
    tending : Tending or None
        The robot's load and unload, None when planned without a robot.
    simulation : Simulation
        The verify material-removal simulation of the program.
    report : VerifyReport
        Its verdict: gouges, remaining stock, rapid crashes.
    seconds : dict
        Wall time per stage [s].
    """

    request: PlanRequest
    planned: PlannedPart
    program: Program
    setup_sheet: dict[str, Any]
    tending: Tending | None
    simulation: Simulation
    report: VerifyReport
    seconds: dict[str, float]

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
            "stock_mm": job.setup.stock_size.round(3).tolist(),
            **program_summary(self.program, outputs["program"], outputs["setup_sheet"]),
            # what no tool in the library reaches: left in place, and finishing stays out of it [mm]
            "unreached": list(job.parameters.get("unreached", [])),
            "rapids": job.parameters.get("rapids"),
            "verify": self.report.to_dict(),
            "robot": None if tending is None else {
                "cell": tending.cell.name, "robot": tending.world.robot.name,
                "motion_s": round(tending.plan.duration, 3),
                "program_s": round(tending.program.predicted_s, 3), "program_targets": tending.program.targets,
                "moves": [{"name": n, "duration_s": round(d, 3)} for n, d in tending.plan.durations]},
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
            "outputs": {k: str(v) for k, v in outputs.items()},
        }

    def write(self, out_dir: Path, *, overwrite: bool = False) -> dict[str, Any]:
        """Write every output into ``out_dir`` as one set, the summary last; returns the summary.

        Raises
        ------
        OutputExistsError
            An output exists and ``overwrite`` is false (checked before anything is written).
        """
        final = self.request.outputs(out_dir)
        for p in final.values():
            check_writable(p, overwrite)
        watch = Stopwatch()
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
        write_text(outputs["setup_sheet"], json.dumps(self.setup_sheet, indent=2) + "\n")
        write_text(outputs["program"], self.program.text)
        write_verify_outputs(self.simulation, self.report, png=outputs["verify_png"], json_path=outputs["verify_json"],
                             mcap=None, overwrite=False, inputs={})
        write_bytes(outputs["toolpath_png"], png_bytes(toolpath_image(job)))
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
            world_work = None
            if tending is not None:
                world_work = tending.cell.vise.pose.matrix() @ tending.plan.stock.transform_vise_to_work
            log_job(m, planned, world_work)
            log_simulation(m, self.simulation)
            if tending is not None:
                log_tending(m, tending.cell, tending.world, tending.plan)


def plan_part(request: PlanRequest, progress: Progress | None = None) -> PartPlan:
    """Plan a part: CAM, post, setup sheet, robot load/unload and program, verify. Writes nothing.

    Raises
    ------
    FactoryError
        Any stage's error: a bad mesh, an unknown tool or material, an unreachable part, a cell
        the robot cannot tend.
    """
    req = request
    if req.lang not in PROGRAM_SUFFIX:
        raise ValueError(f"unknown robot program language {req.lang!r}")
    watch = Stopwatch()
    planned = compute_job(req.cam, progress, watch)
    job = planned.job
    outputs = req.outputs(Path("."))
    with watch("post"):
        program = post_process(job, PostOptions(dialect=req.post, arc_tolerance=req.arc_tolerance))
        sheet = setup_sheet(job, program, outputs["program"].name)
    tending = None
    if req.robot:
        vertices = np.asarray(planned.loaded.mesh.vertices) / float(job.setup.mesh_scale)
        cell, world, tplan = plan_cell(req.cell, sheet, str(outputs["setup_sheet"]), vertices, watch)
        tending = Tending(cell, world, tplan, post_program(req.lang, outputs["robot_program"], cell, world, tplan))
    with watch("verify"):
        sim, report = run_verify(program.text, str(outputs["program"]), job.setup,
                                 {t.number: t for t in job.tools},
                                 np.asarray(planned.part_work.triangles), VerifyOptions(cell=req.grid), progress,
                                 operations=sheet.get("operations") or ())
    return PartPlan(req, planned, program, sheet, tending, sim, report, dict(watch.seconds))


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
