"""Spindle power and load while a program cuts: the machine's load meter, from the stock model.

The power a cut takes is its material removal rate times the material's specific cutting
energy (unit power)::

    MRR [mm³/s] = removed volume of the move / its time      (side milling: ap * ae * vf / 60)
    P   [W]     = MRR * u                                    u [W·s/mm³ = J/mm³], per material
    load [%]    = 100 * P / rated spindle power

The removed volume of each move is what verify's stock model took off the stock
(:attr:`cadcam.stock.Simulation.removed_volume`): the real engagement of every move, whatever
the strategy (a slot takes the full width, an adaptive pass its thin arc, an air move nothing),
not the nominal stepover and stepdown of its operation. The time of each move is the machine
timeline's (:mod:`cadcam.timeline`). ``u`` comes from the tool library
(:attr:`cadcam.tools.MaterialData.specific_energy`), the rated power from its machine
(:attr:`cadcam.tools.ToolLibrary.spindle_power_kw`).

A load meter shows an average: :meth:`SpindleLoad.power_at` is the mean power over the window
before each time (energy removed in it / its length), which also smooths the grid's
discreteness (a short move that finishes off a grid column is credited with all of it).

Not modelled: the rise of specific energy with thinner chips (finishing takes somewhat more
energy per mm³ than this says), tool wear, drive losses and the spindle's idle power: the load is
the cut's own. Units: millimetres and seconds, power in watts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadcam.model import frozen_array
from cadcam.timeline import MachineTimeline
from cadcam.tools import ToolLibrary
from factory.core.errors import ToolError, VerifyError

#: Averaging window of the load meter [s].
METER_WINDOW_S = 1.0


@dataclass(frozen=True)
class SpindleLoad:
    """Cutting power along a program's timeline.

    Attributes
    ----------
    times : (k,) float
        Knots of the timeline [s], non-decreasing (read-only).
    energy : (k,) float
        Cutting energy spent from the start to each knot [J], non-decreasing (read-only):
        each move spends its share evenly over its time.
    move_power : (n,) float
        Mean cutting power of each move of the program [W] (0 for moves that take no time or
        cut nothing), indexed like the timeline's points (read-only).
    rated_power : float
        The spindle's rated power [W]: 100 % load.
    """

    times: np.ndarray
    energy: np.ndarray
    move_power: np.ndarray
    rated_power: float

    def __post_init__(self) -> None:
        for name in ("times", "energy", "move_power"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)).reshape(-1))

    def power_at(self, t: np.ndarray | float, window_s: float = METER_WINDOW_S) -> np.ndarray:
        """Mean cutting power over ``[t - window_s, t]`` [W] at each program time ``t`` [s]
        (0 before the program starts and once it has ended a window ago).

        Raises
        ------
        ValueError
            ``window_s`` not a positive number of seconds.
        """
        if not (np.isfinite(window_s) and window_s > 0):
            raise ValueError(f"the load meter's window must be a positive number of seconds, got {window_s}")
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        done = np.interp(t, self.times, self.energy, left=0.0)
        before = np.interp(t - window_s, self.times, self.energy, left=0.0)
        return np.maximum(done - before, 0.0) / window_s

    def load_percent_at(self, t: np.ndarray | float, window_s: float = METER_WINDOW_S) -> np.ndarray:
        """:meth:`power_at` as a share of the rated power [%]."""
        return 100.0 * self.power_at(t, window_s) / self.rated_power


def spindle_load(timeline: MachineTimeline, removed_volume: np.ndarray, specific_energy: float,
                 rated_power_kw: float) -> SpindleLoad:
    """The cutting power of a program from the volume each of its moves removed.

    Parameters
    ----------
    timeline : MachineTimeline
        When the machine makes each move [s].
    removed_volume : (n,) float
        Stock volume each move removed [mm³], indexed like ``timeline.points``
        (:attr:`cadcam.stock.Simulation.removed_volume` of the same program).
    specific_energy : float
        The material's specific cutting energy [W·s/mm³], > 0.
    rated_power_kw : float
        The spindle's rated power [kW], > 0.

    Raises
    ------
    VerifyError
        Volumes of another program (another length), or negative or non-finite ones.
    ToolError
        A specific energy or rated power that is not a positive number.
    """
    volume = np.asarray(removed_volume, dtype=np.float64).reshape(-1)
    if len(volume) != len(timeline.points):
        raise VerifyError(f"removed volumes of {len(volume)} moves for a program of {len(timeline.points)}",
                          source="removed_volume")
    if not np.isfinite(volume).all() or (volume < 0).any():
        raise VerifyError("removed volumes must be finite and >= 0 mm³", source="removed_volume")
    for name, value, unit in (("specific_energy", specific_energy, "W·s/mm³"), ("spindle_power", rated_power_kw, "kW")):
        if not (np.isfinite(value) and value > 0):
            raise ToolError(f"{name} must be a positive number of {unit}, got {value}", source=name)
    joules = volume * float(specific_energy)
    span = timeline.end - timeline.start
    move_power = np.where(span > 0, joules / np.where(span > 0, span, 1.0), 0.0)
    # knots (0, start1, end1, start2, end2, ...): a move spends its energy between its start and end
    times = np.empty(2 * len(span) - 1)
    times[0] = 0.0
    times[1::2] = timeline.start[1:]
    times[2::2] = timeline.end[1:]
    spent = np.cumsum(joules[1:])
    energy = np.empty_like(times)
    energy[0] = 0.0
    energy[2::2] = spent
    energy[1::2] = np.r_[0.0, spent[:-1]]
    return SpindleLoad(times, energy, move_power, 1000.0 * float(rated_power_kw))


def program_spindle_load(timeline: MachineTimeline, removed_volume: np.ndarray, library: ToolLibrary,
                         material: str) -> SpindleLoad:
    """:func:`spindle_load` with the material's specific energy and the spindle's rated power
    from the tool library.

    Raises
    ------
    ToolError
        An unknown material, or one the library gives no ``specific_energy`` for.
    """
    m = library.material(material)
    if m.specific_energy is None:
        raise ToolError(f"materials.{m.name}: no specific_energy [W·s/mm³], needed to model the spindle load",
                        source=library.source)
    return spindle_load(timeline, removed_volume, m.specific_energy, library.spindle_power_kw)


__all__ = ["METER_WINDOW_S", "SpindleLoad", "program_spindle_load", "spindle_load"]
