"""The test renderer in real light draws the mesh's own surfaces: flat faces flat, freeform ones smooth."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from vision.lit import SMOOTH_BELOW_DEG, corner_normals


@settings(max_examples=25, deadline=None)
@given(radius=st.floats(2.0, 20.0), height=st.floats(1.0, 30.0), sections=st.integers(8, 96),
       plate=st.floats(30.0, 80.0))
def test_a_flat_face_beside_a_rim_is_drawn_flat(radius, height, sections, plate):
    """A boss on a plate: every corner of the plate's top and the boss's top shades straight up.

    Averaging every face at a vertex tilts a flat top by up to the rim's angle inside the
    triangles touching the rim, and the picture shows lit arcs where the mesh has none.
    """
    base = trimesh.creation.box((plate, plate, 5.0))
    boss = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    boss.apply_translation([0, 0, 2.5 + height / 2])
    mesh = trimesh.util.concatenate([base, boss])
    mesh.merge_vertices()
    normals = corner_normals(mesh)
    up = mesh.face_normals[:, 2] > 0.999
    assert up.any()
    np.testing.assert_allclose(normals[up], np.broadcast_to([0.0, 0.0, 1.0], normals[up].shape), atol=1e-9)
    # And a face is never tilted by a neighbour across an edge sharper than the smoothing angle.
    cos = np.einsum("fkj,fj->fk", normals, mesh.face_normals)
    assert (cos > np.cos(np.radians(SMOOTH_BELOW_DEG)) - 1e-9).all()


@settings(max_examples=10, deadline=None)
@given(subdivisions=st.integers(3, 4), radius=st.floats(5.0, 50.0))
def test_a_freeform_surface_is_drawn_smooth(subdivisions, radius):
    """On a sphere fine enough that its faces meet under the smoothing angle, each corner's normal is nearer the true (radial) normal than its face's normal is."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    normals = corner_normals(mesh)
    radial = mesh.vertices[mesh.faces] / radius
    corner_err = np.degrees(np.arccos(np.clip(np.einsum("fkj,fkj->fk", normals, radial), -1, 1)))
    face_err = np.degrees(np.arccos(np.clip(np.einsum("fj,fkj->fk", mesh.face_normals, radial), -1, 1)))
    assert corner_err.max() < 0.5 * face_err.min() + 0.5
    assert np.allclose(np.linalg.norm(normals, axis=2), 1.0)
