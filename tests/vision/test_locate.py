"""Locating blanks on a tray in rendered pictures: position and yaw against the truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from shapely.geometry import Polygon

from factory.core.errors import VisionError
from tests.vision import TRUE_CAMERA
from vision.camera import CameraModel, bin_image, binned_camera
from vision.handeye import invert
from vision.locate import footprint_from_mesh, locate_parts, mm_to_m
from vision.render import Box, look_at_pose, pixel_rays, render_boxes
from vision.station import station_above

ROOT = Path(__file__).resolve().parents[2]

TRAY_Z = 0.05
BLANK_MM = (80.0, 50.0, 20.0)
#: A camera 0.55 m above the tray, looking down 15-20 deg off vertical.
BASE_CAM = invert(look_at_pose(np.array([0.56, -0.12, TRAY_Z + 0.55]), np.array([0.5, 0.05, TRAY_Z]),
                               up=np.array([0.0, 1.0, 0.0])))


@pytest.fixture(scope="module")
def rays():
    return pixel_rays(TRUE_CAMERA, 3)


def blank_mesh(size=BLANK_MM, offset=(10.0, -5.0, 3.0)) -> trimesh.Trimesh:
    """A box in mm with its corner away from the mesh origin (the pose must not depend on it)."""
    m = trimesh.creation.box(size)
    m.apply_translation(np.array(size) / 2 + offset)
    return m


def yaw_error(a: float, b: float, period: float) -> float:
    """Smallest difference of two yaws modulo a symmetry period [rad]."""
    d = (a - b) % period
    return min(d, period - d)


def random_layout(rng, n: int, size_m) -> list[Box]:
    """n non-overlapping boxes in the camera's view on the tray."""
    boxes: list[Box] = []
    while len(boxes) < n:
        x, y = rng.uniform(0.38, 0.62), rng.uniform(-0.06, 0.16)
        if all(np.hypot(x - b.x, y - b.y) > 0.11 for b in boxes):
            boxes.append(Box(x, y, rng.uniform(-np.pi, np.pi), tuple(size_m)))
    return boxes


def test_mm_to_m_is_the_one_conversion():
    assert mm_to_m(25.0) == 0.025
    np.testing.assert_allclose(mm_to_m(np.array([1000.0, 2.0])), [1.0, 0.002])


def test_footprint_of_a_box_and_an_l_shape():
    fp = footprint_from_mesh(blank_mesh().vertices, blank_mesh().faces)
    assert fp.height == pytest.approx(0.02) and fp.symmetry == 2 and fp.convex
    np.testing.assert_allclose(fp.centroid, [0.05, 0.02])
    np.testing.assert_allclose(np.ptp(fp.outline, axis=0), [0.08, 0.05])
    l_shape = trimesh.util.concatenate([trimesh.creation.box((60, 20, 10)).apply_translation((30, 10, 5)),
                                        trimesh.creation.box((20, 40, 10)).apply_translation((10, 40, 5))])
    fl = footprint_from_mesh(l_shape.vertices, l_shape.faces)
    assert not fl.convex and fl.symmetry == 1
    assert Polygon(fl.outline).area == pytest.approx(
        mm_to_m(1.0) ** 2 * (60 * 20 + 20 * 40), rel=1e-6)
    two = trimesh.util.concatenate([trimesh.creation.box((10, 10, 10)),
                                    trimesh.creation.box((10, 10, 10)).apply_translation((50, 0, 0))])
    with pytest.raises(VisionError, match="2 separate pieces"):
        footprint_from_mesh(two.vertices, two.faces)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_finds_blanks_within_a_millimetre_and_half_a_degree(rays, seed):
    rng = np.random.default_rng(seed)
    size = mm_to_m(np.array(BLANK_MM))
    boxes = random_layout(rng, 3, size)
    image = render_boxes(rays, invert(BASE_CAM), boxes, plane_z=TRAY_Z, noise_sigma=2.0, seed=seed)
    part = footprint_from_mesh(blank_mesh().vertices, blank_mesh().faces)
    found = locate_parts(image, TRUE_CAMERA, BASE_CAM, part, TRAY_Z)
    assert len(found) == 3
    for box in boxes:
        near = min(found, key=lambda p: np.hypot(p.x - box.x, p.y - box.y))
        assert np.hypot(near.x - box.x, near.y - box.y) < 1e-3
        assert np.degrees(yaw_error(near.yaw, box.yaw, np.pi)) < 0.5
        # score: the share of the outline's edges found (a wall as bright as the tray hides its foot).
        assert near.z == TRAY_Z and near.score > 0.7 and near.rms_px < 0.6
        # The expected error is a fraction of a pixel at roughly 1 mm per pixel.
        assert 0.7 < near.mm_per_px < 1.4 and 0.1e-3 < near.sigma_xy < 1e-3


