"""The small typed values that CAM stages pass to each other.

Everything here is in millimetres, millimetres per minute and revolutions per minute, in
*work coordinates* (the frame the G-code is written in: see :class:`Setup`), unless a
field says otherwise. Arrays are read-only ``float64``.

A :class:`Job` is what ``factory toolpath`` writes and ``factory gcode`` reads: the setup,
the tools and the operations, each operation a polyline of cutter locations (tool *tip*
positions) with the kind of motion that reaches each point.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

ToolShape = Literal["flat", "ball", "bull", "drill"]
WorkOrigin = Literal["top-front-left", "top-centre"]

#: Largest plausible part or stock extent [mm]: above two metres a part file is far more likely
#: in the wrong units than a real job for a milling machine (:mod:`cadcam.mesh`), and no stock
#: is longer (:mod:`cadcam.setup`).
MAX_EXTENT_MM = 2000.0


def frozen_array(values: Any, shape_tail: tuple[int, ...] = (), dtype: Any = np.float64) -> np.ndarray:
    """Return a read-only copy of ``values`` as an array of ``dtype``.

    ``shape_tail`` checks the trailing dimensions, e.g. ``(3,)`` for an ``(n, 3)`` array.
    """
    a = np.array(values, dtype=dtype, copy=True)
    if shape_tail and a.shape[a.ndim - len(shape_tail):] != shape_tail:
        raise ValueError(f"expected shape (..., {', '.join(map(str, shape_tail))}), got {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class HolderSegment:
    """One cylinder or cone of a tool holder; a holder is a stack of them from the gauge line up.

    Attributes
    ----------
    diameter : float
        Diameter at the segment's lower end [mm].
    length : float
        Height of the segment along the tool axis [mm].
    top_diameter : float
        Diameter at the upper end [mm]; equal to ``diameter`` for a cylinder, different
        for a cone (the taper of a collet nut or a shrink-fit holder).
    """

    diameter: float
    length: float
    top_diameter: float

    def __post_init__(self) -> None:
        if not (self.diameter > 0 and self.top_diameter > 0 and self.length > 0):
            raise ValueError("holder segment diameters and length must be > 0")


#: Holder assumed for a tool whose library entry or setup sheet names none (sheets written
#: before holders were recorded): a generic ER20 collet chuck, its nut a cone from
#: 28 mm at the gauge line to 35 mm over 12 mm, then a 42 mm body 40 mm tall. Generous
#: for the small tools of the default library, so old sheets verify on the safe side.
DEFAULT_HOLDER: tuple[HolderSegment, ...] = (
    HolderSegment(diameter=28.0, length=12.0, top_diameter=35.0),
    HolderSegment(diameter=42.0, length=40.0, top_diameter=42.0),
)


#: The full-width axial depth of an end mill whose library entry gives no ``axial_limit``:
#: ``(share, from_diameter, smaller_share)``, 1 x D from 3 mm up and 0.5 x D below [share of D]
#: (the most a carbide end mill's maker gives for full slotting, halved for miniature end mills;
#: the sources are cited in fixtures/tools.yaml).
FULL_WIDTH_DEPTH_RULE = (1.0, 3.0, 0.5)

#: The radial engagement of an end mill whose library entry gives no ``engagement``/``radial_limit``:
#: ``(target, limit)`` [share of D]. ``target``: what adaptive clearing holds its cut to (the middle of
#: the 10-20 % of D issue 32 asks for; WIDIA's trochoidal range is 5-15 %). ``limit``: the widest a cut
#: deeper than the tool's full-width limit may take (fixtures/tools.yaml cites the sources).
RADIAL_ENGAGEMENT_RULE = (0.15, 0.3)

#: Radial step of roughing levels' loops [share of D] (:attr:`Tool.level_stepover`). 0.4 before: the same
#: full-width ``fz`` chip (thinning gives 1.02 x at 0.4 D), so 1.75 x the path for the same stock.
#: 0.85 D measured no better (more gap loops, more links).
LEVEL_STEPOVER = 0.7

#: Cutter shapes as integer codes, one per move in arrays: :attr:`cadcam.envelope.Segments.shape`, read by the
#: compiled sweep (:mod:`cadcam.toolsweep`) and the chip rule (:mod:`cadcam.engagement`).
FLAT, BALL, BULL, CONE = 0, 1, 2, 3


@dataclass(frozen=True)
class Tool:
    """An end mill or a drill.

    The cutting surface is described by one profile for every shape: at radial
    distance ``r`` from the axis, the lowest point of the cutter is
    :meth:`profile_height` above the tip. Flat: ``corner_radius == 0``; ball:
    ``corner_radius == diameter / 2``; bull-nose: anything between. Drill (twist drills
    and spot drills): ``corner_radius == 0`` and a conical point of ``point_angle``; it
    only ever cuts along its axis (drill cycles), never sideways.

    Attributes
    ----------
    number : int
        Tool number in the machine's tool table (``T`` word), >= 1.
    name : str
        Human name, e.g. ``"6 mm flat 3FL carbide"``.
    shape : {"flat", "ball", "bull"}
    diameter : float
        Cutting diameter [mm].
    corner_radius : float
        Corner (torus) radius [mm].
    flute_length : float
        Length of cut [mm]: the deepest a wall can be cut in one step.
    flutes : int
        Number of cutting edges, for feed per tooth.
    length : float
        Stick-out from the holder [mm]: the deepest the tool reaches without the holder
        touching the part. Also the tool length offset written to tool tables. The
        holder's *gauge line* (its lower face) is this far above the tip.
    shank_diameter : float
        Diameter of the body between the top of the flutes and the holder [mm] (the
        neck of a long-neck tool); None on construction means the cutting diameter.
    holder : tuple of HolderSegment
        The holder from the gauge line up [mm]; :data:`DEFAULT_HOLDER` unless given.
    point_angle : float
        Included angle of a drill's point [deg]: 118 for a twist drill, 90 for a spot
        drill; 180 (no point) for end mills.
    axial_limit : float or None
        Deepest axial cut at full width, in a slot or an inside corner [mm] (the tool library's
        ``axial_limit``); None: the rule :data:`FULL_WIDTH_DEPTH_RULE` gives it
        (:attr:`full_width_limit`). ``factory verify`` fails a move that cuts deeper at full width.
    engagement : float or None
        Radial engagement adaptive clearing holds this end mill to, as a share of D (the tool library's
        ``engagement``); None: :data:`RADIAL_ENGAGEMENT_RULE` (:attr:`engagement_target`).
    radial_limit : float or None
        Widest radial engagement of a cut deeper than :attr:`full_width_limit`, as a share of D (the
        library's ``radial_limit``); None: :data:`RADIAL_ENGAGEMENT_RULE` (:attr:`deep_radial_limit`).
        ``factory verify`` fails a deeper move that cuts wider.
    """

    number: int
    name: str
    shape: ToolShape
    diameter: float
    corner_radius: float
    flute_length: float
    flutes: int
    length: float
    shank_diameter: float | None = None
    holder: tuple[HolderSegment, ...] = DEFAULT_HOLDER
    point_angle: float = 180.0
    axial_limit: float | None = None
    engagement: float | None = None
    radial_limit: float | None = None

    def __post_init__(self) -> None:
        if self.shank_diameter is None:
            object.__setattr__(self, "shank_diameter", float(self.diameter))
        object.__setattr__(self, "holder", tuple(self.holder))
        if not self.holder:
            raise ValueError("a tool needs at least one holder segment")
        # Programming errors, not user input: the tool library validates user files.
        expected = {"flat": 0.0, "ball": self.diameter / 2, "drill": 0.0}
        if self.shape in expected and abs(self.corner_radius - expected[self.shape]) > 1e-9:
            raise ValueError(f"{self.shape} tool needs corner_radius {expected[self.shape]}")
        if not 0.0 <= self.corner_radius <= self.diameter / 2:
            raise ValueError("corner_radius must lie in [0, diameter/2]")
        if (self.shape == "drill") != (self.point_angle < 180.0) or not 0.0 < self.point_angle <= 180.0:
            raise ValueError("a drill needs a point_angle in (0, 180) deg; an end mill has 180")
        if self.axial_limit is not None and not self.axial_limit > 0.0:
            raise ValueError("axial_limit must be > 0 mm")
        if not 0.0 < self.engagement_share < 0.5 or not self.engagement_share <= self.radial_limit_share <= 1.0:
            raise ValueError("engagement must lie in (0, 0.5) D and radial_limit in [engagement, 1] D")

    @property
    def is_drill(self) -> bool:
        """A twist or spot drill: cuts only along its axis."""
        return self.shape == "drill"

    @property
    def point_slope(self) -> float:
        """Rise of the drill point per mm of radius [mm/mm]: ``1 / tan(point_angle / 2)``; 0 for end mills."""
        return 0.0 if self.point_angle >= 180.0 else 1.0 / math.tan(math.radians(self.point_angle) / 2)

    @property
    def point_length(self) -> float:
        """Height of the drill's conical point from the tip to the full diameter [mm]; 0 for end mills."""
        return self.radius * self.point_slope

    @property
    def full_width_limit(self) -> float:
        """Deepest axial cut at full width [mm]: :attr:`axial_limit`, else :data:`FULL_WIDTH_DEPTH_RULE`
        (never beyond the flutes)."""
        if self.axial_limit is not None:
            return float(self.axial_limit)
        share = FULL_WIDTH_DEPTH_RULE[0] if self.diameter >= FULL_WIDTH_DEPTH_RULE[1] else FULL_WIDTH_DEPTH_RULE[2]
        return min(share * self.diameter, float(self.flute_length))

    @property
    def engagement_share(self) -> float:
        """Radial engagement target of adaptive clearing [share of D]: :attr:`engagement`, else the rule's."""
        return RADIAL_ENGAGEMENT_RULE[0] if self.engagement is None else float(self.engagement)

    @property
    def radial_limit_share(self) -> float:
        """Widest radial engagement below :attr:`full_width_limit` [share of D]: :attr:`radial_limit`, else the rule's."""
        return RADIAL_ENGAGEMENT_RULE[1] if self.radial_limit is None else float(self.radial_limit)

    @property
    def engagement_target(self) -> float:
        """Radial engagement adaptive clearing holds this tool to [mm]."""
        return self.engagement_share * self.diameter

    @property
    def deep_radial_limit(self) -> float:
        """Widest radial engagement [mm] of a cut deeper than :attr:`full_width_limit`."""
        return self.radial_limit_share * self.diameter

    @property
    def level_stepdown(self) -> float:
        """Default depth of one roughing level [mm]: half the diameter, never past :attr:`full_width_limit`
        (a level's first cut into a pocket is a slot)."""
        return min(0.5 * self.diameter, self.full_width_limit)

    @property
    def level_stepover(self) -> float:
        """Default radial step between a roughing level's loops [mm]: :data:`LEVEL_STEPOVER` of the diameter.
        A level is never deeper than :attr:`full_width_limit`, so any width of cut is within the library's
        limits there, and above half the diameter the chip is the full ``fz`` (no thinning): the removal
        per mm of path grows with the step, so the levels take it wide, as the floors' finishing does."""
        return LEVEL_STEPOVER * self.diameter

    @property
    def radius(self) -> float:
        """Cutting radius [mm]."""
        return self.diameter / 2

    def profile_height(self, r: np.ndarray | float) -> np.ndarray:
        """Height of the cutting surface above the tip at radial distance ``r`` [mm].

        Parameters
        ----------
        r : (...) float
            Radial distance from the tool axis [mm]. Values beyond the radius give ``inf``.

        Returns
        -------
        (...) float
            0 on the flat bottom, rising along the corner radius to ``corner_radius`` at
            ``r == radius``; a drill's cone rises as ``r * point_slope``.
        """
        r = np.asarray(r, dtype=np.float64)
        if self.point_slope > 0.0:
            return np.where(r <= self.radius + 1e-12, r * self.point_slope, np.inf)
        rc = self.corner_radius
        a = self.radius - rc  # radius of the flat bottom
        d = np.clip(r - a, 0.0, None)
        with np.errstate(invalid="ignore"):
            h = rc - np.sqrt(np.clip(rc * rc - d * d, 0.0, None))
        return np.where(r <= self.radius + 1e-12, h, np.inf)

    def body(self, step: float = 2.0) -> tuple[tuple[float, float], ...]:
        """The tool's non-cutting body as stacked cylinders: ``(height above the tip, radius)`` [mm].

        The shank from the top of the flutes, then each holder segment from the gauge
        line (:attr:`length` above the tip) up. Cones become cylinders at most ``step``
        tall, each as wide as the cone gets over its height and starting at its bottom,
        so the stack holds the true body (contacts are found on the safe side). Each
        cylinder is taken to reach up forever (material is a height field, so only the
        lowest body point over a spot matters); cylinders hidden by a wider one lower
        down are dropped, leaving radii that grow with height.
        """
        parts = [(float(self.flute_length), float(self.shank_diameter) / 2)]
        z = float(self.length)
        for seg in self.holder:
            n = max(1, math.ceil(seg.length / step)) if seg.top_diameter != seg.diameter else 1
            for k in range(n):
                d = max(seg.diameter + (seg.top_diameter - seg.diameter) * (k + f) / n for f in (0, 1))
                parts.append((z + seg.length * k / n, d / 2))
            z += seg.length
        out: list[tuple[float, float]] = []
        for h, r in sorted(parts):
            if not out or r > out[-1][1]:
                out.append((h, r))
        return tuple(out)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for key in ("axial_limit", "engagement", "radial_limit"):
            if d[key] is None:  # the rule's: sheets of tools without the key stay as they were
                del d[key]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Tool":
        """Read :meth:`to_dict` output; dictionaries from before holders were recorded get
        the cutting diameter as shank and :data:`DEFAULT_HOLDER`."""
        values = {f.name: d[f.name] for f in dataclasses.fields(cls)
                  if f.name not in ("shank_diameter", "holder", "point_angle", "axial_limit", "engagement",
                                    "radial_limit")}
        for key in ("axial_limit", "engagement", "radial_limit"):
            if d.get(key) is not None:
                values[key] = float(d[key])
        if d.get("point_angle") is not None:
            values["point_angle"] = float(d["point_angle"])
        if d.get("shank_diameter") is not None:
            values["shank_diameter"] = float(d["shank_diameter"])
        if d.get("holder"):
            values["holder"] = tuple(
                HolderSegment(diameter=float(h["diameter"]), length=float(h["length"]),
                              top_diameter=float(h.get("top_diameter", h["diameter"])))
                for h in d["holder"]
            )
        return cls(**values)


@dataclass(frozen=True)
class CuttingData:
    """Spindle speed and feeds for one tool in one material.

    Attributes
    ----------
    spindle_rpm : float
        Spindle speed [rev/min].
    feed : float
        Cutting feed [mm/min].
    plunge_feed : float
        Feed for ramps, helices and vertical entries [mm/min].
    chip_load : float or None
        The library's feed per tooth ``fz`` for this tool in this material [mm/tooth]: the thickest chip
        the tool may cut, whatever the feed (a feed raised for chip thinning keeps it, and ``factory verify``
        holds every move's chip to it). None where unknown (a job written before it was recorded).
    """

    spindle_rpm: float
    feed: float
    plunge_feed: float
    chip_load: float | None = None


class Motion(enum.IntEnum):
    """How the tool reaches a cutter location."""

    RAPID = 0  #: G0, maximum traverse rate; must never touch stock
    CUT = 1  #: G1/G2/G3 at the cutting feed
    PLUNGE = 2  #: G1/G2/G3 at the plunge feed: ramps, helices, vertical entries


@dataclass(frozen=True)
class DrillCycle:
    """A canned drilling cycle over a row of holes: how a post writes a drilling operation.

    The operation's points hold the same motion expanded into rapids and feeds (what the
    controller does, for grbl and for the stock model); the post writes this instead on
    controllers with canned cycles.

    Attributes
    ----------
    code : {81, 83}
        G81 drill in one feed, G83 peck drill.
    holes : (k, 3) float
        Hole positions and the depth the tip feeds to: ``x, y, z`` [mm].
    r_plane : float
        Z of the R plane: rapid down to it over each hole, feed from it [mm].
    peck : float
        G83 peck depth Q [mm]; 0 for G81.
    retract : {"r", "initial"}
        Between holes, back to the R plane (G99) or to the initial level, the Z the
        cycle starts at (G98).
    initial_z : float
        Z the cycle starts at: the operation's first point [mm].
    """

    code: int
    holes: np.ndarray
    r_plane: float
    peck: float
    retract: Literal["r", "initial"]
    initial_z: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "holes", frozen_array(self.holes, (3,)).reshape(-1, 3))
        if self.code not in (81, 83) or (self.code == 83) != (self.peck > 0):
            raise ValueError("a drill cycle is G81 (peck 0) or G83 (peck > 0)")
        if self.retract not in ("r", "initial") or self.initial_z < self.r_plane:
            raise ValueError("retract is 'r' or 'initial'; the initial level is at or above R")
        if len(self.holes) == 0 or (self.holes[:, 2] > self.r_plane).any():
            raise ValueError("a drill cycle needs holes below its R plane")

    def to_dict(self) -> dict[str, Any]:
        return {"code": self.code, "holes": np.round(self.holes, 6).tolist(), "r_plane": self.r_plane,
                "peck": self.peck, "retract": self.retract, "initial_z": self.initial_z}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "DrillCycle":
        return cls(code=int(d["code"]), holes=np.asarray(d["holes"], dtype=np.float64).reshape(-1, 3),
                   r_plane=float(d["r_plane"]), peck=float(d["peck"]), retract=d["retract"],
                   initial_z=float(d["initial_z"]))


