"""``factory robot CELL.yaml --setup PART.setup.json -o PART.robot.mcap``: plan machine tending.

Loads the stock from the rack into the vise and unloads the finished part to the out-tray,
collision-checked against the cell, timed within the joint limits. Writes the plan as
MCAP (robot description, joint states, TF, trajectories, the cell's boxes) and, with
``--program``, a robot program (URScript, RAPID or KRL).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from cadcam.mesh import load_planned_part
from cli.common import JsonFlag, Overwrite, Quiet, print_json, reports_errors, setup_logging, stderr
from factory.core.atomic import check_writable, write_text
from factory.catalog import sha256_file
from factory.core.progress import Stopwatch
from factory.tending import plan_cell, write_robot_mcap
from factory.verify import read_sheet
from robotprog.programs import LANGS, post_program


@reports_errors
def robot(
    cell_path: Annotated[Path, typer.Argument(help="Robot cell file (YAML, factory.cell/1).", exists=True, dir_okay=False)],
    setup_path: Annotated[Path, typer.Option("--setup", help="Setup sheet written by `factory gcode`.", exists=True, dir_okay=False)],
    output: Annotated[Path, typer.Option("-o", "--output", help="MCAP file to write (PART.robot.mcap).", dir_okay=False)],
    part: Annotated[Path | None, typer.Option("--part", help="Part mesh: its box is what unload grips (default: the stock box).", exists=True, dir_okay=False)] = None,
    program: Annotated[Path | None, typer.Option("--program", help="Also write a robot program.", dir_okay=False)] = None,
    lang: Annotated[str, typer.Option("--lang", help="Robot program language: urscript, rapid (ABB .mod) or krl (KUKA .src + .dat).")] = "urscript",
    setups: Annotated[int, typer.Option("--setups", min=1, max=2, help="2: the part is turned over on the cell's flip station between op 1 and op 2 (its holding block is the stock below --part).")] = 1,
    overwrite: Overwrite = False,
    json_out: JsonFlag = False,
    quiet: Quiet = False,
) -> None:
    """Plan loading the stock into the vise and unloading the part; write MCAP and a robot program."""
    setup_logging(quiet)
    if lang not in LANGS:
        raise typer.BadParameter(f"expected one of {', '.join(LANGS)}, got {lang!r}", param_hint="--lang")
    programs = [program, program.with_suffix(".dat")] if program is not None and lang == "krl" else [program]
    for p in (output, *programs):
        if p is not None:
            check_writable(p, overwrite)
    watch = Stopwatch()
    with watch("load"):
        read = read_sheet(setup_path)
        setup, sheet = read.setup, read.sheet
        vertices = None
        if part is not None:
            loaded = load_planned_part(part, setup.mesh_scale, sheet.intake, source=str(setup_path))
            vertices = np.asarray(loaded.mesh.vertices) / float(setup.mesh_scale)
    planned = plan_cell(cell_path, sheet, str(setup_path), vertices, watch, setups=setups)
    cell, world, plan = planned.cell, planned.world, planned.plan
    posted = post_program(lang, program, cell, world, plan) if program is not None else None
    with watch("write"):
        for path, text in (posted.texts if posted else {}).items():
            write_text(path, text, overwrite=overwrite)
        inputs = {str(cell_path): sha256_file(cell_path), str(setup_path): sha256_file(setup_path)}
        if part is not None:
            inputs[str(part)] = sha256_file(part)
        n = write_robot_mcap(output, cell, world, plan, overwrite=overwrite, inputs=inputs)
    summary = {
        "cell": cell.name,
        "robot": world.robot.name,
        "mcap": str(output),
        "program": str(program) if program else None,
        "duration_s": round(plan.duration, 3),
        "program_duration_s": round(posted.predicted_s, 3) if posted else None,
        "program_targets": posted.targets if posted else None,
        "moves": [{"name": nm, "duration_s": round(d, 3)} for nm, d in plan.durations],
        "joint_states": n,
        "seconds": watch.rounded(),
    }
    if json_out:
        print_json(summary)
    elif not quiet:
        stderr.print(f"robot: {len(plan.moves)} moves, {plan.duration:.2f} s of motion, planned in "
                     f"{plan.planning_s:.2f} s -> {output}", highlight=False, markup=False)