def test_an_l_shaped_part_and_a_wrong_size_blob(rays):
    """Two boxes forming an L: the non-convex silhouette path; a small box nearby is not the part."""
    yaw, x, y = 0.7, 0.47, 0.02
    r = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    # L of a 60x20 arm and a 20x40 arm (mm), as in test_footprint_of_a_box_and_an_l_shape.
    l_shape = trimesh.util.concatenate([trimesh.creation.box((60, 20, 15)).apply_translation((30, 10, 7.5)),
                                        trimesh.creation.box((20, 40, 15)).apply_translation((10, 40, 7.5))])
    part = footprint_from_mesh(l_shape.vertices, l_shape.faces)
    boxes = []
    for centre_mm, size_mm in (((30, 10), (60, 20)), ((10, 40), (20, 40))):
        c = np.array([x, y]) + r @ (mm_to_m(np.array(centre_mm)) - part.centroid)
        boxes.append(Box(c[0], c[1], yaw, (*mm_to_m(np.array(size_mm)), 0.015)))
    boxes.append(Box(0.6, 0.12, 0.2, (0.02, 0.02, 0.015)))
    image = render_boxes(rays, invert(BASE_CAM), boxes, plane_z=TRAY_Z, noise_sigma=2.0, seed=5)
    found = locate_parts(image, TRUE_CAMERA, BASE_CAM, part, TRAY_Z)
    assert len(found) == 1
    assert np.hypot(found[0].x - x, found[0].y - y) < 1e-3
    assert np.degrees(yaw_error(found[0].yaw, yaw, 2 * np.pi)) < 0.5


def test_nothing_to_find(rays):
    part = footprint_from_mesh(blank_mesh().vertices, blank_mesh().faces)
    empty = render_boxes(rays, invert(BASE_CAM), [], plane_z=TRAY_Z, noise_sigma=2.0, seed=1)
    with pytest.raises(VisionError, match="no part found") as e:
        locate_parts(empty, TRUE_CAMERA, BASE_CAM, part, TRAY_Z, source="tray.png")
    assert e.value.source == "tray.png"
    with pytest.raises(VisionError, match="320x240"):
        locate_parts(np.zeros((240, 320), np.uint8), TRUE_CAMERA, BASE_CAM, part, TRAY_Z)
    with pytest.raises(VisionError, match="not above"):
        locate_parts(empty, TRUE_CAMERA, BASE_CAM, part, 1.0)