@dataclass(frozen=True)
class Operation:
    """One machining operation: a tool following a polyline of cutter locations.

    Attributes
    ----------
    name : str
        What a machinist would call it, e.g. ``"rough z-level"``; becomes a G-code comment.
    kind : {"roughing", "raster", "waterline"}
    tool : Tool
    cutting : CuttingData
    points : (n, 3) float
        Cutter locations: tool tip positions in work coordinates [mm]. Point 0 is where the
        operation starts; the post reaches it from the safe height.
    motion : (n,) int8
        ``motion[i]`` is the :class:`Motion` of the move that *ends* at ``points[i]``
        (``motion[0]`` is ignored: the post positions there by rapid at safe height).
    allowance : float
        Stock deliberately left on the part by this operation [mm].
    cycle : DrillCycle or None
        For drilling operations, the canned cycle the points expand (see
        :mod:`cadcam.drilling`); None for everything else.
    feeds : (n,) float or None
        ``feeds[i]``: the feed of the feed move that ends at ``points[i]`` [mm/min] where it is not its kind's
        (``cutting.feed``, or ``cutting.plunge_feed`` for a ramp or helix): a move raised for the chip its
        engagement allows, :mod:`cadcam.chipfeed`; NaN where it is. None: every move at its kind's feed.
    """

    name: str
    kind: str
    tool: Tool
    cutting: CuttingData
    points: np.ndarray
    motion: np.ndarray
    allowance: float = 0.0
    cycle: DrillCycle | None = None
    feeds: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", frozen_array(self.points, (3,)).reshape(-1, 3))
        object.__setattr__(self, "motion", frozen_array(self.motion, dtype=np.int8).reshape(-1))
        if len(self.points) != len(self.motion):
            raise ValueError("points and motion must have the same length")
        if self.feeds is not None:
            object.__setattr__(self, "feeds", frozen_array(self.feeds).reshape(-1))
            if len(self.feeds) != len(self.points):
                raise ValueError("feeds and points must have the same length")

    def move_feeds(self) -> np.ndarray:
        """(n,) the feed of the move ending at each point [mm/min]: ``feeds`` where it gives one, else a cutting
        move's ``cutting.feed`` and a plunge's ``cutting.plunge_feed``; NaN for rapids (``[0]`` is no move)."""
        m = self.motion
        given = np.full(len(m), np.nan) if self.feeds is None else self.feeds
        own = np.where(m == Motion.PLUNGE, self.cutting.plunge_feed, self.cutting.feed)
        return np.where(m == Motion.RAPID, np.nan, np.where(np.isnan(given), own, given))

    def lengths(self) -> dict[str, float]:
        """Path length by motion kind [mm]: ``{"rapid": .., "cut": .., "plunge": ..}``."""
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        kinds = self.motion[1:]
        return {m.name.lower(): float(seg[kinds == m].sum()) for m in Motion}

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "tool": self.tool.to_dict(),
            "cutting": dataclasses.asdict(self.cutting),
            "allowance": self.allowance,
            "points": np.round(self.points, 6).tolist(),
            "motion": self.motion.tolist(),
            **({"cycle": self.cycle.to_dict()} if self.cycle is not None else {}),
            # Python floats (tolist) for a per-element test and round: numpy scalars cost ten times as much
            **({"feeds": [None if f != f else round(f, 1) for f in self.feeds.tolist()]}
               if self.feeds is not None else {}),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Operation":
        return cls(
            name=d["name"],
            kind=d["kind"],
            tool=Tool.from_dict(d["tool"]),
            cutting=CuttingData(**d["cutting"]),
            points=np.asarray(d["points"], dtype=np.float64).reshape(-1, 3),
            motion=np.asarray(d["motion"], dtype=np.int8),
            allowance=float(d.get("allowance", 0.0)),
            cycle=DrillCycle.from_dict(d["cycle"]) if d.get("cycle") else None,
            feeds=None if d.get("feeds") is None else np.array([np.nan if f is None else f for f in d["feeds"]], float),
        )


