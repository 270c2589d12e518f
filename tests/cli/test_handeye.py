"""``factory handeye`` end to end on rendered views of a board from a wrist camera."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from cli.main import app
from tests.vision import TRUE_CAMERA
from tests.vision.test_handeye import BASE_BOARD, TRUE_FLANGE_CAM, jitter, rotation_angle, views_looking_at
from vision.board import BoardSpec
from vision.handeye import invert, read_extrinsics, transform_to_xyz_quat
from vision.render import pixel_rays, render
from tests.cli.expect import assert_one_line_error

runner = CliRunner()
BOARD = BoardSpec.parse("chessboard:9x6:0.025")


def run(*args):
    return runner.invoke(app, ["handeye", *[str(a) for a in args]], catch_exceptions=False)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    """12 rendered views of a board fixed in the cell, the flange poses (0.2 mm / 0.05 deg robot
    noise) as YAML (rotation vectors) and CSV (quaternions), and the camera file."""
    d = tmp_path_factory.mktemp("handeye")
    images = d / "views"
    images.mkdir()
    rng = np.random.default_rng(7)
    centre = BASE_BOARD @ np.r_[BOARD.object_points.mean(axis=0), 1.0]
    rays = pixel_rays(TRUE_CAMERA, 2)
    texture = BOARD.texture(32)
    yaml_poses, csv_rows = {}, ["image,x,y,z,qx,qy,qz,qw"]
    for i, base_cam in enumerate(views_looking_at(centre[:3], rng, 12)):
        name = f"view{i:02d}.png"
        image = render(rays, invert(base_cam) @ BASE_BOARD, texture, noise_sigma=1.5, seed=i)
        cv2.imwrite(str(images / name), image)
        flange = jitter(base_cam @ invert(TRUE_FLANGE_CAM), rng, 0.2, 0.05)
        rv = Rotation.from_matrix(flange[:3, :3]).as_rotvec()
        yaml_poses[name] = {"xyz": flange[:3, 3].tolist(), "rotvec": rv.tolist()}
        xyz, q = transform_to_xyz_quat(flange)
        csv_rows.append(",".join([name, *(repr(float(v)) for v in (*xyz, *q))]))
    cv2.imwrite(str(images / "zz_blank.png"), np.full((480, 640), 128, np.uint8))
    yaml_poses["zz_blank.png"] = yaml_poses["view00.png"]
    (d / "poses.yaml").write_text(yaml.safe_dump({"poses": yaml_poses}))
    (d / "poses.csv").write_text("\n".join(csv_rows) + "\n")
    (d / "camera.yaml").write_text(TRUE_CAMERA.to_camera_info_yaml())
    return {"dir": d, "images": images, "camera": d / "camera.yaml"}


def args(scene, poses: str, out: Path, *extra) -> list:
    return [scene["dir"] / poses, scene["images"], "--camera", scene["camera"], "--board", str(BOARD),
            "-o", out, *extra]


@pytest.mark.parametrize("poses", ["poses.yaml", "poses.csv"])
def test_recovers_the_wrist_camera(scene, tmp_path, poses):
    out = tmp_path / "handeye.yaml"
    r = run(*args(scene, poses, out, "--mode", "eye-in-hand", "--json"))
    assert r.exit_code == 0, r.output
    doc = yaml.safe_load(out.read_text())
    assert doc["format"] == "factory.handeye/1" and doc["mode"] == "eye-in-hand"
    assert (doc["transform"]["parent_frame"], doc["transform"]["child_frame"]) == ("flange", "camera")
    t = np.array(doc["transform"]["matrix"])
    assert np.linalg.norm(t[:3, 3] - TRUE_FLANGE_CAM[:3, 3]) < 1e-3
    assert np.degrees(rotation_angle(t, TRUE_FLANGE_CAM)) < 0.1
    np.testing.assert_allclose(doc["transform"]["xyz"], t[:3, 3])
    q = Rotation.from_quat(doc["transform"]["quaternion_xyzw"]).as_matrix()
    np.testing.assert_allclose(q, t[:3, :3], atol=1e-9)
    assert np.linalg.norm(np.array(doc["board"]["matrix"])[:3, 3] - BASE_BOARD[:3, 3]) < 2e-3
    res = doc["residuals"]
    assert res["translation_rms_m"] < 1e-3 and len(res["views"]) == 12
    assert all(v["reprojection_px"] < 0.3 for v in res["views"])
    blank = ["zz_blank.png"] if poses == "poses.yaml" else []
    assert doc["views_without_board"] == blank
    assert json.loads(r.stdout)["output"] == str(out)
    back = read_extrinsics(out.read_text())
    np.testing.assert_array_equal(back.transform, t)
    assert back.mode == "eye-in-hand" and back.tray_z is None


def test_writes_mcap_and_report_like_calibrate(scene, tmp_path):
    """The log holds every used view with its flange pose, and the TF chain through the fitted
    camera puts the board where each view saw it, as close as the residuals say."""
    from factory.mcaplog import read_messages
    from tests.mcapcheck import check_rosbag2_mcap

    out, mcap, png = tmp_path / "handeye.yaml", tmp_path / "handeye.mcap", tmp_path / "handeye.png"
    r = run(*args(scene, "poses.yaml", out, "--mcap", mcap, "--report", png, "--quiet"))
    assert r.exit_code == 0, r.output
    image = cv2.imread(str(png))
    assert image is not None and image.shape[1] > 1000
    counts = check_rosbag2_mcap(mcap)
    assert counts == {"/tf_static": 1, "/handeye/board": 1, "/tf": 12, "/camera/image_raw/compressed": 12,
                      "/camera/corners": 12, "/camera/camera_info": 12}

    def matrix(tf) -> np.ndarray:
        t = np.eye(4)
        q, p = tf.transform.rotation, tf.transform.translation
        t[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
        t[:3, 3] = [p.x, p.y, p.z]
        return t

    edges = {}
    for topic, stamp, msg in read_messages(mcap, ["/tf_static", "/tf"]):
        for tf in msg.transforms:
            edges.setdefault((tf.header.frame_id, tf.child_frame_id), []).append(matrix(tf))
    (flange_cam,) = edges["flange", "camera"]
    (base_board,) = edges["base", "board"]
    doc = yaml.safe_load(out.read_text())
    np.testing.assert_allclose(flange_cam, doc["transform"]["matrix"], atol=1e-9)
    for base_flange, cam_seen in zip(edges["base", "flange"], edges["camera", "board_seen"], strict=True):
        seen = base_flange @ flange_cam @ cam_seen
        assert np.linalg.norm(seen[:3, 3] - base_board[:3, 3]) < 3 * doc["residuals"]["translation_rms_m"] + 1e-4


def test_bad_inputs_are_one_line_errors(scene, tmp_path):
    out = tmp_path / "out.yaml"
    bad_cam = tmp_path / "notcam.yaml"
    bad_cam.write_text("hello: world\n")
    r = run(*args(scene, "poses.yaml", out)[:2], "--camera", bad_cam, "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "notcam.yaml", "image_width")
    r = run(*args(scene, "poses.yaml", out)[:2], "--camera", tmp_path / "nope.yaml", "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "nope.yaml", "cannot read camera file")
    extra = tmp_path / "extra.yaml"
    extra.write_text(yaml.safe_dump({"poses": {"ghost.png": {"xyz": [0, 0, 0], "rotvec": [0, 0, 0]}}}))
    r = run(extra, scene["images"], "--camera", scene["camera"], "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "extra.yaml", "ghost.png")
    header = tmp_path / "p.csv"
    header.write_text("name,x,y,z\nview00.png,0,0,0\n")
    r = run(header, scene["images"], "--camera", scene["camera"], "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "p.csv", "header")
    both = tmp_path / "both.yaml"
    both.write_text(yaml.safe_dump({"poses": {"view00.png": {"xyz": [0, 0, 0], "rotvec": [0, 0, 0],
                                                             "quat": [0, 0, 0, 1]}}}))
    r = run(both, scene["images"], "--camera", scene["camera"], "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "both.yaml", "exactly one of rotvec or quat")
    few = tmp_path / "few.yaml"
    doc = yaml.safe_load((scene["dir"] / "poses.yaml").read_text())
    few.write_text(yaml.safe_dump({"poses": dict(list(doc["poses"].items())[:2])}))
    r = run(few, scene["images"], "--camera", scene["camera"], "--board", str(BOARD), "-o", out)
    assert_one_line_error(r, "only 2", "at least 3")
    assert not out.exists()


def test_eye_to_hand_from_csv_rotation_vectors(tmp_path):
    """A fixed camera, the board on the flange: 10 rendered views, CSV poses with rotation vectors."""
    from tests.vision.test_handeye import FLANGE_BOARD, TRUE_BASE_CAM

    rng = np.random.default_rng(21)
    images = tmp_path / "views"
    images.mkdir()
    rays = pixel_rays(TRUE_CAMERA, 2)
    texture = BOARD.texture(32)
    centre = BOARD.object_points.mean(axis=0)
    rows = ["image,x,y,z,rx,ry,rz"]
    for i in range(10):
        r = Rotation.from_rotvec(np.r_[rng.uniform(-0.6, 0.6, 2), rng.uniform(-np.pi, np.pi)]).as_matrix()
        cam_board = np.eye(4)
        cam_board[:3, :3] = r
        cam_board[:3, 3] = np.r_[rng.uniform(-0.04, 0.04, 2), rng.uniform(0.45, 0.6)] - r @ centre
        cv2.imwrite(str(images / f"v{i}.png"), render(rays, cam_board, texture, noise_sigma=1.5, seed=i))
        flange = jitter(TRUE_BASE_CAM @ cam_board @ invert(FLANGE_BOARD), rng, 0.2, 0.05)
        rv = Rotation.from_matrix(flange[:3, :3]).as_rotvec()
        rows.append(",".join([f"v{i}.png", *(repr(float(v)) for v in (*flange[:3, 3], *rv))]))
    (tmp_path / "poses.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "camera.yaml").write_text(TRUE_CAMERA.to_camera_info_yaml())
    out = tmp_path / "he.yaml"
    r = run(tmp_path / "poses.csv", images, "--camera", tmp_path / "camera.yaml", "--board", str(BOARD), "-o", out,
            "--mode", "eye-to-hand", "--quiet")
    assert r.exit_code == 0, r.output
    doc = yaml.safe_load(out.read_text())
    assert doc["transform"]["parent_frame"] == "base" and doc["board"]["parent_frame"] == "flange"
    t = np.array(doc["transform"]["matrix"])
    assert np.linalg.norm(t[:3, 3] - TRUE_BASE_CAM[:3, 3]) < 1e-3
    assert np.degrees(rotation_angle(t, TRUE_BASE_CAM)) < 0.1
    np.testing.assert_allclose(read_extrinsics(out.read_text()).base_camera(), t)
