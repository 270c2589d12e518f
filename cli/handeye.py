"""``factory handeye POSES IMAGES_DIR --camera camera.yaml --board ... --mode ... -o handeye.yaml``."""

from __future__ import annotations

import logging
from enum import Enum
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
import yaml

from cli.calibrate import list_images, parse_board, read_image
from cli.common import JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr
from factory.atomic import check_writable, write_text
from factory.errors import CalibrationError, VisionError
from vision.board import BOARD_SYNTAX
from vision.calibrate import detect
from vision.camera import CameraModel
from vision.handeye import board_pose, calibrate_handeye, handeye_document, parse_robot_poses

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
    check_writable(output, overwrite)
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
    flange, boards, used, rms, without_board = [], [], [], [], []
    with progress_bars(quiet) as bars:
        step = bars.stage("detect")
        for i, name in enumerate(names):
            image, _ = read_image(files[name])
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
    if without_board:
        log.warning("board not found in %d image(s), left out: %s", len(without_board), ", ".join(without_board))
    if len(used) < 3:
        raise VisionError(f"board found in only {len(used)} posed image(s); hand-eye calibration needs at least 3",
                          source=images_dir)
    result = calibrate_handeye(np.array(flange), np.array(boards), mode.value)
    doc = handeye_document(result, used, rms, without_board)
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
