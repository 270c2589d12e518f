"""The tool library: machine limits, end mills and cutting data per material, from YAML.

The file format is documented in ``fixtures/tools.yaml`` (the default library). Every field
is checked on load; an error names the field the way a user would find it in the file, e.g.
``tools[2].diameter: must be > 0`` or ``machine.max_rmp: unknown key (did you mean max_rpm?)``.

Speeds and feeds follow the usual shop formulas::

    n  = 1000 * Vc / (pi * D)      spindle speed [rev/min], capped at the machine's max rpm
    vf = n * z * fz                cutting feed [mm/min], capped at the machine's max feed
    plunge = vf * plunge_fraction

with ``fz`` (chip load per tooth [mm]) interpolated linearly in the tool diameter from the
material's table. On an internal arc the edge runs faster than the centre the controller feeds
(:func:`internal_arc_feed`).
"""

from __future__ import annotations

import difflib
import logging
import math
from dataclasses import dataclass

import numpy as np
from pathlib import Path
from typing import Any

from cadcam.model import DEFAULT_HOLDER, RADIAL_ENGAGEMENT_RULE, CuttingData, HolderSegment, Tool
from factory.core.errors import ToolError, field_name, shown
from factory.core.yamlfile import load_yaml
from factory.core.resources import FIXTURES

log = logging.getLogger(__name__)

_SHAPES = ("flat", "ball", "bull", "drill")
#: A tool's optional engagement target and limits (:meth:`_Parser.axial_limit`, :meth:`_Parser.radial`).
_ENGAGEMENT_KEYS = {"axial_limit", "engagement", "radial_limit"}
#: Rated spindle power when the library's machine gives none [kW]: the continuous (S1) rating
#: of a small VMC's spindle (fixtures/tools.yaml states its own).
DEFAULT_SPINDLE_POWER_KW = 7.5


@dataclass(frozen=True)
class DrillingData:
    """Cutting data for drills (twist and spot) in one material.

    Attributes
    ----------
    surface_speed : float
        Cutting speed Vc at the drill's periphery [m/min].
    feed_per_rev : tuple of (float, float)
        ``(diameter [mm], f [mm/rev])`` pairs, ascending diameter; interpolated linearly,
        clamped to the end values outside the table.
    peck : float
        Peck depth Q of a G83 cycle as a multiple of the drill diameter [D].
    """

    surface_speed: float
    feed_per_rev: tuple[tuple[float, float], ...]
    peck: float

    def feed_per_rev_for(self, diameter: float) -> float:
        """Feed per revolution for a drill of this diameter [mm/rev]."""
        return _interpolated(self.feed_per_rev, diameter)


def internal_arc_feed(feed: float, tool_diameter: float, edge_diameter: float) -> float:
    """The feed at the cutter's centre [mm/min] that gives the edge ``feed`` [mm/min] on an internal arc.

    Inside a bore the cutting edge, on a circle of ``edge_diameter`` Dh [mm], travels faster than
    the centre line, on a circle of Dh - D (``tool_diameter`` D [mm]); controllers feed the centre
    line, so a program written with the straight-line feed overloads each tooth by Dh / (Dh - D).
    The centre's feed is ``feed * (Dh - D) / Dh`` (Sandvik Coromant, *Heat resistant super alloys*
    application guide, "Circular ramping from solid": vf = vfm * Dvf / Dm, Dvf = Dm - D3).
    A path on the tool's axis (Dh <= D) gets none: ValueError.
    """
    if not edge_diameter > tool_diameter > 0:
        raise ValueError(f"an internal arc needs the edge's diameter {edge_diameter:g} > the tool's {tool_diameter:g} mm")
    return feed * (edge_diameter - tool_diameter) / edge_diameter


def _interpolated(table: tuple[tuple[float, float], ...], x: float) -> float:
    """Linear interpolation in ascending ``(x, y)`` pairs, clamped to the end values."""
    xs = [a for a, _ in table]
    ys = [b for _, b in table]
    return float(np.interp(x, xs, ys))


