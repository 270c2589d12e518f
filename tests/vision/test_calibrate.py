"""Calibration against OpenCV's published results, on synthetic views, and its failure modes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from factory.core.errors import CalibrationError
from tests.vision import SAMPLES, TRUE_CAMERA, calibration_poses
from vision.board import BoardSpec
from vision.calibrate import Detection, calibrate, detect, outlier_views, subpix_half_window
from vision.camera import CameraModel
from vision.render import pixel_rays, render

# OpenCV's Python regression test (calib3d/misc/python/test/test_calibration.py) on left/.
REF_RMS = 0.196
REF_K = np.array([532.81, 532.93, 342.50, 233.89])  # fx, fy, cx, cy [px]
REF_DIST = np.array([-0.2813, 0.0291, 0.00121, -0.00014, 0.1549])
CHESS = BoardSpec.parse("chessboard:9x6:0.025")
CHARUCO_SAMPLE = BoardSpec.parse("charuco:5x7:0.04:0.02:DICT_6X6_250")


def intrinsics(result) -> np.ndarray:
    c = result.camera
    return np.array([c.fx, c.fy, c.cx, c.cy])


@pytest.fixture(scope="module")
def left_images() -> dict[str, np.ndarray]:
    files = sorted((SAMPLES / "left").glob("*.jpg"))
    return {p.name: cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in files}


@pytest.mark.parametrize("window", [None, 5], ids=["adaptive-window", "reference-5x5"])
def test_reproduces_opencv_reference_on_left(left_images, window):
    dets = [detect(img, CHESS, name, subpix_window=window) for name, img in left_images.items()]
    assert len(dets) == 13 and all(d.method == "classic" for d in dets)
    result = calibrate(dets, "plumb_bob")
    assert result.camera.rms == pytest.approx(REF_RMS, abs=0.01)
    assert np.abs(intrinsics(result) - REF_K).sum() <= 10
    assert np.abs(result.camera.dist - REF_DIST).sum() <= 0.05
    assert result.outliers == () and result.without_board == ()
    # The standard deviations are what OpenCV reports: small, positive [px].
    assert np.all((result.std_K > 0) & (result.std_K < 2))


def test_adaptive_window_follows_corner_spacing(left_images):
    """left02's corners are about 22 px apart: its window must be smaller than the widest view's."""
    windows = {n: detect(img, CHESS, n).subpix_window for n, img in left_images.items()}
    assert 2 <= min(windows.values()) and max(windows.values()) <= 11
    assert windows["left02.jpg"] == min(windows.values()) < max(windows.values())


def test_subpix_window_is_clamped():
    grid = np.stack(np.meshgrid(np.arange(4), np.arange(3)), -1).reshape(-1, 2).astype(float)
    assert subpix_half_window(grid * 3, 4, 3) == 2
    assert subpix_half_window(grid * 500, 4, 3) == 11
    assert subpix_half_window(grid * 30, 4, 3) == round(0.18 * 30)


def test_charuco_sample_detection():
    image = cv2.imread(str(SAMPLES / "charuco" / "choriginal.jpg"))
    det = detect(image, CHARUCO_SAMPLE, "choriginal.jpg")
    assert det.method == "charuco"
    assert 18 <= len(det.ids) <= 24  # 24 inner corners on a 5x7 board; nearly all visible
    assert len(set(det.ids.tolist())) == len(det.ids)
    np.testing.assert_allclose(det.object_points, CHARUCO_SAMPLE.object_points[det.ids])
    h, w = image.shape[:2]
    assert np.all((det.image_points >= 0) & (det.image_points < (w, h)))


def test_no_board_in_an_image_is_an_error_naming_it():
    blank = np.full((120, 160), 200, np.uint8)
    with pytest.raises(CalibrationError, match="9x6 chessboard") as e:
        detect(blank, CHESS, "empty.png")
    assert e.value.source == "empty.png"
    with pytest.raises(CalibrationError, match="ChArUco") as e:
        detect(blank, CHARUCO_SAMPLE, "empty.png")
    with pytest.raises(CalibrationError, match="8-bit"):
        detect(blank.astype(np.float32), CHESS, "float.tif")


def test_too_few_views_and_mixed_sizes(left_images):
    dets = [detect(img, CHESS, n) for n, img in list(left_images.items())[:3]]
    with pytest.raises(CalibrationError, match="at least 3"):
        calibrate(dets[:2])
    odd = Detection("odd.png", (320, 240), dets[0].image_points, dets[0].object_points, dets[0].ids)
    with pytest.raises(CalibrationError, match="320x240") as e:
        calibrate([*dets, odd])
    assert e.value.source == "odd.png"
    with pytest.raises(CalibrationError, match="model"):
        calibrate(dets, "fisheye")


def test_outlier_rule():
    assert not outlier_views(np.full(10, 0.2)).any()
    # Uniformly good views with a tiny spread: nothing twice the median, nothing flagged.
    assert not outlier_views(np.linspace(0.19, 0.26, 12)).any()
    flags = outlier_views(np.r_[np.full(10, 0.2) + np.linspace(0, 0.02, 10), 0.9])
    assert flags.tolist() == [False] * 10 + [True]


def test_a_corrupted_view_is_flagged_and_rejected(left_images):
    dets = [detect(img, CHESS, n) for n, img in left_images.items()]
    rng = np.random.default_rng(3)
    bad = dets[4]
    dets[4] = Detection(bad.name, bad.image_size, bad.image_points + rng.normal(0, 1.5, bad.image_points.shape),
                        bad.object_points, bad.ids)
    flagged = calibrate(dets, without_board=["blank.png"])
    assert flagged.outliers == (bad.name,) and not flagged.rejected
    assert flagged.without_board == ("blank.png",)
    assert bad.name in flagged.views
    rejected = calibrate(dets, reject=True)
    assert rejected.rejected and bad.name not in rejected.views and len(rejected.views) == 12
    assert rejected.camera.rms < flagged.camera.rms
    assert rejected.camera.rms == pytest.approx(REF_RMS, abs=0.02)


# --- synthetic views: exact renderings of a known camera -------------------------------

SYNTHETIC = [
    ("chessboard:13x10:0.02", 0.6),
    ("charuco:12x9:0.025:0.0125:DICT_5X5_100", 0.45),
]


@pytest.fixture(scope="module")
def true_rays():
    return pixel_rays(TRUE_CAMERA, 4)


@pytest.mark.parametrize("spec, distance", SYNTHETIC, ids=["chessboard", "charuco"])
def test_recovers_a_known_camera_from_synthetic_views(true_rays, spec, distance):
    board = BoardSpec.parse(spec)
    texture = board.texture(48)
    dets = [detect(render(true_rays, pose, texture, noise_sigma=2.0, seed=i), board, f"view{i:02d}")
            for i, pose in enumerate(calibration_poses(TRUE_CAMERA, board, distance))]
    result = calibrate(dets, "plumb_bob")
    true = np.array([TRUE_CAMERA.fx, TRUE_CAMERA.fy, TRUE_CAMERA.cx, TRUE_CAMERA.cy])
    rel = np.abs(intrinsics(result) / true - 1)
    assert rel.max() < 1e-3, rel
    assert result.camera.rms < 0.15
    # Distortion: the estimated coefficients bend every ray the board covered to within
    # 0.2 px of the true lens (single coefficients of a polynomial trade off against each
    # other, so they are compared by what they do).
    covered = cv2.convexHull(np.vstack([d.image_points for d in dets]).astype(np.float32))
    grid = np.stack(np.meshgrid(np.arange(0, 640, 16.0), np.arange(0, 480, 16.0)), -1).reshape(-1, 2)
    inside = np.array([cv2.pointPolygonTest(covered, (float(x), float(y)), False) >= 0 for x, y in grid])
    assert inside.mean() > 0.5
    lens = CameraModel(K=TRUE_CAMERA.K, dist=result.camera.dist, image_size=TRUE_CAMERA.image_size)
    moved = lens.project(TRUE_CAMERA.rays(grid[inside]), np.zeros(3), np.zeros(3))
    assert np.abs(moved - grid[inside]).max() < 0.2
    assert abs(result.camera.dist[0] - TRUE_CAMERA.dist[0]) < 0.01


def test_rational_model_calibrates_synthetic_views(true_rays):
    board = BoardSpec.parse(SYNTHETIC[0][0])
    texture = board.texture(48)
    dets = [detect(render(true_rays, pose, texture, noise_sigma=1.0, seed=i), board, f"v{i}")
            for i, pose in enumerate(calibration_poses(TRUE_CAMERA, board, SYNTHETIC[0][1]))]
    result = calibrate(dets, "rational_polynomial")
    assert result.camera.model == "rational_polynomial" and result.camera.dist.shape == (8,)
    assert result.std_dist.shape == (8,)
    true = np.array([TRUE_CAMERA.fx, TRUE_CAMERA.fy, TRUE_CAMERA.cx, TRUE_CAMERA.cy])
    assert np.abs(intrinsics(result) / true - 1).max() < 3e-3
