"""A gallery of parts factory was not tuned for: what a machinist brings (issue 34, "Real parts").

Each part is made here with manifold3d CSG (or a meshed heightfield), millimetres, bottom on z = 0, and
carries what a machinist would expect of a vise cell: ``plans`` (planned with defaults, every program
accepted by ``rs274`` and passed by verify) or ``refused`` (one line with the figures: it fits no
orientation of the vise, or is thinner than the grip allows). The expectations are the cell's, not
today's engine's: the benchmark ``benchmarks/gallery.py`` reports where the engine falls short.

The parts deliberately span what the samples do not: tall parts that need both operations, deep pockets,
wide plates, thin plates, sharp inside corners in narrow slots, reliefs that reach the stock's edge, and
parts that fit the jaws only when turned about Z.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import manifold3d as mf
import numpy as np
import trimesh

from samples.make_relief import heightfield_sheet
from samples.make_samples import SEGMENTS, box, cylinder, rounded_rect, to_trimesh


@dataclass(frozen=True)
class GalleryPart:
    """One part of the gallery and what a machinist expects the cell to do with it.

    make : () -> trimesh.Trimesh
        The part [mm], bottom on z = 0.
    expect : str
        ``"plans"``: plans with defaults and passes verify; ``"refused"``: refused in one line.
    why : str
        What the part tries (a tall boss, a sliver in a sharp corner, ...).
    """

    name: str
    make: Callable[[], trimesh.Trimesh]
    expect: str
    why: str

    def write(self, folder: Path) -> Path:
        """The part as a binary STL in ``folder``."""
        path = folder / f"{self.name}.stl"
        path.write_bytes(trimesh.exchange.stl.export_stl(self.make()))
        return path


def _solid(build: Callable[[], mf.Manifold]) -> Callable[[], trimesh.Trimesh]:
    return lambda: to_trimesh(build())


def _cone(cx: float, cy: float, r0: float, r1: float, z0: float, z1: float) -> mf.Manifold:
    return mf.Manifold.cylinder(z1 - z0, r0, r1, circular_segments=SEGMENTS).translate((cx, cy, z0))


def boss_on_base() -> mf.Manifold:
    """A 60 mm tall boss on a 10 mm base: deeper than any short end mill reaches from the top."""
    return rounded_rect(0, 0, 80, 60, 4, 0, 10) + cylinder(40, 30, 15, 9, 70)


def cone_on_base() -> mf.Manifold:
    """A cone 45 mm tall on a base: a steep freeform flank."""
    return box(0, 0, 0, 70, 70, 10) + _cone(35, 35, 30, 6, 9.5, 55)


def sphere_on_base() -> mf.Manifold:
    """A ball on a plinth: the lower half undercuts from the top, so op 2 has to reach it."""
    ball = mf.Manifold.sphere(22, circular_segments=SEGMENTS).translate((35, 35, 30))
    return box(0, 0, 0, 70, 70, 10) + ball


def deep_pocket() -> mf.Manifold:
    """A 40 x 30 pocket 50 mm deep with R6 corners, in a 60 mm block."""
    return box(0, 0, 0, 80, 70, 60) - rounded_rect(20, 20, 60, 50, 6, 10, 61)


def wide_plate_pockets() -> mf.Manifold:
    """A 200 mm plate with four pockets: wider along X than the jaws are long."""
    part = box(0, 0, 0, 200, 100, 15)
    for x in (10, 58, 106, 154):
        part -= rounded_rect(x, 20, x + 36, 80, 5, 7, 16)
    return part


def thin_plate_holes() -> mf.Manifold:
    """A 3 mm plate with six 6 mm drilled holes: barely more than the grip allows."""
    part = box(0, 0, 0, 100, 60, 3)
    for x in (15, 50, 85):
        for y in (15, 45):
            part -= cylinder(x, y, 3, -1, 4)
    return part


def sheet_1mm() -> mf.Manifold:
    """A 1 mm sheet: thinner than any vise grip, to be refused with the figures."""
    return box(0, 0, 0, 80, 50, 1)


def filleted_block() -> mf.Manifold:
    """A block with R8 vertical edges and a 45 degree chamfered top edge (a hull of two slabs)."""
    lower = rounded_rect(0, 0, 70, 50, 8, 0, 16)
    top = rounded_rect(3, 3, 67, 47, 5, 16, 19)
    return mf.Manifold.batch_hull([lower, top]) - rounded_rect(20, 15, 50, 35, 4, 12, 20)


def narrow_slots() -> mf.Manifold:
    """Slots 4 mm wide with sharp inside corners: slivers only the smallest end mill reaches."""
    part = box(0, 0, 0, 70, 40, 15)
    for y in (6, 18, 30):
        part -= box(10, y, 9, 60, y + 4, 16)
    return part


def cross_pocket() -> mf.Manifold:
    """A plus-shaped pocket with four sharp re-entrant corners."""
    part = box(0, 0, 0, 80, 80, 20)
    part -= box(30, 10, 10, 50, 70, 21)
    part -= box(10, 30, 10, 70, 50, 21)
    return part


def island_pocket() -> mf.Manifold:
    """A pocket with an island left standing in it: a narrow neck on each side."""
    part = box(0, 0, 0, 80, 60, 20) - rounded_rect(10, 10, 70, 50, 5, 8, 21)
    return part + rounded_rect(22, 20, 58, 40, 3, 7.5, 20)


def counterbored_plate() -> mf.Manifold:
    """A plate with counterbored and plain holes of several sizes."""
    part = box(0, 0, 0, 90, 60, 12)
    for x, r, rc in ((15, 3.3, 5.5), (45, 4.5, 8), (75, 5.5, 9)):
        part -= cylinder(x, 20, r, -1, 13)
        part -= cylinder(x, 20, rc, 6, 13)
        part -= cylinder(x, 45, r, -1, 13)
    return part


def tall_rib() -> mf.Manifold:
    """A 2.5 mm rib 35 mm tall on a base: a wall no roughing step may bend."""
    return box(0, 0, 0, 70, 40, 8) + box(10, 18.75, 7.5, 60, 21.25, 43)


def stepped_tower() -> mf.Manifold:
    """Four steps to 48 mm: each level a flat at its own height."""
    part = box(0, 0, 0, 80, 60, 12)
    part += box(10, 8, 11.5, 70, 52, 24)
    part += box(20, 16, 23.5, 60, 44, 36)
    return part + box(30, 22, 35.5, 50, 38, 48)


def split_tower() -> mf.Manifold:
    """A 24 x 18 tower to 72 mm on a 50 x 40 base: deeper than any tool reaches from one side, prismatic."""
    return box(0, 0, 0, 50, 40, 10) + box(13, 11, 9.5, 37, 29, 72)


def web_in_tube(height: float = 72.0, web: tuple[float, float] = (10.0, 16.0)) -> mf.Manifold:
    """A 44 x 36 tube ``height`` tall with 5 mm walls and a web across it at ``web`` (bottom, top) [mm]: the
    pocket under the web only op 2 sees, and it reaches past where op 1 stops from the top (OpenCAMLib's
    wheel_in_box: the rim under the wheel's plate). Deeper than the tools reach from one side by default."""
    inside = (5.0, 5.0, 39.0, 31.0, 4.0)
    return box(0, 0, 0, 44, 36, height) - rounded_rect(*inside, -1, web[0]) - rounded_rect(*inside, web[1], height + 1)


def l_bracket() -> mf.Manifold:
    """An L-shaped bracket standing on its long leg, a 40 mm upright with two holes."""
    part = box(0, 0, 0, 90, 50, 8) + box(0, 0, 7.5, 10, 50, 48)
    for x in (35, 70):
        part -= cylinder(x, 25, 4.5, -1, 9)
    return part


def hex_boss() -> mf.Manifold:
    """A hexagonal boss with a bore, on a round-cornered base."""
    hexagon = mf.CrossSection.circle(18, circular_segments=6)
    boss = mf.Manifold.extrude(hexagon, 20).translate((40, 35, 9.5))
    return rounded_rect(0, 0, 80, 70, 6, 0, 10) + boss - cylinder(40, 35, 8, 12, 30.5)


def tiny_part() -> mf.Manifold:
    """A 20 x 16 x 12 part with a 6 mm pocket: the smallest stock the vise and gripper hold."""
    return box(0, 0, 0, 20, 16, 12) - rounded_rect(6, 5, 14, 11, 3, 7, 13)


def frame() -> mf.Manifold:
    """A rectangular frame: a through window with R5 corners, outer walls 8 mm."""
    return box(0, 0, 0, 100, 70, 14) - rounded_rect(8, 8, 92, 62, 5, -1, 15)


def long_turned() -> mf.Manifold:
    """230 mm along Y and 50 along X: too wide for the 6-inch vise's 223.5 mm opening unless turned 90 degrees about Z."""
    part = box(0, 0, 0, 50, 230, 16)
    for y in (20, 70, 120, 170):
        part -= rounded_rect(10, y, 40, y + 40, 5, 8, 17)
    return part


def random_blocks(seed: int = 7) -> mf.Manifold:
    """A machinable block: random rectangular steps and pockets, seeded."""
    rng = np.random.default_rng(seed)
    part = box(0, 0, 0, 90, 70, 12)
    for _ in range(4):
        x, y = rng.uniform(5, 55), rng.uniform(5, 40)
        w, d = rng.uniform(12, 30), rng.uniform(12, 25)
        part += box(x, y, 11.5, x + w, y + d, 12 + rng.uniform(3, 15))
    for _ in range(2):
        x, y = rng.uniform(8, 60), rng.uniform(8, 45)
        part -= rounded_rect(x, y, x + 18, y + 14, 4, 12 - rng.uniform(3, 8), 40)
    return part


def _heightfield_solid(heights: Callable[[np.ndarray, np.ndarray], np.ndarray], size: tuple[float, float],
                       n: tuple[int, int], base: float) -> trimesh.Trimesh:
    """A closed solid under a heightfield [mm]: the sheet hung down to z = 0 over a flat bottom."""
    x, y = np.linspace(0.0, size[0], n[0]), np.linspace(0.0, size[1], n[1])
    top = heightfield_sheet(x, y, base + heights(*np.meshgrid(x, y)), sides_to=0.0)
    bottom = heightfield_sheet(x, y, np.zeros((len(y), len(x))))
    bottom.invert()  # faces down
    # The hung sides end on the bottom's rim vertices: welding equal positions closes the solid.
    mesh = trimesh.util.concatenate([top, bottom])
    mesh.merge_vertices()
    if not (mesh.is_watertight and mesh.volume > 0):
        raise RuntimeError("heightfield solid is not closed")
    return mesh


def relief_to_edge() -> trimesh.Trimesh:
    """A closed relief whose ripples run out to the stock's edge, over an 8 mm plinth."""
    def heights(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        return 4.0 + 3.0 * np.sin(X / 7.0) * np.cos(Y / 9.0) + 2.0 * np.exp(-((X - 40) ** 2 + (Y - 30) ** 2) / 200)
    return _heightfield_solid(heights, (80.0, 60.0), (81, 61), 8.0)


PARTS: tuple[GalleryPart, ...] = (
    GalleryPart("boss_on_base", _solid(boss_on_base), "plans", "a 60 mm boss: op 1 and op 2 split the depth"),
    GalleryPart("cone_on_base", _solid(cone_on_base), "plans", "a 45 mm cone: steep freeform, tall"),
    GalleryPart("sphere_on_base", _solid(sphere_on_base), "plans", "a ball: its lower half only op 2 reaches"),
    GalleryPart("deep_pocket", _solid(deep_pocket), "plans", "a 50 mm deep pocket: long-reach tools"),
    GalleryPart("wide_plate_pockets", _solid(wide_plate_pockets), "plans", "a 200 mm plate"),
    GalleryPart("thin_plate_holes", _solid(thin_plate_holes), "plans", "a 3 mm plate with drilled holes"),
    GalleryPart("sheet_1mm", _solid(sheet_1mm), "refused", "thinner than any grip"),
    GalleryPart("filleted_block", _solid(filleted_block), "plans", "R8 edges and a chamfered top edge"),
    GalleryPart("narrow_slots", _solid(narrow_slots), "plans", "4 mm slots with sharp inside corners"),
    GalleryPart("cross_pocket", _solid(cross_pocket), "plans", "sharp re-entrant corners"),
    GalleryPart("island_pocket", _solid(island_pocket), "plans", "an island with narrow necks"),
    GalleryPart("counterbored_plate", _solid(counterbored_plate), "plans", "counterbores and holes"),
    GalleryPart("tall_rib", _solid(tall_rib), "plans", "a thin rib 35 mm tall"),
    GalleryPart("stepped_tower", _solid(stepped_tower), "plans", "four flats to 48 mm"),
    GalleryPart("l_bracket", _solid(l_bracket), "plans", "a 40 mm upright on a leg"),
    GalleryPart("split_tower", _solid(split_tower), "plans", "72 mm: op 1 and op 2 split the depth, walls meet"),
    GalleryPart("web_in_tube", _solid(web_in_tube), "plans",
                "72 mm: op 2 reaches past op 1's floor into the pocket under a web"),
    GalleryPart("hex_boss", _solid(hex_boss), "plans", "a hexagonal boss with a bore"),
    GalleryPart("tiny_part", _solid(tiny_part), "plans", "the smallest stock the cell holds"),
    GalleryPart("frame", _solid(frame), "plans", "a through window"),
    GalleryPart("long_turned", _solid(long_turned), "plans", "fits the jaws only turned about Z"),
    GalleryPart("random_blocks", _solid(random_blocks), "plans", "seeded random steps and pockets"),
    GalleryPart("relief_to_edge", relief_to_edge, "plans", "a closed relief reaching the stock's edge"),
)

BY_NAME = {p.name: p for p in PARTS}
