"""Wall time of the vision stages: camera calibration against bare OpenCV, locate, hand-eye.

    python benchmarks/vision.py [--reps 5] [--frames 5] [--json]

1. Calibration on OpenCV's ``left/`` sample views (9x6 inner corners, 0.025 m squares):
   factory's library path as ``factory calibrate`` runs it (read every image, ``detect``,
   ``calibrate``; no MCAP log, report picture or camera file) against a bare OpenCV script
   doing the same work (``imread``, ``findChessboardCorners``, ``cornerSubPix`` with a 5x5
   half-window as OpenCV's regression test, ``calibrateCamera``). Runs alternate, medians are
   reported with the ratio factory / bare and both RMS values. Breakdown rows say where any
   difference goes: each side's detection alone (the rest is calibration), and factory with
   the bare script's fixed 5 px window.
2. ``locate_parts`` per frame on synthetic 640x480 pictures of 3 blanks on a tray (rendered
   with :func:`vision.render.render_boxes`, as the tests do), median [ms].
3. ``calibrate_handeye`` (Park-Martin + refinement) on 15 noisy synthetic views, median [ms].

With ``--json`` the last line is one JSON object of the figures. Timings are wall time on
whatever machine this is, shared with whatever else runs: compare ratios, not absolute times.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cli.calibrate import detect_all, list_images  # noqa: E402
from vision.board import BoardSpec  # noqa: E402
from vision.calibrate import calibrate, detect  # noqa: E402
from vision.camera import CameraModel  # noqa: E402
from vision.handeye import calibrate_handeye, invert, make_transform  # noqa: E402
from vision.locate import footprint_from_mesh, locate_parts  # noqa: E402
from vision.render import Box, look_at_pose, pixel_rays, render_boxes  # noqa: E402

SAMPLES = ROOT / "tests" / "data" / "opencv-samples" / "left"
BOARD = BoardSpec.parse("chessboard:9x6:0.025")
#: cornerSubPix half-window of OpenCV's regression test [px].
BARE_WINDOW = 5
_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)  # the same as factory's

#: The tests' synthetic camera: 640x480 px, barrel distortion.
CAMERA = CameraModel(K=[[600.0, 0, 322.0], [0, 605.0, 238.0], [0, 0, 1]],
                     dist=[-0.2, 0.08, 0.001, -0.0005, -0.02], image_size=(640, 480))
TRAY_Z = 0.05
BLANK_MM = (80.0, 50.0, 20.0)
#: A camera 0.55 m above the tray looking down 15-20 deg off vertical (as tests/vision/test_locate.py).
BASE_CAM = invert(look_at_pose(np.array([0.56, -0.12, TRAY_Z + 0.55]), np.array([0.5, 0.05, TRAY_Z]),
                               up=np.array([0.0, 1.0, 0.0])))


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


# ---------------------------------------------------------------- calibration

def factory_calibration(files: list[Path], window: int | None = None):
    """``factory calibrate``'s library path: read + detect every image, then calibrate."""
    if window is None:
        detections, missing, _ = detect_all(files, BOARD, lambda done, total: None)
    else:
        detections, missing = [], []
        for path in files:
            grey = cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), cv2.IMREAD_GRAYSCALE)
            detections.append(detect(grey, BOARD, path.name, subpix_window=window))
    return calibrate(detections, "plumb_bob", without_board=missing)


def factory_detection_only(files: list[Path]):
    return detect_all(files, BOARD, lambda done, total: None)


