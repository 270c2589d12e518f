"""``factory locate IMAGE --camera camera.yaml --extrinsics handeye.yaml --part PART.stl``: parts on the tray."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from cadcam.mesh import load_part
from cli.calibrate import read_image
from cli.common import JsonFlag, Quiet, print_json, reports_errors, setup_logging, stderr
from factory.core.errors import VisionError
from vision.camera import CameraModel
from vision.handeye import pose_from_xyz_rotation, read_extrinsics
from vision.locate import footprint_from_mesh, locate_parts


def parse_flange(text: str | None) -> np.ndarray | None:
    """``"x,y,z,rx,ry,rz"`` [m, rad] → ``T_base_flange``; a usage error names the option."""
    if text is None:
        return None
    try:
        v = [float(s) for s in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 6 or not np.isfinite(v).all():
        raise typer.BadParameter(f"expected x,y,z,rx,ry,rz [m, rad], got {text!r}", param_hint="--flange")
    return pose_from_xyz_rotation(np.array(v[:3]), rotvec=np.array(v[3:]))


def read_view(camera_file: Path, extrinsics_file: Path, flange_pose: np.ndarray | None,
              tray_z: float | None) -> tuple[CameraModel, np.ndarray, float]:
    """The camera, its pose in the robot base frame (4x4, m) and the tray height [m].

    ``tray_z`` overrides the extrinsics file's; ``flange_pose`` is needed for eye-in-hand.
    """
    camera = CameraModel.read(camera_file)
    try:
        text = extrinsics_file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise VisionError(f"cannot read extrinsics file: {getattr(e, 'strerror', None) or e}",
                          source=extrinsics_file) from None
    extrinsics = read_extrinsics(text, source=str(extrinsics_file))
    height = tray_z if tray_z is not None else extrinsics.tray_z
    if height is None:
        raise VisionError("tray height unknown: pass --tray-z or add tray_z [m] to the file", source=extrinsics_file)
    try:
        base_camera = extrinsics.base_camera(flange_pose)
    except VisionError as e:
        raise e.with_source(extrinsics_file) from None
    return camera, base_camera, float(height)


@reports_errors
def locate(
    image_file: Annotated[Path, typer.Argument(help="Picture of the tray.", dir_okay=False)],
    camera_file: Annotated[Path, typer.Option("--camera", help="Calibrated camera (ROS camera_info YAML).",
                                              dir_okay=False)],
    extrinsics_file: Annotated[Path, typer.Option("--extrinsics", help="Hand-eye file (factory handeye).",
                                                  dir_okay=False)],
    part_file: Annotated[Path, typer.Option("--part", help="Part or blank mesh (STL/OBJ/PLY/3MF), lying on the "
                                                           "tray with its mesh z up.", dir_okay=False)],
    tray_z: Annotated[float | None, typer.Option("--tray-z", help="Tray height in the robot base frame [m]; "
                                                                  "default: tray_z of the extrinsics file.")] = None,
    flange: Annotated[str | None, typer.Option("--flange", help="Flange pose of the picture, x,y,z,rx,ry,rz "
                                                                "[m, rad] (eye-in-hand extrinsics only).")] = None,
    units: Annotated[str, typer.Option("--units", help="Mesh units: auto, mm, inch, m.")] = "auto",
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Find copies of a part lying on a tray: x, y [m] and yaw [rad] in the robot base frame.

    The JSON output (--json) is a list, best score first, of {x, y, z, yaw, score, rms_px,
    mm_per_px, expected_error_mm, expected_error_deg, pixel}; (x, y, z) is the footprint's
    centroid on the tray.
    """
    setup_logging(quiet)
    flange_pose = parse_flange(flange)
    camera, base_camera, height = read_view(camera_file, extrinsics_file, flange_pose, tray_z)
    mesh = load_part(part_file, units).mesh  # type: ignore[arg-type]
    part = footprint_from_mesh(mesh.vertices, mesh.faces, source=str(part_file))
    image, _ = read_image(image_file)
    found = locate_parts(image, camera, base_camera, part, float(height), source=str(image_file))
    if not quiet:
        for p in found:
            stderr.print(f"x {p.x:.4f}  y {p.y:.4f}  z {p.z:.4f} m  yaw {np.degrees(p.yaw):7.2f} deg  "
                         f"score {p.score:.2f}  ±{p.sigma_xy * 1e3:.2f} mm ±{np.degrees(p.sigma_yaw):.2f} deg "
                         f"({p.mm_per_px:.2f} mm/px)", highlight=False, markup=False)
    if json_out:
        print_json([p.to_dict() for p in found])
