"""Edges beside a pose that neither the part nor its shadow explains (vision/stray_edges.py), on plain geometry:
the part's own edges and its shadow's are never stray, an edge beside the part on the light's side always is,
one far off never. And the shadow's light fit (vision/shadow.py) from an estimate below its floor."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.vision.lit import cell_station
from vision.locate import footprint_from_mesh
from vision.mesh_edges import edge_model
from vision.shadow import LOWEST_LIGHT, shadow_evidence
from vision.stray_edges import BESIDE_PX, COVER_PX, stray_edges

BOX_MM = (40.0, 30.0, 20.0)
LOWEST_LIGHT_DEG = float(np.degrees(LOWEST_LIGHT))


@pytest.fixture(scope="module")
def box_model():
    station = cell_station()
    box = trimesh.creation.box(BOX_MM)
    box.apply_translation([0.0, 0.0, BOX_MM[2] / 2])
    part = footprint_from_mesh(box.vertices, box.faces)
    return edge_model(part, station.camera, np.linalg.inv(station.camera_pose), station.plane_z)


def towards(az: float, el: float) -> np.ndarray:
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def drawn(model, pose, points) -> np.ndarray:
    """``(h, w)`` bool edge picture with a pixel at each part-frame point (k, 3) [m] at ``pose``."""
    w, h = model.camera.image_size
    thin = np.zeros((h, w), bool)
    uv = np.rint(model.camera.project(model.world(pose, points), model.rvec, model.tvec)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    thin[uv[inside, 1], uv[inside, 0]] = True
    return thin


def cast(points: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Each part-frame point's shadow on the tray (z = 0) under ``light`` (unit, part frame)."""
    return points - (points[:, 2] / light[2])[:, None] * light


poses = st.tuples(st.floats(0.0, 0.1), st.floats(0.35, 0.45), st.floats(-np.pi, np.pi))
lights = st.tuples(st.floats(-np.pi, np.pi), st.floats(np.radians(14.0), np.radians(35.0)))


@settings(max_examples=30, deadline=None)
@given(pose=poses, light=lights)
def test_the_part_and_its_shadow_leave_no_stray_edge(box_model, pose, light):
    """Every edge of the box and of the shadow it casts under the light: nothing stray."""
    p = np.array(pose)
    towards_part = towards(*light)
    base = np.r_[towards_part[:2] @ np.array([[np.cos(p[2]), np.sin(p[2])], [-np.sin(p[2]), np.cos(p[2])]]),
                 towards_part[2]]  # the same light in the base frame
    thin = drawn(box_model, p, np.vstack([box_model.points, cast(box_model.points, towards_part)]))
    assert stray_edges(box_model, p, base, thin) == 0.0


@settings(max_examples=30, deadline=None)
@given(pose=poses, light=lights, gap=st.integers(COVER_PX + 3, BESIDE_PX))
def test_an_edge_beside_the_part_towards_the_light_is_stray_and_one_far_off_is_not(box_model, pose, light, gap):
    """Pixels ``gap`` px past the box's edge towards the light (where no shadow falls) count, one each per
    visible outline sample; pixels 3 part sizes away do not."""
    p = np.array(pose)
    towards_part = towards(*light)
    rot = np.array([[np.cos(p[2]), -np.sin(p[2])], [np.sin(p[2]), np.cos(p[2])]])
    base = np.r_[rot @ towards_part[:2], towards_part[2]]
    own = drawn(box_model, p, box_model.points)
    # Past the box's hull in the picture, furthest along the light's direction there (its shadow falls the other way).
    hull = box_model.camera.project(box_model.world(p, box_model.hull_points), box_model.rvec, box_model.tvec)
    centre = box_model.camera.project(box_model.world(p, np.array([[0.0, 0.0, 0.0], [*(0.01 * towards_part[:2]), 0.0]])),
                                      box_model.rvec, box_model.tvec)
    ahead = (centre[1] - centre[0]) / np.linalg.norm(centre[1] - centre[0])
    side = np.array([-ahead[1], ahead[0]])
    edge = hull[np.argmax(hull @ ahead)]
    beside = np.rint(edge + (gap + 2) * ahead + np.arange(-2, 3)[:, None] * side).astype(int)
    thin = own.copy()
    thin[beside[:, 1], beside[:, 0]] = True
    outline = box_model.outer[box_model.visible(p)].sum()
    assert stray_edges(box_model, p, base, thin) == pytest.approx(len(np.unique(beside, axis=0)) / outline)
    far = np.rint(edge + 3 * 60 * ahead + np.arange(-2, 3)[:, None] * side).astype(int)
    h, w = own.shape
    far = far[(far[:, 0] >= 0) & (far[:, 0] < w) & (far[:, 1] >= 0) & (far[:, 1] < h)]
    thin = own.copy()
    thin[far[:, 1], far[:, 0]] = True
    assert stray_edges(box_model, p, base, thin) == 0.0


@settings(max_examples=20, deadline=None)
@given(az=st.floats(-np.pi, np.pi), el_deg=st.floats(0.5, 8.0), off=st.floats(-1.0, 1.0))
def test_the_light_fit_starts_from_an_estimate_below_its_floor(box_model, az, el_deg, off):
    """An estimate of the key light under 5 deg (the light estimated at a low-angle stepped wall's true pose was
    4.7 deg) is fitted from within the fit's bounds, not refused by the solver: the fitted light is at 5 deg or
    more and within the turn allowed (vision.shadow.shadow_evidence)."""
    m, pose = box_model, np.array([0.05, 0.40, 0.3])
    idx = m.visible(pose)
    eye, _ = m.in_part_frame(pose, np.zeros(3))
    light = towards(az, np.radians(el_deg))
    got = shadow_evidence(m.field, m.points, m.direction, m.n1, m.n2, idx, eye, light,
                          lambda pts, d: m.image_of(pose, pts, d),
                          lambda uv, n, reach: np.full(len(uv), off), lambda pts: m.pixels(pose, pts))
    assert np.degrees(np.arcsin(got.light[2])) >= min(el_deg, LOWEST_LIGHT_DEG) - 1e-6
    assert abs(np.angle(np.exp(1j * (np.arctan2(got.light[1], got.light[0]) - az)))) <= np.radians(6.0) + 1e-6
