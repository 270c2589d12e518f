"""The synthetic renderer: geometry against exact projection, and the report picture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from factory.errors import VisionError
from tests.vision import TRUE_CAMERA, calibration_poses
from vision.board import BoardSpec, PlanarTexture
from vision.calibrate import Detection, calibrate, detect
from vision.camera import CameraModel
from vision.render import look_at_pose, orbit_pose, pixel_rays, render
from vision.report import bgr_png_bytes, report_image


def test_square_patch_lands_where_projection_says():
    """A white square on black: its rendered area and centroid match the exact projection."""
    cam = CameraModel(K=[[400.0, 0, 79.5], [0, 400.0, 59.5], [0, 0, 1]], dist=[], image_size=(160, 120))
    tex = PlanarTexture(image=np.pad(np.full((100, 100), 255, np.uint8), 50), pixel_size=0.0005, origin=(100, 100))
    pose = np.eye(4)
    pose[:3, 3] = (0.01, -0.005, 0.5)  # 0.05 m square, 0.5 m away, fronto-parallel: 40 x 40 px
    img = render(cam, pose, tex, supersample=4, background=0).astype(float)
    corners = np.array([[-0.025, -0.025, 0], [0.025, 0.025, 0]])
    (u0, v0), (u1, v1) = cam.project(corners, np.zeros(3), pose[:3, 3])
    assert img.sum() / 255 == pytest.approx((u1 - u0) * (v1 - v0), rel=2e-3)
    vs, us = np.mgrid[0:120, 0:160]
    centroid = np.array([(img * us).sum(), (img * vs).sum()]) / img.sum()
    np.testing.assert_allclose(centroid, [(u0 + u1) / 2, (v0 + v1) / 2], atol=0.01)


def test_rendered_corners_match_exact_projection_under_distortion():
    board = BoardSpec.parse("chessboard:13x10:0.02")
    rays = pixel_rays(TRUE_CAMERA, 4)
    pose = calibration_poses(TRUE_CAMERA, board, 0.6)[3]
    det = detect(render(rays, pose, board.texture(48)), board, "view")
    truth = TRUE_CAMERA.project(det.object_points, cv2.Rodrigues(pose[:3, :3])[0], pose[:3, 3])
    err = det.image_points - truth
    # cornerSubPix on a perspective view leaves ~0.05 px RMS; any error of the renderer's
    # geometry (half-pixel shifts, a wrong lens inversion) would be far larger.
    assert np.sqrt((err ** 2).mean()) < 0.08
    assert np.abs(err.mean(axis=0)).max() < 0.02


def test_poses_and_noise():
    target = np.array([0.1, 0.05, 0.0])
    t = orbit_pose(target, 0.4, np.radians(30), 0.0)
    assert np.allclose(t[:3, :3] @ t[:3, :3].T, np.eye(3))
    assert (t @ np.r_[target, 1])[:3] == pytest.approx([0, 0, 0.4])
    eye = np.array([0.0, 0.0, -0.5])
    assert (look_at_pose(eye, np.zeros(3)) @ np.r_[eye, 1])[:3] == pytest.approx([0, 0, 0])
    cam = CameraModel(K=[[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]], dist=[], image_size=(64, 48))
    flat = PlanarTexture(np.full((8, 8), 100, np.uint8), 0.1, (4, 4))
    pose = np.eye(4)
    pose[2, 3] = 1.0
    a = render(cam, pose, flat, noise_sigma=3.0, seed=1)
    b = render(cam, pose, flat, noise_sigma=3.0, seed=1)
    np.testing.assert_array_equal(a, b)
    assert abs(a.astype(float).mean() - 100) < 1 and 2 < a.astype(float).std() < 4
    behind = pose.copy()
    behind[2, 3] = -1.0  # plane behind the camera: nothing of it is seen
    assert (render(cam, behind, flat, background=7) == 7).all()
    with pytest.raises(VisionError):
        render(cam, np.eye(3), flat)


def test_report_picture_marks_outliers():
    board = BoardSpec.parse("chessboard:9x6:0.025")
    rng = np.random.default_rng(0)
    dets = []
    for i, pose in enumerate(calibration_poses(TRUE_CAMERA, board, 0.5, n=6)):
        uv = TRUE_CAMERA.project(board.object_points, cv2.Rodrigues(pose[:3, :3])[0], pose[:3, 3])
        noise = 1.5 if i == 2 else 0.05
        dets.append(Detection(f"v{i}.png", (640, 480), uv + rng.normal(0, noise, uv.shape), board.object_points,
                              np.arange(54)))
    result = calibrate(dets)
    assert result.outliers == ("v2.png",)
    img = report_image(result)
    assert img.ndim == 3 and img.shape[1] > 640
    red = (img[..., 2] > 200) & (img[..., 0] < 60) & (img[..., 1] < 60)
    assert red.sum() > 100
    assert cv2.imdecode(np.frombuffer(bgr_png_bytes(img), np.uint8), cv2.IMREAD_COLOR).shape == img.shape


def test_texture_of_the_sample_charuco_board_is_detected_exactly():
    board = BoardSpec.parse("charuco:5x7:0.04:0.02:DICT_6X6_250")
    tex = board.texture(48)
    det = detect(tex.image, board, "texture")
    expected = np.array(tex.origin) + det.object_points[:, :2] / tex.pixel_size - 0.5
    assert len(det.ids) == 24
    np.testing.assert_allclose(det.image_points, expected, atol=0.05)
