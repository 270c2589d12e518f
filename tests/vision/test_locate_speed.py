"""The shortcuts that made locate fast must not change what it computes (no timings here: those are in
benchmarks/locate_real_light.py and the reports): the edge fit's Jacobian is the projection's own, a
line's march to the light ends past the part's box, and the edge model is made once per part and view."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.vision.lit import cell_station, sample_mesh
from vision.mesh_edges import MeshEdges, edge_model
from vision.shadow import MARCH_BLOCK, SHADOW_BIAS_M, TEXEL_M, height_field, landing, shadowed

STATION = cell_station(None)


def _model(part: str = "bracket") -> MeshEdges:
    return MeshEdges(sample_mesh(part)[1], STATION.camera, np.linalg.inv(STATION.camera_pose), STATION.plane_z)


@settings(max_examples=20, deadline=None)
@given(x=st.floats(-0.12, 0.12), y=st.floats(-0.1, 0.1), yaw=st.floats(-np.pi, np.pi))
def test_the_edge_fits_jacobian_is_the_projections_own(x, y, yaw):
    """MeshEdges.placed's derivatives by x, y [px/m] and yaw [px/rad] match central differences of the
    projection to 1e-4 of their size, anywhere in the view (the lens's distortion included)."""
    model = _model()
    p = np.array([STATION.camera_pose[0, 3] + x, STATION.camera_pose[1, 3] + y, yaw])  # off the camera's axis by x, y [m]
    pts = model.points[model.visible(p)]
    uv, by_pose = model.placed(p, pts)
    for k, h in enumerate((1e-6, 1e-6, 1e-5)):
        dp = np.zeros(3)
        dp[k] = h
        numeric = (model.placed(p + dp, pts)[0] - model.placed(p - dp, pts)[0]) / (2 * h)
        assert np.abs(numeric - by_pose[:, :, k]).max() <= 1e-4 * np.abs(by_pose[:, :, k]).max() + 1e-3


def _marched(field, points, light, reach_m=0.7):
    """The slow truth: every look sampled at the march's own cadence out to ``reach_m`` [m] (past where a line at
    5 degrees of elevation rises above a 5 cm part from 2 mm under the tray), with no early end of any kind."""
    p = np.asarray(points, dtype=np.float64)
    flat = np.hypot(light[0], light[1])
    rise, ahead = light[2] / flat, light[:2] / flat
    blocks, s = [], TEXEL_M * np.arange(1, MARCH_BLOCK + 1)
    while s[0] < reach_m:  # the march's own sums, so each sample falls where the march's does
        blocks.append(s)
        s = s + MARCH_BLOCK * TEXEL_M
    s = np.concatenate(blocks)
    out = np.zeros(len(p), bool)
    for i in np.array_split(np.arange(len(p)), 30):
        z = p[i, 2, None] + s[None, :] * rise
        q = p[i, None, :2] + s[None, :, None] * ahead[None, None, :]
        out[i] = (field.at(q.reshape(-1, 2)).reshape(z.shape) > z + SHADOW_BIAS_M).any(axis=1)
    return out


@settings(max_examples=15, deadline=None)
@given(part=st.sampled_from(["bracket", "stepped_wall", "plate_bosses", "l_bracket"]),
       az=st.floats(0.0, 2 * np.pi), el=st.floats(np.radians(5.0), np.radians(80.0)), seed=st.integers(0, 99))
def test_a_march_ended_past_the_parts_box_shadows_the_same_points(part, az, el, seed):
    """Points on and around a part (some just below the tray, as a bottom face's side points are): shadowed
    with the march ended past the height field's box says what the full march says, point for point."""
    footprint = sample_mesh(part)[1]
    field = height_field(np.asarray(footprint.vertices) - np.r_[footprint.centroid, footprint.zmin], footprint.faces)
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(-0.12, 0.12, (3000, 2)), rng.uniform(-2e-3, 0.05, 3000)])
    light = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    assert np.array_equal(shadowed(field, points, light), _marched(field, points, light))


def test_the_edge_model_is_made_once_per_part_and_view():
    """The same mesh, camera and pose give the same model, also from a new part object made from the same
    vertices (as inspection makes one each picture); another tray height, another part, or one vertex moved a new one."""
    part = sample_mesh("bracket")[1]
    cam_base = np.linalg.inv(STATION.camera_pose)
    first = edge_model(part, STATION.camera, cam_base, STATION.plane_z)
    assert edge_model(part, STATION.camera, cam_base.copy(), STATION.plane_z) is first
    assert edge_model(replace(part, vertices=np.array(part.vertices), faces=np.array(part.faces)), STATION.camera,
                      cam_base, STATION.plane_z) is first
    moved = np.array(part.vertices)
    moved[0, 2] += 1e-4
    assert edge_model(replace(part, vertices=moved), STATION.camera, cam_base, STATION.plane_z) is not first
    assert edge_model(part, STATION.camera, cam_base, STATION.plane_z + 0.01) is not first
    other = edge_model(sample_mesh("hex_boss")[1], STATION.camera, cam_base, STATION.plane_z)
    assert other is not first and other.part is sample_mesh("hex_boss")[1]


def _landed_step_by_step(field, start, eye):
    """The slow truth of :func:`vision.shadow.landing`: each line of sight on its own, one step at a time (at most a
    cell across or down), until it is under the tray or not above the part."""
    landed, flat = np.array(start, dtype=np.float64), np.zeros(len(start), bool)
    for k, point in enumerate(landed):
        sight = (point - eye) / np.linalg.norm((point - eye)[None], axis=1)[0]  # rounded as the march's rows are
        step = TEXEL_M / max(np.hypot(sight[0], sight[1]), -sight[2]) * sight
        going = point[2] > 0 and field.at(point[None, :2])[0] <= point[2]
        while going:
            point += step  # in place: the running sum, as the march adds its steps
            point[2] = max(point[2], 0.0)
            going = point[2] > 0 and field.at(point[None, :2])[0] < point[2]
        top = field.at(point[None, :2])[0]
        flat[k] = top - point[2] <= 1.5 * TEXEL_M
        point[2] = max(point[2], top)
    return landed, flat


@settings(max_examples=10, deadline=None)
@given(part=st.sampled_from(["bracket", "stepped_wall", "plate_bosses", "l_bracket"]),
       x=st.floats(-0.15, 0.15), y=st.floats(-0.12, 0.12), seed=st.integers(0, 99))
def test_lines_of_sight_marched_in_blocks_land_where_they_land_step_by_step(part, x, y, seed):
    """Lines of sight from a camera 0.5 m up (x, y [m] off the part) through points on and above the part land on
    the same points to the bit, and on a face turned up or not alike, as when stepped one step at a time."""
    footprint = sample_mesh(part)[1]
    field = height_field(np.asarray(footprint.vertices) - np.r_[footprint.centroid, footprint.zmin], footprint.faces)
    rng = np.random.default_rng(seed)
    start = np.column_stack([rng.uniform(-0.1, 0.1, (250, 2)), rng.uniform(0.0, 0.06, 250)])
    eye = np.array([x, y, 0.5])
    landed, flat = landing(field, start, eye)
    truth, truth_flat = _landed_step_by_step(field, start, eye)
    assert np.array_equal(landed, truth) and np.array_equal(flat, truth_flat)
