"""What the greys beyond an outline sample's own edge say (vision.inspect_material), on drawn pictures."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from vision.inspect_material import defect_edge, material_agrees
from vision.picture_edges import edge_peaks, gradients

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


def _lip_read(grey: np.ndarray, silhouette: bool, where: np.ndarray = STRETCH) -> np.ndarray:
    """Where the material ends outward [px] at the stretch's samples (or those ``where``; NaN: at the own
    edge), as vision.inspect judges an outline sample at a top edge: its own edge within 1.5 px, the rest
    beyond. ``silhouette``: the wall below the top edge is turned away from the camera."""
    k = len(ROWS)
    uv = np.column_stack([np.full(k, SIDE_X), ROWS])
    outward = np.tile([1.0, 0.0], (k, 1))
    gx, gy, threshold = gradients(grey)
    steps, resp, peak = edge_peaks(gx, gy, threshold, uv, outward, 21.0)
    near = np.where(peak & (np.abs(steps)[None, :] <= 1.5), resp, -np.inf)
    own_j = np.argmax(near, axis=1)
    own = np.isfinite(near[np.arange(k), own_j])
    beyond = peak & (np.abs(steps)[None, :] > 1.5)
    found, _ = defect_edge(grey, uv, outward, steps, np.ones(k), resp, beyond, np.zeros_like(peak), np.zeros(k),
                           threshold, np.zeros(k, int), own, own_j, silhouette=np.full(k, silhouette))
    return found[where]


@settings(max_examples=40, deadline=None)
@given(tray=st.floats(50.0, 140.0), contrast=st.floats(10.0, 50.0), width=st.integers(6, 8),
       bright=st.floats(0.6, 2.5), tone=st.sampled_from(["one", "two", "dark rim"]), seed=st.integers(0, 2**16))
def test_a_lip_reads_its_whole_width_however_it_catches_the_light(tray, contrast, width, bright, tone, seed):
    """A 1 mm lip along a stretch of a top edge whose wall is turned away from the camera (the edge is the
    part's silhouette), ``width`` px wide at 5 MP, as bright as the face or brighter (``bright`` of the
    face's contrast over the tray: a lip's narrow top catches the light apart from the brushed face).
    Its top may show two tones (its outer half halfway to the tray's grey: an edge halfway out as strong
    as the lip's outer one), or the face
    may be darker along its edge (a dark rim 4 px wide along the side: the stretch's own edge then steps
    up into the lip).
    Wherever the light puts those edges, the material ends at the lip's outer edge, ``width`` px out
    (the held-out 5 MP diffuse and dim plate_bosses 9 and low-angle dome_mould 8 read 0.04-0.57 mm of a
    1 mm lip). Where the wall is turned to the camera, a band brighter than the face by half the
    contrast or more beyond the top edge is the lit wall, not extra material."""
    face = tray + contrast
    lip = tray + bright * contrast
    x = np.arange(200.0)
    on_lip = (x >= SIDE_X) & (x < SIDE_X + width)
    inside = np.where(x < SIDE_X, face, tray)
    inside = np.where(on_lip, lip, inside)
    if tone == "two":  # the lip's outer half halfway to the tray: two steps alike, the nearer not the end
        inside = np.where(on_lip & (x >= SIDE_X + width // 2), 0.5 * (lip + tray), inside)
        assume(bright >= 1.2)  # the band's median face-like: its outer half at 0.6 of the contrast or more
    grey = _side(tray, face, inside)
    if tone == "dark rim":  # along the whole side; the lip at least as bright as the face
        grey[:, int(SIDE_X) - 4:int(SIDE_X)] = tray + 0.5 * contrast
        assume(bright >= 1.0)
    grey += np.random.default_rng(seed).normal(0.0, 1.0, grey.shape).astype(np.float32)
    read = _lip_read(grey, silhouette=True)
    assert np.nanmedian(read) == pytest.approx(width - 0.5, abs=1.0), read
    if bright >= 2.0 and tone == "one":
        assert not (_lip_read(grey, silhouette=False) > 1.5).any()


@settings(max_examples=40, deadline=None)
@given(tray=st.floats(90.0, 140.0), contrast=st.floats(10.0, 40.0), wall=st.floats(60.0, 200.0),
       wall_px=st.integers(3, 14), width=st.integers(6, 8), crease=st.booleans(), shade=st.floats(0.0, 15.0),
       seed=st.integers(0, 2**16))
def test_a_lip_over_a_lit_wall_reads_to_its_end(tray, contrast, wall, wall_px, width, crease, shade, seed):
    """A 1 mm lip (``width`` px at 5 MP) along a stretch of a top edge whose wall is turned to the camera and
    lit, ``wall`` grey brighter than the face (clipped white at 255), ``wall_px`` wide beyond the edge. The
    lip covers the wall with the face's grey: where it covers part of it the rest of the wall shows past
    the lip, where it covers it to its foot the tray lies past it, in the lip's shadow (``shade`` darker);
    the lip's inner crease may show as a dark line 1-2 px out (its own edge then). The material ends at
    the lip's end, ``width`` px out, not at the far side of the wall past it (seeds 0-1 5 MP low-angle
    dome_mould 1 and plate_bosses 1 read 0.02-0.05 mm of the lip: the line's other side, the wall, is
    not what lies past a lip that covers it). Beside the stretch the lit wall is no extra material."""
    assume(width <= wall_px - 2 or width >= wall_px)  # the rest of the wall, when it shows, wider than the blur
    face = tray + contrast
    lit = min(face + wall, 255.0)
    x = np.arange(200.0)
    good = np.where(x < SIDE_X, face, np.where(x < SIDE_X + wall_px, lit, tray))
    inside = np.where((x >= SIDE_X) & (x < SIDE_X + width), face, good)
    if width >= wall_px:
        inside = np.where((x >= SIDE_X + width) & (x < SIDE_X + width + 3), tray - shade, inside)
    if crease:
        inside = np.where((x >= SIDE_X + 1) & (x < SIDE_X + 2), face - 0.8 * contrast, inside)
    grey = _side(tray, face, inside)
    rows = (np.arange(200.0) >= ROWS[STRETCH].min() - 2) & (np.arange(200.0) <= ROWS[STRETCH].max() + 2)
    grey[~rows] = good  # beside the stretch, the lit wall beyond the top edge
    grey = np.clip(grey + np.random.default_rng(seed).normal(0.0, 1.0, grey.shape), 0.0, 255.0).astype(np.float32)
    read = _lip_read(grey, silhouette=False)
    assert np.nanmedian(read) == pytest.approx(width - 0.5, abs=1.0), read
    assert not (_lip_read(grey, silhouette=False, where=~STRETCH) > 1.5).any()
