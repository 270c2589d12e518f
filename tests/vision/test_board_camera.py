"""Board specs and the ROS camera_info YAML file."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import CalibrationError, VisionError
from vision.board import BoardSpec
from vision.camera import CameraModel

ROS_KEYS = ["image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
            "distortion_coefficients", "rectification_matrix", "projection_matrix"]


def test_parse_chessboard_and_charuco():
    b = BoardSpec.parse("chessboard:9x6:0.025")
    assert (b.kind, b.cols, b.rows, b.square) == ("chessboard", 9, 6, 0.025)
    assert b.object_points.shape == (54, 3)
    # Row-major, x fastest, z = 0 [m]: the order findChessboardCorners reports.
    np.testing.assert_allclose(b.object_points[1], [0.025, 0, 0])
    np.testing.assert_allclose(b.object_points[9], [0, 0.025, 0])
    c = BoardSpec.parse("charuco:5x7:0.04:0.02:DICT_6X6_250")
    assert c.corner_count == 24 and c.object_points.shape == (24, 3)
    assert BoardSpec.parse(str(c)) == c and BoardSpec.parse(str(b)) == b


@pytest.mark.parametrize("text", [
    "chessboard:9x6", "chessboard:9by6:0.025", "chessboard:9x6:-1", "chessboard:1x6:0.02",
    "charuco:5x7:0.04:0.05:DICT_6X6_250", "charuco:5x7:0.04:0.02:DICT_NOPE", "circles:4x11:0.02", "",
    "chessboard:9x6:nan",
])
def test_malformed_board_is_an_error_naming_the_option(text):
    with pytest.raises(CalibrationError) as e:
        BoardSpec.parse(text)
    assert e.value.source == "--board"


@given(cols=st.integers(2, 30), rows=st.integers(2, 30), square=st.floats(1e-4, 1.0))
@settings(max_examples=50, deadline=None)
def test_board_text_round_trips(cols, rows, square):
    b = BoardSpec("chessboard", cols, rows, square)
    back = BoardSpec.parse(str(b))
    assert (back.cols, back.rows) == (cols, rows)
    assert back.square == pytest.approx(square, rel=1e-5)


def test_texture_places_inner_corners_on_square_edges():
    b = BoardSpec.parse("chessboard:4x3:0.02")
    tex = b.texture(10)
    ox, oy = tex.origin
    # Around the first inner corner the four squares alternate black and white.
    quad = tex.image[oy - 5, ox - 5], tex.image[oy - 5, ox + 4], tex.image[oy + 4, ox - 5], tex.image[oy + 4, ox + 4]
    assert quad[0] == quad[3] and quad[1] == quad[2] and quad[0] != quad[1]
    assert tex.pixel_size == pytest.approx(0.002)


def camera(model="plumb_bob") -> CameraModel:
    dist = [-0.2, 0.08, 0.001, -0.0005, -0.02] + ([0.01, -0.002, 0.0005] if model != "plumb_bob" else [])
    return CameraModel(K=[[600.5, 0, 322.25], [0, 605.125, 238.0], [0, 0, 1]], dist=dist, model=model,
                       image_size=(640, 480), name="cell cam: left")


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_camera_info_yaml_round_trips_with_ros_keys(model):
    cam = camera(model)
    text = cam.to_camera_info_yaml()
    doc = yaml.safe_load(text)
    assert list(doc) == ROS_KEYS
    assert doc["camera_matrix"]["rows"] == 3 and doc["camera_matrix"]["cols"] == 3
    assert doc["distortion_coefficients"]["cols"] == len(cam.dist) and doc["distortion_coefficients"]["rows"] == 1
    assert len(doc["projection_matrix"]["data"]) == 12
    back = CameraModel.from_camera_info_yaml(text)
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.dist, cam.dist)
    np.testing.assert_array_equal(back.P, cam.P)
    assert (back.model, back.image_size, back.name) == (cam.model, cam.image_size, cam.name)


def _break(doc: dict, key: str, value) -> str:
    doc = dict(doc)
    if value is KeyError:
        del doc[key]
    else:
        doc[key] = value
    return yaml.safe_dump(doc)


@pytest.mark.parametrize("key, value", [
    ("camera_matrix", KeyError),
    ("image_width", -3),
    ("image_height", "tall"),
    ("camera_matrix", {"rows": 3, "cols": 3, "data": [1, 2, 3]}),
    ("camera_matrix", {"rows": 2, "cols": 3, "data": [1, 0, 0, 0, 1, 0]}),
    ("distortion_model", "fisheye_magic"),
    ("distortion_coefficients", {"rows": 1, "cols": 3, "data": [0, 0, 0]}),
    ("rectification_matrix", {"rows": 3, "cols": 3, "data": [2, 0, 0, 0, 1, 0, 0, 0, 1]}),
    ("projection_matrix", {"rows": 3, "cols": 4, "data": ["a"] * 12}),
])
def test_reader_names_file_and_field(key, value):
    doc = yaml.safe_load(camera().to_camera_info_yaml())
    with pytest.raises(VisionError) as e:
        CameraModel.from_camera_info_yaml(_break(doc, key, value), source="cam.yaml")
    assert e.value.source == "cam.yaml"
    assert key in e.value.message


def test_reader_rejects_non_yaml_and_missing_file(tmp_path):
    with pytest.raises(VisionError, match="not valid YAML|mapping"):
        CameraModel.from_camera_info_yaml("a: [1, 2", source="x.yaml")
    with pytest.raises(VisionError) as e:
        CameraModel.read(tmp_path / "none.yaml")
    assert e.value.source == str(tmp_path / "none.yaml")


def test_rays_invert_projection():
    cam = camera()
    rng = np.random.default_rng(0)
    pix = rng.uniform([0, 0], [640, 480], (200, 2))
    rays = cam.rays(pix)
    back = cam.project(rays, np.zeros(3), np.zeros(3))
    np.testing.assert_allclose(back, pix, atol=1e-6)
