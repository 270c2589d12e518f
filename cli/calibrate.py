"""``factory calibrate IMAGES_DIR --board ... -o camera.yaml``: camera intrinsics from board views."""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from cli.common import JsonFlag, Overwrite, Quiet, print_json, progress_bars, reports_errors, setup_logging, stderr
from factory.core.atomic import check_writable, write_bytes, write_text
from factory.core.errors import CalibrationError, VisionError
from factory.camera_msgs import camera_info_msg, compressed_image_msg, header as _header
from factory.mcaplog import McapLog
from factory.rosmsgs import TYPESTORE
from vision.board import BOARD_SYNTAX, BoardSpec
from vision.imagefile import decode_grey
from vision.calibrate import CalibrationResult, Detection, calibrate as run_calibration, detect
from vision.report import bgr_png_bytes, report_image

log = logging.getLogger(__name__)

#: Image files the command reads from IMAGES_DIR (case-insensitive suffixes).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")

_T = TYPESTORE.types


class Model(str, Enum):
    """Distortion models `--model` accepts (ROS names)."""

    plumb_bob = "plumb_bob"
    rational_polynomial = "rational_polynomial"


def parse_board(text: str) -> BoardSpec:
    """``--board`` text → BoardSpec; a malformed one is a usage error (exit 2)."""
    try:
        return BoardSpec.parse(text)
    except CalibrationError as e:
        raise typer.BadParameter(e.message, param_hint="--board") from None


def list_images(folder: Path) -> list[Path]:
    """The image files in ``folder``, sorted by name."""
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise CalibrationError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in folder", source=folder)
    return files


