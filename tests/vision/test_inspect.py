"""Inspection on exactly rendered trays: a good blank passes, a notched one fails where it is notched.

The ``factory inspect`` command is driven here too (this file is the inspect feature's test file).
"""

from __future__ import annotations

import json
import cv2
import numpy as np
import pytest
import trimesh
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cli.main import app
from tests.conftest import SAMPLES
from tests.vision import TRUE_CAMERA
from tests.vision.test_locate import BASE_CAM, TRAY_Z, blank_mesh
from vision.handeye import invert
from vision.inspect import (InspectOptions, _line_level, _one_polarity, _profile_shift, _windowed, inspect_part,
                            inspection_image, part_transform)
from vision.locate import LocatedPart, footprint_from_mesh, mm_to_m
from vision.mesh_edges import MeshEdges
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
    assert good.passed and good.max_deviation < 0.5e-3 and not good.missing_features
    assert not bad.passed
    # The notch is 20 mm deep: material is missing, by most of that, near the notched corner.
    summary = bad.to_dict()
    assert 12 < summary["missing_mm"] < 22 and summary["excess_mm"] < 2
    # Locate's robust fit keeps the pose of the notched blank on its true footprint.
    assert np.hypot(bad.part.x - NOTCH_AT[0], bad.part.y - NOTCH_AT[1]) < 2e-3
    worst = bad.outline_px[np.nanargmin(bad.deviation)]
    corner = TRUE_CAMERA.project(np.array([[*(np.array(NOTCH_AT[:2]) + np.array(
        [[np.cos(NOTCH_AT[2]), -np.sin(NOTCH_AT[2])], [np.sin(NOTCH_AT[2]), np.cos(NOTCH_AT[2])]])
        @ np.array([0.02, 0.005])), TRAY_Z + 0.02]]) @ invert(BASE_CAM)[:3, :3].T + invert(BASE_CAM)[:3, 3],
        np.zeros(3), np.zeros(3))[0]
    assert np.hypot(*(worst - corner)) < 40  # the worst point is in the notch (20 mm, about 40 px) [px]
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
    # Each verdict says how narrow a burr the picture resolves: a pixel and a half at the part, at least.
    for p in json.loads(r.stdout):
        assert p["smallest_burr_mm"] >= max(1.5 * p["pose"]["mm_per_px"], p["tolerance_mm"]) - 1e-9
    assert r.stderr.count("is not resolved") == 2
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


def test_a_stepped_part_passes_and_its_broken_corner_fails(stepped):
    """Stepped tops at their real heights: the good wall passes (located by its mesh's edges), the
    one with a corner broken off fails by material missing, none extra."""
    mesh, part, image = stepped[False]
    args = (image, TRUE_CAMERA, BASE_CAM, part, mesh.vertices, mesh.faces, TRAY_Z)
    (good,) = inspect_part(*args)
    assert good.passed and good.max_deviation < 0.5e-3 and not good.missing_features
    assert np.hypot(good.part.x - STEPPED_AT[0], good.part.y - STEPPED_AT[1]) < good.part.sigma_xy
    assert abs(np.angle(np.exp(1j * (good.part.yaw - STEPPED_AT[2])))) < np.radians(0.3)  # not turned 180 deg
    (broken,) = inspect_part(stepped[True][2], *args[1:])
    summary = broken.to_dict()
    assert not broken.passed and summary["missing_mm"] > 4 and summary["excess_mm"] < 0.6


@settings(max_examples=30, deadline=None)
@given(level=st.floats(-3.0, 3.0), tilt=st.floats(-0.02, 0.02), step=st.floats(2.5, 4.0), start=st.integers(0, 80),
       length=st.integers(12, 20), gaps=st.lists(st.integers(0, 99), max_size=10))
