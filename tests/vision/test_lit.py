"""The lit test renderer's shading (vision/lit.py): a flat face is drawn flat, a round one round."""

from __future__ import annotations

import cv2
import manifold3d as mf
import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.vision.lit import cell_station
from vision.lit import CONDITIONS, Material, corner_normals, render_lit


def plate_with_filled_hole(radius_mm: float, segments: int, centre_mm: tuple[float, float]) -> trimesh.Trimesh:
    """A 60 x 40 x 10 mm plate [mm] drilled through and filled again, as tests/vision/defects.py leaves a
    hole not drilled: a flat top whose triangles fan out to the old rim's vertices, and walls beside it."""
    cx, cy = centre_mm
    plate = mf.Manifold.cube((60.0, 40.0, 10.0))
    hole = mf.Manifold.cylinder(10.0, radius_mm, circular_segments=segments).translate((cx, cy, 0.0))
    plug = mf.Manifold.cylinder(10.0, radius_mm + 0.3, circular_segments=96).translate((cx, cy, 0.0))
    return as_trimesh((plate - hole) + plug)


def as_trimesh(solid: mf.Manifold) -> trimesh.Trimesh:
    m = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(m.vert_properties[:, :3], np.float64), np.asarray(m.tri_verts, np.int64))


@settings(max_examples=25, deadline=None)
@given(radius=st.floats(2.0, 8.0), segments=st.integers(12, 64), cx=st.floats(15.0, 45.0),
       cy=st.floats(12.0, 28.0))
def test_a_flat_face_is_shaded_with_its_own_normal(radius, segments, cx, cy):
    """Every corner of a flat face carries the face's normal, whatever the faces beyond a crease at its
    vertex lean; a round bore's corners lean as the bore does, within half its facets' turn."""
    mesh = plate_with_filled_hole(radius, segments, (cx, cy))
    normals = corner_normals(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    flat = np.abs(mesh.face_normals[:, 2]) > 1 - 1e-9
    assert np.allclose(normals[flat], mesh.face_normals[flat][:, None, :], atol=1e-9)
    # The walls of a 96-facet cylinder are one smooth surface: each corner's normal points away from the axis.
    bored = as_trimesh(mf.Manifold.cube((60.0, 40.0, 10.0))
                       - mf.Manifold.cylinder(10.0, radius, circular_segments=96).translate((cx, cy, 0.0)))
    corners = bored.vertices[bored.faces]
    wall = (np.abs(bored.face_normals[:, 2]) < 1e-6) & (np.hypot(corners[:, :, 0] - cx, corners[:, :, 1] - cy)
                                                       < radius + 1e-4).all(axis=1)
    towards_axis = np.array([cx, cy, 0.0]) - corners[wall]
    towards_axis[..., 2] = 0.0
    towards_axis /= np.linalg.norm(towards_axis, axis=2, keepdims=True)
    cos = np.einsum("nkj,nkj->nk", corner_normals(np.asarray(bored.vertices), np.asarray(bored.faces))[wall],
                    towards_axis)
    assert cos.min() > np.cos(np.radians(360 / 96 / 2 + 0.1))


def test_a_filled_hole_leaves_a_flat_top_under_a_low_light():
    """A plain plate, and one with a hole drilled and filled, under the low-angle light at the cell camera,
    no brushing: each top reads as even as the sensor's noise. The renderer once tilted a flat top's
    normals by up to 12 deg inside triangles whose corners touch walls (a plain box's 9.6 grey, the filled
    plate's 14.3): lines along triangle edges, and round a filled hole a lit arc and a dark patch no part
    has (the 5 MP low-angle bracket 1 with its hole not drilled passed inspection for them)."""
    station = cell_station()
    light = np.array([-0.439, 0.858, 0.268])
    light /= np.linalg.norm(light)
    spread = []
    for mesh_mm in (trimesh.creation.box((60.0, 40.0, 10.0)), plate_with_filled_hole(5.5, 48, (30.0, 20.0))):
        mesh_mm.apply_translation(-mesh_mm.bounds[0] - [30.0, 20.0, 0.0])
        frame = np.eye(4)
        frame[:3, 3] = [*station.camera_pose[:2, 3], station.plane_z]
        placed = trimesh.Trimesh(mesh_mm.vertices / 1e3, mesh_mm.faces, process=False)
        placed.apply_transform(frame)
        matte = Material(albedo=0.55, brushed=0.0, specular=0.0, shininess=1.0, frame=frame)
        image = render_lit(station, [(placed, matte)], CONDITIONS["low_angle"], light, np.random.default_rng(3))
        # The top's pixels 3 mm or more inside its edges (clear of the walls and the blur).
        u, v = _top_pixels(station, frame, inset_mm=3.0)
        spread.append(float(np.std(image[v, u].astype(float))))
    # The sensor's noise at the top's grey is about 6 (shot and read noise, vision.lit._exposed): a top
    # shaded flat reads that, the plate with a filled hole as the plain one.
    assert max(spread) < 8.0 and spread[1] < 1.1 * spread[0], spread


def _top_pixels(station, frame: np.ndarray, inset_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (u, v) that see the 60 x 40 mm plate's top ``inset_mm`` [mm] or more inside its edges."""
    xs, ys = np.meshgrid(np.linspace(-30 + inset_mm, 30 - inset_mm, 120), np.linspace(-20 + inset_mm, 20 - inset_mm, 80))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 10.0)]) / 1e3 @ frame[:3, :3].T + frame[:3, 3]
    w2c = station.world_to_camera
    uv = station.camera.project(points, cv2.Rodrigues(w2c[:3, :3])[0].ravel(), w2c[:3, 3])
    uv = np.unique(np.rint(uv).astype(int), axis=0)
    return uv[:, 0], uv[:, 1]
