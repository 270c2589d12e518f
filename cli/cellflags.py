"""The options ``factory simulate`` and ``factory cell`` share: what the cell runs orders with, and how it
joins a ROS 2 graph. Defaults sit with each command's parameter."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from factory.cellinputs import CellInputs

__all__ = ["Bag", "BlankOffsets", "RackLight", "CameraFile", "Catalog", "CellFile", "Db", "FaultRate", "Faults", "RobotRate", "Ros2KeepAll",
           "Ros2Localhost", "RosDistro", "Tools", "cell_inputs"]

Catalog = Annotated[Path, typer.Option("--catalog", help="Folder of `factory plan` outputs to reuse; parts not in it are planned into it.", file_okay=False)]
CellFile = Annotated[Path, typer.Option("--cell", help="Robot cell file.", exists=True, dir_okay=False)]
CameraFile = Annotated[Path, typer.Option("--camera", help="Camera of the rack and out-tray stations (ROS camera_info YAML).", exists=True, dir_okay=False)]
Tools = Annotated[Path | None, typer.Option("--tools", help="Tool library YAML (default: fixtures/tools.yaml).", exists=True, dir_okay=False)]
Faults = Annotated[int | None, typer.Option("--faults", help="Inject faults drawn from this seed: missed grasps, missing stock, machine alarms, failed inspections.")]
FaultRate = Annotated[float | None, typer.Option("--fault-rate", help="With --faults: probability of each fault per attempt (default: grasp 5 %, stock 5 %, alarm 3 %, inspection 5 %).", min=0.0, max=1.0)]
BlankOffsets = Annotated[int | None, typer.Option("--blank-offsets", metavar="SEED", help="Stand each blank a few mm and degrees off its rack slot's centre (drawn from this seed): the rack camera locates it, the grasp is corrected and proven, or refused with the reason.")]
RackLight = Annotated[str | None, typer.Option("--rack-light", metavar="LIGHT", help="With --blank-offsets: the rack camera takes its pictures in real light (aluminium, shadows, exposure, noise): diffuse, low_angle, dim, glare or distractor (default: exact pictures).")]
Db = Annotated[str | None, typer.Option("--db", metavar="FILE|URL", help="Append the run to this process record, event by event: a SQLite file (created if missing) or a SQLAlchemy database URL (sqlite:///cell.sqlite, postgresql+psycopg://user@host/plant). See `factory report`.")]
Ros2Localhost = Annotated[bool, typer.Option("--ros2-localhost", help="With --ros2: keep all DDS traffic on the loopback interface.")]
RosDistro = Annotated[str, typer.Option("--ros-distro", help="With --ros2: the distribution of the graph's nodes, humble or jazzy (its discovery-info layout).")]
Ros2KeepAll = Annotated[bool, typer.Option("--ros2-keep-all", help="With --ros2: every subscriber gets every message, the run waiting for the slowest (default: the last 10 per topic are kept for a slow one).")]
RobotRate = Annotated[float, typer.Option("--robot-rate", metavar="HZ", help="Robot joint states and link transforms per second of simulated time in the log and the live view (each move's ends always); lower it for long runs, e.g. 1.", min=1e-3)]
Bag = Annotated[Path | None, typer.Option("--bag", metavar="DIR", help="Write the run as a rosbag2 folder (metadata.yaml and MCAP) that `ros2 bag info` and `ros2 bag play` take.", file_okay=False)]


def cell_inputs(catalog: Path, cell: Path, camera: Path, tools: Path | None, faults: int | None,
                fault_rate: float | None, blank_offsets: int | None = None,
                rack_light: str | None = None) -> CellInputs:
    """The cell's inputs as both commands are given them; a fault rate without a seed is a usage error
    (exit 2, naming the option), refused before any file is read."""
    if fault_rate is not None and faults is None:
        raise typer.BadParameter("needs --faults SEED", param_hint="--fault-rate")
    from factory.cellinputs import CellInputs

    return CellInputs(catalog=catalog, cell=cell, camera=camera, tools=tools, faults=faults, fault_rate=fault_rate,
                      blank_offsets=blank_offsets, rack_light=rack_light)
