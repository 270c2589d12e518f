"""Machining features recognised in a part: round holes, holes for another setup, undercuts, flat faces, inside corners.

Each feature is a small frozen value in millimetres, in the part file's own axes (only scaled
to mm, like :class:`cadcam.mesh.PartMesh`), and says where it was read from: ``source`` is
``"step"`` for a feature taken from a STEP file's exact B-rep (:mod:`cadcam.step`), ``"mesh"``
for one guessed from triangles. The drilling stage takes the round holes as its input
(:meth:`PartFeatures.holes_in_work`) instead of guessing them from the tessellation.
"""

from __future__ import annotations

import dataclasses
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from cadcam.drilling import Countersink, Hole

Source = Literal["step", "mesh"]
#: How a vertical round hole ends: the three :mod:`cadcam.drilling` cuts, ``stepped`` (its floor
#: is an annulus around a narrower bore: a counterbore, left to roughing as on a mesh) or ``other``.
HoleEnd = Literal["through", "flat", "conical", "stepped", "other"]


def _placed(point: tuple[float, float, float], how: str, direction: tuple[float, float, float]) -> str:
    """``at X.. Y.. Z.. <how> (i, j, k)``: a place [mm] and a direction [1] as a report gives them."""
    x, y, z, i, j, k = (c + 0.0 for c in (*point, *direction))  # + 0.0: a -0.0 reads 0.000
    return f"at X{x:.3f} Y{y:.3f} Z{z:.3f} {how} ({i:.3f}, {j:.3f}, {k:.3f})"


@dataclass(frozen=True)
class Counterbore:
    """A wider flat-bottomed bore over a hole, on its axis: ``diameter`` [mm], from ``top_z`` down to ``floor_z`` [mm]."""

    diameter: float
    top_z: float
    floor_z: float

    @property
    def depth(self) -> float:
        """From its top to its floor [mm]."""
        return self.top_z - self.floor_z


@dataclass(frozen=True)
class RoundHole:
    """A full round bore along Z, open to the top.

    Attributes
    ----------
    x, y : float
        Axis position [mm].
    diameter : float
        Exact diameter of the cylinder [mm].
    top_z, bottom_z : float
        Where the cylindrical wall starts and ends [mm].
    tip_z : float
        Lowest point of the hole [mm]: the apex of a drill-point (conical) bottom, else ``bottom_z``.
    bottom : {"through", "flat", "conical", "stepped", "other"}
    source : {"step", "mesh"}
    counterbore : Counterbore or None
        The wider bore over it (its floor is this hole's ``top_z``); None: none.
    countersink : Countersink or None
        The cone at its mouth (at the counterbore's floor where there is one); None: none.
    """

    x: float
    y: float
    diameter: float
    top_z: float
    bottom_z: float
    tip_z: float
    bottom: HoleEnd
    source: Source
    counterbore: Counterbore | None = None
    countersink: Countersink | None = None

    @property
    def depth(self) -> float:
        """From the top of the wall to the lowest point [mm]."""
        return self.top_z - self.tip_z

    @property
    def drillable(self) -> bool:
        """A bore :mod:`cadcam.drilling` cuts: through, flat or drill-point bottom."""
        return self.bottom in ("through", "flat", "conical")

    def to_hole(self, transform_mesh_to_work: np.ndarray, chord: float) -> Hole:
        """The drilling stage's hole in work coordinates.

        ``transform_mesh_to_work`` (4, 4) [mm] takes the file's axes to work coordinates
        (:attr:`cadcam.model.Setup.transform_mesh_to_work`: a turn about Z, then a translation);
        ``chord`` [mm] the tessellation's chordal deviation: the wall's facets lie up to that far
        inside the true circle, so a tool ``diameter - 2 chord`` wide cuts nothing of the tessellated wall.
        """
        t = np.asarray(transform_mesh_to_work, dtype=np.float64)
        x, y = (float(v) for v in t[:2, :2] @ (self.x, self.y) + t[:2, 3])
        dz = float(t[2, 3])
        sink = self.countersink
        if sink is not None:
            sink = dataclasses.replace(sink, top_z=sink.top_z + dz)
        return Hole(x=x, y=y, diameter=self.diameter, inscribed=self.diameter - 2 * chord,
                    top_z=self.top_z + dz, bottom_z=self.bottom_z + dz, tip_z=self.tip_z + dz,
                    bottom=self.bottom, countersink=sink)  # type: ignore[arg-type]

    def counterbore_hole(self, transform_mesh_to_work: np.ndarray, chord: float) -> Hole | None:
        """The counterbore as the drilling stage's flat-bottomed hole in work coordinates (the bore
        below is air once drilled, so its annular floor cuts as a flat one); None without one."""
        cb = self.counterbore
        if cb is None:
            return None
        bore = dataclasses.replace(self, diameter=cb.diameter, top_z=cb.top_z, bottom_z=cb.floor_z,
                                   tip_z=cb.floor_z, bottom="flat", counterbore=None, countersink=None)
        return bore.to_hole(transform_mesh_to_work, chord)

    def describe(self) -> str:
        seat = ""
        if self.counterbore is not None:
            seat += f", counterbore {self.counterbore.diameter:.3f} mm x {self.counterbore.depth:.3f} mm deep"
        if self.countersink is not None:
            seat += f", countersink {self.countersink.diameter:.3f} mm x {self.countersink.angle:g} deg"
        return (f"{self.diameter:.3f} mm {self.bottom} hole at X{self.x:.3f} Y{self.y:.3f}, "
                f"{self.depth:.3f} mm deep{seat} ({self.source})")

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "depth": self.depth}


