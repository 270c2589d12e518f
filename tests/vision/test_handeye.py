"""Hand-eye calibration against synthetic truth: noisy robot and board poses, both modes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from factory.core.errors import VisionError
from tests.vision import TRUE_CAMERA
from vision.board import BoardSpec
from vision.calibrate import detect
from vision.handeye import (board_pose, calibrate_handeye, invert, make_transform, pose_from_xyz_rotation,
                            transform_to_xyz_quat)
from vision.render import pixel_rays, render

#: The camera 6 cm off the flange axis, 9 cm out, turned 10 deg and 95 deg: a typical wrist camera.
TRUE_FLANGE_CAM = make_transform(Rotation.from_euler("zyx", [95, 4, -10], degrees=True).as_matrix(),
                                 [0.045, -0.06, 0.09])
#: A camera fixed on the cell wall looking down at the robot's work area.
TRUE_BASE_CAM = make_transform(Rotation.from_euler("xyz", [180 - 25, 0, 30], degrees=True).as_matrix(),
                               [0.9, 0.4, 0.8])


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between the rotations of two transforms [rad]."""
    return float(np.linalg.norm(Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).as_rotvec()))


def jitter(t: np.ndarray, rng, mm: float, deg: float) -> np.ndarray:
    """A transform disturbed by Gaussian noise of ``mm`` [mm] per axis and ``deg`` [deg] per axis."""
    out = t.copy()
    out[:3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(deg), 3)).as_matrix() @ t[:3, :3]
    out[:3, 3] += rng.normal(0, mm * 1e-3, 3)
    return out


def views_looking_at(target_in_base: np.ndarray, rng, n: int) -> list[np.ndarray]:
    """``T_base_cam`` of n cameras 0.45-0.6 m from a target, tilted up to 35 deg, rolled freely."""
    out = []
    for _ in range(n):
        tilt, az, roll = np.radians(rng.uniform(10, 35)), rng.uniform(0, 2 * np.pi), rng.uniform(-np.pi, np.pi)
        d = rng.uniform(0.45, 0.6)
        eye = target_in_base + d * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        z = (target_in_base - eye) / d
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        r = np.stack([x, y, z], axis=1) @ Rotation.from_rotvec([0, 0, roll]).as_matrix()
        out.append(make_transform(r, eye))
    return out


def eye_in_hand_views(rng, n: int, base_board: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True flange poses and board-in-camera poses of n views of a board fixed in the cell."""
    cams = views_looking_at(base_board[:3, 3], rng, n)
    flange = np.array([c @ invert(TRUE_FLANGE_CAM) for c in cams])
    board = np.array([invert(c) @ base_board for c in cams])
    return flange, board


def eye_to_hand_views(rng, n: int, flange_board: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True flange poses and board-in-camera poses of n views of a board carried by the flange."""
    cam = TRUE_BASE_CAM
    flange, board = [], []
    for _ in range(n):
        # The board 0.5-0.7 m in front of the camera, tilted up to 35 deg toward it.
        centre = cam @ np.r_[rng.uniform(-0.08, 0.08, 2), rng.uniform(0.5, 0.7), 1.0]
        r = cam[:3, :3] @ Rotation.from_rotvec(np.r_[rng.uniform(-0.6, 0.6, 2), rng.uniform(-np.pi, np.pi)]).as_matrix()
        base_board = make_transform(r, centre[:3])
        flange.append(base_board @ invert(flange_board))
        board.append(invert(cam) @ base_board)
    return np.array(flange), np.array(board)


BASE_BOARD = make_transform(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0.5, -0.1, 0.02])
FLANGE_BOARD = make_transform(Rotation.from_euler("y", 180, degrees=True).as_matrix(), [0.0, 0.02, 0.12])


