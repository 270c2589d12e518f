"""``factory gcode PART.toolpath.mcap -o PART.nc``: post a job for a controller, with its setup sheet and,
for LinuxCNC, its tool table (``PART.tbl``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from cadcam.model import Job
from cadcam.post import DialectName, PostOptions, Program, post_process, tool_table_file
from cadcam.sheet import setup_sheet
from cli.common import JsonFlag, Overwrite, Quiet, print_json, reports_errors, setup_logging, stderr
from factory.core.atomic import check_writable, write_text
from factory.cam import read_job

PostOpt = Annotated[DialectName, typer.Option("--post", help="Controller dialect.")]
ArcTolOpt = Annotated[float, typer.Option("--arc-tolerance", help="Arc and line fitting tolerance [mm].", min=1e-5)]


def setup_sheet_path(program: Path) -> Path:
    """``DIR/PART.nc`` → ``DIR/PART.setup.json``."""
    return program.with_suffix(".setup.json")


def tool_table_path(program: Path) -> Path:
    """``DIR/PART.nc`` → ``DIR/PART.tbl``: the tool table of the job, for a controller that reads one."""
    return program.with_suffix(".tbl")


def write_program(job: Job, output: Path, options: PostOptions, overwrite: bool) -> tuple[Program, Path]:
    """Post ``job`` and write the program, its setup sheet and, when the controller reads one (LinuxCNC),
    its tool table beside it (all or none)."""
    sheet_path = setup_sheet_path(output)
    table = tool_table_file(options, job.tools)
    check_writable(output, overwrite)
    check_writable(sheet_path, overwrite)
    if table is not None:
        check_writable(tool_table_path(output), overwrite)
    program = post_process(job, options)
    sheet = setup_sheet(job, program, output.name)
    if table is not None:
        write_text(tool_table_path(output), table, overwrite=overwrite)
    write_text(sheet_path, json.dumps(sheet.to_json(), indent=2) + "\n", overwrite=overwrite)
    write_text(output, program.text, overwrite=overwrite)
    return program, sheet_path


@reports_errors
def gcode(
    toolpath: Annotated[Path, typer.Argument(help="Toolpath MCAP from `factory toolpath`.", exists=True, dir_okay=False)],
    output: Annotated[Path, typer.Option("-o", "--output", dir_okay=False,
                                         help="G-code file; PART.setup.json is written beside it, and for "
                                              "--post linuxcnc the tool table PART.tbl.")],
    post: PostOpt = "linuxcnc",
    arc_tolerance: ArcTolOpt = 0.002,
    coolant: Annotated[bool, typer.Option("--coolant/--no-coolant", help="Flood coolant on while cutting.")] = True,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Write G-code for a controller and the setup sheet beside it (and LinuxCNC's tool table)."""
    setup_logging(quiet)
    job = read_job(toolpath)
    options = PostOptions(dialect=post, arc_tolerance=arc_tolerance, coolant=coolant)
    program, sheet_path = write_program(job, output, options, overwrite)
    # Here, not at the top: factory.plan brings the robot's libraries (Pinocchio), which G-code never needs.
    from factory.plan import program_summary

    summary = program_summary(program, output, sheet_path)
    if options.controller.tool_table is not None:
        summary["tool_table"] = str(tool_table_path(output))
    if json_out:
        print_json(summary)
    elif not quiet:
        stderr.print(f"{output}: {program.line_count} lines, estimated {program.total_time / 60:.1f} min")
