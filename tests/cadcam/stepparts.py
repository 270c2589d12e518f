"""STEP test parts modelled with build123d (a test-only dependency), written where the test says.

Each builder returns the part and the modelling parameters the recognised features must equal:
plates with through holes, blind holes with flat and drill-point (118 deg) bottoms, an inch part,
two solids in one file, an inclined hole, a surfaces-only file, and a plate of many pockets and
holes for the intake benchmark. Millimetres unless a name says otherwise; the plate's top is at Z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

#: A twist drill's point angle [deg]: the cone a drill leaves at a blind hole's bottom.
DRILL_POINT = 118.0


@dataclass(frozen=True)
class ModelledHole:
    """A vertical hole as modelled: axis X, Y [mm], diameter [mm], depth of its wall [mm] (None: through), bottom."""

    x: float
    y: float
    diameter: float
    depth: float | None
    bottom: str = "flat"  # "flat" or "conical" for blind holes
    counterbore: tuple[float, float] | None = None  # diameter, depth [mm]
    countersink: float | None = None  # diameter at the top of a 90 deg countersink [mm]

    @property
    def tip_depth(self) -> float | None:
        """Depth of the lowest point [mm]: the drill point's apex for a conical bottom."""
        if self.depth is None or self.bottom != "conical":
            return self.depth
        return self.depth + self.diameter / 2 / math.tan(math.radians(DRILL_POINT / 2))


def plate(size: tuple[float, float, float], holes: list[ModelledHole]):
    """A block ``size`` X, Y, Z [mm] with its top face at Z = 0, centred on X = Y = 0, and ``holes`` from the top."""
    from build123d import Align, Box, Cone, Cylinder, Location, Pos

    sx, sy, sz = size
    part = Box(sx, sy, sz, align=(Align.CENTER, Align.CENTER, Align.MAX))
    for h in holes:
        r = h.diameter / 2
        depth = sz + 2 if h.depth is None else h.depth
        top = 1.0 if h.depth is None else 0.0  # a through cutter starts above the top
        cutter = Pos(h.x, h.y, top) * Cylinder(r, depth + top, align=(Align.CENTER, Align.CENTER, Align.MAX))
        if h.depth is not None and h.bottom == "conical":
            height = r / math.tan(math.radians(DRILL_POINT / 2))
            cone = Location((h.x, h.y, -h.depth)) * Cone(0.0, r, height, align=(Align.CENTER, Align.CENTER, Align.MAX))
            cutter = cutter + cone
        if h.counterbore is not None:
            d, depth = h.counterbore
            cutter = cutter + Pos(h.x, h.y, 1.0) * Cylinder(d / 2, depth + 1.0, align=(Align.CENTER, Align.CENTER,
                                                                                        Align.MAX))
        if h.countersink is not None:  # 90 deg: as deep as its radius, from the top face down
            cs = h.countersink / 2
            cutter = cutter + Location((h.x, h.y, -cs)) * Cone(0.0, cs + 1.0, cs + 1.0,
                                                               align=(Align.CENTER, Align.CENTER, Align.MIN))
        part = part - cutter
    return part


def write_step(shape, path: Path, unit: str = "MM") -> Path:
    """Write ``shape`` (a build123d shape, in mm) as STEP in ``unit`` (``"MM"`` or ``"INCH"``): coordinates
    converted and the unit declared by OpenCASCADE's writer."""
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer

    from cadcam.step import _quiet_stdout

    with _quiet_stdout():
        writer = STEPControl_Writer()
        Interface_Static.SetCVal_s("write.step.unit", unit)
        try:
            writer.Transfer(shape.wrapped, STEPControl_AsIs)
            writer.Write(str(path))
        finally:
            Interface_Static.SetCVal_s("write.step.unit", "MM")  # a global: leave it as found
    return path


def write_stl(shape, path: Path, tolerance: float = 0.001) -> Path:
    """A fine STL of ``shape``: chordal deviation ``tolerance`` [mm], 0.05 rad angular."""
    from build123d import export_stl

    export_stl(shape, str(path), tolerance=tolerance, angular_tolerance=0.05)
    return path


def two_solids():
    """Two disjoint blocks in one compound: 40 x 30 x 10 mm and 20 x 20 x 15 mm beside it."""
    from build123d import Align, Box, Compound, Pos

    a = Box(40, 30, 10, align=(Align.CENTER, Align.CENTER, Align.MAX))
    b = Pos(60, 0, 0) * Box(20, 20, 15, align=(Align.CENTER, Align.CENTER, Align.MAX))
    return Compound([a, b])


def countersunk_head(shank: float = 6.0, length: float = 10.0, head: float = 12.0):
    """A countersunk screw's blank, thread left out: a ``shank`` mm cylinder ``length`` mm long under a 90 deg cone
    widening to ``head`` mm at the top face (Z = 0): the cone looks down, so only op 2 cuts it, where its jaws hold it."""
    from build123d import Align, Cone, Cylinder, Pos

    sink = (head - shank) / 2  # the 90 deg cone's height [mm]
    cone = Cone(shank / 2, head / 2, sink, align=(Align.CENTER, Align.CENTER, Align.MAX))
    return cone + Pos(0, 0, -sink) * Cylinder(shank / 2, length, align=(Align.CENTER, Align.CENTER, Align.MAX))


