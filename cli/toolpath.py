"""``factory toolpath PART.stl -o PART.toolpath.mcap``: compute the operations of a part."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli import cam
from cli.common import JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr
from factory.cam import compute_job, job_summary, log_job
from factory.core.atomic import check_writable, write_bytes
from factory.mcaplog import McapLog
from factory.pictures import png_bytes
from factory.core.progress import Stopwatch


@reports_errors
@cam.cam_options
def toolpath(
    part: Annotated[Path, typer.Argument(help="Part: STL, OBJ, 3MF, PLY or STEP (.step, .stp).", dir_okay=False)],
    output: Annotated[Path, typer.Option("-o", "--output", help="Toolpath MCAP to write.", dir_okay=False)],
    png: Annotated[Path | None, typer.Option("--png", help="Also write a top-view picture of the toolpaths.", dir_okay=False)] = None,
    cam_flags: cam.CamFlags = cam.CamFlags(),
    cell: cam.CellOpt = cam.CELL,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Rough and finish a part; write the job and its views to an MCAP file."""
    setup_logging(quiet)
    req = cam_flags.request(part, cell)
    check_writable(output, overwrite)
    if png is not None:
        check_writable(png, overwrite)
    watch = Stopwatch()
    with progress_bars(quiet) as bars:
        planned = compute_job(req, bars, watch)
    with watch("write"):
        with McapLog(output, stage="toolpath", overwrite=overwrite,
                     inputs={str(part): planned.loaded.sha256},
                     parameters=planned.job.parameters) as log:
            log_job(log, planned)
        if png is not None:
            write_bytes(png, png_bytes(planned.toolpath_picture()), overwrite=overwrite)
    summary = job_summary(planned.job) | {"output": str(output), "seconds": watch.rounded()}
    if json_out:
        print_json(summary)
    elif not quiet:
        for op in summary["operations"]:
            stderr.print(f"{op['name']}: T{op['tool']}, {op['points']} points, cut {op['cut_mm']:.0f} mm")
