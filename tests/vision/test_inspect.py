"""Silhouette inspection on rendered trays: a good blank passes, a notched one fails where it is notched.

The ``factory inspect`` command is driven here too (this file is the inspect feature's test file).
"""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cli.main import app
from tests.conftest import SAMPLES
from tests.vision import TRUE_CAMERA
from tests.vision.test_locate import BASE_CAM, TRAY_Z, blank_mesh
from vision.handeye import invert
from vision.inspect import InspectOptions, inspect_part, inspection_image, part_transform, refine_pose
from vision.locate import LocatedPart, LocateOptions, footprint_from_mesh, locate_parts, mm_to_m
from vision.render import Box, pixel_rays, render_boxes, render_mesh
from vision.station import cut_corner

GOOD = Box(0.47, 0.03, 0.4, (0.08, 0.05, 0.02))
NOTCH_AT = (0.58, 0.1, -0.6)


def notched_blank(x: float, y: float, yaw: float) -> list[Box]:
    """The 80x50x20 mm blank with a 20x20 mm notch at its +x +y corner, as two boxes."""
    r = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    a = np.array([x, y]) + r @ np.array([-0.01, 0.0])
    b = np.array([x, y]) + r @ np.array([0.03, -0.01])
    return [Box(a[0], a[1], yaw, (0.06, 0.05, 0.02)), Box(b[0], b[1], yaw, (0.02, 0.03, 0.02))]


@pytest.fixture(scope="module")
def tray() -> np.ndarray:
    return render_boxes(pixel_rays(TRUE_CAMERA, 2), invert(BASE_CAM), [GOOD, *notched_blank(*NOTCH_AT)],
                        plane_z=TRAY_Z, noise_sigma=2.0, seed=0)


def test_good_blank_passes_and_notched_blank_fails(tray):
    m = blank_mesh()
    part = footprint_from_mesh(m.vertices, m.faces)
    results = inspect_part(tray, TRUE_CAMERA, BASE_CAM, part, m.vertices, m.faces, TRAY_Z, InspectOptions(1e-3))
    assert len(results) == 2
    good = min(results, key=lambda r: np.hypot(r.part.x - GOOD.x, r.part.y - GOOD.y))
    bad = next(r for r in results if r is not good)
    assert good.passed and good.max_deviation < 0.8e-3
    assert not bad.passed
    # The notch is 20 mm deep: material is missing, by most of that, near the notched corner.
    summary = bad.to_dict()
    assert 12 < summary["missing_mm"] < 22 and summary["excess_mm"] < 2
    # The robust fit keeps the pose of the notched blank on its true footprint.
    assert np.hypot(bad.part.x - NOTCH_AT[0], bad.part.y - NOTCH_AT[1]) < 2e-3
    worst = bad.part.outline[np.argmin(bad.deviation)]
    corner = TRUE_CAMERA.project(np.array([[*(np.array(NOTCH_AT[:2]) + np.array(
        [[np.cos(NOTCH_AT[2]), -np.sin(NOTCH_AT[2])], [np.sin(NOTCH_AT[2]), np.cos(NOTCH_AT[2])]])
        @ np.array([0.02, 0.005])), TRAY_Z + 0.02]]) @ invert(BASE_CAM)[:3, :3].T + invert(BASE_CAM)[:3, 3],
        np.zeros(3), np.zeros(3))[0]
    assert np.hypot(*(worst - corner)) < 25  # the worst point is in the notch [px]
    picture = inspection_image(tray, results)
    red = (picture[..., 2] > 200) & (picture[..., 1] < 80) & (picture[..., 0] < 80)
    assert picture.shape == (*tray.shape, 3) and red.sum() > 20


def test_inspect_command(tray, tmp_path):
    cv2.imwrite(str(tmp_path / "tray.png"), tray)
    (tmp_path / "camera.yaml").write_text(TRUE_CAMERA.to_camera_info_yaml())
    (tmp_path / "he.yaml").write_text(yaml.safe_dump({"format": "factory.handeye/1", "mode": "eye-to-hand",
                                                      "transform": {"matrix": BASE_CAM.tolist()}}))
    blank_mesh().export(tmp_path / "blank.stl")
    args = ["inspect", str(tmp_path / "tray.png"), "--camera", str(tmp_path / "camera.yaml"), "--extrinsics",
            str(tmp_path / "he.yaml"), "--part", str(tmp_path / "blank.stl"), "--tray-z", str(TRAY_Z),
            "--png", str(tmp_path / "out.png"), "--json"]
    r = CliRunner().invoke(app, args, catch_exceptions=False)
    assert r.exit_code == 3, r.output  # one blank fails
    verdicts = sorted(p["pass"] for p in json.loads(r.stdout))
    assert verdicts == [False, True] and "FAIL" in r.stderr
    assert cv2.imread(str(tmp_path / "out.png")) is not None
    r = CliRunner().invoke(app, args, catch_exceptions=False)  # the picture exists now
    assert r.exit_code == 1 and "--overwrite" in r.stderr and r.stdout == ""
    r = CliRunner().invoke(app, [*args[:-3], "--tolerance", "30", "--quiet"], catch_exceptions=False)
    assert r.exit_code == 0, r.output


