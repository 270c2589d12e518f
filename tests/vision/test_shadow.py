"""The key light and the part's shadows (vision/shadow.py): checked against the lit renderer's own
shadow map (tests/vision/lit.py, a z-buffer from the light) and against plain geometry of a box."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.vision.lit import ROOT
from vision.lit import _lit_by
from vision.locate import footprint_from_mesh
from vision.shadow import LOW_LIGHT, dark_both_sides, estimate_light, height_field, shadowed

BOX_MM = (40.0, 30.0, 20.0)


def towards(az_deg: float, el_deg: float) -> np.ndarray:
    az, el = np.radians(az_deg), np.radians(el_deg)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def box_field():
    """A 40 x 30 x 20 mm box in the part frame (footprint centred on the origin, standing on z = 0) [m]."""
    box = trimesh.creation.box(np.array(BOX_MM) / 1e3)
    box.apply_translation([0.0, 0.0, BOX_MM[2] / 2e3])
    return box, height_field(box.vertices, box.faces)


def around(rng, n=4000, reach=0.08):
    return rng.uniform(-reach, reach, (n, 2))


@pytest.mark.parametrize("az, el", [(30.0, 15.0), (200.0, 22.0), (-100.0, 35.0)])
def test_the_light_comes_back_from_the_shadow_it_casts(az, el):
    """Tray points around a box, dark where the box shadows them under a known light (one label in 50
    flipped, as texture and noise would): the estimate is within 3 deg of azimuth and 2 deg of
    elevation (the edge fit refines it, :func:`vision.shadow.shadow_evidence`)."""
    _, field = box_field()
    rng = np.random.default_rng(1)
    tray = around(rng)
    light = towards(az, el)
    dark = shadowed(field, np.column_stack([tray, np.zeros(len(tray))]), light)
    dark = dark ^ (rng.uniform(size=len(dark)) < 0.02)
    got = estimate_light(field, tray, dark, np.array([0.01, -0.02, 0.5]), min_dark=30)
    assert got is not None
    d_az = np.degrees(np.angle(np.exp(1j * (np.arctan2(got[1], got[0]) - np.radians(az)))))
    d_el = np.degrees(np.arcsin(got[2])) - el
    assert abs(d_az) < 3.0 and abs(d_el) < 2.0, (d_az, d_el)


def test_no_key_light_without_a_hard_shadow_or_from_high_up():
    """Nothing dark (diffuse light), or the shadow of a light higher than LOW_LIGHT: no key light."""
    _, field = box_field()
    tray = around(np.random.default_rng(2))
    eye = np.array([0.0, 0.0, 0.5])
    assert estimate_light(field, tray, np.zeros(len(tray), bool), eye, min_dark=30) is None
    high = towards(40.0, np.degrees(LOW_LIGHT) + 15.0)
    dark = shadowed(field, np.column_stack([tray, np.zeros(len(tray))]), high)
    assert dark.sum() > 30
    assert estimate_light(field, tray, dark, eye, min_dark=30) is None


@pytest.mark.parametrize("az, el", [(20.0, 18.0), (135.0, 30.0)])
def test_shadowed_agrees_with_the_lit_renderers_shadow_map(az, el):
    """The plate with bosses: which points of the tray and of the part's top see the light, by the
    height field here and by the lit renderer's z-buffer from the light, agree at 97 % of the points
    (they differ within a cell of the shadow's edge)."""
    mesh = trimesh.load(ROOT / "samples" / "plate_bosses.stl")
    fp = footprint_from_mesh(mesh.vertices, mesh.faces)
    v = np.asarray(mesh.vertices) / 1e3 - np.r_[fp.centroid, fp.zmin]
    field = height_field(v, mesh.faces)
    rng = np.random.default_rng(3)
    xy = around(rng, 3000, 0.1)
    z = field.at(xy).astype(np.float64)  # on the part's top where it stands, else the tray
    points = np.column_stack([xy, z])
    light = towards(az, el)
    ours = shadowed(field, points + [0.0, 0.0, 1e-4], light)
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    theirs = _lit_by(v, np.asarray(mesh.faces), light, points, normals) < 0.5
    assert 0.05 < theirs.mean() < 0.8  # the test sees shadow and light both
    assert np.mean(ours == theirs) > 0.97


def test_the_foot_of_a_wall_turned_from_a_low_light_is_dark_on_both_sides():
    """A box lit from +x at 20 deg, the camera above it: the crease at the foot of the -x wall lies
    between the wall in its own shade and the tray in the box's shadow (dark on both sides); the
    foot of the lit +x wall and the top's edge over the -x wall (the lit top against the shadow) are
    not."""
    _, field = box_field()
    hx, hz = BOX_MM[0] / 2e3, BOX_MM[2] / 1e3
    eye = np.array([0.1, 0.0, 0.5])  # sees the +x wall
    eye_left = np.array([-0.1, 0.0, 0.5])  # sees the -x wall
    light = towards(0.0, 20.0)
    down, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, 1.0])
    left, right = np.array([-1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    foot_left = dark_both_sides(field, np.array([[-hx, 0.0, 0.0]]), left[None], down[None], eye_left, light)
    foot_right = dark_both_sides(field, np.array([[hx, 0.0, 0.0]]), right[None], down[None], eye, light)
    top_left = dark_both_sides(field, np.array([[-hx, 0.0, hz]]), up[None], left[None], eye, light)
    assert foot_left[0] and not foot_right[0] and not top_left[0]
    # With the light from -x the same feet swap.
    light = towards(180.0, 20.0)
    assert not dark_both_sides(field, np.array([[-hx, 0.0, 0.0]]), left[None], down[None], eye_left, light)[0]
    assert dark_both_sides(field, np.array([[hx, 0.0, 0.0]]), right[None], down[None], eye, light)[0]
