"""``factory verify PART.nc --setup PART.setup.json --part PART.stl``: prove a program never gouges.

Op 2 (``PART.op2.nc`` with ``PART.op2.setup.json``) runs on what op 1 left, turned over: its
sheet names op 1's program and sheet, which are simulated first (``--after`` gives another
op-1 program); the verdict covers both.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import typer

from cadcam.verify import VerifyOptions
from cli.common import (EXIT_VERIFY_FAILED, JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors,
                        setup_logging, stderr)
from factory.core.atomic import check_writable
from factory.core.errors import VerifyError
from factory.verify import (flip_of, op1_of, part_triangles, read_sheet, report_text, run_verify, run_verify_after,
                            write_verify_outputs)


def _read(program: Path) -> str:
    try:
        return program.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise VerifyError(f"cannot read program: {e}", source=program) from None


@reports_errors
def verify(
    program: Annotated[Path, typer.Argument(help="G-code program.", exists=True, dir_okay=False)],
    setup_path: Annotated[Path, typer.Option("--setup", help="Setup sheet written by `factory gcode`.", exists=True, dir_okay=False)],
    part: Annotated[Path, typer.Option("--part", help="The part mesh the program was made for.", exists=True, dir_okay=False)],
    after: Annotated[Path | None, typer.Option("--after", help="Op 2 only: op 1's program, simulated first (default: the one the op-2 setup sheet names).", exists=True, dir_okay=False)] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write a deviation map picture.", dir_okay=False)] = None,
    json_path: Annotated[Path | None, typer.Option("-o", "--output", help="Write the report as JSON to this file.", dir_okay=False)] = None,
    as_json: JsonFlag = False,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write the simulated stock to MCAP.", dir_okay=False)] = None,
    grid: Annotated[float, typer.Option("--grid", help="Simulation grid spacing [mm].", min=0.01)] = 0.2,
    tolerance: Annotated[float, typer.Option("--tolerance", help="Cuts deeper into the part than this are gouges [mm].", min=0.0)] = 0.01,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
) -> None:
    """Simulate material removal; report gouges, remaining stock and rapid crashes.

    Exits 3 when the program gouges the part, a rapid or the shank or holder meets stock, a
    tool is engaged deeper than its flutes (a finishing tool: deeper than the allowance plus
    the roughing terraces) or deeper than its axial limit at full width (a slot, an inside
    corner), a tool goes below the stock bottom, or nothing is cut. For op 2
    the report, picture and MCAP are op 2's, and op 1 failing fails the command too.
    """
    setup_logging(quiet)
    outputs = [p for p in (png, mcap, json_path) if p is not None]
    for p in outputs:
        check_writable(p, overwrite)
    read = read_sheet(setup_path)
    setup, tools, sheet = read.setup, read.tools, read.sheet
    first = op1_of(sheet, setup_path, after)
    triangles = part_triangles(part, setup, sheet.source_sha256, sheet.intake, tolerance)
    text = _read(program)
    options = VerifyOptions(cell=grid, gouge_tolerance=tolerance, relief=sheet.relief is not None)
    before_ok = True
    with progress_bars(quiet) as bars:
        if first is None:
            verified = run_verify(text, str(program), setup, tools, triangles,
                                  dataclasses.replace(options, op2_follows=sheet.next is not None), bars,
                                  operations=sheet.operations)
        else:
            program1, sheet1_path = first
            op1 = read_sheet(sheet1_path)
            verified1 = run_verify(_read(program1), str(program1), op1.setup, op1.tools,
                                   part_triangles(part, op1.setup, op1.sheet.source_sha256, op1.sheet.intake,
                                                  tolerance),
                                   dataclasses.replace(options, op2_follows=True), bars,
                                   operations=op1.sheet.operations)
            before_ok = verified1.report.ok
            if not quiet:
                stderr.print(f"op 1 ({program1.name}): {report_text(verified1.report)}", highlight=False,
                             markup=False)
            verified = run_verify_after(verified1.simulation, flip_of(sheet, setup_path), text, str(program), setup,
                                        tools, triangles, options, bars, operations=sheet.operations,
                                        op1=verified1.report)
    report = verified.report
    write_verify_outputs(verified.simulation, report, png=png, json_path=json_path, mcap=mcap,
                         overwrite=overwrite, inputs={str(program): "", str(part): ""},
                         relief=triangles if sheet.relief is not None else None)
    if as_json:
        print_json(report.to_dict())
    if not quiet:
        label = "" if first is None else f"op 2 ({program.name}): "
        stderr.print(label + report_text(report), highlight=False)
    if not (report.ok and before_ok):
        raise typer.Exit(EXIT_VERIFY_FAILED)