@dataclass(frozen=True)
class SetupHole:
    """A round hole this setup cannot cut from the top: off the Z axis, or covered from above.

    Attributes
    ----------
    point : (3,) tuple of float
        A point on the axis, halfway along the wall [mm].
    direction : (3,) tuple of float
        Unit axis direction [1], turned to point up (or along +X, +Y when horizontal).
    diameter, length : float
        Exact diameter and length of the wall along its axis [mm].
    reason : str
        Why another setup (or a 4th axis) is needed.
    source : {"step", "mesh"}
    """

    point: tuple[float, float, float]
    direction: tuple[float, float, float]
    diameter: float
    length: float
    reason: str
    source: Source

    def describe(self) -> str:
        return (f"{self.diameter:.3f} mm hole {_placed(self.point, 'along', self.direction)}, "
                f"{self.length:.3f} mm long: {self.reason}; needs another setup or a 4th axis")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Undercut:
    """A face that looks down with the part under it: no tool from the top reaches it (the material
    lies over it), nor one from below once the part is turned over (the material under it is in
    the way), as under a T-slot's lips or on a dovetail's flanks.

    Attributes
    ----------
    face : int
        The B-rep face (0-based, in the solid's order).
    point : (3,) tuple of float
        Where it is [mm]: the middle of the face's covered triangles, weighted by their area.
    direction : (3,) tuple of float
        Unit vector [1] out of the material there (the face's mean outward normal): the way a
        tool must come from, in another setup or on a 4th axis.
    area : float
        Area of the face's triangles that look down with the part under them [mm^2].
    source : {"step", "mesh"}
    """

    face: int
    point: tuple[float, float, float]
    direction: tuple[float, float, float]
    area: float
    source: Source

    def describe(self) -> str:
        return (f"undercut face {self.face} {_placed(self.point, 'facing', self.direction)}, {self.area:.1f} mm^2: "
                "looks down with the part under it, no tool from the top or from below reaches it; needs another "
                "setup or a 4th axis")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class FlatFace:
    """A plane face square to Z at its exact height.

    ``z`` [mm]; ``area`` [mm^2]; ``facing`` ``"up"`` (material below, reached from the top) or ``"down"``.
    """

    z: float
    area: float
    facing: Literal["up", "down"]
    source: Source

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class InsideCorner:
    """A concave vertical fillet: the smallest tool radius that finishes it is ``radius``.

    ``x, y`` the fillet's axis [mm], ``radius`` [mm], ``bottom_z, top_z`` its extent [mm].
    """

    x: float
    y: float
    radius: float
    bottom_z: float
    top_z: float
    source: Source

    def describe(self) -> str:
        return f"inside corner R{self.radius:.3f} at X{self.x:.3f} Y{self.y:.3f} Z{self.bottom_z:.3f}..{self.top_z:.3f}"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class PartFeatures:
    """Every feature recognised in one part [mm, the file's axes]."""

    holes: tuple[RoundHole, ...] = ()
    elsewhere: tuple[SetupHole, ...] = ()
    flats: tuple[FlatFace, ...] = ()
    corners: tuple[InsideCorner, ...] = ()
    undercuts: tuple[Undercut, ...] = ()
    #: B-rep faces of free-form surfaces (B-spline, Bezier, extrusion, revolution, offset): a bore made
    #: of them (the public as1-oc-214's holes are extrusions) is not read as a round hole.
    freeform: int = 0

    def holes_in_work(self, transform_mesh_to_work: np.ndarray, chord: float) -> tuple[Hole, ...]:
        """The drillable holes as :class:`cadcam.drilling.Hole` in work coordinates.

        ``transform_mesh_to_work`` (4, 4): a turn about Z, then a translation (:func:`cadcam.setup.make_setup`);
        ``chord`` the tessellation's chordal deviation [mm] (:meth:`RoundHole.to_hole`).
        """
        found = [h.to_hole(transform_mesh_to_work, chord) for h in self.holes if h.drillable]
        # a counterbore is a flat-bottomed hole over its bore: helixed, or left to roughing when wide
        found += [cb for h in self.holes if h.drillable
                  if (cb := h.counterbore_hole(transform_mesh_to_work, chord)) is not None]
        return tuple(sorted(found, key=lambda h: (round(h.x, 6), round(h.y, 6), -h.top_z)))

    def unreachable_corners(self, smallest_radius: float) -> tuple[InsideCorner, ...]:
        """Inside corners tighter than ``smallest_radius`` [mm] (the library's narrowest end mill)."""
        return tuple(c for c in self.corners if c.radius < smallest_radius - 1e-9)

    def to_dict(self) -> dict[str, Any]:
        return {"holes": [h.to_dict() for h in self.holes], "elsewhere": [h.to_dict() for h in self.elsewhere],
                "flats": [f.to_dict() for f in self.flats], "corners": [c.to_dict() for c in self.corners],
                "undercuts": [u.to_dict() for u in self.undercuts], "freeform": self.freeform}
