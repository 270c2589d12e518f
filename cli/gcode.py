"""``factory gcode PART.toolpath.mcap -o PART.nc``: post a job for a controller, with its setup sheet."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Literal

import typer

from cadcam.model import Job
from cadcam.post import PostOptions, Program, post_process
from cadcam.sheet import setup_sheet
from cli.common import JsonFlag, Overwrite, Quiet, print_json, reports_errors, setup_logging, stderr
from factory.core.atomic import check_writable, write_text
from factory.cam import read_job

Dialect = Literal["linuxcnc", "grbl", "fanuc"]
PostOpt = Annotated[Dialect, typer.Option("--post", help="Controller dialect.")]
ArcTolOpt = Annotated[float, typer.Option("--arc-tolerance", help="Arc and line fitting tolerance [mm].", min=1e-5)]


def setup_sheet_path(program: Path) -> Path:
    """``DIR/PART.nc`` → ``DIR/PART.setup.json``."""
    return program.with_suffix(".setup.json")


def write_program(job: Job, output: Path, options: PostOptions, overwrite: bool) -> tuple[Program, Path]:
    """Post ``job`` and write the program and its setup sheet beside it (both or neither)."""
    sheet_path = setup_sheet_path(output)
    check_writable(output, overwrite)
    check_writable(sheet_path, overwrite)
    program = post_process(job, options)
    sheet = setup_sheet(job, program, output.name)
    write_text(sheet_path, json.dumps(sheet.to_json(), indent=2) + "\n", overwrite=overwrite)
    write_text(output, program.text, overwrite=overwrite)
    return program, sheet_path


@reports_errors
def gcode(
    toolpath: Annotated[Path, typer.Argument(help="Toolpath MCAP from `factory toolpath`.", exists=True, dir_okay=False)],
    output: Annotated[Path, typer.Option("-o", "--output", help="G-code file; PART.setup.json is written beside it.", dir_okay=False)],
    post: PostOpt = "linuxcnc",
    arc_tolerance: ArcTolOpt = 0.002,
    coolant: Annotated[bool, typer.Option("--coolant/--no-coolant", help="Flood coolant on while cutting.")] = True,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Write G-code for a controller and the setup sheet beside it."""
    setup_logging(quiet)
    job = read_job(toolpath)
    program, sheet_path = write_program(
        job, output, PostOptions(dialect=post, arc_tolerance=arc_tolerance, coolant=coolant), overwrite
    )
    # Here, not at the top: factory.plan brings the robot's libraries (Pinocchio), which G-code never needs.
    from factory.plan import program_summary

    summary = program_summary(program, output, sheet_path)
    if json_out:
        print_json(summary)
    elif not quiet:
        stderr.print(f"{output}: {program.line_count} lines, estimated {program.total_time / 60:.1f} min")
