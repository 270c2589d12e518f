"""``factory locate`` on a rendered tray picture, with an eye-to-hand extrinsics file."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from cli.main import app
from tests.vision import TRUE_CAMERA
from tests.vision.test_locate import BASE_CAM, BLANK_MM, TRAY_Z, blank_mesh, random_layout, yaw_error
from vision.handeye import handeye_document, invert
from vision.locate import mm_to_m
from vision.render import render_boxes
from tests.cli.expect import assert_one_line_error

runner = CliRunner()


def run(*args):
    return runner.invoke(app, ["locate", *[str(a) for a in args]], catch_exceptions=False)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("locate")
    rng = np.random.default_rng(11)
    boxes = random_layout(rng, 2, mm_to_m(np.array(BLANK_MM)))
    cv2.imwrite(str(d / "tray.png"), render_boxes(TRUE_CAMERA, invert(BASE_CAM), boxes, plane_z=TRAY_Z,
                                                  supersample=2, noise_sigma=2.0, seed=3))
    cv2.imwrite(str(d / "empty.png"), render_boxes(TRUE_CAMERA, invert(BASE_CAM), [], plane_z=TRAY_Z,
                                                   supersample=1, noise_sigma=2.0, seed=4))
    (d / "camera.yaml").write_text(TRUE_CAMERA.to_camera_info_yaml())
    doc = {"format": "factory.handeye/1", "mode": "eye-to-hand",
           "transform": {"matrix": BASE_CAM.tolist()}, "tray_z": TRAY_Z}
    (d / "handeye.yaml").write_text(yaml.safe_dump(doc))
    blank_mesh().export(d / "blank.stl")
    return {"dir": d, "boxes": boxes}


def common(scene, image: str = "tray.png") -> list:
    d: Path = scene["dir"]
    return [d / image, "--camera", d / "camera.yaml", "--extrinsics", d / "handeye.yaml", "--part", d / "blank.stl"]


def test_locates_blanks_in_the_base_frame(scene):
    r = run(*common(scene), "--json")
    assert r.exit_code == 0, r.output
    parts = json.loads(r.stdout)
    assert len(parts) == 2
    for box in scene["boxes"]:
        p = min(parts, key=lambda p: np.hypot(p["x"] - box.x, p["y"] - box.y))
        assert np.hypot(p["x"] - box.x, p["y"] - box.y) < 1e-3
        assert np.degrees(yaw_error(p["yaw"], box.yaw, np.pi)) < 0.5
        assert p["z"] == TRAY_Z and 0 < p["expected_error_mm"] < 1 and 0 < p["score"] <= 1
    assert "mm/px" in r.stderr
    # --tray-z overrides the file: 2 mm off still fits (answers on that plane), 30 mm off does not.
    r2 = run(*common(scene), "--json", "--tray-z", str(TRAY_Z + 0.002), "--quiet")
    assert r2.exit_code == 0, r2.output
    assert all(p["z"] == pytest.approx(TRAY_Z + 0.002) for p in json.loads(r2.stdout))
    assert_one_line_error(run(*common(scene), "--json", "--tray-z", str(TRAY_Z + 0.03)), "tray height")


def test_bad_input(scene, tmp_path):
    d: Path = scene["dir"]
    assert_one_line_error(run(*common(scene, "empty.png"), "--json"), "empty.png", "no part found")
    assert_one_line_error(run(*common(scene, "missing.png"), "--json"), "missing.png", "cannot read image")
    not_cam = tmp_path / "cam.yaml"
    not_cam.write_text("[1, 2, 3]\n")
    args = common(scene)
    args[2] = not_cam
    assert_one_line_error(run(*args, "--json"), "cam.yaml", "camera_info")
    args = common(scene)
    args[4] = d / "camera.yaml"  # a camera file where the hand-eye file belongs
    assert_one_line_error(run(*args, "--json"), "camera.yaml", "not a hand-eye file")
    no_tray = tmp_path / "he.yaml"
    no_tray.write_text(yaml.safe_dump({"format": "factory.handeye/1", "mode": "eye-in-hand",
                                       "transform": {"matrix": np.eye(4).tolist()}}))
    args = common(scene)
    args[4] = no_tray
    assert_one_line_error(run(*args, "--json"), "he.yaml", "--tray-z")
    assert_one_line_error(run(*args, "--json", "--tray-z", "0.05"), "he.yaml", "--flange")
    args = common(scene)
    args[6] = tmp_path / "nope.stl"
    assert_one_line_error(run(*args, "--json"), "nope.stl")


def test_reads_a_handeye_document():
    """The file `factory handeye` writes is what locate reads (plus an optional tray_z)."""
    from vision.handeye import HandEyeResult, read_extrinsics

    res = HandEyeResult("eye-to-hand", BASE_CAM, np.eye(4), BASE_CAM, np.zeros(3), np.zeros(3), 0.5)
    doc = handeye_document(res, ["a", "b", "c"], [0.1, 0.1, 0.1])
    back = read_extrinsics(yaml.safe_dump(doc, sort_keys=False))
    np.testing.assert_allclose(back.base_camera(), BASE_CAM)


def test_eye_in_hand_needs_and_uses_the_flange_pose(scene, tmp_path):
    """A wrist camera: T_base_cam = T_base_flange (--flange) @ T_flange_cam (the file)."""
    from scipy.spatial.transform import Rotation

    from tests.vision.test_handeye import TRUE_FLANGE_CAM

    flange = BASE_CAM @ invert(TRUE_FLANGE_CAM)
    he = tmp_path / "wrist.yaml"
    he.write_text(yaml.safe_dump({"format": "factory.handeye/1", "mode": "eye-in-hand",
                                  "transform": {"matrix": TRUE_FLANGE_CAM.tolist()}, "tray_z": TRAY_Z}))
    args = common(scene)
    args[4] = he
    text = ",".join(repr(float(v)) for v in (*flange[:3, 3], *Rotation.from_matrix(flange[:3, :3]).as_rotvec()))
    r = run(*args, "--flange", text, "--json", "--quiet")
    assert r.exit_code == 0, r.output
    parts = json.loads(r.stdout)
    for box in scene["boxes"]:
        assert min(np.hypot(p["x"] - box.x, p["y"] - box.y) for p in parts) < 1e-3
    r = run(*args, "--flange", "1,2,3")
    assert r.exit_code == 2 and "--flange" in r.stderr
