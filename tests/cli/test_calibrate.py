"""``factory calibrate`` driven through typer's CliRunner on temp folders of real images."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from cli.main import app
from tests.vision import SAMPLES
from vision.camera import CameraModel
from tests.cli.expect import assert_one_line_error

runner = CliRunner()
BOARD = ["--board", "chessboard:9x6:0.025"]


def run(*args):
    return runner.invoke(app, ["calibrate", *[str(a) for a in args]], catch_exceptions=False)


def images(tmp_path: Path, names: list[str] | None = None) -> Path:
    d = tmp_path / "views"
    d.mkdir()
    for p in sorted((SAMPLES / "left").glob("*.jpg")):
        if names is None or p.name in names:
            shutil.copy(p, d / p.name)
    return d


def test_calibrate_writes_camera_report_and_mcap(tmp_path):
    from rosbags.highlevel import AnyReader

    d = images(tmp_path)
    cv2.imwrite(str(d / "zz_blank.png"), np.full((480, 640), 190, np.uint8))
    out, mcap, png = tmp_path / "camera.yaml", tmp_path / "calib.mcap", tmp_path / "report.png"
    r = run(d, *BOARD, "-o", out, "--mcap", mcap, "--report", png, "--json")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["without_board"] == ["zz_blank.png"] and len(summary["views"]) == 13
    assert "zz_blank.png" in r.stderr and "RMS" in r.stderr
    assert summary["rms_px"] == pytest.approx(0.196, abs=0.01)

    doc = yaml.safe_load(out.read_text())
    assert list(doc) == ["image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                         "distortion_coefficients", "rectification_matrix", "projection_matrix"]
    cam = CameraModel.read(out)
    assert cam.image_size == (640, 480) and cam.model == "plumb_bob"
    assert cam.fx == pytest.approx(summary["fx"]) and cam.cy == pytest.approx(summary["cy"])

    picture = cv2.imread(str(png))
    assert picture is not None and picture.shape[1] > 640

    counts: dict[str, int] = {}
    with AnyReader([mcap]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {"/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
                         "/camera/corners": "visualization_msgs/msg/ImageMarker",
                         "/camera/camera_info": "sensor_msgs/msg/CameraInfo"}
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == "/camera/camera_info":
                np.testing.assert_allclose(msg.k.reshape(3, 3), cam.K)
                assert (msg.width, msg.height, msg.distortion_model) == (640, 480, "plumb_bob")
            elif conn.topic == "/camera/corners":
                assert len(msg.points) == 54
            else:
                decoded = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
                assert decoded.shape == (480, 640) and msg.format in ("jpeg", "png")
    assert counts == {"/camera/image_raw/compressed": 14, "/camera/corners": 13, "/camera/camera_info": 14}


def test_reject_drops_no_view_of_a_clean_set_and_rational_model(tmp_path):
    d = images(tmp_path)
    out = tmp_path / "camera.yaml"
    r = run(d, *BOARD, "-o", out, "--reject", "--model", "rational_polynomial", "--json", "--quiet")
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout)
    assert summary["outliers"] == [] and not summary["rejected"]
    assert len(CameraModel.read(out).dist) == 8


def assert_no_outputs(tmp_path: Path) -> None:
    assert not list(tmp_path.glob("out.*")) and not list(tmp_path.glob(".out*"))


OUTS = ["-o", "{t}/out.yaml", "--mcap", "{t}/out.mcap", "--report", "{t}/out.png"]


def outs(tmp_path: Path) -> list[str]:
    return [a.format(t=tmp_path) for a in OUTS]


def test_empty_folder(tmp_path):
    d = tmp_path / "empty"
    d.mkdir()
    (d / "notes.txt").write_text("not an image")
    assert_one_line_error(run(d, *BOARD, *outs(tmp_path)), str(d), "no images")
    assert_no_outputs(tmp_path)


def test_unreadable_image(tmp_path):
    d = images(tmp_path, ["left01.jpg", "left02.jpg", "left03.jpg"])
    (d / "left04.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    assert_one_line_error(run(d, *BOARD, *outs(tmp_path)), "left04.jpg", "cannot read image")
    assert_no_outputs(tmp_path)


def test_wrong_board_size_is_found_in_no_view(tmp_path):
    d = images(tmp_path, ["left01.jpg", "left02.jpg", "left03.jpg"])
    r = run(d, "--board", "chessboard:10x7:0.025", *outs(tmp_path))
    assert_one_line_error(r, str(d), "found in none of 3 images", "inner corners")
    assert_no_outputs(tmp_path)


def test_too_few_views(tmp_path):
    d = images(tmp_path, ["left01.jpg", "left02.jpg"])
    cv2.imwrite(str(d / "blank.png"), np.full((480, 640), 190, np.uint8))
    assert_one_line_error(run(d, *BOARD, *outs(tmp_path)), str(d), "only 2 of 3", "at least 3")
    assert_no_outputs(tmp_path)


def test_mixed_image_sizes(tmp_path):
    d = images(tmp_path, ["left01.jpg", "left02.jpg", "left03.jpg"])
    cv2.imwrite(str(d / "small.png"), np.full((240, 320), 190, np.uint8))
    assert_one_line_error(run(d, *BOARD, *outs(tmp_path)), "small.png", "320x240")
    assert_no_outputs(tmp_path)


@pytest.mark.parametrize("board", ["chessboard:9x6", "chessboard:nine:0.02", "charuco:5x7:0.04:0.02:DICT_BAD"])
def test_malformed_board_is_a_usage_error(tmp_path, board):
    d = images(tmp_path, ["left01.jpg"])
    r = run(d, "--board", board, *outs(tmp_path))
    assert r.exit_code == 2, r.output
    assert "--board" in r.stderr and "Traceback" not in r.output
    assert_no_outputs(tmp_path)


def test_existing_output_needs_overwrite(tmp_path):
    d = images(tmp_path, ["left01.jpg", "left02.jpg", "left03.jpg", "left04.jpg"])
    out = tmp_path / "out.yaml"
    out.write_text("keep me")
    assert_one_line_error(run(d, *BOARD, "-o", out), str(out), "--overwrite")
    assert out.read_text() == "keep me"
    r = run(d, *BOARD, "-o", out, "--overwrite", "--quiet")
    assert r.exit_code == 0, r.output
    assert CameraModel.read(out).image_size == (640, 480)