def bare_calibration(files: list[Path], calibrate_too: bool = True):
    """The plain OpenCV script: imread, findChessboardCorners, cornerSubPix 5x5, calibrateCamera."""
    pattern = (BOARD.cols, BOARD.rows)
    obj = np.zeros((BOARD.cols * BOARD.rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:BOARD.cols, 0:BOARD.rows].T.reshape(-1, 2) * BOARD.square
    obj_pts, img_pts, size = [], [], None
    for path in files:
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        size = grey.shape[::-1]
        found, corners = cv2.findChessboardCorners(grey, pattern)
        if not found:
            continue
        corners = cv2.cornerSubPix(grey, corners, (BARE_WINDOW, BARE_WINDOW), (-1, -1), _CRITERIA)
        obj_pts.append(obj)
        img_pts.append(corners)
    if not calibrate_too:
        return img_pts
    rms, k, dist, _, _ = cv2.calibrateCamera(obj_pts, img_pts, size, None, None)
    return rms, k, dist


def bench_calibration(reps: int) -> dict:
    files = list_images(SAMPLES)
    # One warm-up of each (imports, OpenCV's lazy initialisation, the file cache).
    factory_calibration(files)
    bare_calibration(files)
    times: dict[str, list[float]] = {"factory": [], "bare": [], "factory_detect": [], "bare_detect": [],
                                     "factory_win5": []}
    result = bare = win5 = None
    for _ in range(reps):
        result, t = timed(factory_calibration, files)
        times["factory"].append(t)
        bare, t = timed(bare_calibration, files)
        times["bare"].append(t)
        _, t = timed(factory_detection_only, files)
        times["factory_detect"].append(t)
        _, t = timed(bare_calibration, files, False)
        times["bare_detect"].append(t)
        win5, t = timed(factory_calibration, files, BARE_WINDOW)
        times["factory_win5"].append(t)
    med = {k: statistics.median(v) for k, v in times.items()}
    return {
        "views": len(files),
        "views_used": len(result.views),
        "factory_s": med["factory"],
        "bare_s": med["bare"],
        "ratio": med["factory"] / med["bare"],
        "factory_detect_s": med["factory_detect"],
        "factory_calibrate_s": med["factory"] - med["factory_detect"],
        "bare_detect_s": med["bare_detect"],
        "bare_calibrate_s": med["bare"] - med["bare_detect"],
        "factory_win5_s": med["factory_win5"],
        "ratio_win5": med["factory_win5"] / med["bare"],
        "factory_rms_px": float(result.camera.rms),
        "factory_win5_rms_px": float(win5.camera.rms),
        "bare_rms_px": float(bare[0]),
        "factory_fx_fy_cx_cy": [result.camera.fx, result.camera.fy, result.camera.cx, result.camera.cy],
        "bare_fx_fy_cx_cy": [float(bare[1][0, 0]), float(bare[1][1, 1]), float(bare[1][0, 2]),
                             float(bare[1][1, 2])],
        "reps": reps,
        "all_s": {k: [round(x, 4) for x in v] for k, v in times.items()},
    }


# ---------------------------------------------------------------- locate

def blank_footprint():
    import trimesh  # only the locate benchmark needs it

    mesh = trimesh.creation.box(BLANK_MM)
    mesh.apply_translation(np.array(BLANK_MM) / 2)
    return footprint_from_mesh(mesh.vertices, mesh.faces)


def layout(rng, n: int) -> list[Box]:
    """n non-overlapping blanks in the camera's view, random yaw."""
    size = tuple(np.array(BLANK_MM) / 1000.0)
    boxes: list[Box] = []
    while len(boxes) < n:
        x, y = rng.uniform(0.38, 0.62), rng.uniform(-0.06, 0.16)
        if all(np.hypot(x - b.x, y - b.y) > 0.11 for b in boxes):
            boxes.append(Box(x, y, rng.uniform(-np.pi, np.pi), size))
    return boxes


def bench_locate(frames: int) -> dict:
    rays = pixel_rays(CAMERA, 3)
    part = blank_footprint()
    images, truths = [], []
    for seed in range(frames):
        boxes = layout(np.random.default_rng(seed), 3)
        images.append(render_boxes(rays, invert(BASE_CAM), boxes, plane_z=TRAY_Z, noise_sigma=2.0, seed=seed))
        truths.append(boxes)
    locate_parts(images[0], CAMERA, BASE_CAM, part, TRAY_Z)  # warm-up
    times, errors_mm, found = [], [], []
    for image, boxes in zip(images, truths):
        parts, t = timed(locate_parts, image, CAMERA, BASE_CAM, part, TRAY_Z)
        times.append(t)
        found.append(len(parts))
        for b in boxes:
            errors_mm.append(1e3 * min(np.hypot(p.x - b.x, p.y - b.y) for p in parts))
    return {"frames": frames, "parts_per_frame": 3, "found": found,
            "median_ms": 1e3 * statistics.median(times), "max_ms": 1e3 * max(times),
            "median_ms_per_part": 1e3 * statistics.median(times) / 3,
            "max_position_error_mm": float(max(errors_mm))}


# ---------------------------------------------------------------- hand-eye

def handeye_views(rng, n: int, flange_cam: np.ndarray, base_board: np.ndarray):
    """Noisy flange and board-in-camera poses of n eye-in-hand views of a fixed board."""
    from scipy.spatial.transform import Rotation

    flange, board = [], []
    for _ in range(n):
        tilt, az, roll = np.radians(rng.uniform(10, 35)), rng.uniform(0, 2 * np.pi), rng.uniform(-np.pi, np.pi)
        d = rng.uniform(0.45, 0.6)
        target = base_board[:3, 3]
        eye = target + d * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
        z = (target - eye) / d
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        r = np.stack([x, np.cross(z, x), z], axis=1) @ Rotation.from_rotvec([0, 0, roll]).as_matrix()
        cam = make_transform(r, eye)
        f = cam @ invert(flange_cam)
        c = invert(cam) @ base_board
        for t, mm, deg in ((f, 0.1, 0.02), (c, 0.3, 0.05)):
            t[:3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(deg), 3)).as_matrix() @ t[:3, :3]
            t[:3, 3] += rng.normal(0, mm * 1e-3, 3)
        flange.append(f)
        board.append(c)
    return np.array(flange), np.array(board)