@pytest.mark.parametrize("mode", ["eye-in-hand", "eye-to-hand"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_transform_from_noisy_poses(mode, seed):
    """15 views, robot noise 0.2 mm / 0.05 deg, board poses 0.3 mm / 0.05 deg (solvePnP at ~0.5 m)."""
    rng = np.random.default_rng(seed)
    if mode == "eye-in-hand":
        flange, board = eye_in_hand_views(rng, 15, BASE_BOARD)
        truth, other = TRUE_FLANGE_CAM, BASE_BOARD
    else:
        flange, board = eye_to_hand_views(rng, 15, FLANGE_BOARD)
        truth, other = TRUE_BASE_CAM, FLANGE_BOARD
    # Exact data first: both the closed form and the refinement are exact.
    exact = calibrate_handeye(flange, board, mode)
    np.testing.assert_allclose(exact.transform, truth, atol=1e-9)
    np.testing.assert_allclose(exact.closed_form, truth, atol=1e-9)
    np.testing.assert_allclose(exact.board, other, atol=1e-9)

    noisy_f = np.array([jitter(t, rng, 0.2, 0.05) for t in flange])
    noisy_c = np.array([jitter(t, rng, 0.3, 0.05) for t in board])
    result = calibrate_handeye(noisy_f, noisy_c, mode)
    assert np.linalg.norm(result.transform[:3, 3] - truth[:3, 3]) < 1e-3
    assert np.degrees(rotation_angle(result.transform, truth)) < 0.1
    # The closed form alone is in the same ballpark (it is the refinement's start).
    assert np.linalg.norm(result.closed_form[:3, 3] - truth[:3, 3]) < 3e-3
    # Residuals reflect the injected noise: sub-millimetre, sub-0.2-degree.
    assert 1e-5 < result.translation_rms < 1.5e-3
    assert np.degrees(result.rotation_rms) < 0.2
    assert result.condition > 0.01


def test_parallel_axes_are_refused():
    rng = np.random.default_rng(4)
    flange = np.array([make_transform(Rotation.from_rotvec([0, 0, a]).as_matrix(), rng.uniform(-0.1, 0.1, 3))
                       for a in np.linspace(0, 1.5, 6)])
    board = np.array([invert(TRUE_FLANGE_CAM) @ invert(f) @ BASE_BOARD for f in flange])
    with pytest.raises(VisionError, match="parallel"):
        calibrate_handeye(flange, board, "eye-in-hand")


def test_bad_inputs():
    eye = np.repeat(np.eye(4)[None], 4, axis=0)
    with pytest.raises(VisionError, match="mode"):
        calibrate_handeye(eye, eye, "eye-on-shoulder")
    with pytest.raises(VisionError, match="3 flange poses but 4"):
        calibrate_handeye(eye[:3], eye, "eye-in-hand")
    with pytest.raises(VisionError, match="at least 3"):
        calibrate_handeye(eye[:2], eye[:2])
    skew = eye.copy()
    skew[1, 0, 1] = 0.3
    with pytest.raises(VisionError, match="#1 is not a rigid"):
        calibrate_handeye(skew, eye)
    with pytest.raises(VisionError, match="rotate"):
        calibrate_handeye(eye, eye)  # no motion at all


@given(q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
       xyz=st.lists(st.floats(-2, 2), min_size=3, max_size=3))
@settings(max_examples=50, deadline=None)
def test_quaternion_round_trip(q, xyz):
    t = pose_from_xyz_rotation(np.array(xyz), quat_xyzw=np.array(q))
    p, back = transform_to_xyz_quat(t)
    np.testing.assert_allclose(p, xyz)
    assert back[3] >= 0 and np.linalg.norm(back) == pytest.approx(1.0)
    np.testing.assert_allclose(pose_from_xyz_rotation(p, quat_xyzw=back), t, atol=1e-12)
    rv = Rotation.from_matrix(t[:3, :3]).as_rotvec()
    np.testing.assert_allclose(pose_from_xyz_rotation(p, rotvec=rv), t, atol=1e-12)


def test_board_pose_from_a_rendered_view():
    board = BoardSpec.parse("chessboard:9x6:0.03")
    truth = make_transform(Rotation.from_euler("xy", [20, -15], degrees=True).as_matrix(), [-0.1, -0.06, 0.55])
    image = render(pixel_rays(TRUE_CAMERA, 2), truth, board.texture(32), noise_sigma=1.0, seed=0)
    pose, rms = board_pose(detect(image, board, "v.png"), TRUE_CAMERA)
    assert rms < 0.2
    assert np.linalg.norm(pose[:3, 3] - truth[:3, 3]) < 1e-3
    assert np.degrees(rotation_angle(pose, truth)) < 0.1