def inclined_hole(diameter: float = 6.0, tilt_deg: float = 30.0):
    """A 60 x 40 x 20 mm block with a through hole tilted ``tilt_deg`` from Z towards +Y, through its centre."""
    from build123d import Align, Box, Cylinder, Rot

    block = Box(60, 40, 20, align=(Align.CENTER, Align.CENTER, Align.CENTER))
    return block - Rot(-tilt_deg, 0, 0) * Cylinder(diameter / 2, 80)


def pillow_surface():
    """Surfaces only: the top of a 50 x 40 x 10 mm block whose top and vertical edges are rounded R5, cut off
    5 mm down, without sides or bottom: an open sheet facing up with a rounded outline (a relief)."""
    from build123d import Align, Axis, Box, Shell, fillet

    box = Box(50, 40, 10, align=(Align.CENTER, Align.CENTER, Align.MAX))
    rounded = fillet(box.edges() - box.edges().group_by(Axis.Z)[0], 5.0)
    top = [f for f in rounded.faces() if f.center().Z > -5.0 + 1e-6]
    return Shell(top)


def feature_plate(columns: int = 10, rows: int = 8, pitch: float = 14.0) -> tuple[object, list[ModelledHole]]:
    """A plate with a grid of features, alternating a 9 x 7 x 3 mm pocket with R1.5 inside corners (9 faces) and a
    hole cycling through drill sizes and ends: about 500 B-rep faces at 12 x 8 (the intake benchmark's part)."""
    from build123d import Align, Axis, Box, Pos, fillet

    sizes = [3.3, 4.2, 5.0, 6.8, 8.5]
    holes, pockets = [], []
    for i in range(columns):
        for j in range(rows):
            k = i * rows + j
            x, y = (i - (columns - 1) / 2) * pitch, (j - (rows - 1) / 2) * pitch
            if (i + j) % 2:
                pocket = Pos(x, y, 0) * Box(9, 7, 3, align=(Align.CENTER, Align.CENTER, Align.MAX))
                pockets.append(fillet(pocket.edges().filter_by(Axis.Z), 1.5))
            else:
                kind = k % 3
                depth = None if kind == 0 else 6.0 + (k % 4)
                holes.append(ModelledHole(x, y, sizes[k % len(sizes)], depth, "conical" if kind == 2 else "flat"))
    part = plate((columns * pitch + 10, rows * pitch + 10, 16.0), holes)
    for pocket in pockets:
        part = part - pocket
    return part, holes


def t_slot(length: float = 60.0, neck: float = 8.0, neck_depth: float = 8.0, head: float = 18.0,
           head_depth: float = 6.0):
    """A ``length`` x 40 x 30 mm block with a T-slot along X through it: a ``neck`` mm wide slot from the top face
    (Z = 0) down ``neck_depth`` mm, over a ``head`` mm wide one ``head_depth`` mm tall. The lips' undersides at
    Z = -``neck_depth`` look down over the slot's floor: undercuts."""
    from build123d import Align, Box, Pos

    block = Box(length, 40, 30, align=(Align.CENTER, Align.CENTER, Align.MAX))
    top = Pos(0, 0, 1) * Box(length + 2, neck, neck_depth + 1, align=(Align.CENTER, Align.CENTER, Align.MAX))
    low = Pos(0, 0, -neck_depth) * Box(length + 2, head, head_depth, align=(Align.CENTER, Align.CENTER, Align.MAX))
    return block - top - low


def dovetail(length: float = 60.0, mouth: float = 10.0, floor: float = 20.0, depth: float = 8.0):
    """A ``length`` x 40 x 30 mm block with a dovetail slot along X through it: ``mouth`` mm wide at the top face
    (Z = 0), ``floor`` mm wide at its floor ``depth`` mm down. Its flanks look down over the floor: undercuts."""
    from build123d import Align, Box, Plane, Polygon, extrude

    block = Box(length, 40, 30, align=(Align.CENTER, Align.CENTER, Align.MAX))
    # the slot's section in the YZ plane (its local X, Y are Y, Z), carried 1 mm past both ends
    section = Plane.YZ * Polygon((-mouth / 2, 0), (mouth / 2, 0), (floor / 2, -depth), (-floor / 2, -depth),
                                 align=None)
    return block - extrude(section, amount=length / 2 + 1, both=True)


def bored_plates(diameter: float = 13.0, plate: float = 6.0, gap: float = 10.0):
    """Two ``plate`` mm plates 40 x 30 mm, ``gap`` mm of air between them, joined by a 6 mm back wall (Y = 15), and
    one ``diameter`` mm bore along Z at X = 0, Y = -4 through both. The top face is at Z = 0. The two bores
    are separate holes on one axis (a bearing jig's, Too Tall Toby 01-06)."""
    from build123d import Align, Box, Cylinder, Pos

    block = Box(40, 30, 2 * plate + gap, align=(Align.CENTER, Align.CENTER, Align.MAX))
    slot = Pos(0, -3 - 1, -plate) * Box(42, 24 + 2, gap, align=(Align.CENTER, Align.CENTER, Align.MAX))
    bore = Pos(0, -4, 1) * Cylinder(diameter / 2, 2 * plate + gap + 2, align=(Align.CENTER, Align.CENTER, Align.MAX))
    return block - slot - bore
