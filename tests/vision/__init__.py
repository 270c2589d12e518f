"""Shared test helpers for vision: a true camera and board poses that calibrate well."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vision.board import BoardSpec
from vision.camera import CameraModel

#: OpenCV's sample calibration images (Apache-2.0), kept in the project so a fresh clone tests them.
SAMPLES = Path(__file__).resolve().parents[1] / "data" / "opencv-samples"

#: The camera synthetic views are rendered with: 640x480 px, barrel distortion.
TRUE_CAMERA = CameraModel(K=[[600.0, 0, 322.0], [0, 605.0, 238.0], [0, 0, 1]],
                          dist=[-0.2, 0.08, 0.001, -0.0005, -0.02], image_size=(640, 480))


def calibration_poses(camera: CameraModel, board: BoardSpec, distance: float, n: int = 12,
                      tilts_deg=(30.0, 40.0), spread: float = 0.2) -> list[np.ndarray]:
    """Board-to-camera transforms (translation [m]) of ``n`` views: the board centre on a
    ring around the image centre (``spread`` of the image size), tilted 30-40 deg about
    axes that turn with the view, rolled a little, at distances varying +-15 %."""
    w, h = camera.image_size
    centre = board.object_points.mean(axis=0)
    poses = []
    for i in range(n):
        a = 2 * np.pi * i / n
        phase = np.pi / 4 * (i % 3 - 1)
        u, v = 0.5 + spread * np.cos(a + phase), 0.5 + spread * np.sin(a + phase)
        tilt = np.radians(tilts_deg[i % len(tilts_deg)])
        axis = a + np.pi / 2 * (i % 2)
        r = (cv2.Rodrigues(tilt * np.array([np.cos(axis), np.sin(axis), 0.0]))[0]
             @ cv2.Rodrigues(np.array([0.0, 0.0, np.radians(25 * np.sin(3 * i))]))[0])
        ray = camera.rays(np.array([[u * w, v * h]]))[0]
        t = np.eye(4)
        t[:3, :3] = r
        t[:3, 3] = distance * (1 + 0.15 * np.sin(5 * i)) * ray / np.linalg.norm(ray) - r @ centre
        poses.append(t)
    return poses
