"""``factory cell``: the cell as a long-running service, and what it prepares once per cell file.

A command group: each sub-command is registered on :data:`cell_app` below.
"""

from __future__ import annotations

import contextlib
import signal
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cli.cellflags import Bag, CameraFile, Catalog, CellFile, Db, FaultRate, Faults, RobotRate, Ros2KeepAll, \
    Ros2Localhost, RosDistro, Tools, cell_inputs
from cli.common import JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr
from cli.main import TYPER_SETTINGS
from factory.core.resources import FIXTURES
from factory.simulation import ROBOT_RATE_HZ

if TYPE_CHECKING:
    from factory.cellservice import CellOptions
    from factory.ros2 import Ros2Graph

__all__ = ["cell", "cell_app"]

cell_app = typer.Typer(name="cell", **TYPER_SETTINGS)


@cell_app.callback(invoke_without_command=True)
@reports_errors
def cell(
    ctx: typer.Context,
    ros2: Annotated[bool, typer.Option("--ros2", help="Run the cell on the ROS 2 graph (domain ROS_DOMAIN_ID): take work orders on /order (factory_msgs/WorkOrder, or std_msgs/String: a catalog part's name), answer on /order_status, publish each run as `simulate --ros2` does. Ctrl-C or SIGTERM stops it: the run under way is finished at once, the log and record closed.")] = False,
    catalog: Catalog = Path("build"),
    cell_path: CellFile = FIXTURES / "cell.yaml",
    camera_path: CameraFile = FIXTURES / "camera.yaml",
    tools: Tools = None,
    faults: Faults = None,
    fault_rate: FaultRate = None,
    db: Db = None,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write the session (every run, every order status) to this MCAP file when the cell stops.", dir_okay=False)] = None,
    bag: Bag = None,
    speed: Annotated[float, typer.Option("--speed", help="Play each run at this many times real time.", min=1e-3)] = 60.0,
    ros2_localhost: Ros2Localhost = False,
    ros_distro: RosDistro = "jazzy",
    ros2_keep_all: Ros2KeepAll = False,
    robot_rate: RobotRate = ROBOT_RATE_HZ,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
) -> None:
    """Run the cell as a service, or prepare what it needs once per cell file."""
    if ctx.invoked_subcommand is not None:
        return
    if not ros2:
        typer.echo(ctx.get_help())
        raise typer.Exit(2)
    setup_logging(quiet)
    inputs = cell_inputs(catalog, cell_path, camera_path, tools, faults, fault_rate)
    from factory.cellservice import CellOptions  # the cell's libraries, DDS among them, load only to serve
    from factory.ros2 import Ros2Graph

    _serve(CellOptions(inputs, robot_rate_hz=robot_rate, speed=speed),
           Ros2Graph(localhost=ros2_localhost, distro=ros_distro, speed=float("inf"), keep_all=ros2_keep_all),
           mcap=mcap, bag=bag, db=db, overwrite=overwrite, quiet=quiet)


def _serve(options: CellOptions, graph: Ros2Graph, *, mcap: Path | None, bag: Path | None, db: str | None,
           overwrite: bool, quiet: bool) -> None:
    """Serve until SIGINT or SIGTERM: the first stops the service once the run under way is written; a
    second interrupts at once (outputs not yet closed are then discarded, as every output is)."""
    from factory.cellservice import CellService
    from factory.live import Fanout
    from factory.mcaplog import McapLog
    from factory.record import Record

    with contextlib.ExitStack() as stack:
        stack.enter_context(graph)
        sinks: list[Any] = [graph]
        if mcap is not None:
            sinks.append(stack.enter_context(McapLog(mcap, stage="cell", overwrite=overwrite,
                                                     parameters={"catalog": str(options.inputs.catalog)})))
        if bag is not None:
            from factory.bag import BagLog

            sinks.append(stack.enter_context(BagLog(bag, overwrite=overwrite)))
        record = Record(db) if db is not None else None
        if record is not None:
            stack.callback(record.close)
        service = CellService(options, graph, Fanout(sinks), record)

        def stop(signum: int, frame: Any) -> None:
            if service.stop.is_set():
                raise KeyboardInterrupt
            service.stop.set()

        for sig in (signal.SIGINT, signal.SIGTERM):
            stack.callback(signal.signal, sig, signal.signal(sig, stop))
        if not quiet:
            stderr.print(f"cell: taking orders on /order (ROS 2 domain {graph.domain_id}"
                         f"{', localhost only' if graph.localhost else ''}); Ctrl-C stops",
                         highlight=False, markup=False)
        service.serve()
    if not quiet:
        stderr.print(f"cell stopped after {service.runs} runs" + (f"; log: {mcap}" if mcap else "") + (f"; bag: {bag}" if bag else ""),
                     highlight=False, markup=False)


@cell_app.command("warm")
@reports_errors
def warm(
    cell_path: Annotated[Path, typer.Argument(help="Robot cell file (YAML, factory.cell/1).", exists=True, dir_okay=False)],
    rebuild: Annotated[bool, typer.Option("--rebuild", help="Build and prove it again even when cached.")] = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Build, prove and cache the cell's roadmap, so that plans in this cell start warm."""
    from factory.roadmaps import cached_roadmap  # the robot's libraries load only to build
    from robotprog.cell import load_cell
    from robotprog.collision import collision_world

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
