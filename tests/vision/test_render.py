"""The synthetic renderer: geometry against exact projection, and the report picture."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from factory.core.errors import VisionError
from tests.conftest import SAMPLES
from tests.vision import TRUE_CAMERA, calibration_poses
from vision.board import BoardSpec, PlanarTexture
from vision.calibrate import Detection, calibrate, detect
from vision.camera import CameraModel
from vision.render import Box, look_at_pose, orbit_pose, pixel_rays, render, render_boxes, render_mesh
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


def box_mesh(box: Box, plane_z: float) -> trimesh.Trimesh:
    """The triangle mesh of a yaw-0 :class:`Box` standing on the tray [m]."""
    m = trimesh.creation.box(box.size)
    m.apply_translation((box.x, box.y, plane_z + box.size[2] / 2))
    return m


#: A camera 0.55 m above a tray at z = 0.05 m, looking down about 17 deg off vertical from -y.
TILTED = look_at_pose(np.array([0.56, -0.12, 0.6]), np.array([0.5, 0.05, 0.05]), up=np.array([0.0, 1.0, 0.0]))


def test_mesh_of_boxes_renders_as_render_boxes_with_occlusion():
    """A tall box in front of a low one: the mesh renderer gives render_boxes' picture, hidden parts hidden."""
    rays = pixel_rays(TRUE_CAMERA, 3)
    tall, low = Box(0.5, 0.0, 0.0, (0.06, 0.03, 0.15)), Box(0.49, 0.06, 0.0, (0.08, 0.05, 0.02))
    expected = render_boxes(rays, TILTED, [tall, low], plane_z=0.05, noise_sigma=2.0, seed=4)
    both = trimesh.util.concatenate([box_mesh(tall, 0.05), box_mesh(low, 0.05)])
    got = render_mesh(rays, TILTED, both.vertices, both.faces, plane_z=0.05, noise_sigma=2.0, seed=4)
    diff = np.abs(got.astype(int) - expected)
    assert got.shape == (480, 640) and diff.max() <= 1 and (diff > 0).mean() < 1e-3
    # The order of the triangles does not matter, and the tall box does hide part of the low one.
    flipped = render_mesh(rays, TILTED, both.vertices, both.faces[::-1], plane_z=0.05, noise_sigma=2.0, seed=4)
    np.testing.assert_array_equal(flipped, got)
    alone = render_mesh(rays, TILTED, box_mesh(low, 0.05).vertices, box_mesh(low, 0.05).faces, plane_z=0.05)
    low_top = (alone > 200).sum()
    clean = render_mesh(rays, TILTED, both.vertices, both.faces, plane_z=0.05)
    tall_top = render_mesh(rays, TILTED, box_mesh(tall, 0.05).vertices, box_mesh(tall, 0.05).faces, plane_z=0.05)
    assert (clean > 200).sum() < low_top + (tall_top > 200).sum() - 500


def test_mesh_with_a_pocket_matches_ray_casting():
    """Pixel centres of the dome mould (a pocket, 11k triangles) against trimesh's ray caster (independent)."""
    mesh = trimesh.load(SAMPLES / "dome_mould.stl")
    vertices = mesh.vertices / 1000.0 + np.array([0.455, 0.01, 0.05])  # 90 x 70 x 30 mm around (0.5, 0.045)
    # Top faces white, sides black, the tray 40: the grey level says which way the seen face points.
    # 0.2 m above the tray, 40 deg off vertical: the pocket hides part of itself and the part's far side.
    pose = look_at_pose(np.array([0.62, -0.12, 0.25]), np.array([0.5, 0.045, 0.05]), up=np.array([0.0, 1.0, 0.0]))
    img = render_mesh(TRUE_CAMERA, pose, vertices, mesh.faces, plane_z=0.05, shades=(255.0, 0, 0, 0, 0),
                      supersample=1)
    world = trimesh.Trimesh(vertices, mesh.faces, process=False)
    rng = np.random.default_rng(0)
    ys, xs = np.nonzero(img != 40)
    bounds = np.array([[xs.min() - 10, ys.min() - 10], [xs.max() + 10, ys.max() + 10]])  # part and some tray [px]
    assert (bounds[1] - bounds[0]).min() > 150
    pix = rng.integers(bounds[0], bounds[1], size=(3000, 2))
    rays = TRUE_CAMERA.rays(pix.astype(float)) @ pose[:3, :3]  # world directions, R^T ray
    eye = -pose[:3, :3].T @ pose[:3, 3]
    loc, ray_id, tri_id = world.ray.intersects_location(np.tile(eye, (len(pix), 1)), rays, multiple_hits=True)
    expected = np.full(len(pix), 40.0)
    nearest = np.full(len(pix), np.inf)
    for p, r, t in zip(loc, ray_id, tri_id):
        d = np.linalg.norm(p - eye)
        if d < nearest[r]:
            nz = world.face_normals[t][2]
            nearest[r], expected[r] = d, 255.0 * max(nz, 0.0) ** 2
    got = img[pix[:, 1], pix[:, 0]].astype(float)
    assert np.isfinite(nearest).mean() > 0.5  # most samples are on the part
    # Rounding to grey levels only; a sample exactly on an edge may go either way. (Without the
    # depth test about 100 of these samples differ.)
    assert (np.abs(got - np.rint(expected)) > 1).sum() <= 3


def test_mesh_errors_and_an_empty_mesh():
    cam = CameraModel(K=[[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]], dist=[], image_size=(64, 48))
    down = look_at_pose(np.array([0.0, 0.0, 0.5]), np.zeros(3), up=np.array([0.0, 1.0, 0.0]))
    empty = render_mesh(cam, down, np.zeros((0, 3)), np.zeros((0, 3), np.int64), tray=40.0)
    assert (empty == 40).all()
    box = trimesh.creation.box((0.1, 0.1, 0.1))
    with pytest.raises(VisionError, match="behind the camera"):
        render_mesh(cam, down, box.vertices + [0, 0, 0.6], box.faces)
    with pytest.raises(VisionError, match="indices"):
        render_mesh(cam, down, box.vertices, box.faces + 100)
    with pytest.raises(VisionError, match=r"\(n, 3\)"):
        render_mesh(cam, down, box.vertices[:, :2], box.faces)