@dataclass(frozen=True)
class SoftJaws:
    """How op 2 holds the flipped part (data for op 2; op 1 never uses it).

    Attributes
    ----------
    kind : {"pocket", "parallels"}
        ``pocket``: soft jaws with a pocket shaped like the part's outline; ``parallels``:
        plain jaws, the part's finished top face resting on parallels.
    depth : float
        How deep the part sits in the pocket, or how far the jaws grip it above the
        parallels [mm].
    """

    kind: str
    depth: float


@dataclass(frozen=True)
class FixtureBox:
    """A piece of workholding placed in work coordinates: an axis-aligned box the tool and its
    holder must never enter.

    Attributes
    ----------
    name : str
        ``"front jaw"``, ``"back jaw"`` or ``"parallels"``: named in verify faults.
    lo, hi : (3,) float
        Box corners in work coordinates [mm].
    """

    name: str
    lo: np.ndarray
    hi: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "lo", frozen_array(self.lo).reshape(3))
        object.__setattr__(self, "hi", frozen_array(self.hi).reshape(3))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "lo": self.lo.tolist(), "hi": self.hi.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "FixtureBox":
        return cls(str(d["name"]), d["lo"], d["hi"])


@dataclass(frozen=True)
class ViseJaws:
    """The machine vise as CAM sees it, in millimetres: the cell file's ``vise`` converted at
    :func:`factory.cam.vise_jaws` (the one place metres become millimetres).

    Heights are up from the vise bed; the stock's bottom rests on the parallels, clamped
    across work Y (the jaws run along work X), centred in the jaws.

    Attributes
    ----------
    jaw_height : float
        Top of the jaws above the vise bed [mm].
    jaw_width : float
        Length of the jaws along work X [mm].
    jaw_thickness : float
        Thickness of each jaw plate along work Y [mm].
    parallels_height : float
        Top of the parallels above the vise bed [mm]: where the stock's bottom rests.
    opening_min, opening_max : float
        Stock widths (along work Y) the vise clamps [mm].
    soft_jaws : SoftJaws or None
        Op 2's soft jaws; None: plain jaws on parallels.
    """

    jaw_height: float
    jaw_width: float
    jaw_thickness: float
    parallels_height: float
    opening_min: float
    opening_max: float
    soft_jaws: SoftJaws | None = None

    @property
    def grip_depth(self) -> float:
        """How far up the stock the jaws grip: the jaws' top above the stock's bottom [mm]."""
        return self.jaw_height - self.parallels_height

    def place(self, stock_min: np.ndarray, stock_max: np.ndarray) -> tuple[FixtureBox, ...]:
        """The jaws and parallels around a stock box clamped in this vise, in work coordinates [mm].

        The jaws touch the stock's front (Y-) and back (Y+) faces, centred on it along X, from
        the bed to ``grip_depth`` above the stock's bottom; the parallels fill the jaw gap
        under the stock (the two bars and the gap between them as one box: nothing may go
        below the stock's bottom anyway)."""
        lo, hi = np.asarray(stock_min, dtype=float), np.asarray(stock_max, dtype=float)
        cx = (lo[0] + hi[0]) / 2
        x0, x1 = cx - self.jaw_width / 2, cx + self.jaw_width / 2
        bed, top = lo[2] - self.parallels_height, lo[2] + self.grip_depth
        t = self.jaw_thickness
        boxes = [FixtureBox("front jaw", (x0, lo[1] - t, bed), (x1, lo[1], top)),
                 FixtureBox("back jaw", (x0, hi[1], bed), (x1, hi[1] + t, top))]
        if self.parallels_height > 0:
            boxes.append(FixtureBox("parallels", (x0, lo[1], bed), (x1, hi[1], lo[2])))
        return tuple(boxes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ViseJaws":
        soft = d.get("soft_jaws")
        values = {f.name: float(d[f.name]) for f in dataclasses.fields(cls) if f.name != "soft_jaws"}
        return cls(**values, soft_jaws=None if soft is None else SoftJaws(str(soft["kind"]), float(soft["depth"])))


@dataclass(frozen=True)
class Setup:
    """Where the part sits in the stock and where the work origin is.

    Work coordinates: X right, Y away from the operator, Z up the spindle, origin as
    named by ``origin`` (default: top of stock, front-left corner, so the whole stock
    lies in X >= 0, Y >= 0, Z <= 0).

    Attributes
    ----------
    stock_min, stock_max : (3,) float
        Stock box corners in work coordinates [mm].
    transform_mesh_to_work : (4, 4) float
        Homogeneous transform from the mesh file's coordinates (after unit scaling to
        mm) to work coordinates.
    mesh_scale : float
        Factor from the mesh file's units to mm (1 for mm, 25.4 for inch, 1000 for m);
        already applied before ``transform_mesh_to_work``.
    origin : {"top-front-left", "top-centre"}
    material : str
        Stock material key into the tool library's cutting data, e.g. ``"aluminium"``.
    safe_z : float
        Height for rapids between regions and tool changes, above the stock [mm].
    clearance : float
        Gap above already-cut material for short retracts [mm].
    floor_z : float
        The lowest any feed may reach in this operation [mm]: the part's bottom minus the
        breakthrough (op 1 breaks out into the holding allowance, never into the vise).
        None on construction: the stock's bottom (sheets from before workholding).
    jaws : tuple of FixtureBox or None
        The vise's jaws and parallels placed in work coordinates: obstacles for the tool and
        its holder. None: the workholding is unknown (nothing checked).
    """

    stock_min: np.ndarray
    stock_max: np.ndarray
    transform_mesh_to_work: np.ndarray
    mesh_scale: float = 1.0
    origin: WorkOrigin = "top-front-left"
    material: str = "aluminium"
    safe_z: float = 10.0
    clearance: float = 1.0
    floor_z: float | None = None
    jaws: tuple[FixtureBox, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stock_min", frozen_array(self.stock_min).reshape(3))
        object.__setattr__(self, "stock_max", frozen_array(self.stock_max).reshape(3))
        if self.floor_z is None:
            object.__setattr__(self, "floor_z", float(self.stock_min[2]))
        if self.jaws is not None:
            object.__setattr__(self, "jaws", tuple(self.jaws))
        object.__setattr__(
            self, "transform_mesh_to_work", frozen_array(self.transform_mesh_to_work).reshape(4, 4)
        )

    @property
    def stock_size(self) -> np.ndarray:
        """Stock box extents (x, y, z) [mm]."""
        return self.stock_max - self.stock_min

    def to_dict(self) -> dict[str, Any]:
        return {
            "stock_min": self.stock_min.tolist(),
            "stock_max": self.stock_max.tolist(),
            "transform_mesh_to_work": self.transform_mesh_to_work.tolist(),
            "mesh_scale": self.mesh_scale,
            "origin": self.origin,
            "material": self.material,
            "safe_z": self.safe_z,
            "clearance": self.clearance,
            "floor_z": self.floor_z,
            "jaws": None if self.jaws is None else [b.to_dict() for b in self.jaws],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Setup":
        return cls(
            stock_min=d["stock_min"],
            stock_max=d["stock_max"],
            transform_mesh_to_work=d["transform_mesh_to_work"],
            mesh_scale=float(d.get("mesh_scale", 1.0)),
            origin=d.get("origin", "top-front-left"),
            material=d.get("material", "aluminium"),
            safe_z=float(d.get("safe_z", 10.0)),
            clearance=float(d.get("clearance", 1.0)),
            floor_z=None if d.get("floor_z") is None else float(d["floor_z"]),
            jaws=None if d.get("jaws") is None else tuple(FixtureBox.from_dict(b) for b in d["jaws"]),
        )


@dataclass(frozen=True)
class Job:
    """Everything ``factory gcode`` needs: the setup and the operations in cutting order.

    Attributes
    ----------
    part_name : str
        Stem of the part file, used for program names.
    setup : Setup
    operations : tuple of Operation
    source_sha256 : str
        Hash of the part mesh file, for traceability.
    """

    part_name: str
    setup: Setup
    operations: tuple[Operation, ...]
    source_sha256: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)

    @property
    def tools(self) -> tuple[Tool, ...]:
        """The distinct tools in first-use order."""
        seen: dict[int, Tool] = {}
        for op in self.operations:
            seen.setdefault(op.tool.number, op.tool)
        return tuple(seen.values())

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": "factory.job/1",
            "part_name": self.part_name,
            "source_sha256": self.source_sha256,
            "parameters": self.parameters,
            "setup": self.setup.to_dict(),
            "operations": [op.to_dict() for op in self.operations],
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Job":
        if d.get("format") != "factory.job/1":
            raise ValueError(f"not a factory job (format {d.get('format')!r})")
        return cls(
            part_name=d["part_name"],
            setup=Setup.from_dict(d["setup"]),
            operations=tuple(Operation.from_dict(o) for o in d["operations"]),
            source_sha256=d.get("source_sha256", ""),
            parameters=dict(d.get("parameters", {})),
        )


@dataclass(frozen=True)
class ProgramMoves:
    """The moves of a G-code program, arcs already broken into short chords.

    What the G-code parser produces and the material-removal simulation consumes.
    Positions are tool tip positions in work coordinates [mm] (tool length offset
    applied, as a controller with G43 would). Axes not yet programmed are NaN.

    Attributes
    ----------
    points : (n, 3) float
        Position after each move [mm]; ``points[0]`` is the position before the first
        move (all NaN at program start).
    motion : (n,) int8
        :class:`Motion` of the move ending at ``points[i]`` (RAPID for G0, CUT for
        G1/G2/G3; the parser never produces PLUNGE). ``motion[0]`` is meaningless.
    tool : (n,) int32
        Tool number in the spindle during the move ending at ``points[i]`` (0: none).
    feed : (n,) float
        Programmed feed during that move [mm/min] (NaN for rapids).
    line : (n,) int32
        1-based source line of the block that made the move (0 for ``points[0]``).
    source : str or None
        The program file the moves were read from, named in errors about a line.
    """

    points: np.ndarray
    motion: np.ndarray
    tool: np.ndarray
    feed: np.ndarray
    line: np.ndarray
    source: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", frozen_array(self.points, (3,)).reshape(-1, 3))
        object.__setattr__(self, "motion", frozen_array(self.motion, dtype=np.int8).reshape(-1))
        object.__setattr__(self, "tool", frozen_array(self.tool, dtype=np.int32).reshape(-1))
        object.__setattr__(self, "feed", frozen_array(self.feed).reshape(-1))
        object.__setattr__(self, "line", frozen_array(self.line, dtype=np.int32).reshape(-1))
        n = len(self.points)
        if not all(len(a) == n for a in (self.motion, self.tool, self.feed, self.line)):
            raise ValueError("ProgramMoves arrays must have the same length")
