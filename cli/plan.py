"""``factory plan PART.stl -o DIR``: the one-shot: toolpaths, G-code, setup sheet, verify, one MCAP."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from cadcam.post import PostOptions
from cadcam.verify import VerifyOptions
from cli import cam
from cli.common import (EXIT_VERIFY_FAILED, JsonFlag, Overwrite, Quiet, Stopwatch, print_json, progress_bars,
                        reports_errors, setup_logging, stderr)
from cli.gcode import ArcTolOpt, PostOpt, program_summary, write_program
from cli.verify import log_simulation, report_text, run_verify, write_verify_outputs
from cadcam.preview import toolpath_image
from factory.atomic import check_writable, write_bytes, write_text
from factory.mcaplog import McapLog
from factory.pictures import png_bytes


def plan_outputs(part: Path, out_dir: Path) -> dict[str, Path]:
    """Every file ``factory plan`` writes for ``part`` into ``out_dir``."""
    stem = out_dir / part.stem
    return {
        "program": stem.with_suffix(".nc"),
        "setup_sheet": stem.with_suffix(".setup.json"),
        "mcap": stem.with_suffix(".mcap"),
        "verify_json": stem.with_suffix(".verify.json"),
        "verify_png": stem.with_suffix(".verify.png"),
        "toolpath_png": stem.with_suffix(".toolpath.png"),
        "summary": stem.with_suffix(".plan.json"),
    }


@reports_errors
def plan(
    part: Annotated[Path, typer.Argument(help="Part mesh: STL, OBJ, 3MF or PLY.", dir_okay=False)],
    out_dir: Annotated[Path, typer.Option("-o", "--output-dir", help="Folder for all outputs.", file_okay=False)] = Path("."),
    tools: cam.ToolsOpt = None,
    stock: cam.StockOpt = None,
    material: cam.MaterialOpt = "aluminium",
    units: cam.UnitsOpt = "auto",
    origin: cam.OriginOpt = "top-front-left",
    rough_tool: cam.RoughToolOpt = 1,
    finish_tool: cam.FinishToolOpt = 3,
    allowance: cam.AllowanceOpt = 0.3,
    scallop: cam.ScallopOpt = 0.005,
    stepdown: cam.StepdownOpt = None,
    waterline: cam.WaterlineOpt = True,
    post: PostOpt = "linuxcnc",
    arc_tolerance: ArcTolOpt = 0.002,
    cell: Annotated[float, typer.Option("--cell", help="Verify grid spacing [mm].", min=0.01)] = 0.2,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Plan a part end to end: G-code, setup sheet, verify report and picture, one MCAP.

    Exits 3 (after writing everything) when verification finds a gouge or a rapid crash.
    """
    setup_logging(quiet)
    req = cam.CamRequest.from_options(part, tools, stock, material, units, origin, rough_tool, finish_tool,
                                      allowance, scallop, stepdown, waterline)
    outputs = plan_outputs(part, out_dir)
    for p in outputs.values():
        check_writable(p, overwrite)

    watch = Stopwatch()
    with progress_bars(quiet) as bars:
        planned = cam.compute_job(req, bars, watch)
        with watch("post"):
            program, _ = write_program(
                planned.job, outputs["program"], PostOptions(dialect=post, arc_tolerance=arc_tolerance), overwrite
            )
        with watch("verify"):
            sim, report = run_verify(program.text, str(outputs["program"]), planned.job.setup,
                                     {t.number: t for t in planned.job.tools},
                                     np.asarray(planned.part_work.triangles), VerifyOptions(cell=cell), bars)
    with watch("write"):
        write_verify_outputs(sim, report, png=outputs["verify_png"], json_path=outputs["verify_json"], mcap=None,
                             overwrite=overwrite, inputs={})
        write_bytes(outputs["toolpath_png"], png_bytes(toolpath_image(planned.job)), overwrite=overwrite)
        with McapLog(outputs["mcap"], stage="plan", overwrite=overwrite,
                     inputs={str(part): planned.loaded.sha256}, parameters=planned.job.parameters) as log:
            cam.log_job(log, planned)
            log_simulation(log, sim)

    summary = {
        "part": str(part),
        "triangles": int(len(planned.loaded.mesh.faces)),
        "repairs": list(planned.loaded.repairs),
        "stock_mm": planned.job.setup.stock_size.round(3).tolist(),
        **program_summary(program, outputs["program"], outputs["setup_sheet"]),
        "verify": report.to_dict(),
        "seconds": watch.rounded(),
        "outputs": {k: str(v) for k, v in outputs.items()},
    }
    write_text(outputs["summary"], json.dumps(summary, indent=2) + "\n", overwrite=overwrite)
    if json_out:
        print_json(summary)
    elif not quiet:
        stderr.print(f"{part.name}: {len(planned.job.operations)} operations, {program.line_count} lines, "
                     f"estimated {program.total_time / 60:.1f} min; {report_text(report)}", highlight=False)
    if not report.ok:
        raise typer.Exit(EXIT_VERIFY_FAILED)