def read_image(path: Path) -> tuple[np.ndarray, bytes]:
    """An image file as an 8-bit grey image, and the file's bytes (for logging them as they are)."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise VisionError(f"cannot read image: {e.strerror}", source=path) from None
    return decode_grey(data, path), data


def detect_all(files: list[Path], board: BoardSpec, progress: Callable[[int, int], None]
               ) -> tuple[list[Detection], list[str], dict[str, tuple[np.ndarray, bytes]]]:
    """Detections of the views with the board, names of those without, and every image.

    Raises
    ------
    VisionError
        An image cannot be read.
    CalibrationError
        An image differs in size from the first.
    """
    detections, missing, images = [], [], {}
    size = None
    for i, path in enumerate(files):
        image, data = read_image(path)
        if size is None:
            size = image.shape
        elif image.shape != size:
            raise CalibrationError(f"image is {image.shape[1]}x{image.shape[0]} px, the first was "
                                   f"{size[1]}x{size[0]} px", source=path)
        images[path.name] = (image, data)
        try:
            detections.append(detect(image, board, path.name))
        except CalibrationError as e:
            log.info("%s", e)
            missing.append(path.name)
        progress(i + 1, len(files))
    return detections, missing, images


def corners_marker_msg(det: Detection, stamp_ns: int) -> Any:
    """``visualization_msgs/ImageMarker`` POINTS at the detected corners [px]."""
    marker = _T["visualization_msgs/msg/ImageMarker"]
    point, colour = _T["geometry_msgs/msg/Point"], _T["std_msgs/msg/ColorRGBA"]
    green = colour(r=0.1, g=0.9, b=0.2, a=1.0)
    return marker(
        header=_header(stamp_ns), ns="corners", id=0, type=marker.POINTS, action=marker.ADD,
        position=point(x=0.0, y=0.0, z=0.0), scale=3.0, outline_color=green, filled=1, fill_color=green,
        lifetime=_T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
        points=[point(x=float(u), y=float(v), z=0.0) for u, v in det.image_points],
        outline_colors=[])


def write_mcap(path: Path, result: CalibrationResult, images: dict[str, tuple[np.ndarray, bytes]],
               board: BoardSpec, overwrite: bool) -> None:
    """One message per view, 1 s apart: the image, its corners, and the camera_info."""
    found = {d.name: d for d in result.detections}
    inputs = {name: hashlib.sha256(data).hexdigest() for name, (_, data) in images.items()}
    with McapLog(path, stage="calibrate", overwrite=overwrite, inputs=inputs,
                 parameters={"board": str(board), "model": result.camera.model}) as m:
        for i, (name, (image, data)) in enumerate(images.items()):
            t = (i + 1) * 1_000_000_000
            m.write("/camera/image_raw/compressed", compressed_image_msg(data, name, image, t), t)
            if name in found:
                m.write("/camera/corners", corners_marker_msg(found[name], t), t)
            m.write("/camera/camera_info", camera_info_msg(result.camera, t), t)


def summary_text(result: CalibrationResult) -> str:
    cam = result.camera
    lines = [f"calibrated {cam.model} from {len(result.views)} views: RMS {cam.rms:.3f} px",
             f"  fx {cam.fx:.2f} ± {result.std_K[0]:.2f}  fy {cam.fy:.2f} ± {result.std_K[1]:.2f}  "
             f"cx {cam.cx:.2f} ± {result.std_K[2]:.2f}  cy {cam.cy:.2f} ± {result.std_K[3]:.2f} px",
             "  dist " + " ".join(f"{v:.5g}" for v in cam.dist)]
    worst = int(np.argmax(result.per_view_rms))
    lines.append(f"  worst view {result.views[worst]} {result.per_view_rms[worst]:.3f} px")
    if result.outliers:
        verb = "rejected" if result.rejected else "flagged (use --reject to leave them out)"
        lines.append(f"  outlier views {verb}: {', '.join(result.outliers)}")
    if result.without_board:
        lines.append(f"  no board found in {len(result.without_board)} view(s): {', '.join(result.without_board)}")
    return "\n".join(lines)


@reports_errors
def calibrate(
    images_dir: Annotated[Path, typer.Argument(help="Folder of board images.", exists=True, file_okay=False)],
    board_text: Annotated[str, typer.Option("--board", help=f"The board: {BOARD_SYNTAX} (lengths [m]).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Camera file to write (ROS camera_info YAML).",
                                         dir_okay=False)],
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write images, corners and camera_info to MCAP.",
                                              dir_okay=False)] = None,
    report: Annotated[Path | None, typer.Option("--report", help="Write a report picture (PNG).",
                                                dir_okay=False)] = None,
    model: Annotated[Model, typer.Option("--model", help="Distortion model.")] = Model.plumb_bob,
    reject: Annotated[bool, typer.Option("--reject", help="Recalibrate without outlier views.")] = False,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Calibrate a camera from views of a chessboard or ChArUco board.

    Views without the board are listed, never dropped silently. Outlier views (RMS above
    median + 3 robust sigma and above twice the median) are flagged; --reject leaves them out.
    """
    setup_logging(quiet)
    board = parse_board(board_text)
    for p in (output, mcap, report):
        if p is not None:
            check_writable(p, overwrite)
    files = list_images(images_dir)
    with progress_bars(quiet) as bars:
        detections, missing, images = detect_all(files, board, bars.stage("detect"))
        if not detections:
            hint = (" (COLSxROWS counts inner corners: a board of 10x7 squares is 9x6)" if board.kind == "chessboard"
                    else " (check the square counts and the dictionary)")
            raise CalibrationError(f"board {board} found in none of {len(files)} images; check the board size"
                                   f"{hint}", source=images_dir)
        if len(detections) < 3:
            raise CalibrationError(f"board found in only {len(detections)} of {len(files)} images; "
                                   f"calibration needs at least 3 views", source=images_dir)
        result = run_calibration(detections, model.value, reject=reject, without_board=missing,
                                 progress=bars.stage("calibrate"))
    # The camera file last: a failure writing the log or the picture leaves no camera file.
    report_png = bgr_png_bytes(report_image(result)) if report is not None else b""
    if mcap is not None:
        write_mcap(mcap, result, images, board, overwrite)
    if report is not None:
        write_bytes(report, report_png, overwrite=overwrite)
    write_text(output, result.camera.to_camera_info_yaml(), overwrite=overwrite)
    if not quiet:
        stderr.print(summary_text(result), highlight=False, markup=False)
    if json_out:
        print_json({"output": str(output), "board": str(board), **result.to_dict()})
