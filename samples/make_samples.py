"""Make the sample parts in ``samples/`` with manifold3d CSG: ``python samples/make_samples.py``.

Four parts that look like ordinary shop work, 3-axis machinable from the top (every face
visible from +Z, no undercuts), features sized for a 6 mm cutter (holes and pockets at
least 10 mm wide, internal pocket corners with >= 4 mm radius):

- ``bracket.stl``       100 x 60 x 15 plate, two rounded 5 mm deep pockets, five through-holes
- ``plate_bosses.stl``  90 x 70 x 8 base with four bosses, three of them counterbored
- ``dome_mould.stl``    90 x 70 x 30 block with a smooth half-ellipsoid mould cavity, 15 mm deep,
                        and four 10 mm guide-pin bores
- ``stepped_wall.stl``  100 x 50 part with three steps and a 3 mm thin wall 20 mm tall

All dimensions in millimetres; the part's bottom lies on z = 0. Output is binary STL,
deterministic (same bytes on every run).
"""

from __future__ import annotations

import sys
from pathlib import Path

import manifold3d as mf
import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
SEGMENTS = 96  # around a full circle: smooth enough for finishing, few enough triangles


def box(x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> mf.Manifold:
    return mf.Manifold.cube((x1 - x0, y1 - y0, z1 - z0)).translate((x0, y0, z0))


def rounded_rect(x0: float, y0: float, x1: float, y1: float, r: float, z0: float, z1: float) -> mf.Manifold:
    """A prism with a rounded-rectangle footprint: the shape an end mill leaves in a pocket."""
    core = mf.CrossSection.square((x1 - x0 - 2 * r, y1 - y0 - 2 * r)).translate((x0 + r, y0 + r))
    outline = core.offset(r, mf.JoinType.Round, circular_segments=SEGMENTS)
    return mf.Manifold.extrude(outline, z1 - z0).translate((0, 0, z0))


def cylinder(cx: float, cy: float, r: float, z0: float, z1: float) -> mf.Manifold:
    return mf.Manifold.cylinder(z1 - z0, r, circular_segments=SEGMENTS).translate((cx, cy, z0))


def bracket() -> mf.Manifold:
    part = rounded_rect(0, 0, 100, 60, 3, 0, 15)  # outside corners broken with r3
    part -= rounded_rect(12, 16, 40, 44, 5, 10, 16)
    part -= rounded_rect(60, 16, 88, 44, 5, 10, 16)
    for x, y in [(8, 8), (92, 8), (8, 52), (92, 52)]:
        part -= cylinder(x, y, 5.5, -1, 16)  # M10 clearance holes
    part -= cylinder(50, 30, 6, -1, 16)
    return part


def plate_bosses() -> mf.Manifold:
    part = rounded_rect(0, 0, 90, 70, 4, 0, 8)
    for x, y in [(22, 20), (68, 20), (45, 50)]:
        part += cylinder(x, y, 13, 7, 20)
        part -= cylinder(x, y, 8, 15, 21)  # counterbore 16 mm x 5 deep
        part -= cylinder(x, y, 5, -1, 21)  # 10 mm through hole
    part += cylinder(78, 56, 8, 7, 14)  # plain locating boss
    return part


def dome_mould() -> mf.Manifold:
    part = box(0, 0, 0, 90, 70, 30)
    # Finer than the prismatic parts: the cavity is finished with a ball end mill and its
    # facets would show as scallop-like ridges (chord error ~0.005 mm at 192 segments).
    cavity = mf.Manifold.sphere(1.0, circular_segments=192).scale((35, 25, 15)).translate((45, 35, 30))
    part -= cavity
    for x, y in [(9, 9), (81, 9), (9, 61), (81, 61)]:
        part -= cylinder(x, y, 5, 18, 31)  # guide-pin bores, 10 mm x 12 deep
    return part


def stepped_wall() -> mf.Manifold:
    part = box(0, 0, 0, 100, 50, 10)
    part += box(40, 0, 9, 100, 50, 18)
    part += box(70, 0, 17, 100, 50, 26)
    part += box(14, 5, 9, 17, 45, 30)  # 3 mm thin wall standing on the first step
    return part


PARTS = {
    "bracket": bracket,
    "plate_bosses": plate_bosses,
    "dome_mould": dome_mould,
    "stepped_wall": stepped_wall,
}


def to_trimesh(solid: mf.Manifold) -> trimesh.Trimesh:
    if solid.status() != mf.Error.NoError:
        raise RuntimeError(f"CSG failed: {solid.status()}")
    m = solid.to_mesh()
    mesh = trimesh.Trimesh(
        vertices=np.asarray(m.vert_properties[:, :3], dtype=np.float64),
        faces=np.asarray(m.tri_verts, dtype=np.int64),
        process=True,
    )
    if not (mesh.is_watertight and mesh.volume > 0):
        raise RuntimeError("CSG result is not a closed solid")
    return mesh


def main(out_dir: Path = HERE) -> None:
    for name, make in PARTS.items():
        mesh = to_trimesh(make())
        path = out_dir / f"{name}.stl"
        path.write_bytes(trimesh.exchange.stl.export_stl(mesh))
        size = np.ptp(mesh.vertices, axis=0)
        print(f"{path.name:18s} {len(mesh.faces):6d} triangles  {size[0]:.0f} x {size[1]:.0f} x {size[2]:.0f} mm")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
