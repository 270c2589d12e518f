"""``factory plan PART.stl -o DIR``: the one-shot: toolpaths, G-code, setup sheet, verify, robot program, MCAP."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cadcam.stock import Unreached
from cli import cam
from cli.common import EXIT_VERIFY_FAILED, JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, \
    setup_logging, stderr
from cli.gcode import ArcTolOpt, PostOpt
from factory.core.atomic import check_writable
from factory.plan import PROGRAM_SUFFIX, PlanRequest, plan_part
from factory.verify import report_text

#: Places no tool reaches named on stderr; the rest are counted (all are in the plan summary).
_UNREACHED_SHOWN = 5


@reports_errors
@cam.cam_options
def plan(
    part: Annotated[Path, typer.Argument(help="Part: STL, OBJ, 3MF, PLY or STEP (.step, .stp).", dir_okay=False)],
    out_dir: Annotated[Path, typer.Option("-o", "--output-dir", help="Folder for all outputs.", file_okay=False)] = Path("."),
    cam_flags: cam.CamFlags = cam.CamFlags(),
    post: PostOpt = PlanRequest.post,
    arc_tolerance: ArcTolOpt = PlanRequest.arc_tolerance,
    grid: Annotated[float, typer.Option("--grid", help="Verify grid spacing [mm].", min=0.01)] = PlanRequest.grid,
    robot_cell: Annotated[Path, typer.Option("--cell", help="Robot cell file for the load/unload program.", exists=True, dir_okay=False)] = PlanRequest.cell,
    robot: Annotated[bool, typer.Option("--robot/--no-robot", help="Plan loading and unloading with the robot cell.")] = PlanRequest.robot,
    lang: Annotated[str, typer.Option("--lang", help="Robot program language: urscript, rapid or krl.")] = PlanRequest.lang,
    ops: Annotated[int | None, typer.Option("--ops", help="2: op 1, then the part turned over and op 2 faces off the holding allowance (PART.op2.nc); 1: op 1 only. Default: 2 for a solid, 1 for a relief (a block not turned over).", min=1, max=2)] = PlanRequest.ops,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Plan a part end to end: G-code, setup sheet, verify report and picture, robot program, one MCAP.

    Every stage runs before any file is written, and the files appear as one set (the summary
    PART.plan.json last). Two operations by default: op 1 from the top (PART.nc, G54), then the
    part turned over about the jaw axis and op 2 facing off the holding allowance (PART.op2.nc,
    G55, PART.op2.setup.json). Exits 3 (after writing everything) when verification of either
    finds a gouge or a rapid crash.
    """
    setup_logging(quiet)
    req = cam_flags.request(part, robot_cell)
    if lang not in PROGRAM_SUFFIX:
        raise typer.BadParameter(f"expected one of {', '.join(PROGRAM_SUFFIX)}, got {lang!r}", param_hint="--lang")
    request = PlanRequest(req, post=post, arc_tolerance=arc_tolerance, grid=grid, cell=robot_cell, robot=robot,
                          lang=lang, ops=ops)
    for p in request.outputs(out_dir).values():  # before the work, not after it
        check_writable(p, overwrite)
    with progress_bars(quiet, lines_when_piped=True) as bars:  # a big part plans for minutes: show where
        planned = plan_part(request, bars)
        summary = planned.write(out_dir, overwrite=overwrite, progress=bars)
    if json_out:
        print_json(summary)
    elif not quiet:
        robot_text = f"; robot load+unload {summary['robot']['motion_s']:.1f} s" if summary["robot"] else ""
        if summary.get("intake"):  # a STEP part: what its B-rep gave
            got = summary["intake"]
            stderr.print(f"{part.name}: STEP in {got['units'] or got['unit']}, {got['brep_faces']} B-rep faces tessellated to "
                         f"{got['triangles']} triangles within {got['chordal_deviation_mm']:g} mm; "
                         f"{len(got['features']['holes'])} round holes read exactly", highlight=False, markup=False)
            if got.get("coarsened"):  # more triangles than planned in bounded time at the share asked
                stderr.print(f"{part.name}: {got['coarsened']['said']}", highlight=False, markup=False)
        holes = summary["holes"]
        if holes.get("holes"):
            stderr.print(f"{part.name}: {len(holes['holes'])} round holes, {len(holes['drilled'])} drilled, "
                         f"{len(holes['helixed'])} helixed", highlight=False, markup=False)
        if summary.get("relief"):
            stderr.print(f"{part.name}: {summary['relief']['found']}", highlight=False, markup=False)
        # The largest few name the places; a relief can leave scores of small spots, all in the summary.
        unreached = summary["unreached"]
        for u in unreached[:_UNREACHED_SHOWN]:
            stderr.print(f"{part.name}: no tool in the library reaches {Unreached(**u).describe()}: left uncut",
                         highlight=False, markup=False)
        if len(unreached) > _UNREACHED_SHOWN:
            stderr.print(f"{part.name}: and {len(unreached) - _UNREACHED_SHOWN} more places no tool reaches "
                         f"(listed in {Path(summary['outputs']['summary']).name})", highlight=False, markup=False)
        op1 = "op 1: " if planned.op2 is not None else ""
        verdict, _, left = report_text(planned.report).partition("\n")  # the regions left under the line
        stderr.print(f"{part.name}: {op1}{len(summary['operations'])} operations, {summary['lines']} lines, estimated "
                     f"{summary['estimated_cycle_s'] / 60:.1f} min; {verdict}{robot_text}" + (left and "\n" + left),
                     highlight=False, markup=False)
        if planned.op2 is not None:
            op2 = planned.op2
            for u in op2.job.parameters.get("unreached", [])[:_UNREACHED_SHOWN]:
                stderr.print(f"{part.name}: op 2: no tool in the library reaches {Unreached(**u).describe()} from "
                             f"below: left uncut", highlight=False, markup=False)
            stderr.print(f"{part.name}: op 2 (turned over about X, G55): {len(op2.job.operations)} operations, "
                         f"{op2.program.line_count} lines, estimated {op2.program.total_time / 60:.1f} min, faces "
                         f"{op2.job.parameters['holding_mm']:g} mm of holding allowance; {report_text(op2.report)}",
                         highlight=False, markup=False)
    elif not (planned.report.finished and (planned.op2 is None or planned.op2.report.finished) and planned.ok):
        # Quiet, but what changes the verdict is said: stock left on the part, a failed verify.
        for label, report in (("", planned.report), ("op 2: ", None if planned.op2 is None else planned.op2.report)):
            if report is not None and not (report.ok and report.finished):
                stderr.print(f"{part.name}: {label}{report_text(report)}", highlight=False, markup=False)
    if not planned.ok:
        raise typer.Exit(EXIT_VERIFY_FAILED)
