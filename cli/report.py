"""``factory report RECORD [--png P.png] [--json]``: what a process record says about the cell.

The figures are :func:`factory.report.cell_report`'s (definitions there: OEE, cycle time, Pareto);
this command opens the record read-only, prints them, and draws the one-page dashboard.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cli.common import JsonFlag, Overwrite, print_json, reports_errors, setup_logging
from factory.core.atomic import check_writable, write_bytes
from factory.pictures import png_bytes
from factory.record import Record
from factory.report import cell_report, dashboard, report_text


@reports_errors
def report(
    record: Annotated[str, typer.Argument(metavar="RECORD", help="The process record `factory simulate --db` wrote: a SQLite file or a SQLAlchemy database URL.")],
    png: Annotated[Path | None, typer.Option("--png", help="Write a one-page dashboard picture.", dir_okay=False)] = None,
    run: Annotated[list[int] | None, typer.Option("--run", metavar="ID", help="Only this run (repeat for several); default every run.")] = None,
    serial: Annotated[str | None, typer.Option("--serial", metavar="SERIAL", help="Print this part's whole history instead of the parts table.")] = None,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
) -> None:
    """Throughput, OEE (availability x performance x quality), cycle times, an alarm Pareto and
    every part by serial, from a process record."""
    setup_logging(quiet=False)
    if png is not None:
        check_writable(png, overwrite)
    with Record(record, write=False) as rec:
        doc = cell_report(rec, run)
    text = report_text(doc, serial)  # also checks --serial
    if png is not None:
        write_bytes(png, png_bytes(dashboard(doc)), overwrite=overwrite)
    if json_out:
        print_json(doc)
    else:
        typer.echo(text)
