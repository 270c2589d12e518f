"""``factory verify PART.nc --setup PART.setup.json --part PART.stl``: prove a program never gouges."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from collections.abc import Mapping, Sequence
from typing import Annotated, Any

import numpy as np
import typer

from cadcam.gcode import parse_gcode
from cadcam.mesh import load_part, units_of_scale
from cadcam.model import Setup, Tool
from cadcam.sheet import read_setup_sheet
from cadcam.verify import Simulation, VerifyOptions, VerifyReport, deviation_image, finishing_moves, simulate
from cli.common import (EXIT_VERIFY_FAILED, Overwrite, Quiet, StageProgress, print_json,
                        progress_bars, reports_errors, setup_logging, stderr)
from cli.views import heightfield_mesh
from factory.atomic import check_writable, write_bytes, write_text
from factory.errors import SetupError, VerifyError
from factory.pictures import png_bytes
from factory.mcaplog import McapLog, marker_array, triangle_mesh_marker

log = logging.getLogger(__name__)

def read_sheet(path: Path) -> tuple[Setup, dict[int, Tool], dict[str, Any]]:
    """Setup, tool table and raw document of a setup sheet file."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SetupError(f"cannot read setup sheet: {e}", source=path) from None
    setup, tools = read_setup_sheet(data, source=str(path))
    return setup, tools, data


def part_triangles(part: Path, setup: Setup, expected_sha256: str = "") -> np.ndarray:
    """The part's triangles in work coordinates [mm], placed as the setup sheet says."""
    loaded = load_part(part, units=units_of_scale(setup.mesh_scale, "setup sheet"))
    if expected_sha256 and loaded.sha256 != expected_sha256:
        log.warning("%s differs from the part the program was made for (sha256 mismatch)", part)
    mesh = loaded.mesh.copy()
    mesh.apply_transform(setup.transform_mesh_to_work)
    return np.asarray(mesh.triangles)


def run_verify(gcode_text: str, gcode_source: str, setup: Setup, tools: dict[int, Tool],
               triangles: np.ndarray, options: VerifyOptions, bars: StageProgress,
               operations: Sequence[Mapping[str, Any]] = ()) -> tuple[Simulation, VerifyReport]:
    """Parse and simulate a program against the part (``operations``: the setup sheet's, for finishing limits)."""
    moves = parse_gcode(gcode_text, source=gcode_source)
    finishing = finishing_moves(gcode_text, moves, operations)
    return simulate(moves, tools, setup, triangles, options, progress=bars.stage("verify"), finishing=finishing)


def log_simulation(mcap: McapLog, sim: Simulation) -> None:
    """The simulated stock as a mesh in work coordinates (metres) on ``/verify/stock``."""
    vertices, faces = heightfield_mesh(sim.grid.xs, sim.grid.ys, sim.stock_top)
    marker = triangle_mesh_marker("verify_stock", 0, vertices / 1000.0, faces, (0.75, 0.75, 0.8, 1.0), "work", 0)
    mcap.write("/verify/stock", marker_array([marker]), 0, latched=True)


def report_text(report: VerifyReport) -> str:
    verdict = "OK" if report.ok else "FAILED"
    text = (f"verify {verdict}: max gouge {report.max_gouge:.4f} mm, remaining stock max "
            f"{report.remaining_max:.3f} / mean {report.remaining_mean:.3f} / p95 {report.remaining_p95:.3f} mm, "
            f"{len(report.rapid_crashes)} rapid crash(es)")
    if report.gouged and report.gouge_line is not None:
        text += f"\n  gouge: {report.max_gouge:.3f} mm into the part, line {report.gouge_line}"
    for f in report.faults:
        text += f"\n  {f.kind}: {f.message}" + (f", line(s) {line_ranges(f.lines)}" if f.lines else "")
    return text


def line_ranges(lines: Sequence[int], most: int = 12) -> str:
    """``1203-1210, 1304`` for program lines; at most ``most`` runs, then how many more lines."""
    runs: list[list[int]] = []
    for n in lines:
        if runs and n <= runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    shown = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:most])
    rest = sum(b - a + 1 for a, b in runs[most:])
    return shown + (f" and {rest} more" if rest else "")


@reports_errors
def verify(
    program: Annotated[Path, typer.Argument(help="G-code program.", exists=True, dir_okay=False)],
    setup_path: Annotated[Path, typer.Option("--setup", help="Setup sheet written by `factory gcode`.", exists=True, dir_okay=False)],
    part: Annotated[Path, typer.Option("--part", help="The part mesh the program was made for.", exists=True, dir_okay=False)],
    png: Annotated[Path | None, typer.Option("--png", help="Write a deviation map picture.", dir_okay=False)] = None,
    json_path: Annotated[Path | None, typer.Option("--json", help="Write the report as JSON ('-' for stdout).")] = None,
    mcap: Annotated[Path | None, typer.Option("--mcap", help="Write the simulated stock to MCAP.", dir_okay=False)] = None,
    grid: Annotated[float, typer.Option("--grid", help="Simulation grid spacing [mm].", min=0.01)] = 0.2,
    tolerance: Annotated[float, typer.Option("--tolerance", help="Cuts deeper into the part than this are gouges [mm].", min=0.0)] = 0.01,
    overwrite: Overwrite = False,
    quiet: Quiet = False,
) -> None:
    """Simulate material removal; report gouges, remaining stock and rapid crashes.

    Exits 3 when the program gouges the part, a rapid or the shank or holder meets stock, a
    tool is engaged deeper than its flutes (a finishing tool: deeper than the allowance plus
    the roughing terraces), a tool goes below the stock bottom, or nothing is cut.
    """
    setup_logging(quiet)
    outputs = [p for p in (png, mcap) if p is not None] + ([json_path] if json_path and str(json_path) != "-" else [])
    for p in outputs:
        check_writable(p, overwrite)
    setup, tools, sheet = read_sheet(setup_path)
    triangles = part_triangles(part, setup, sheet.get("source_sha256", ""))
    try:
        text = program.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise VerifyError(f"cannot read program: {e}", source=program) from None
    options = VerifyOptions(cell=grid, gouge_tolerance=tolerance)
    with progress_bars(quiet) as bars:
        sim, report = run_verify(text, str(program), setup, tools, triangles, options, bars,
                                 operations=sheet.get("operations") or ())
    write_verify_outputs(sim, report, png=png, json_path=json_path, mcap=mcap, overwrite=overwrite,
                         inputs={str(program): "", str(part): ""})
    if not quiet:
        stderr.print(report_text(report), highlight=False)
    if not report.ok:
        raise typer.Exit(EXIT_VERIFY_FAILED)


def write_verify_outputs(sim: Simulation, report: VerifyReport, *, png: Path | None, json_path: Path | None,
                         mcap: Path | None, overwrite: bool, inputs: dict[str, str]) -> None:
    """The report as JSON, the deviation picture, the simulated stock in MCAP: each where asked."""
    if png is not None:
        write_bytes(png, png_bytes(deviation_image(sim, report)), overwrite=overwrite)
    if mcap is not None:
        with McapLog(mcap, stage="verify", overwrite=overwrite, inputs=inputs) as m:
            log_simulation(m, sim)
    if json_path is not None:
        if str(json_path) == "-":
            print_json(report.to_dict())
        else:
            write_text(json_path, json.dumps(report.to_dict(), indent=2) + "\n", overwrite=overwrite)

