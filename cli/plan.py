"""``factory plan PART.stl -o DIR``: the one-shot: toolpaths, G-code, setup sheet, verify, robot program, MCAP."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from cadcam.post import PostOptions, post_process
from cadcam.preview import toolpath_image
from cadcam.sheet import setup_sheet
from cadcam.verify import VerifyOptions, VerifyReport
from cli import cam
from cli.catalog import catalog_record
from cli.common import (EXIT_VERIFY_FAILED, JsonFlag, Overwrite, Quiet, StageProgress, Stopwatch, print_json,
                        progress_bars, reports_errors, setup_logging, sha256_file, stderr)
from cli.gcode import ArcTolOpt, PostOpt, program_summary
from cli.robot import log_tending, plan_cell
from cli.verify import log_simulation, report_text, run_verify, write_verify_outputs
from factory.atomic import check_writable, write_bytes, write_text
from factory.mcaplog import McapLog
from factory.pictures import png_bytes
from factory.resources import FIXTURES
from robotprog.programs import post_program


#: Robot program file ending per language.
PROGRAM_SUFFIX = {"urscript": ".script", "rapid": ".mod", "krl": ".src"}


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
        "summary": stem.with_suffix(".plan.json"),
    }
    if robot_lang is not None:
        outputs["robot_program"] = stem.with_suffix(PROGRAM_SUFFIX[robot_lang])
        if robot_lang == "krl":
            outputs["robot_program_dat"] = stem.with_suffix(".dat")
    return outputs


@dataclasses.dataclass(frozen=True)
class PlanRequest:
    """Everything ``factory plan`` needs besides the output folder.

    ``grid`` is the verify grid spacing [mm]; ``arc_tolerance`` [mm]; ``cell`` the robot cell
    file, used when ``robot`` is true."""

    cam: cam.CamRequest
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
        return cls(cam.CamRequest.defaults(part, material, tools), cell=cell)

    def outputs(self, out_dir: Path) -> dict[str, Path]:
        return plan_outputs(self.cam.part, out_dir, self.lang if self.robot else None)


def run_plan(req: PlanRequest, out_dir: Path, *, overwrite: bool, bars: StageProgress,
             watch: Stopwatch) -> tuple[dict[str, Any], VerifyReport]:
    """Plan a part and write every output; returns the ``PART.plan.json`` summary and the verify report.

    Every stage runs before anything is written: a stage that fails leaves no files.

    Raises
    ------
    FactoryError
        Any stage's error (bad mesh, unknown tool or material, unreachable part, ...), or an
        output that exists without ``overwrite``.
    """
    part = req.cam.part
    outputs = req.outputs(out_dir)
    for p in outputs.values():
        check_writable(p, overwrite)

    planned = cam.compute_job(req.cam, bars, watch)
    job = planned.job
    with watch("post"):
        program = post_process(job, PostOptions(dialect=req.post, arc_tolerance=req.arc_tolerance))
        sheet = setup_sheet(job, program, outputs["program"].name)
    tending = None
    if req.robot:
        vertices = np.asarray(planned.loaded.mesh.vertices) / float(job.setup.mesh_scale)
        tending = plan_cell(req.cell, sheet, str(outputs["setup_sheet"]), vertices, watch)
        posted = post_program(req.lang, outputs["robot_program"], *tending)
    with watch("verify"):
        sim, report = run_verify(program.text, str(outputs["program"]), job.setup,
                                 {t.number: t for t in job.tools},
                                 np.asarray(planned.part_work.triangles), VerifyOptions(cell=req.grid), bars)
    with watch("write"):
        write_text(outputs["setup_sheet"], json.dumps(sheet, indent=2) + "\n", overwrite=overwrite)
        write_text(outputs["program"], program.text, overwrite=overwrite)
        write_verify_outputs(sim, report, png=outputs["verify_png"], json_path=outputs["verify_json"], mcap=None,
                             overwrite=overwrite, inputs={})
        write_bytes(outputs["toolpath_png"], png_bytes(toolpath_image(job)), overwrite=overwrite)
        inputs = {str(part): planned.loaded.sha256}
        parameters = dict(job.parameters)
        if tending is not None:
            inputs[str(req.cell)] = sha256_file(req.cell)
            parameters["robot"] = {"cell": tending[0].name, "robot": tending[1].robot.name,
                                   "durations_s": {n: round(d, 4) for n, d in tending[2].durations},
                                   "program_duration_s": round(posted.predicted_s, 4)}
            for path, text in posted.texts.items():
                write_text(path, text, overwrite=overwrite)
        # One log of the whole plan: with a robot, the work frame sits in the cell's vise.
        with McapLog(outputs["mcap"], stage="plan", overwrite=overwrite, inputs=inputs,
                     parameters=parameters) as log:
            world_work = None
            if tending is not None:
                cell, _, tplan = tending
                world_work = cell.vise.pose.matrix() @ tplan.stock.transform_vise_to_work
            cam.log_job(log, planned, world_work)
            log_simulation(log, sim)
            if tending is not None:
                log_tending(log, *tending)

    tools_path = req.cam.tools or FIXTURES / "tools.yaml"
    summary = {
        "part": str(part),
        "catalog": catalog_record(planned.loaded.sha256, req.cam.material,
                                  sha256_file(req.cell) if tending is not None else None, sha256_file(tools_path)),
        "triangles": int(len(planned.loaded.mesh.faces)),
        "repairs": list(planned.loaded.repairs),
        "stock_mm": planned.job.setup.stock_size.round(3).tolist(),
        **program_summary(program, outputs["program"], outputs["setup_sheet"]),
        "verify": report.to_dict(),
        "robot": None if tending is None else {
            "cell": tending[0].name, "robot": tending[1].robot.name, "motion_s": round(tending[2].duration, 3),
            "program_s": round(posted.predicted_s, 3), "program_targets": posted.targets,
            "moves": [{"name": n, "duration_s": round(d, 3)} for n, d in tending[2].durations]},
        "seconds": watch.rounded(),
        "outputs": {k: str(v) for k, v in outputs.items()},
    }
    write_text(outputs["summary"], json.dumps(summary, indent=2) + "\n", overwrite=overwrite)
    return summary, report


@reports_errors
def plan(
    part: Annotated[Path, typer.Argument(help="Part mesh: STL, OBJ, 3MF or PLY.", dir_okay=False)],
    out_dir: Annotated[Path, typer.Option("-o", "--output-dir", help="Folder for all outputs.", file_okay=False)] = Path("."),
    tools: cam.ToolsOpt = None,
    stock: cam.StockOpt = None,
    material: cam.MaterialOpt = cam.MATERIAL,
    units: cam.UnitsOpt = cam.UNITS,
    origin: cam.OriginOpt = cam.ORIGIN,
    rough_tool: cam.RoughToolOpt = cam.ROUGH_TOOL,
    finish_tool: cam.FinishToolOpt = cam.FINISH_TOOL,
    allowance: cam.AllowanceOpt = cam.ALLOWANCE,
    scallop: cam.ScallopOpt = cam.SCALLOP,
    stepdown: cam.StepdownOpt = None,
    waterline: cam.WaterlineOpt = True,
    post: PostOpt = PlanRequest.post,
    arc_tolerance: ArcTolOpt = PlanRequest.arc_tolerance,
    grid: Annotated[float, typer.Option("--grid", help="Verify grid spacing [mm].", min=0.01)] = PlanRequest.grid,
    robot_cell: Annotated[Path, typer.Option("--cell", help="Robot cell file for the load/unload program.", exists=True, dir_okay=False)] = PlanRequest.cell,
    robot: Annotated[bool, typer.Option("--robot/--no-robot", help="Plan loading and unloading with the robot cell.")] = PlanRequest.robot,
    lang: Annotated[str, typer.Option("--lang", help="Robot program language: urscript, rapid or krl.")] = PlanRequest.lang,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Plan a part end to end: G-code, setup sheet, verify report and picture, robot program, one MCAP.

    Exits 3 (after writing everything) when verification finds a gouge or a rapid crash.
    """
    setup_logging(quiet)
    req = cam.CamRequest.from_options(part, tools, stock, material, units, origin, rough_tool, finish_tool,
                                      allowance, scallop, stepdown, waterline)
    if lang not in PROGRAM_SUFFIX:
        raise typer.BadParameter(f"expected one of {', '.join(PROGRAM_SUFFIX)}, got {lang!r}", param_hint="--lang")
    request = PlanRequest(req, post=post, arc_tolerance=arc_tolerance, grid=grid, cell=robot_cell, robot=robot,
                          lang=lang)
    watch = Stopwatch()
    with progress_bars(quiet) as bars:
        summary, report = run_plan(request, out_dir, overwrite=overwrite, bars=bars, watch=watch)
    if json_out:
        print_json(summary)
    elif not quiet:
        robot_text = f"; robot load+unload {summary['robot']['motion_s']:.1f} s" if summary["robot"] else ""
        stderr.print(f"{part.name}: {len(summary['operations'])} operations, {summary['lines']} lines, estimated "
                     f"{summary['estimated_cycle_s'] / 60:.1f} min; {report_text(report)}{robot_text}",
                     highlight=False, markup=False)
    if not report.ok:
        raise typer.Exit(EXIT_VERIFY_FAILED)
