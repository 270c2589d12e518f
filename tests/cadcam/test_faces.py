"""The part's faces by kind: flats at their heights, walls, steep and shallow freeform."""

from __future__ import annotations

import math

import manifold3d
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.faces import FLAT, HIDDEN, SHALLOW, STEEP, WALL, classify_faces
from tests.conftest import manifold_to_trimesh, pocket_block


def test_a_pocketed_block_is_flats_and_walls_at_their_heights():
    faces = classify_faces(pocket_block(size=(30.0, 20.0, 10.0), pocket=(16.0, 12.0, 4.0)))
    areas = faces.areas()
    assert areas["steep"] == areas["shallow"] == 0.0 and not faces.freeform
    assert faces.flat_z.tolist() == [10.0, 6.0]
    # top with the pocket's hole, and the pocket floor
    assert areas["flat"] == pytest.approx(30 * 20 - 16 * 12 + 16 * 12)
    assert areas["wall"] == pytest.approx(2 * (30 + 20) * 10 + 2 * (16 + 12) * 4)
    assert areas["hidden"] == pytest.approx(30 * 20)
    floor = faces.flat_level == 1
    assert np.all(faces.kind[floor] == FLAT)
    assert faces.area[floor].sum() == pytest.approx(16 * 12)


def test_a_dome_is_freeform_split_at_the_steep_angle():
    dome = manifold3d.Manifold.sphere(20.0, 256) ^ manifold3d.Manifold.cube((60.0, 60.0, 30.0)).translate(
        (-30.0, -30.0, 0.0))
    faces = classify_faces(manifold_to_trimesh(dome))
    areas = faces.areas()
    # only the band within the wall angle of the equator is wall: 2 pi R^2 sin(1 deg) and facets
    assert faces.freeform and areas["wall"] < 0.05 * areas["steep"]
    # A sphere's cap above polar angle a has area 2 pi R^2 (1 - cos a); slopes above 50 deg
    # lie beyond polar angle 50 deg.
    r = 20.0
    shallow = 2 * math.pi * r * r * (1 - math.cos(math.radians(50)))
    assert areas["shallow"] + areas["flat"] == pytest.approx(shallow, rel=0.03)
    assert areas["steep"] + areas["wall"] == pytest.approx(2 * math.pi * r * r - shallow, rel=0.03)
    assert areas["hidden"] == pytest.approx(math.pi * r * r, rel=0.01)


@settings(max_examples=20, deadline=None)
@given(tilt=st.floats(0.0, 89.0), up=st.booleans())
def test_a_tilted_plane_falls_in_the_class_of_its_slope(tilt, up):
    t = math.radians(tilt)
    s = 1.0 if up else -1.0
    # two triangles of a unit square tilted about the X axis, facing up (or down)
    v = np.array([[0, 0, 0], [1, 0, 0], [1, math.cos(t), s * math.sin(t)], [0, math.cos(t), s * math.sin(t)]])
    import trimesh

    faces = classify_faces(trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]] if up else [[0, 2, 1], [0, 3, 2]],
                                           process=False))
    nz = math.cos(t) if up else -math.cos(t)
    want = (FLAT if tilt <= 0.5 else SHALLOW if tilt < 50 else STEEP if tilt < 89 else WALL) if nz > 0 else HIDDEN
    if abs(tilt - 50) > 1e-6 and abs(tilt - 0.5) > 1e-6 and abs(tilt - 89) > 1e-6:
        assert set(faces.kind.tolist()) == {want}


def test_near_grows_the_footprint_by_the_reach():
    faces = classify_faces(pocket_block(size=(30.0, 20.0, 10.0), pocket=(16.0, 12.0, 4.0)))
    near_floor = faces.near((FLAT,), 2.0)
    # the part covers x 0..30, y 0..20
    assert near_floor(np.array([[15.0, 10.0], [-1.9, 10.0], [-2.1, 10.0], [15.0, 21.9]])).tolist() == [
        True, True, False, True]
    assert not faces.near((STEEP, SHALLOW), 5.0)(np.array([[15.0, 10.0]])).any()