def bench_handeye(reps: int, views: int = 15) -> dict:
    from scipy.spatial.transform import Rotation

    flange_cam = make_transform(Rotation.from_euler("zyx", [95, 4, -10], degrees=True).as_matrix(),
                                [0.045, -0.06, 0.09])
    base_board = make_transform(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [0.5, -0.1, 0.02])
    f, c = handeye_views(np.random.default_rng(0), views, flange_cam, base_board)
    calibrate_handeye(f, c)  # warm-up
    times, closed = [], []
    for _ in range(max(reps, 5)):
        res, t = timed(calibrate_handeye, f, c)
        times.append(t)
        _, t = timed(calibrate_handeye, f, c, refine=False)
        closed.append(t)
    err_mm = 1e3 * float(np.linalg.norm(res.transform[:3, 3] - flange_cam[:3, 3]))
    return {"views": views, "median_ms": 1e3 * statistics.median(times),
            "closed_form_median_ms": 1e3 * statistics.median(closed), "translation_error_mm": err_mm,
            "translation_rms_mm": 1e3 * res.translation_rms}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--reps", type=int, default=5, help="repetitions of each calibration (alternating)")
    ap.add_argument("--frames", type=int, default=5, help="synthetic frames for locate")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args()

    print(f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"OpenCV {cv2.__version__}, numpy {np.__version__}")
    out: dict = {}
    if SAMPLES.is_dir():
        cal = out["calibration"] = bench_calibration(args.reps)
        print(f"\ncalibration, {cal['views']} views of left/ ({cal['views_used']} used), "
              f"median of {cal['reps']} alternating runs")
        print(f"  {'':34} {'time [s]':>9} {'RMS [px]':>9}")
        print(f"  {'factory (detect_all + calibrate)':34} {cal['factory_s']:9.3f} {cal['factory_rms_px']:9.4f}")
        print(f"  {'bare OpenCV (5x5 window)':34} {cal['bare_s']:9.3f} {cal['bare_rms_px']:9.4f}")
        print(f"  {'ratio factory / bare':34} {cal['ratio']:9.2f}   (goal <= 1.3)")
        print(f"  {'  factory detection alone':34} {cal['factory_detect_s']:9.3f}")
        print(f"  {'  factory calibrate (difference)':34} {cal['factory_calibrate_s']:9.3f}")
        print(f"  {'  bare detection alone':34} {cal['bare_detect_s']:9.3f}")
        print(f"  {'  bare calibrateCamera (difference)':34} {cal['bare_calibrate_s']:9.3f}")
        print(f"  {'  factory with 5 px window':34} {cal['factory_win5_s']:9.3f} {cal['factory_win5_rms_px']:9.4f}"
              f"   ratio {cal['ratio_win5']:.2f}")
        print("  fx fy cx cy factory " + " ".join(f"{v:.2f}" for v in cal["factory_fx_fy_cx_cy"])
              + " | bare " + " ".join(f"{v:.2f}" for v in cal["bare_fx_fy_cx_cy"]))
    else:
        print(f"\ncalibration skipped: {SAMPLES} not present")
    loc = out["locate"] = bench_locate(args.frames)
    print(f"\nlocate, {loc['frames']} synthetic 640x480 frames of 3 blanks 80x50x20 mm")
    print(f"  median {loc['median_ms']:.1f} ms/frame ({loc['median_ms_per_part']:.1f} ms/part), "
          f"max {loc['max_ms']:.1f} ms; found {loc['found']}; max position error {loc['max_position_error_mm']:.3f} mm")
    he = out["handeye"] = bench_handeye(args.reps)
    print(f"\nhand-eye (eye-in-hand), {he['views']} synthetic views, 0.1-0.3 mm / 0.02-0.05 deg noise")
    print(f"  median {he['median_ms']:.1f} ms (closed form alone {he['closed_form_median_ms']:.1f} ms); "
          f"error {he['translation_error_mm']:.2f} mm, residual RMS {he['translation_rms_mm']:.2f} mm")
    if args.json:
        print(json.dumps(out))


if __name__ == "__main__":
    main()