@dataclass(frozen=True)
class MaterialData:
    """Cutting data for one stock material.

    Attributes
    ----------
    name : str
        Key used in setups, e.g. ``"aluminium"``.
    surface_speed : float
        Cutting speed Vc at the tool's periphery [m/min].
    chip_load : tuple of (float, float)
        ``(diameter [mm], fz [mm/tooth])`` pairs, ascending diameter; interpolated linearly,
        clamped to the end values outside the table.
    plunge_fraction : float
        Plunge/ramp feed as a fraction of the cutting feed, in (0, 1].
    aliases : tuple of str
        Other names accepted for this material (matched case-insensitively).
    description : str
    drilling : DrillingData or None
        Cutting data for drills; None when the library gives none (drills are then not
        used in this material).
    specific_energy : float or None
        Specific cutting energy (unit power) [W·s/mm³ = J/mm³]: the spindle power a cut
        takes per unit of material removal rate (:mod:`cadcam.cutting_power`); None when the
        library gives none (the spindle load is then not modelled in this material).
    density : float or None
        Mass per volume [g/cm³ = kg/dm³]: the stock's mass, checked against what the robot
        carries (:func:`factory.refusals.check_setup`); None when the library gives none.
    """

    name: str
    surface_speed: float
    chip_load: tuple[tuple[float, float], ...]
    plunge_fraction: float
    aliases: tuple[str, ...] = ()
    description: str = ""
    drilling: DrillingData | None = None
    specific_energy: float | None = None
    density: float | None = None

    def mass_kg(self, volume_mm3: float) -> float | None:
        """Mass [kg] of ``volume_mm3`` [mm³] of this material; None without a density."""
        return None if self.density is None else float(volume_mm3) * self.density * 1e-6

    def chip_load_for(self, diameter: float) -> float:
        """Chip load per tooth for a tool of this diameter [mm/tooth]."""
        ds = [d for d, _ in self.chip_load]
        fs = [f for _, f in self.chip_load]
        if diameter <= ds[0]:
            return fs[0]
        if diameter >= ds[-1]:
            return fs[-1]
        for (d0, f0), (d1, f1) in zip(self.chip_load, self.chip_load[1:]):
            if d0 <= diameter <= d1:
                return f0 + (f1 - f0) * (diameter - d0) / (d1 - d0)
        return fs[-1]  # unreachable: the table is sorted and covers the interval