def test_a_stretch_off_its_line_stands_out_and_the_line_own_level_does_not(level, tilt, step, start, length, gaps):
    """Samples 1 mm apart along one straight side, off by ``level`` + ``tilt`` per sample [px] (the
    pose's shift and yaw) but a stretch of ``length`` mm off by ``step`` more (a burr): against the
    side's own level the stretch's middle reads ``step``, the rest 0, and unseen samples change neither."""
    points = np.column_stack([np.arange(100) * 1e-3, np.full(100, 0.02), np.full(100, 0.01)])
    direction = np.tile([1.0, 0.0, 0.0], (100, 1))
    values = level + tilt * np.arange(100)
    values[start:start + length] += step
    values[gaps] = np.nan
    got = _windowed(points, values - _line_level(points, direction, values), 8e-3)
    middle = start + length // 2
    if np.isfinite(got[middle]):
        assert got[middle] == pytest.approx(step, abs=1e-6)
    far = [i for i in range(100) if (i < start - 5 or i > start + length + 5) and np.isfinite(got[i])]
    assert np.allclose(got[far], 0.0, atol=1e-6)


def test_a_window_by_a_corner_runs_along_its_own_side():
    """Two sides at a corner: one judged all along at 0, the other hidden (a lit wall clipped white)
    but for its three samples by the corner, which read 1.8 px (its wall's foot). Counted with the
    judged side round the corner those three made a window's median; along their own side they are
    too few to tell; their own side's count decides. Away from the corner the judged side still
    reads its own 0."""
    a = np.column_stack([np.arange(30) * 1e-3, np.zeros(30), np.full(30, 0.01)])
    b = np.column_stack([np.full(30, 0.0), -np.arange(1, 31) * 1e-3, np.full(30, 0.01)])
    points = np.vstack([a, b])
    direction = np.vstack([np.tile([1.0, 0.0, 0.0], (30, 1)), np.tile([0.0, -1.0, 0.0], (30, 1))])
    values = np.r_[np.zeros(30), np.full(30, np.nan)]
    values[30:33] = 1.8
    assert np.isfinite(_windowed(points, values, 8e-3)[31])  # the old window, round the corner
    got = _windowed(points, values, 8e-3, direction)
    assert np.isnan(got[30:33]).all()
    assert np.allclose(got[:30][np.isfinite(got[:30])], 0.0) and np.isfinite(got[5:30]).all()


def test_a_long_side_with_no_edge_at_its_place_takes_the_pose_level_not_a_neighbour():
    """Two sides at a corner: one shows its edges (level 0.3 px), the other none within reach (its
    yaw a little off). The unseen long side takes the level the pose gives it, not its neighbour's;
    without a pose level it keeps the neighbour's near the corner and 0 beyond."""
    a = np.column_stack([np.arange(30) * 1e-3, np.zeros(30), np.full(30, 0.01)])
    b = np.column_stack([np.full(30, 0.03), np.arange(1, 31) * 1e-3, np.full(30, 0.01)])
    points = np.vstack([a, b])
    direction = np.vstack([np.tile([1.0, 0.0, 0.0], (30, 1)), np.tile([0.0, 1.0, 0.0], (30, 1))])
    values = np.r_[np.full(30, 0.3), np.full(30, np.nan)]
    calls = []

    def rigid(level, fitted):
        calls.append(fitted.copy())
        return np.where(fitted, level, -1.4)

    got = _line_level(points, direction, values, rigid=rigid)
    assert np.allclose(got[:30], 0.3) and np.allclose(got[30:], -1.4)
    assert calls and calls[0][:30].all() and not calls[0][30:].any()
    plain = _line_level(points, direction, values)
    assert np.allclose(plain[30:34], 0.3) and np.allclose(plain[40:], 0.0)


