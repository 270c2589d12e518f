"""``factory simulate [ORDERS] --mcap out.mcap``: the cell runs orders, much faster than real time.

The work, with the MCAP log, its Foxglove layout and the Gantt chart, is
:func:`factory.production.simulate_orders`; this command turns the options into its request, binds
the live view, and prints the summary.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Annotated

import typer

from cli.cellflags import Bag, BlankOffsets, CameraFile, Catalog, CellFile, Db, FaultRate, Faults, RackLight, \
    RobotRate, Ros2KeepAll, Ros2Localhost, RosDistro, Tools, cell_inputs
from cli.common import EXIT_FINDINGS, JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, \
    setup_logging, stderr
from factory.core.resources import FIXTURES
from factory.live import Fanout, LiveView
from factory.production import SAMPLE_ORDERS, SimulateRequest, simulate_orders
from factory.simulation import ROBOT_RATE_HZ
from robotprog.cellsim import SimulationResult

__all__ = ["SAMPLE_ORDERS", "simulate", "summary_text"]


def _pct(share: float | None) -> str:
    return "-" if share is None else f"{100 * share:.1f} %"


def summary_text(result: SimulationResult, seconds: float) -> str:
    s = result.summary
    cycle = f"{s['cycle_time_s'] / 60:.1f} min" if s["cycle_time_s"] else "-"
    faults = ", ".join(f"{k} {v}" for k, v in sorted(s["faults"].items())) or "none"
    lines = [
        f"simulated {s['makespan_s'] / 3600:.2f} h in {seconds:.1f} s: {s['parts_good']} good, "
        f"{s['parts_rejected']} rejected; {s['parts_per_hour']:.2f} parts/h, cycle {cycle}",
        f"utilisation: robot {100 * s['robot_utilisation']:.1f} %, machine {100 * s['machine_utilisation']:.1f} %",
        f"OEE {_pct(s.get('oee'))} = availability {_pct(s.get('availability'))} x performance "
        f"{_pct(s.get('performance'))} x quality {_pct(s.get('quality'))}",
        f"faults: {faults}; recovered {s['recoveries']}, failed {s['failures']}",
    ]
    lines += [f"  {o.order} {Path(o.part).name}: {o.outcome} ({o.good}/{o.quantity} good, {o.rejected} rejected)"
              + ("" if o.outcome == "done" else f": {o.reason}") for o in result.outcomes]
    return "\n".join(lines)


@reports_errors
def simulate(
    orders_path: Annotated[Path, typer.Argument(help="Orders file (YAML or CSV: part, quantity, material, priority); default: the sample orders.", dir_okay=False)] = SAMPLE_ORDERS,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write the run to this MCAP file, and OUT.layout.json (Foxglove) beside it.", dir_okay=False)] = None,
    catalog: Catalog = Path("build"),
    cell_path: CellFile = FIXTURES / "cell.yaml",
    camera_path: CameraFile = FIXTURES / "camera.yaml",
    tools: Tools = None,
    bag: Bag = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write a Gantt chart of the robot, machine and cameras.", dir_okay=False)] = None,
    faults: Faults = None,
    blank_offsets: BlankOffsets = None,
    rack_light: RackLight = None,
    fault_rate: FaultRate = None,
    db: Db = None,
    serve: Annotated[int | None, typer.Option("--serve", metavar="PORT", help="Stream the run live to the Foxglove app (ws://HOST:PORT) with the channels of the MCAP log.", min=0, max=65535)] = None,
    host: Annotated[str, typer.Option("--host", help="Address the live view binds (with --serve).")] = "127.0.0.1",
    speed: Annotated[float, typer.Option("--speed", help="With --serve or --ros2: play the run at this many times real time.", min=1e-3)] = 60.0,
    ros2: Annotated[bool, typer.Option("--ros2", help="Publish the run live on the ROS 2 graph (domain ROS_DOMAIN_ID) as the cell's nodes, with the topics of the MCAP log.")] = False,
    ros2_localhost: Ros2Localhost = False,
    ros_distro: RosDistro = "jazzy",
    ros2_keep_all: Ros2KeepAll = False,
    ros2_wait: Annotated[list[str] | None, typer.Option("--ros2-wait", metavar="TOPIC", help="With --ros2: hold this topic's first message until a subscriber has matched it (at most 60 s); repeatable.")] = None,
    robot_rate: RobotRate = ROBOT_RATE_HZ,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Run orders through the cell (fetch, load, machine, unload, inspect, sort) and report throughput.

    Parts not in the catalog are planned first (as `factory plan` with its defaults). An order
    whose part is missing or cannot be planned fails on its own; the others run. Exits 3 (after
    writing everything) when an order ends failed or rejected: the reasons are in the summary.
    """
    setup_logging(quiet)
    inputs = cell_inputs(catalog, cell_path, camera_path, tools, faults, fault_rate, blank_offsets, rack_light)
    if (ros2_localhost or ros2_keep_all or ros2_wait or ros_distro != "jazzy") and not ros2:
        raise typer.BadParameter("needs --ros2", param_hint="--ros2-localhost, --ros2-keep-all, --ros2-wait, --ros-distro")
    request = SimulateRequest(orders_path, inputs, db=db, robot_rate_hz=robot_rate, mcap=mcap, png=png, overwrite=overwrite)
    orders = request.checked()
    # Bound before any work, so a port in use fails at once; it streams once the run is simulated.
    live = LiveView(serve, host=host, speed=speed) if serve is not None else None
    if live is not None and not quiet:
        stderr.print(f"live view: ws://{host}:{live.port} (Foxglove: open connection, Foxglove WebSocket)",
                     highlight=False, markup=False)
    if ros2:  # joined before any work, so discovery runs while the cell is simulated
        from factory.ros2 import Ros2Graph  # DDS loads only for --ros2

        graph = Ros2Graph(localhost=ros2_localhost, distro=ros_distro, speed=speed, wait_for=tuple(ros2_wait or ()),
                          keep_all=ros2_keep_all)
        live = Fanout([s for s in (live, graph) if s is not None])
    # the bag is checked before any work, closed (renamed into place) with the log, and left out if the run fails
    with contextlib.ExitStack() as outputs, progress_bars(quiet) as bars:
        if bag is not None:
            from factory.bag import BagLog  # rosbags' rosbag2 writer loads only for --bag

            live = Fanout([s for s in (live, outputs.enter_context(BagLog(bag, overwrite=overwrite))) if s is not None])
        done = simulate_orders(request, orders=orders, live=live, progress=bars)
    doc = done.summary
    if json_out:
        print_json(doc)
    elif not quiet:
        stderr.print(summary_text(done.run.result, sum(done.seconds.values())), highlight=False, markup=False)
        if mcap is not None:
            stderr.print(f"log: {mcap} ({doc['mcap']['bytes'] / 1e6:.1f} MB), layout: {request.layout}",
                         highlight=False, markup=False)
        if db is not None:
            stderr.print(f"record: {doc['db']['url']}, run {doc['db']['run']}", highlight=False, markup=False)
    if any(o.outcome != "done" for o in done.run.result.outcomes):
        raise typer.Exit(EXIT_FINDINGS)
