"""``factory verify PART.nc --setup PART.setup.json --part PART.stl``: prove a program never gouges."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cadcam.verify import VerifyOptions
from cli.common import (EXIT_VERIFY_FAILED, Overwrite, Quiet, print_json, progress_bars, reports_errors,
                        setup_logging, stderr)
from factory.atomic import check_writable
from factory.errors import VerifyError
from factory.verify import part_triangles, read_sheet, report_text, run_verify, write_verify_outputs


@reports_errors
def verify(
    program: Annotated[Path, typer.Argument(help="G-code program.", exists=True, dir_okay=False)],
    setup_path: Annotated[Path, typer.Option("--setup", help="Setup sheet written by `factory gcode`.", exists=True, dir_okay=False)],
    part: Annotated[Path, typer.Option("--part", help="The part mesh the program was made for.", exists=True, dir_okay=False)],
    png: Annotated[Path | None, typer.Option("--png", help="Write a deviation map picture.", dir_okay=False)] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the report as JSON ('-' for stdout).")] = None,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write the simulated stock to MCAP.", dir_okay=False)] = None,
    grid: Annotated[float, typer.Option("--grid", help="Simulation grid spacing [mm].", min=0.01)] = 0.2,
    tolerance: Annotated[float, typer.Option("--tolerance", help="Cuts deeper into the part than this are gouges [mm].", min=0.0)] = 0.01,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
) -> None:
    """Simulate material removal; report gouges, remaining stock and rapid crashes.

    Exits 3 when the program gouges the part, a rapid or the shank or holder meets stock, a
    tool is engaged deeper than its flutes (a finishing tool: deeper than the allowance plus
    the roughing terraces), a tool goes below the stock bottom, or nothing is cut.
    """
    setup_logging(quiet)
    outputs = [p for p in (png, mcap) if p is not None] + ([json_path] if json_path and str(json_path) != "-" else [])
    for p in outputs:
        check_writable(p, overwrite)
    setup, tools, sheet = read_sheet(setup_path)
    triangles = part_triangles(part, setup, sheet.get("source_sha256", ""))
    try:
        text = program.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise VerifyError(f"cannot read program: {e}", source=program) from None
    options = VerifyOptions(cell=grid, gouge_tolerance=tolerance)
    with progress_bars(quiet) as bars:
        sim, report = run_verify(text, str(program), setup, tools, triangles, options, bars,
                                 operations=sheet.get("operations") or ())
    to_stdout = json_path is not None and str(json_path) == "-"
    write_verify_outputs(sim, report, png=png, json_path=None if to_stdout else json_path, mcap=mcap,
                         overwrite=overwrite, inputs={str(program): "", str(part): ""})
    if to_stdout:
        print_json(report.to_dict())
    if not quiet:
        stderr.print(report_text(report), highlight=False)
    if not report.ok:
        raise typer.Exit(EXIT_VERIFY_FAILED)