def _square_sides(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The four sides of a 40 mm square, ``n`` samples each: points [m] and unit directions (4 n, 3)."""
    t = (np.arange(n) + 0.5) / n * 0.04
    zero, full = np.zeros(n), np.full(n, 0.04)
    points = np.vstack([np.column_stack(c + (np.full(n, 0.01),)) for c in ((t, zero), (full, t), (t, full), (zero, t))])
    direction = np.vstack([np.tile(d, (n, 1)) for d in ([1.0, 0, 0], [0, 1.0, 0], [1.0, 0, 0], [0, 1.0, 0])])
    return points, direction


@settings(max_examples=60, deadline=None)
@given(n=st.integers(12, 40), crease=st.floats(1.8, 2.5), cover=st.floats(0.55, 1.0), rest=st.sampled_from(["hidden", "seen"]),
       push=st.floats(-0.6, 0.6), seed=st.integers(0, 2**16))
def test_a_lip_along_most_of_a_side_does_not_set_its_level(n, crease, cover, rest, push, seed):
    """A lip along most of one side of a square (``cover`` of it) shows its inner crease ``crease`` px out,
    within the own window; the rest of that side is hidden (a lit wall clipped white beside it) or shows
    its edge at the side's place. The other three sides show theirs at ``push`` px (the pose's error, a
    blur). The side's level is the rest of the part's, not the crease's: a lip fitted as the side read
    0 mm (seeds 0-1 5 MP low-angle plate_bosses 1, held-out stepped_wall 8). A side all of whose edges
    lie at its wall's foot (a narrow wall turned to the camera, as wide as the crease's offset) keeps its
    level. ``rigid`` stands for vision.inspect._pose_level: a push common to the sides given, None for
    fewer than three."""
    points, direction = _square_sides(n)
    rng = np.random.default_rng(seed)
    values = push + rng.normal(0.0, 0.1, 4 * n)
    lip = np.arange(n) < round(cover * n)
    values[2 * n:3 * n] = np.where(lip, push + crease + rng.normal(0.0, 0.1, n), np.nan if rest == "hidden" else push)
    side = np.repeat(np.arange(4), n)

    def rigid(level, fitted):
        if len(np.unique(side[fitted])) < 3:
            return None
        return np.full(len(level), np.median(level[fitted]))

    got = _line_level(points, direction, values, rigid=rigid)
    assert np.allclose(got[2 * n:3 * n], push, atol=0.35), got[2 * n:3 * n]
    # Sides that show their own edges keep their own levels.
    assert np.allclose(got[:2 * n], push, atol=0.35) and np.allclose(got[3 * n:], push, atol=0.35)
    foot = np.zeros(4 * n)
    foot[2 * n:3 * n] = crease
    at_foot = np.where(side == 2, push + crease + rng.normal(0.0, 0.1, 4 * n), values)
    kept = _line_level(points, direction, at_foot, rigid=rigid, foot=foot)
    assert np.allclose(kept[2 * n:3 * n], push + crease, atol=0.35), kept[2 * n:3 * n]


def test_one_polarity_along_a_side_where_a_narrow_band_two_edges_alternate():
    """A narrow lit wall: every sample of a side has a rising and a falling edge within reach, the
    stronger one alternating with the noise. All take the side's stronger polarity on average; a
    sample with one edge only keeps it, and another side chooses for itself."""
    near = np.full((6, 5), -np.inf)
    rising = np.zeros((6, 5), bool)
    rising[:, 1] = True
    near[:4, 1] = [10.0, 9.0, 10.0, 9.0]  # rising, column 1
    near[:4, 3] = [9.0, 9.5, 9.0, 9.5]    # falling, column 3: stronger in samples 1 and 3, weaker on average
    near[4, 3] = 7.0                       # one falling edge only
    near[5, 1], near[5, 3] = 1.0, 2.0      # another side, both: falling stronger
    line = np.array([0, 0, 0, 0, 0, 1])
    assert _one_polarity(near, rising, line).tolist() == [1, 1, 1, 1, 3, 3]


def test_a_stretch_of_profile_shifted_outward_reads_its_shift_whatever_the_contrast():
    """A straight dark-to-bright edge whose contrast halves along it (a shadow on the tray), with a
    stretch 1.2 px further out (a burr): the profile shift reads 1.2 px there and 0 elsewhere."""
    h, w = 60, 200
    x = np.arange(w, dtype=float)
    edge = np.full(w, 30.0)
    edge[80:100] -= 1.2
    contrast = np.linspace(120.0, 60.0, w)
    yy = np.arange(h, dtype=float)[:, None]
    soft = 1.0 / (1.0 + np.exp(-(yy - edge[None, :]) / 0.6))  # the part (bright) below row 30
    grey = (60.0 + contrast[None, :] * soft).astype(np.float32)
    u = np.arange(10, 190, 1.0)
    uv = np.column_stack([u, np.full(len(u), 30.0)])
    outward = np.tile([0.0, -1.0], (len(u), 1))
    along = u * 8e-4
    shift = _profile_shift(grey, uv, outward, np.zeros(len(u), int), along, 4.0, 8e-3)
    burr = (u >= 84) & (u <= 95)
    assert np.allclose(shift[burr], 1.2, atol=0.15)
    assert np.allclose(shift[(u < 70) | (u > 110)], 0.0, atol=0.1)


def test_a_burr_along_most_of_a_short_side_stands_out_from_a_trend_started_at_zero():
    """Shifts against the rest of their side: a 25 mm side whose middle 15 mm reads +1 px (a
    burr), the rest about 0. Started flat at the median, the side's level is the burr's and hides
    it; started at 0, the burr reads 1 px."""
    points = np.column_stack([np.arange(25) * 1e-3, np.zeros(25), np.full(25, 0.01)])
    direction = np.tile([1.0, 0.0, 0.0], (25, 1))
    values = np.where((np.arange(25) >= 5) & (np.arange(25) < 20), 1.0, 0.0) + 0.05 * np.sin(np.arange(25))
    hidden = _windowed(points, values - _line_level(points, direction, values, band=0.5), 8e-3)
    shown = _windowed(points, values - _line_level(points, direction, values, band=0.5, start=0.0), 8e-3)
    assert abs(hidden[12]) < 0.2 and shown[12] == pytest.approx(1.0, abs=0.1)


@settings(max_examples=15, deadline=None)
@given(st.floats(4.0, 12.0), st.floats(3.0, 15.0), st.floats(-8.0, 8.0), st.floats(2.0, 5.0), st.floats(6.0, 20.0))
def test_the_feet_are_the_concave_creases_of_a_face_turned_up(radius, height, at, hole, plate):
    """A plate with a boss and a through-hole: the crease samples ``MeshEdges.foot`` takes for feet are those
    trimesh calls concave (its own test, not the height field) between a face turned up and a wall:
    the boss's foot; never its top's rim, the hole's rims or the plate's outline."""
    boss = trimesh.creation.cylinder(radius=radius, height=height + 1.0, sections=48)
    boss.apply_translation((at - 15.0, 0.0, plate + height / 2 - 0.5))
    drill = trimesh.creation.cylinder(radius=hole, height=plate + 2.0, sections=32)
    drill.apply_translation((18.0, 5.0, plate / 2))
    body = trimesh.creation.box((80.0, 50.0, plate))
    body.apply_translation((0.0, 0.0, plate / 2))
    mesh = trimesh.boolean.difference([trimesh.boolean.union([body, boss], engine="manifold"), drill],
                                      engine="manifold")
    model = MeshEdges(footprint_from_mesh(mesh.vertices, mesh.faces), TRUE_CAMERA, BASE_CAM, TRAY_Z)
    idx = np.flatnonzero(model.crease)
    feet = model.foot[idx]
    # The same mesh as the model's, its edges kept alike: trimesh's convexity of each sample's edge.
    same = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)
    convex = same.face_adjacency_convex[same.face_adjacency_angles > np.radians(1.0)][model.edge[idx]]
    n1, n2 = model.n1[idx], model.n2[idx]
    up_and_wall = ((n1[:, 2] > 0.5) & (np.abs(n2[:, 2]) < 0.5)) | ((n2[:, 2] > 0.5) & (np.abs(n1[:, 2]) < 0.5))
    assert (feet == (up_and_wall & ~convex)).all()
    # The boss's foot, all round: at the plate's top [m], within its radius of its axis.
    z = model.points[idx, 2]
    foot = np.isclose(z, plate * 1e-3, atol=1e-5) & \
        (np.hypot(*(model.points[idx, :2] - model.points[idx, :2][feet].mean(axis=0)).T) < radius * 1e-3 + 1e-4)
    assert feet.sum() > 0 and (feet == foot).all()
