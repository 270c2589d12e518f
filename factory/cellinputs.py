"""What the cell runs orders with: the catalog, the cell and camera files, the tools, the faults injected
and the blanks' offsets, as ``factory simulate`` and ``factory cell --ros2`` are given them
(:func:`factory.simulation.run_cell` takes them whole)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from factory.core.errors import FactoryError
from factory.core.resources import FIXTURES
from robotprog.cellsim import FaultModel
from robotprog.rackpick import BlankScatter
from vision.lit import CONDITIONS, Condition


@dataclasses.dataclass(frozen=True)
class CellInputs:
    """What the cell runs orders with, as ``factory simulate`` and ``factory cell --ros2`` are given it.

    Attributes
    ----------
    catalog : Path
        Folder of ``factory plan`` outputs to reuse; parts not in it are planned into it.
    cell, camera : Path
        Robot cell file; camera of the rack and out-tray stations (ROS camera_info YAML).
    tools : Path, optional
        Tool library for the parts planned now (default: ``fixtures/tools.yaml``).
    faults : int, optional
        Seed of the injected faults (missed grasps, missing stock, machine alarms, failed
        inspections); None: no faults.
    fault_rate : float, optional
        With ``faults``: probability of each fault per attempt; None: each kind's default.
    blank_offsets : int, optional
        Seed of the blanks' offsets in their rack slots: each blank stands a few mm and degrees off
        its slot's centre, and the rack camera's located offset corrects the grasp
        (:mod:`factory.rackloop`); None: every blank stands where the plan put it.
    rack_light : str, optional
        With ``blank_offsets``: the rack camera takes its pictures in this real light, one of
        :data:`vision.lit.CONDITIONS` (``diffuse``, ``low_angle``, ...); None: exact pictures.
    """

    catalog: Path = Path("build")
    cell: Path = FIXTURES / "cell.yaml"
    camera: Path = FIXTURES / "camera.yaml"
    tools: Path | None = None
    faults: int | None = None
    fault_rate: float | None = None
    blank_offsets: int | None = None
    rack_light: str | None = None

    def __post_init__(self) -> None:
        # refused before any file is read or written
        if self.rack_light is not None and self.blank_offsets is None:
            raise FactoryError("a rack light needs blank offsets: the rack camera locates only blanks off their slot",
                               source="rack_light")
        if self.rack_light is not None and self.rack_light not in CONDITIONS:
            raise FactoryError(f"unknown rack light {self.rack_light!r}; one of {', '.join(CONDITIONS)}",
                               source="rack_light")

    def scatter(self) -> BlankScatter | None:
        """How the blanks stand off their slots' centres (None: they do not)."""
        return None if self.blank_offsets is None else BlankScatter(seed=self.blank_offsets)

    def rack_condition(self) -> Condition | None:
        """The real light of the rack camera's pictures (None: exact pictures)."""
        return None if self.rack_light is None else CONDITIONS[self.rack_light]

    def fault_model(self) -> FaultModel:
        """The faults to inject.

        Raises
        ------
        FactoryError
            A fault rate without a seed.
        """
        if self.faults is None:
            if self.fault_rate is not None:
                raise FactoryError("a fault rate needs a seed of faults", source="fault_rate")
            return FaultModel()
        if self.fault_rate is None:
            return FaultModel.default(self.faults)
        return FaultModel(self.fault_rate, self.fault_rate, self.fault_rate, self.fault_rate, seed=self.faults)