@dataclass(frozen=True)
class ToolLibrary:
    """The tools a machine holds and how fast to run them.

    Attributes
    ----------
    tools : tuple of Tool
        In file order; tool numbers are unique.
    materials : tuple of MaterialData
    max_rpm : float
        Spindle speed limit [rev/min].
    max_feed : float
        Cutting feed limit [mm/min].
    source : str
        The file it was read from.
    machine_name : str
    spindle_power_kw : float
        The spindle motor's rated (continuous, S1) power [kW]: 100 % spindle load.
    """

    tools: tuple[Tool, ...]
    materials: tuple[MaterialData, ...]
    max_rpm: float
    max_feed: float
    source: str
    machine_name: str = ""
    spindle_power_kw: float = DEFAULT_SPINDLE_POWER_KW
    #: ``(tool number, factor)``: the feed of a tool that runs slower than its diameter's chip load (a
    #: long-reach end mill, whose stick-out bends it), as a share of that feed, in (0, 1]; others 1.
    feed_factors: tuple[tuple[int, float], ...] = ()

    def feed_factor(self, tool: Tool) -> float:
        """Share of the material's feed ``tool`` runs at, in (0, 1] (``feed_factor`` in the file, default 1)."""
        return dict(self.feed_factors).get(tool.number, 1.0)

    def tool(self, number: int) -> Tool:
        """The tool with this T number; ToolError naming the numbers there are if missing."""
        for t in self.tools:
            if t.number == number:
                return t
        have = ", ".join(f"T{t.number}" for t in self.tools) or "none"
        raise ToolError(f"no tool T{number} in the library (have {have})", source=self.source)

    def material(self, name: str) -> MaterialData:
        """Cutting data for a material by name or alias (case-insensitive)."""
        key = name.strip().lower()
        for m in self.materials:
            if key == m.name.lower() or key in (a.lower() for a in m.aliases):
                return m
        known = ", ".join(m.name for m in self.materials)
        raise ToolError(f"unknown material {shown(name)}: the library has cutting data for {known}", source=self.source)

    def cutting_data(self, tool: Tool, material: str) -> CuttingData:
        """Spindle speed, cutting feed and plunge feed for ``tool`` in ``material``.

        Parameters
        ----------
        tool : Tool
        material : str
            Material name or alias, e.g. ``"aluminium"``, ``"pom"``.

        Returns
        -------
        CuttingData
            ``spindle_rpm`` <= ``max_rpm`` [rev/min]; ``feed`` and ``plunge_feed`` in
            (0, ``max_feed``] [mm/min]. Computed from the nominal diameter for every shape
            (conservative for ball ends, whose effective diameter at shallow depth is smaller).

        Raises
        ------
        ToolError
            Unknown material (lists the known ones).
        """
        m = self.material(material)
        if tool.is_drill:
            return self._drilling_data(tool, m)
        rpm = min(self.max_rpm, 1000.0 * m.surface_speed / (math.pi * tool.diameter))
        fz = m.chip_load_for(tool.diameter) * self.feed_factor(tool)
        feed = min(self.max_feed, rpm * tool.flutes * fz)
        plunge = min(self.max_feed, feed * m.plunge_fraction)
        return CuttingData(spindle_rpm=round(rpm), feed=round(feed, 1), plunge_feed=round(plunge, 1),
                           chip_load=round(fz, 6))

    def _drilling_data(self, tool: Tool, m: MaterialData) -> CuttingData:
        # A drill only feeds along its axis: feed = plunge feed = n * f.
        if m.drilling is None:
            raise ToolError(f"materials.{m.name}: no drilling data for drill T{tool.number}", source=self.source)
        rpm = min(self.max_rpm, 1000.0 * m.drilling.surface_speed / (math.pi * tool.diameter))
        feed = round(min(self.max_feed, rpm * m.drilling.feed_per_rev_for(tool.diameter)), 1)
        return CuttingData(spindle_rpm=round(rpm), feed=feed, plunge_feed=feed)

    def peck_depth(self, tool: Tool, material: str) -> float:
        """G83 peck depth Q for ``tool`` in ``material`` [mm] (the material's ``drilling.peck`` x D)."""
        m = self.material(material)
        if m.drilling is None:
            raise ToolError(f"materials.{m.name}: no drilling data for drill T{tool.number}", source=self.source)
        return m.drilling.peck * tool.diameter

    def drills(self, material: str) -> tuple[Tool, ...]:
        """The twist drills usable in ``material`` (point angle over 100 deg), narrowest first."""
        if self.material(material).drilling is None:
            return ()
        return tuple(sorted((t for t in self.tools if t.is_drill and t.point_angle > 100.0),
                            key=lambda t: (t.diameter, t.number)))

    def spot_drills(self, material: str) -> tuple[Tool, ...]:
        """The spot drills usable in ``material`` (point angle 100 deg or less), widest first."""
        if self.material(material).drilling is None:
            return ()
        return tuple(sorted((t for t in self.tools if t.is_drill and t.point_angle <= 100.0),
                            key=lambda t: (-t.diameter, t.number)))


