"""The ``factory`` command: one sub-command per stage, each reading and writing files."""

from __future__ import annotations

import typer

from cli.calibrate import calibrate
from cli.gcode import gcode
from cli.handeye import handeye
from cli.inspect import inspect
from cli.locate import locate
from cli.plan import plan
from cli.report import report
from cli.robot import robot
from cli.simulate import simulate
from cli.toolpath import toolpath
from cli.verify import verify

app = typer.Typer(
    name="factory",
    help="From a part's CAD mesh to a running robotic machining cell.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Help texts carry units in brackets ("[mm]"); rich markup would swallow them as tags.
    rich_markup_mode=None,
)
app.command()(toolpath)
app.command()(gcode)
app.command()(verify)
app.command()(plan)
app.command()(calibrate)
app.command()(robot)
app.command()(handeye)
app.command()(locate)
app.command()(inspect)
app.command()(simulate)
app.command()(report)


def main() -> None:
    app()