#: The stepped wall (three steps, 10-26 mm, and a 30 mm thin wall) where BASE_CAM sees it, 15-20 deg off vertical.
STEPPED_AT = (0.5, 0.06, 0.7)


def stepped_picture(rays, defect: bool):
    """The stepped wall sample at STEPPED_AT, whole or with a corner cut off: (mesh, footprint, picture)."""
    mesh = trimesh.load(SAMPLES / "stepped_wall.stl")
    part = footprint_from_mesh(mesh.vertices, mesh.faces)
    shown = cut_corner(mesh.vertices, mesh.faces) if defect else (mesh.vertices, mesh.faces)
    t = part_transform(part, truth_pose(*STEPPED_AT))
    world = mm_to_m(np.asarray(shown[0])) @ t[:3, :3].T + t[:3, 3]
    return mesh, part, render_mesh(rays, invert(BASE_CAM), world, shown[1], plane_z=TRAY_Z, noise_sigma=2.0, seed=4)


def truth_pose(x: float, y: float, yaw: float) -> LocatedPart:
    return LocatedPart(x=x, y=y, z=TRAY_Z, yaw=yaw, score=1.0, rms_px=0.0, mm_per_px=float("nan"),
                       sigma_xy=0.0, sigma_yaw=0.0, pixel=(float("nan"), float("nan")))


@pytest.fixture(scope="module")
def stepped(request):
    rays = pixel_rays(TRUE_CAMERA, 3)
    return {defect: stepped_picture(rays, defect) for defect in (False, True)}


def test_a_stepped_part_passes_and_the_pose_refined_to_its_silhouette_fits_closer(stepped):
    mesh, part, image = stepped[False]
    args = (image, TRUE_CAMERA, BASE_CAM, part, mesh.vertices, mesh.faces, TRAY_Z)
    # locate fits the mesh's own edges (the steps at their heights), so its pose passes unrefined;
    # the refinement to the silhouette brings it closer still.
    (prism,) = inspect_part(*args, InspectOptions(refine_rounds=0))
    assert prism.passed
    (refined,) = inspect_part(*args)
    assert refined.passed and refined.max_deviation < 0.8e-3 and refined.max_deviation <= prism.max_deviation
    assert np.hypot(refined.part.x - STEPPED_AT[0], refined.part.y - STEPPED_AT[1]) < 0.3e-3
    assert abs(np.angle(np.exp(1j * (refined.part.yaw - STEPPED_AT[2])))) < np.radians(0.3)  # not turned 180 deg
    assert refined.part.rms_px < prism.part.rms_px
    (broken,) = inspect_part(stepped[True][2], *args[1:])
    assert not broken.passed and broken.to_dict()["missing_mm"] > 4


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(dx=st.floats(-2e-3, 2e-3), dy=st.floats(-2e-3, 2e-3), dyaw=st.floats(-0.03, 0.03), defect=st.booleans())
def test_refine_pose_returns_to_the_truth_from_nearby(stepped, dx, dy, dyaw, defect):
    mesh, part, image = stepped[defect]
    # The prism misses the stepped outline by more than locate accepts by default.
    (found,) = locate_parts(image, TRUE_CAMERA, BASE_CAM, part, TRAY_Z, LocateOptions(max_rms_px=np.inf))
    x, y, yaw = STEPPED_AT
    start = replace(found, x=x + dx, y=y + dy, yaw=yaw + dyaw)
    got = refine_pose(TRUE_CAMERA, np.linalg.inv(BASE_CAM), part, start, mesh.vertices, mesh.faces)
    # A corner cut off (18 % legs, ~9 mm) must not drag the pose: the soft-L1 loss discounts it.
    assert np.hypot(got.x - x, got.y - y) < (0.5e-3 if defect else 0.2e-3)
    assert abs(np.angle(np.exp(1j * (got.yaw - yaw)))) < np.radians(0.3)
    assert refine_pose(TRUE_CAMERA, np.linalg.inv(BASE_CAM), part, start, mesh.vertices, mesh.faces, 0) is start
