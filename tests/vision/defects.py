"""Defective sample parts for inspection: a missing hole, a missing boss, a 1 mm burr on an edge.

Each defect is made from the sample part's own mesh with manifold3d CSG (the part as made by
``samples/make_samples.py`` with one machining step left out, or with material left on), in the
part's mesh frame [mm], so a defective part is placed exactly as the good one would be and the
inspection still expects the good mesh:

- ``missing_hole``: one hole not drilled (filled again to the face it opens on);
- ``missing_boss``: one boss not there (cut down to the face it stands on); the stepped wall's
  thin wall counts as its boss;
- ``burr``: a 1 x 1 mm lip of material left along 15 mm of the top edge of one long side,
  sticking out of the side by 1 mm (about 1.2 px at the cell camera's 0.82 mm per pixel).

The features are the ones :mod:`samples.make_samples` cuts (positions in its millimetres).
"""

from __future__ import annotations

from functools import lru_cache

import manifold3d as mf
import numpy as np
import trimesh

from tests.vision.lit import sample_mesh

DEFECTS = ("missing_hole", "missing_boss", "burr")

#: Per defect and part: ("add" | "cut", box (x0, y0, z0, x1, y1, z1) or cylinder (cx, cy, r, z0, z1)) [mm].
_EDITS: dict[str, dict[str, tuple[str, tuple[float, ...]]]] = {
    # The M10 hole near the +x +y corner (the thin rim by the corner); a counterbored boss's
    # through-hole; a guide-pin bore.
    "missing_hole": {"bracket": ("add", (92.0, 52.0, 5.8, 0.0, 15.0)),
                     "plate_bosses": ("add", (68.0, 20.0, 5.3, 0.0, 15.0)),
                     "dome_mould": ("add", (81.0, 61.0, 5.3, 17.0, 30.0))},
    # The plain locating boss (16 mm across, 6 mm above the plate); the 3 mm thin wall on the first step.
    "missing_boss": {"plate_bosses": ("cut", (78.0, 56.0, 8.6, 8.0, 15.0)),
                     "stepped_wall": ("cut", (13.5, 4.5, 10.0, 17.5, 45.5, 31.0))},
    # Along the +y side's top edge, 1 mm out and 1 mm down.
    "burr": {"bracket": ("add", (42.0, 59.5, 14.0, 57.0, 61.0, 15.0)),
             "plate_bosses": ("add", (20.0, 69.5, 7.0, 35.0, 71.0, 8.0)),
             "dome_mould": ("add", (37.0, 69.5, 29.0, 52.0, 71.0, 30.0)),
             "stepped_wall": ("add", (78.0, 49.5, 25.0, 93.0, 51.0, 26.0))},
}


def defect_parts(defect: str) -> tuple[str, ...]:
    """The sample parts that can have ``defect`` (a part with no boss cannot miss one)."""
    return tuple(_EDITS[defect])


def _solid(shape: tuple[float, ...]) -> mf.Manifold:
    if len(shape) == 5:
        cx, cy, r, z0, z1 = shape
        return mf.Manifold.cylinder(z1 - z0, r, circular_segments=96).translate((cx, cy, z0))
    x0, y0, z0, x1, y1, z1 = shape
    return mf.Manifold.cube((x1 - x0, y1 - y0, z1 - z0)).translate((x0, y0, z0))


@lru_cache(maxsize=None)
def defective_mesh(part: str, defect: str) -> trimesh.Trimesh:
    """The sample part [mm] with ``defect``: closed, its volume changed by the edit."""
    good, _, _ = sample_mesh(part)
    how, shape = _EDITS[defect][part]
    solid = mf.Manifold(mf.Mesh(np.asarray(good.vertices, np.float32), np.asarray(good.faces, np.uint32)))
    solid = solid + _solid(shape) if how == "add" else solid - _solid(shape)
    m = solid.to_mesh()
    mesh = trimesh.Trimesh(np.asarray(m.vert_properties[:, :3], np.float64), np.asarray(m.tri_verts, np.int64),
                           process=True)
    if not mesh.is_watertight or abs(mesh.volume - good.volume) < 1.0:
        raise RuntimeError(f"{defect} on {part}: the edit did not change the closed part")
    return mesh
