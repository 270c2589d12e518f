"""``factory cell``: the cell as a long-running service, and what it prepares once per cell file.

A command group: each sub-command is registered on :data:`cell_app` below.
"""

from __future__ import annotations

import typer

__all__ = ["cell", "cell_app"]

cell_app = typer.Typer(name="cell", add_completion=False, pretty_exceptions_enable=False, rich_markup_mode=None)


@cell_app.callback(invoke_without_command=True)
def cell(ctx: typer.Context) -> None:
    """Run the cell as a service, or prepare what it needs once per cell file."""
    if ctx.invoked_subcommand is None:
        typer.echo(ctx.get_help())
        raise typer.Exit(2)


# The warm sub-command's imports stay with it, below the group's callback (the other
# sub-commands add theirs the same way, so that each addition is one block).
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Annotated  # noqa: E402

from cli.common import JsonFlag, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr  # noqa: E402
from factory.roadmaps import cached_roadmap  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402


@cell_app.command("warm")
@reports_errors
def warm(
    cell_path: Annotated[Path, typer.Argument(help="Robot cell file (YAML, factory.cell/1).", exists=True, dir_okay=False)],
    rebuild: Annotated[bool, typer.Option("--rebuild", help="Build and prove it again even when cached.")] = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Build, prove and cache the cell's roadmap, so that plans in this cell start warm."""
    setup_logging(quiet)
    with progress_bars(quiet) as bars:
        cell = load_cell(cell_path)
        world = collision_world(cell)
        t0 = time.perf_counter()
        got = cached_roadmap(cell, world, rebuild=rebuild, progress=bars.stage("roadmap"))
        seconds = time.perf_counter() - t0
    rm = got.roadmap
    if not quiet:
        stderr.print(f"{cell_path}: roadmap {'built' if got.built else 'already cached'}: {len(rm.nodes)} configurations, "
                     f"{len(rm.edges)} proven segments, {seconds:.1f} s; {got.path}", markup=False, highlight=False)
    if json_out:
        print_json({"cell": str(cell_path), "roadmap": str(got.path), "built": got.built, "nodes": len(rm.nodes),
                    "edges": len(rm.edges), "seconds": round(seconds, 3)})
