"""``factory handeye POSES IMAGES_DIR --camera camera.yaml --board ... --mode ... -o handeye.yaml``."""

from __future__ import annotations

import hashlib
import logging
from enum import Enum
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
import yaml

from cli.calibrate import corners_marker_msg, list_images, parse_board, read_image
from cli.common import JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr
from factory.core.atomic import check_writable, write_bytes, write_text
from factory.camera_msgs import camera_info_msg, compressed_image_msg
from factory.core.errors import CalibrationError, VisionError
from factory.mcaplog import McapLog
from factory.rosmsgs import cube_marker, marker_array, tf_message, transforms_stamped
from vision.board import BOARD_SYNTAX, BoardSpec
from vision.calibrate import Detection, detect
from vision.camera import CameraModel
from vision.handeye import (BOARD_FRAMES, FRAMES, HandEyeResult, board_pose, calibrate_handeye, handeye_document,
                            parse_robot_poses)
from vision.report import bgr_png_bytes, handeye_report_image

log = logging.getLogger(__name__)


class Mode(str, Enum):
    """Where the camera is: on the flange or fixed in the cell."""

    eye_in_hand = "eye-in-hand"
    eye_to_hand = "eye-to-hand"


def read_poses(path: Path) -> dict[str, np.ndarray]:
    """The robot pose file (YAML, or CSV by its ``.csv`` suffix) → ``T_base_flange`` per image name."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise VisionError(f"cannot read pose file: {getattr(e, 'strerror', None) or e}", source=path) from None
    return parse_robot_poses(text, source=str(path), csv=path.suffix.lower() == ".csv")


#: Frame of the board where each view's camera saw it (solvePnP); on a good calibration it
#: coincides with the fitted ``board`` frame.
SEEN_BOARD_FRAME = "board_seen"


def board_markers(board: BoardSpec) -> object:
    """``MarkerArray``: the board as a 2 mm plate in the fitted ``board`` frame and where the
    camera saw it (``board_seen``); its corner grid spans the plate [m]."""
    pts = board.object_points
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, size = (lo + hi) / 2 + [0.0, 0.0, -0.001], np.r_[hi[:2] - lo[:2], 0.002]
    return marker_array([
        cube_marker("board", 0, centre, size, (0.2, 0.6, 1.0, 0.6), "board", 0),
        cube_marker("board_seen", 0, centre, size, (1.0, 0.5, 0.1, 0.6), SEEN_BOARD_FRAME, 0),
    ])


def write_mcap(path: Path, result: HandEyeResult, views: list[tuple[str, np.ndarray, bytes, Detection]],
               flange: np.ndarray, boards: np.ndarray, camera: CameraModel, board: BoardSpec, overwrite: bool
               ) -> None:
    """The calibration as Foxglove shows it: per used view (1 s apart) the image, its corners,
    the camera_info, the flange pose (``/tf`` base -> flange) and the board where that view's
    camera saw it (camera -> ``board_seen``); the fitted camera and board on ``/tf_static``.

    ``flange`` (n, 4, 4) is ``T_base_flange`` and ``boards`` (n, 4, 4) ``T_cam_board`` per view [m].
    """
    inputs = {name: hashlib.sha256(data).hexdigest() for name, _, data, _ in views}
    parent, child = FRAMES[result.mode]
    board_parent, board_child = BOARD_FRAMES[result.mode]
    with McapLog(path, stage="handeye", overwrite=overwrite, inputs=inputs,
                 parameters={"board": str(board), "mode": result.mode}) as m:
        static = (transforms_stamped(parent, [child], result.transform[None], 0)
                  + transforms_stamped(board_parent, [board_child], result.board[None], 0))
        m.write("/tf_static", tf_message(static), 0, latched=True)
        m.write("/handeye/board", board_markers(board), 0, latched=True)
        for i, (name, image, data, det) in enumerate(views):
            t = (i + 1) * 1_000_000_000
            m.write("/tf", tf_message(transforms_stamped("base", ["flange"], flange[i][None], t)
                                      + transforms_stamped(child, [SEEN_BOARD_FRAME], boards[i][None], t)), t)
            m.write("/camera/image_raw/compressed", compressed_image_msg(data, name, image, t), t)
            m.write("/camera/corners", corners_marker_msg(det, t), t)
            m.write("/camera/camera_info", camera_info_msg(camera, t), t)


@reports_errors
def handeye(
    poses_file: Annotated[Path, typer.Argument(
        help="Robot flange poses per image (YAML 'poses: {IMAGE: {xyz: [m], rotvec: [rad] | quat: [x,y,z,w]}}' "
             "or CSV image,x,y,z,rx,ry,rz / image,x,y,z,qx,qy,qz,qw).", dir_okay=False)],
    images_dir: Annotated[Path, typer.Argument(help="Folder of board images.", file_okay=False)],
    camera_file: Annotated[Path, typer.Option("--camera", help="Calibrated camera (ROS camera_info YAML).",
                                              dir_okay=False)],
    board_text: Annotated[str, typer.Option("--board", help=f"The board: {BOARD_SYNTAX} (lengths [m]).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Hand-eye file to write (YAML).", dir_okay=False)],
    mode: Annotated[Mode, typer.Option("--mode", help="eye-in-hand: camera on the flange (result T_flange_camera); "
                                                      "eye-to-hand: camera fixed (result T_base_camera).")]
    = Mode.eye_in_hand,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write views, corners, robot poses and the result "
                                                             "(TF) to MCAP.", dir_okay=False)] = None,
    report: Annotated[Path | None, typer.Option("--report", help="Write a report picture (PNG) of the per-view "
                                                                 "residuals.", dir_okay=False)] = None,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Hand-eye calibration: where the camera is relative to the flange or the robot base.

    Each image is paired with the flange pose of its file name; the board pose comes from the
    detected corners and the calibrated camera (solvePnP). Images without a pose or without the
    board are listed and left out.
    """
    setup_logging(quiet)
    board = parse_board(board_text)
    for p in (output, mcap, report):
        if p is not None:
            check_writable(p, overwrite)
    camera = CameraModel.read(camera_file)
    poses = read_poses(poses_file)
    if not images_dir.is_dir():
        raise VisionError("no such folder", source=images_dir)
    files = {p.name: p for p in list_images(images_dir)}
    missing = sorted(set(poses) - set(files))
    if missing:
        raise VisionError(f"{len(missing)} pose(s) name images not in {images_dir}: {', '.join(missing[:5])}",
                          source=poses_file)
    unposed = sorted(set(files) - set(poses))
    if unposed:
        log.warning("no robot pose for %d image(s), left out: %s", len(unposed), ", ".join(unposed))
    names = sorted(poses)
    flange, boards, used, rms, without_board, views = [], [], [], [], [], []
    with progress_bars(quiet) as bars:
        step = bars.stage("detect")
        for i, name in enumerate(names):
            image, data = read_image(files[name])
            if (image.shape[1], image.shape[0]) != camera.image_size:
                w, h = camera.image_size
                raise VisionError(f"image is {image.shape[1]}x{image.shape[0]} px, the camera was calibrated at "
                                  f"{w}x{h} px", source=files[name])
            step(i + 1, len(names))
            try:
                det = detect(image, board, name)
            except CalibrationError as e:
                log.info("%s", e)
                without_board.append(name)
                continue
            pose, err = board_pose(det, camera)
            flange.append(poses[name])
            boards.append(pose)
            used.append(name)
            rms.append(err)
            views.append((name, image, data, det))
    if without_board:
        log.warning("board not found in %d image(s), left out: %s", len(without_board), ", ".join(without_board))
    if len(used) < 3:
        raise VisionError(f"board found in only {len(used)} posed image(s); hand-eye calibration needs at least 3",
                          source=images_dir)
    result = calibrate_handeye(np.array(flange), np.array(boards), mode.value)
    doc = handeye_document(result, used, rms, without_board)
    # The hand-eye file last: a failure writing the log or the picture leaves no result file.
    if mcap is not None:
        write_mcap(mcap, result, views, np.array(flange), np.array(boards), camera, board, overwrite)
    if report is not None:
        write_bytes(report, bgr_png_bytes(handeye_report_image(result, used, rms)), overwrite=overwrite)
    write_text(output, yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120),
               overwrite=overwrite)
    if not quiet:
        t = doc["transform"]
        stderr.print(f"{mode.value} from {len(used)} views: T_{t['parent_frame']}_{t['child_frame']} xyz "
                     + " ".join(f"{v:.4f}" for v in t["xyz"]) + " m, quat "
                     + " ".join(f"{v:.4f}" for v in t["quaternion_xyzw"])
                     + f"\n  residuals RMS {result.translation_rms * 1e3:.2f} mm, "
                     f"{np.degrees(result.rotation_rms):.3f} deg; condition {result.condition:.2f}",
                     highlight=False, markup=False)
    if json_out:
        print_json({"output": str(output), **doc})
