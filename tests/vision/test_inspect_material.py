"""What the greys beyond an outline sample's own edge say (vision.inspect_material), on drawn pictures."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.inspect_material import material_agrees

SIDE_X = 100.0  # the expected outline: the part's face left of it, the tray right of it [px]
ROWS = np.arange(10.0, 190.0, 3.0)  # one outline sample a row [px]
STRETCH = (ROWS >= 80.0) & (ROWS <= 120.0)  # where the side's own edge does not show


def _side(tray: float, face: float, inside: np.ndarray) -> np.ndarray:
    """A 200 x 200 picture: the face left of the side, the tray right of it, and on the stretch's rows
    ``inside`` (200,) the greys of the columns instead (the stretch's own profile)."""
    grey = np.where(np.arange(200.0)[None, :] < SIDE_X, face, tray) * np.ones((200, 1))
    rows = (np.arange(200.0) >= ROWS[STRETCH].min() - 2) & (np.arange(200.0) <= ROWS[STRETCH].max() + 2)
    grey[rows] = inside
    return grey.astype(np.float32)


def _missing_here(grey: np.ndarray, depth: float) -> np.ndarray:
    """Whether the greys say material is missing ``depth`` [px] in from the side, at the stretch's samples."""
    k = len(ROWS)
    uv = np.column_stack([np.full(k, SIDE_X), ROWS])
    outward = np.tile([1.0, 0.0], (k, 1))
    signed = np.where(STRETCH, -depth, np.nan)
    agrees = material_agrees(grey, uv, outward, signed, np.zeros(k), 4.0, np.zeros(k, int), ~STRETCH)
    return agrees[STRETCH]


@settings(max_examples=40, deadline=None)
@given(tray=st.floats(90.0, 140.0), contrast=st.floats(15.0, 50.0), depth=st.integers(4, 9),
       width=st.integers(2, 3), dim=st.floats(0.0, 0.3))
def test_a_broken_corner_is_a_step_up_to_the_face_not_a_bright_line_on_it(tray, contrast, depth, width, dim):
    """On a stretch of a side the face meets the tray with no edge. Where material is missing, the
    tray runs in to an edge ``depth`` px inside and the face holds past it: missing material. Where
    the face there is only as dim as the tray, a bright line on it (a highlight's crease along a
    brushed top, ``width`` px wide, as bright as the face) has its edge at the same place, but past
    the line the face is dim again: not missing material (the held-out 5 MP low-angle bracket 8)."""
    face = tray + contrast
    x = np.arange(200.0)
    corner = _side(tray, face, np.where(x < SIDE_X - depth, face, tray))
    assert _missing_here(corner, depth).all()
    line = (x >= SIDE_X - depth - width) & (x < SIDE_X - depth)
    dimmed = np.where(x < SIDE_X, tray + dim * contrast, tray)
    crease = _side(tray, face, np.where(line, face, dimmed))
    assert not _missing_here(crease, depth).any()
