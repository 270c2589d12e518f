"""``factory inspect IMAGE --camera ... --extrinsics ... --part PART.stl``: outline check of parts on the tray."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cadcam.mesh import load_part
from cli.common import (EXIT_VERIFY_FAILED, JsonFlag, Overwrite, Quiet, print_json, reports_errors, setup_logging,
                        stderr)
from cli.calibrate import read_image
from cli.locate import parse_flange, read_view
from factory.core.atomic import check_writable, write_bytes
from vision.inspect import InspectOptions, inspect_part, inspection_image
from vision.locate import footprint_from_mesh, mm_to_m
from vision.report import bgr_png_bytes


@reports_errors
def inspect(
    image_file: Annotated[Path, typer.Argument(help="Picture of the tray.", dir_okay=False)],
    camera_file: Annotated[Path, typer.Option("--camera", help="Calibrated camera (ROS camera_info YAML).",
                                              dir_okay=False)],
    extrinsics_file: Annotated[Path, typer.Option("--extrinsics", help="Hand-eye file (factory handeye).",
                                                  dir_okay=False)],
    part_file: Annotated[Path, typer.Option("--part", help="Part mesh (STL/OBJ/PLY/3MF), lying on the tray with "
                                                           "its mesh z up.", dir_okay=False)],
    tolerance: Annotated[float, typer.Option("--tolerance", help="Largest deviation of the outline or of a "
                                                                 "feature that passes [mm].", min=0.0)] = 0.7,
    tray_z: Annotated[float | None, typer.Option("--tray-z", help="Tray height in the robot base frame [m]; "
                                                                  "default: tray_z of the extrinsics file.")] = None,
    flange: Annotated[str | None, typer.Option("--flange", help="Flange pose of the picture, x,y,z,rx,ry,rz "
                                                                "[m, rad] (eye-in-hand extrinsics only).")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write the picture with silhouettes and deviations.",
                                             dir_okay=False)] = None,
    units: Annotated[str, typer.Option("--units", help="Mesh units: auto, mm, inch, m.")] = "auto",
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Compare each part's edges in the picture with its mesh's: the outline (a burr, a broken
    corner) and the features inside it (a hole not drilled, a boss not there).

    Exits 3 when a part deviates by more than --tolerance, or is refused (too little of it can be
    judged: glare, shadow). A part that cannot be located confidently is an error, with the reason.
    --json prints a list of {pass, refusal, tolerance_mm, max/p95_deviation_mm, excess_mm, missing_mm,
    outline_seen, smallest_burr_mm, missing_features, pose}. A burr narrower than smallest_burr_mm (the camera's
    pixel at the part) may pass: the verdict says so.
    """
    setup_logging(quiet)
    flange_pose = parse_flange(flange)
    if png is not None:
        check_writable(png, overwrite)
    camera, base_camera, height = read_view(camera_file, extrinsics_file, flange_pose, tray_z)
    mesh = load_part(part_file, units).mesh  # type: ignore[arg-type]
    part = footprint_from_mesh(mesh.vertices, mesh.faces, source=str(part_file))
    image, _ = read_image(image_file)
    results = inspect_part(image, camera, base_camera, part, mesh.vertices, mesh.faces, float(height),
                           InspectOptions(tolerance=float(mm_to_m(tolerance))), source=str(image_file))
    if png is not None:
        write_bytes(png, bgr_png_bytes(inspection_image(image, results)), overwrite=overwrite)
    if not quiet:
        for r in results:
            p = r.part
            verdict = f"REFUSED  {r.refusal}" if r.refusal else f"{'PASS' if r.passed else 'FAIL'}  max " \
                f"{r.max_deviation * 1e3:.2f} mm (tolerance {tolerance:g} mm, {p.mm_per_px:.2f} mm/px; " \
                f"a burr under {r.smallest_burr * 1e3:.2f} mm is not resolved)"
            stderr.print(f"{verdict} at x {p.x:.4f} y {p.y:.4f} m", highlight=False, markup=False)
    if json_out:
        print_json([r.to_dict() for r in results])
    if not all(r.passed for r in results):
        raise typer.Exit(EXIT_VERIFY_FAILED)