def load_tool_library(path: str | Path | None = None) -> ToolLibrary:
    """Read and validate a tool library YAML file.

    Parameters
    ----------
    path : str or Path, optional
        The library file; None reads the shipped ``fixtures/tools.yaml``.

    Returns
    -------
    ToolLibrary

    Raises
    ------
    ToolError
        With ``source=path``: unreadable file or bad YAML (with line), and any invalid
        field, named by its place in the file (``tools[2].diameter: must be > 0``,
        unknown keys with a did-you-mean, missing keys, duplicate tool numbers, a ball
        whose corner radius is not half its diameter, ...).
    """
    path = Path(FIXTURES / "tools.yaml" if path is None else path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ToolError("no such tool library file", source=path) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ToolError(f"cannot read tool library: {e}", source=path) from None
    doc = load_yaml(text, source=path, error=ToolError)
    return _Parser(str(path)).library(doc)


class _Parser:
    """Validates the parsed YAML document, raising ToolError with the field's path."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, where: str, message: str) -> ToolError:
        return ToolError(f"{where}: {message}" if where else message, source=self.source)

    def mapping(self, value: Any, where: str, required: set[str], optional: set[str]) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"must be a mapping, got {_kind(value)}")
        allowed = required | optional
        for key in value:
            if key not in allowed:
                close = difflib.get_close_matches(str(key), sorted(allowed), n=1)
                hint = f"did you mean {close[0]}?" if close else f"expected one of {', '.join(sorted(allowed))}"
                raise self.fail(_join(where, field_name(key)), f"unknown key ({hint})")
        for key in sorted(required):
            if key not in value:
                raise self.fail(_join(where, key), "missing")
        return value

    def number(self, value: Any, where: str, *, positive: bool = True, minimum: float | None = None) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(where, f"must be a number, got {_kind(value)}")
        if positive and value <= 0:
            raise self.fail(where, f"must be > 0, got {value}")
        if minimum is not None and value < minimum:
            raise self.fail(where, f"must be >= {minimum:g}, got {value}")
        return float(value)

    def integer(self, value: Any, where: str, minimum: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(where, f"must be a whole number, got {_kind(value)}")
        if value < minimum:
            raise self.fail(where, f"must be >= {minimum}, got {value}")
        return value

    def string(self, value: Any, where: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"must be a non-empty text, got {_kind(value)}")
        return value.strip()

    def library(self, doc: Any) -> ToolLibrary:
        if doc is None:
            raise self.fail("", "tool library is empty")
        doc = self.mapping(doc, "", {"machine", "materials", "tools"}, set())
        machine = self.mapping(doc["machine"], "machine", {"max_rpm", "max_feed"}, {"name", "spindle_power"})
        max_rpm = self.number(machine["max_rpm"], "machine.max_rpm")
        max_feed = self.number(machine["max_feed"], "machine.max_feed")
        power = self.number(machine["spindle_power"], "machine.spindle_power") if "spindle_power" in machine \
            else DEFAULT_SPINDLE_POWER_KW
        name = self.string(machine["name"], "machine.name") if "name" in machine else ""

        mats = doc["materials"]
        if not isinstance(mats, dict) or not mats:
            raise self.fail("materials", f"must be a non-empty mapping of material name to cutting data, got {_kind(mats)}")
        materials = tuple(self.material(str(k), v) for k, v in mats.items())
        seen_names: dict[str, str] = {}
        for m in materials:
            for n in (m.name, *m.aliases):
                if n.lower() in seen_names and seen_names[n.lower()] != m.name:
                    raise self.fail(f"materials.{m.name}", f"name or alias {shown(n)} also used by {seen_names[n.lower()]}")
                seen_names[n.lower()] = m.name

        tools_doc = doc["tools"]
        if not isinstance(tools_doc, list) or not tools_doc:
            raise self.fail("tools", f"must be a non-empty list of tools, got {_kind(tools_doc)}")
        tools = tuple(self.tool(t, f"tools[{i}]") for i, t in enumerate(tools_doc))
        factors = tuple((tools[i].number, self.share(t["feed_factor"], f"tools[{i}].feed_factor"))
                        for i, t in enumerate(tools_doc) if "feed_factor" in t)
        first: dict[int, int] = {}
        for i, t in enumerate(tools):
            if t.number in first:
                raise self.fail(f"tools[{i}].number", f"duplicate tool number {t.number} (also tools[{first[t.number]}])")
            first[t.number] = i
        return ToolLibrary(
            tools=tools, materials=materials, max_rpm=max_rpm, max_feed=max_feed, source=self.source, machine_name=name,
            spindle_power_kw=power, feed_factors=factors,
        )

    def share(self, value: Any, where: str) -> float:
        """A factor in (0, 1]."""
        x = self.number(value, where)
        if x > 1:
            raise self.fail(where, f"must be in (0, 1], got {x:g}")
        return x

    def material(self, name: str, d: Any) -> MaterialData:
        where = f"materials.{name}"
        d = self.mapping(d, where, {"surface_speed", "chip_load", "plunge_fraction"},
                         {"aliases", "description", "drilling", "specific_energy", "density"})
        vc = self.number(d["surface_speed"], f"{where}.surface_speed")
        pairs = self.by_diameter(d["chip_load"], f"{where}.chip_load", "fz", "mm/tooth", 1.0)
        frac = self.number(d["plunge_fraction"], f"{where}.plunge_fraction")
        if frac > 1:
            raise self.fail(f"{where}.plunge_fraction", f"must be in (0, 1], got {frac}")
        aliases = d.get("aliases", [])
        if not isinstance(aliases, list):
            raise self.fail(f"{where}.aliases", f"must be a list of names, got {_kind(aliases)}")
        aliases_t = tuple(self.string(a, f"{where}.aliases[{i}]") for i, a in enumerate(aliases))
        desc = self.string(d["description"], f"{where}.description") if "description" in d else ""
        drilling = self.drilling(d["drilling"], f"{where}.drilling") if "drilling" in d else None
        energy = self.number(d["specific_energy"], f"{where}.specific_energy") if "specific_energy" in d else None
        density = self.number(d["density"], f"{where}.density") if "density" in d else None
        return MaterialData(name, vc, pairs, frac, aliases_t, desc, drilling, energy, density)

    def drilling(self, d: Any, where: str) -> DrillingData:
        d = self.mapping(d, where, {"surface_speed", "feed_per_rev", "peck"}, set())
        vc = self.number(d["surface_speed"], f"{where}.surface_speed")
        pairs = self.by_diameter(d["feed_per_rev"], f"{where}.feed_per_rev", "f", "mm/rev", 2.0)
        peck = self.number(d["peck"], f"{where}.peck")
        return DrillingData(vc, pairs, peck)

    def by_diameter(self, table: Any, where: str, symbol: str, unit: str,
                    most: float) -> tuple[tuple[float, float], ...]:
        """A table of diameter [mm] to a feed [``unit``], sorted by diameter; a single number holds
        for every diameter. A value over ``most`` is taken for a unit slip."""
        if isinstance(table, (int, float)) and not isinstance(table, bool):
            table = {1.0: table}
        if not isinstance(table, dict) or not table:
            raise self.fail(where, f"must be a mapping of diameter [mm] to {symbol} [{unit}], got {_kind(table)}")
        pairs = sorted(
            (self.number(k, f"{where} (diameter {shown(k)})"), self.number(v, f"{where}[{k}]"))
            for k, v in table.items()
        )
        for _, v in pairs:
            if v > most:
                raise self.fail(where, f"{symbol} {v} {unit} is implausible (> {most:g} mm); is it in mm?")
        return tuple(pairs)

    def tool(self, d: Any, where: str) -> Tool:
        d = self.mapping(
            d, where, {"number", "name", "shape", "diameter", "flute_length", "flutes", "length"},
            {"corner_radius", "shank_diameter", "holder", "point_angle", "feed_factor"} | _ENGAGEMENT_KEYS,  # feed_factor: the library's
        )
        number = self.integer(d["number"], f"{where}.number", 1)
        name = self.string(d["name"], f"{where}.name")
        shape = d["shape"]
        if shape not in _SHAPES:
            raise self.fail(f"{where}.shape", f"unknown shape {shown(shape)}: expected flat, ball, bull or drill")
        diameter = self.number(d["diameter"], f"{where}.diameter")
        radius = diameter / 2
        point_angle = 180.0
        if shape == "drill":
            if "point_angle" not in d:
                raise self.fail(f"{where}.point_angle", "missing (a drill needs its point angle, e.g. 118 or 90 for a spot drill)")
            point_angle = self.number(d["point_angle"], f"{where}.point_angle")
            if not 60 <= point_angle < 180:
                raise self.fail(f"{where}.point_angle", f"must lie in [60, 180) deg, got {point_angle:g}")
        elif "point_angle" in d:
            raise self.fail(f"{where}.point_angle", f"only drills have a point angle (this is a {shape} end mill)")
        if shape in ("flat", "drill"):
            rc = self.number(d.get("corner_radius", 0.0), f"{where}.corner_radius", positive=False, minimum=0)
            if rc != 0:
                what = "a flat end mill" if shape == "flat" else "a drill"
                raise self.fail(f"{where}.corner_radius", f"{what} has corner_radius 0, got {rc} (use shape: bull)"
                                if shape == "flat" else f"{what} has corner_radius 0, got {rc}")
        elif shape == "ball":
            rc = self.number(d.get("corner_radius", radius), f"{where}.corner_radius")
            if abs(rc - radius) > 1e-9:
                raise self.fail(f"{where}.corner_radius", f"a ball end mill has corner_radius = diameter/2 = {radius:g}, got {rc:g}")
            rc = radius
        else:
            if "corner_radius" not in d:
                raise self.fail(f"{where}.corner_radius", "missing (a bull-nose end mill needs its corner radius)")
            rc = self.number(d["corner_radius"], f"{where}.corner_radius")
            if rc >= radius:
                raise self.fail(
                    f"{where}.corner_radius",
                    f"must be < diameter/2 = {radius:g} for a bull-nose, got {rc:g} (use shape: ball)",
                )
        flute_length = self.number(d["flute_length"], f"{where}.flute_length")
        flutes = self.integer(d["flutes"], f"{where}.flutes", 1)
        length = self.number(d["length"], f"{where}.length")
        shank = self.number(d["shank_diameter"], f"{where}.shank_diameter") if "shank_diameter" in d else diameter
        holder = self.holder(d["holder"], f"{where}.holder") if "holder" in d else DEFAULT_HOLDER
        axial_limit = self.axial_limit(d, where, shape, flute_length)
        engagement, radial_limit = self.radial(d, where, shape)
        return Tool(
            number=number,
            name=name,
            shape=shape,
            diameter=diameter,
            corner_radius=float(rc),
            flute_length=flute_length,
            flutes=flutes,
            length=length,
            shank_diameter=shank,
            holder=holder,
            point_angle=point_angle,
            axial_limit=axial_limit,
            engagement=engagement,
            radial_limit=radial_limit,
        )

    def axial_limit(self, d: dict[str, Any], where: str, shape: str, flute_length: float) -> float | None:
        """A tool's ``axial_limit`` [mm], None where not given (the rule :data:`cadcam.model.FULL_WIDTH_DEPTH_RULE`)."""
        if "axial_limit" not in d:
            return None
        if shape == "drill":
            raise self.fail(f"{where}.axial_limit", "a drill cuts only along its axis (its limit is its flute length)")
        limit = self.number(d["axial_limit"], f"{where}.axial_limit")
        if limit > flute_length:
            raise self.fail(f"{where}.axial_limit", f"must be <= flute_length {flute_length:g}, got {limit:g}")
        return limit

    def radial(self, d: dict[str, Any], where: str, shape: str) -> tuple[float | None, float | None]:
        """A tool's ``engagement`` (target, in (0, 0.5) D) and ``radial_limit`` (in [target, 1] D), each None where
        not given (the rule :data:`cadcam.model.RADIAL_ENGAGEMENT_RULE`)."""
        given = {key: self.number(d[key], f"{where}.{key}") for key in ("engagement", "radial_limit") if key in d}
        if given and shape == "drill":
            key = next(iter(given))
            raise self.fail(f"{where}.{key}", "a drill cuts only along its axis (it has no radial engagement)")
        target = given.get("engagement", RADIAL_ENGAGEMENT_RULE[0])
        limit = given.get("radial_limit", RADIAL_ENGAGEMENT_RULE[1])
        if not target < 0.5:
            raise self.fail(f"{where}.engagement", f"must be < 0.5 (a share of the diameter), got {target:g}")
        if limit > 1:
            raise self.fail(f"{where}.radial_limit", f"must be <= 1 (a share of the diameter), got {limit:g}")
        if limit < target:
            key = "radial_limit" if "radial_limit" in given else "engagement"
            raise self.fail(f"{where}.{key}", f"radial_limit {limit:g} must be >= engagement {target:g}")
        return given.get("engagement"), given.get("radial_limit")

    def holder(self, value: Any, where: str) -> tuple[HolderSegment, ...]:
        """A list of ``{diameter, length, top_diameter?}`` from the gauge line up [mm]."""
        if not isinstance(value, list) or not value:
            raise self.fail(where, f"must be a non-empty list of segments {{diameter, length, top_diameter}}, got {_kind(value)}")
        out = []
        for i, seg in enumerate(value):
            w = f"{where}[{i}]"
            seg = self.mapping(seg, w, {"diameter", "length"}, {"top_diameter"})
            d = self.number(seg["diameter"], f"{w}.diameter")
            top = self.number(seg["top_diameter"], f"{w}.top_diameter") if "top_diameter" in seg else d
            out.append(HolderSegment(diameter=d, length=self.number(seg["length"], f"{w}.length"), top_diameter=top))
        return tuple(out)


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, (bool, int, float, str)):
        return shown(value)
    return type(value).__name__
