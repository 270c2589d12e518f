"""The feet of a part's walls, for inspection: creases a picture shows only by shading.

Where a face turned up meets a wall rising from it (a boss's foot, a pocket's floor) the two meet
in a fold that soft light shades over a few pixels, not at a line; :mod:`vision.inspect` does not
judge such a loop of creases on its own.
"""

from __future__ import annotations

import numpy as np

from vision.mesh_edges import MeshEdges

#: A crease is a wall's foot where the part stands this much higher this far behind the wall [m]
#: (two texels of the height field: clear of its rounding at the wall, well under any boss or step).
FOOT_M = 1e-3


def wall_feet(model: MeshEdges, idx: np.ndarray) -> np.ndarray:
    """``(k,)`` bool: the edge samples ``idx`` at the foot of a wall, a concave crease where a face turned
    up meets a wall rising from it (a boss's foot, a pocket's floor), from the height field: behind the
    wall (against its normal) the part stands at least :data:`FOOT_M` above the crease, :data:`FOOT_M` off it."""
    n1, n2 = model.n1[idx], model.n2[idx]
    wall = np.where((n1[:, 2] > 0.5)[:, None], n2, n1)
    across = wall[:, :2] / np.maximum(np.linalg.norm(wall[:, :2], axis=1, keepdims=True), 1e-12)
    up = (np.maximum(n1[:, 2], n2[:, 2]) > 0.5) & (np.abs(wall[:, 2]) < 0.5)
    behind = model.field.at(model.points[idx, :2] - FOOT_M * across)
    return up & (behind > model.points[idx, 2] + FOOT_M)