def test_rendered_box_top_lands_where_projection_says():
    """Straight down onto a box with an ideal lens: the bright top face has the projected area and centre."""
    from vision.camera import CameraModel

    cam = CameraModel(K=[[500.0, 0, 159.5], [0, 500.0, 119.5], [0, 0, 1]], dist=[], image_size=(320, 240))
    down = np.diag([1.0, -1.0, -1.0, 1.0])  # camera z down, x along world x
    down[:3, 3] = -down[:3, :3] @ np.array([0.01, 0.0, 0.5])
    box = Box(0.03, -0.02, 0.0, (0.08, 0.05, 0.1))
    img = render_boxes(cam, down, [box], shades=(255.0, 0, 0, 0, 0), tray=0.0, supersample=4).astype(float)
    # The top at z = 0.1 is 0.4 m from the camera: 100 x 62.5 px.
    assert img.sum() / 255 == pytest.approx(100 * 62.5, rel=2e-3)
    vs, us = np.mgrid[0:240, 0:320]
    centre = cam.project(np.array([[box.x, box.y, 0.1]]) @ down[:3, :3].T + down[:3, 3], np.zeros(3), np.zeros(3))[0]
    np.testing.assert_allclose([(img * us).sum() / img.sum(), (img * vs).sum() / img.sum()], centre, atol=0.02)


def test_a_binned_camera_sees_each_point_at_the_mean_of_its_sensor_pixels():
    """A point's pixel in the n x n binning mode is its sensor pixel's centre mapped onto the bins:
    (u + 0.5) / n - 0.5 (vision.camera.binned_camera), for the 5 MP camera's distortion too."""
    camera = CameraModel.read(ROOT / "fixtures" / "camera_5mp.yaml")
    points = np.random.default_rng(0).uniform([-0.15, -0.12, 0.45], [0.15, 0.12, 0.55], (50, 3))
    full = camera.project(points, np.zeros(3), np.zeros(3))
    for n in (2, 4):
        coarse = binned_camera(camera, n)
        assert coarse.image_size == (camera.image_size[0] // n, camera.image_size[1] // n)
        np.testing.assert_allclose(coarse.project(points, np.zeros(3), np.zeros(3)), (full + 0.5) / n - 0.5,
                                   atol=1e-9)
    image = np.arange(16, dtype=np.uint8).reshape(4, 4)
    np.testing.assert_array_equal(bin_image(image, 2), [[2, 4], [10, 12]])  # rint(2.5) = 2, rint(4.5) = 4


def test_a_5_mp_camera_locates_on_its_binned_picture_and_refines_on_the_full_one():
    """The 5 MP cell camera (0.144 mm per pixel) over a blank: searched and judged on its 4 x 4
    binned picture (0.58 mm per pixel), refined on the full one, so the pose is within 0.05 mm and
    0.05 deg, within its uncertainty, and that uncertainty is the full picture's (under 0.2 mm, a
    third of a binned pixel); the outline for inspection is in full-picture pixels."""
    camera = CameraModel.read(ROOT / "fixtures" / "camera_5mp.yaml")
    station = station_above(camera, np.array([0.05, 0.40, 0.78]), 0.5)
    blank = Box(0.07, 0.38, 0.4, tuple(np.array(BLANK_MM) / 1e3))
    image = render_boxes(pixel_rays(camera, 1), station.world_to_camera, [blank], plane_z=station.plane_z)
    mesh = blank_mesh()
    (p,) = locate_parts(image, camera, station.camera_pose, footprint_from_mesh(mesh.vertices, mesh.faces),
                        station.plane_z)
    error = np.hypot(p.x - blank.x, p.y - blank.y)
    turn = yaw_error(p.yaw, blank.yaw, np.pi)
    assert error < 5e-5 and turn < np.radians(0.05), (error, np.degrees(turn))
    assert error <= p.sigma_xy < 2e-4 and turn <= p.sigma_yaw
    assert p.mm_per_px == pytest.approx(0.14, abs=0.01)
    rvec = cv2.Rodrigues(station.world_to_camera[:3, :3])[0].ravel()
    middle = camera.project(np.array([[blank.x, blank.y, station.plane_z + BLANK_MM[2] / 2e3]]), rvec,
                            station.world_to_camera[:3, 3])[0]
    assert np.hypot(*(np.mean(p.outline, axis=0) - middle)) < 8.0  # px of the full picture
