"""Our op 1 against FreeCAD 0.20's whole program (issue 32, item 4): same tools, feeds and timer.

    python benchmarks/freecad_peer.py [PART.stl ...] [--cell 0.5] [--keep DIR] [--timeout 900]

For each part (default: the four samples but the relief) op 1 is planned as
``factory plan --no-robot`` plans and posts it (:func:`factory.plan.plan_part`, two operations, tools from
fixtures/tools.yaml, LinuxCNC): the program a machinist runs, on the stock that leaves op 2 its holding
block. FreeCAD's Path workbench (run headless by Debian's ``freecadcmd``, benchmarks/freecad_peer_job.py)
then makes the issue's program for the same stock
with op 1's tools, spindle speeds, feeds and plunge feeds (:func:`peer_tools`): Adaptive clearing
with our roughing tool at its defaults (20 % stepover, helix at 5 degrees, no lift on links,
step-down = the tool diameter), level by level down to op 1's floor, leaving our roughing's
allowance; a face pass over the flats and a profile of the part's contour (not its inner walls:
benchmarks/freecad_peer_job.py says why) with our first flats-and-walls finishing tool; and, where our op 1 finishes freeform with a ball, a 3D surface (drop-cutter)
with that ball at our raster's stepover over the freeform faces' box grown by the ball's radius (the
Surface's own region: the stock's outline drawn in by its BoundaryAdjustment; down to the region's
lowest face, the final depth FreeCAD sets from picked faces; not a Boundary dressup, which on the
safe program's 182,000 moves was still at work after 7 minutes and turns rapids crossing its box
into feeds). On such parts (the dome) it also makes the program "made safe" (the issue's target
compares against it): the Adaptive lifts :data:`SAFE_LIFT_MM` on its links and the surface goes
down in layers :data:`SAFE_BALL_STEPDOWN_MM` apart, each lifting over what the layers above cut
(FreeCAD's OptimizeStepOverTransitions). FreeCAD's LinuxCNC post writes the programs.

Both programs are timed by our program timer, the one the plan's cycle time is
(:func:`program_minutes`: :func:`cadcam.gcode.parse_gcode`, then
:func:`cadcam.timeline.machine_timeline`, whose clock is :func:`cadcam.post.move_seconds`),
and judged the same way: by ``factory verify``'s simulation (:func:`cadcam.verify.simulate`):
gouges, rapids through stock, faults, deepest cut per tool, the stock left on the part (max
and mean over its grid points); by counting the rapids below the stock top; and by the
tests' independent sweep (tests/cadcam/sweep.py) for plunges, vertical feed moves into stock.
FreeCAD's other entries are its helices at 5 degrees, steeper than the 3 the issue allows.

Prints one JSON line per part and a last ``{"summary": ...}`` line. ``ratio`` is our op 1 over
FreeCAD's program, ``ratio_safe`` over the one made safe (issue 32 asks for at most 0.8);
``freecad.groups_min`` times each group of FreeCAD's operations posted on its own (no tool
change between groups), ``rough_ratio`` is the part of our op 1 that roughs (holes bored or
drilled, roughing and rest roughing) over FreeCAD's Adaptive. ``bound_min`` is
:func:`benchmarks.adaptive.lower_bound`, the feature-aware lower bound of BOTH operations (stock
removed at T2's adaptive rate, flats (op 1's upward ones and op 2's under the part) at 70 % stepover, the walls' outline once, the freeform faces
once by the finishing ball at its scallop's stepover; no bores, rapids or tool changes), and ``ours_bound_ratio``/``freecad_bound_ratio`` op 1 over it.
``--keep DIR`` writes the programs there. Installs nothing: without ``freecadcmd`` on the PATH it
prints one line and exits 0; a part whose surface needs OpenCAMLib (the ``bench`` extra) and
does not find it is reported as failed.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.adaptive import lower_bound  # noqa: E402
from cadcam.finishing import stepover_for  # noqa: E402
from cadcam.gcode import parse_gcode  # noqa: E402
from cadcam.model import Motion, Operation, ProgramMoves, Setup, Tool  # noqa: E402
from cadcam.plan import PlanOptions  # noqa: E402
from cadcam.post import PostOptions  # noqa: E402
from cadcam.timeline import machine_timeline  # noqa: E402
from cadcam.verify import VerifyOptions, simulate  # noqa: E402
from factory.core.errors import GcodeError  # noqa: E402
from factory.plan import PlanRequest, plan_part  # noqa: E402
from tests.cadcam.sweep import sweep_moves  # noqa: E402

#: The relief is left out: ``factory plan`` plans it inside its boundary (:mod:`cadcam.relief`),
#: which :func:`bench_part` does not, and FreeCAD was still turning its 19,200 triangles into a
#: solid after 4 minutes.
SAMPLES = ("bracket", "plate_bosses", "stepped_wall", "dome_mould")
JOB_SCRIPT = Path(__file__).resolve().parent / "freecad_peer_job.py"
#: Operation kinds of our op 1 that rough (the work FreeCAD's Adaptive does).
ROUGHING_KINDS = ("roughing", "helix", "drill", "peck")
#: Stock a move must cut to count as engaged [mm] (the sweep's grid makes thinner cuts noise).
ENGAGED_MM = 0.05


def program_minutes(text: str, options: PostOptions = PostOptions()) -> float:
    """Cycle time of a G-code program by our timer [min]: the clock of the plan's estimate.

    Any controller's program our parser reads (FreeCAD's LinuxCNC post included) is timed as
    :func:`cadcam.post.post_process` times its own: every move at its programmed feed or
    ``options.rapid_rate``, tool changes at ``options.tool_change_time``.
    """
    timeline = machine_timeline(parse_gcode(text), options)
    return float(timeline.end[-1]) / 60.0


def group_minutes(text: str) -> float:
    """:func:`program_minutes` of one group of FreeCAD's operations posted on its own; 0 for a group FreeCAD made
    no path for (its program never moves across, so the timer has no position to start from)."""
    try:
        return program_minutes(text)
    except GcodeError:
        return 0.0


def plunges(moves: ProgramMoves, engagement: np.ndarray, tools: dict[int, Tool]) -> int:
    """Feed moves of a mill that go straight down into stock (a drill's only way in is not counted).

    ``engagement`` [mm] per move, as :func:`tests.cadcam.sweep.sweep_moves` gives it.
    """
    step = np.diff(moves.points, axis=0)
    drills = [n for n, t in tools.items() if t.shape == "drill"]
    down = (moves.motion[1:] != Motion.RAPID) & (step[:, 2] < -1e-3) & (np.hypot(step[:, 0], step[:, 1]) < 1e-3)
    return int((down & (engagement[1:] > ENGAGED_MM) & ~np.isin(moves.tool[1:], drills)).sum())


def judge(text: str, tools: dict[int, Tool], setup: Setup, triangles: np.ndarray, cell: float) -> dict:
    """Verify's verdict on a program and the sweep's entries into stock (depths [mm])."""
    moves = parse_gcode(text)
    report = simulate(moves, tools, setup, triangles, VerifyOptions(cell=cell)).report
    sw = sweep_moves(moves.points, moves.motion, moves.tool, tools, setup, cell)
    crashes = report.rapid_crashes
    lowest = np.minimum(moves.points[1:, 2], moves.points[:-1, 2])
    low = (moves.motion[1:] == Motion.RAPID) & (lowest < setup.stock_max[2])
    return {
        "rapids_below_top": int(low.sum()),
        "gouge_mm": round(report.max_gouge, 3),
        "rapids_in_stock": len(crashes),
        "worst_rapid_mm": round(max((c.depth for c in crashes), default=0.0), 2),
        "deepest_cut_mm": {f"T{e.tool}": round(e.max_depth, 2) for e in report.engagement},
        "faults": sorted({f"{f.kind}:T{f.tool}" for f in report.faults}),
        "plunges": plunges(moves, sw.engagement, tools),
        "left_max_mm": round(report.remaining_max, 2),
        "left_mean_mm": round(report.remaining_mean, 2),
    }


#: The peer "made safe" (issue 32, on parts with freeform, where FreeCAD's ball cuts deep): the Adaptive lifts
#: this much on its links inside cleared stock (FreeCAD's ``LiftDistance``, 0 by default) [mm], and the 3D
#: surface goes down in layers this far apart ("Multi-pass"), so the ball never takes more [mm].
SAFE_LIFT_MM = 1.0
SAFE_BALL_STEPDOWN_MM = 1.0
#: The FreeCAD program's groups of operations (benchmarks/freecad_peer_job.py posts each on its own too).
GROUPS = ("adaptive", "face", "profile", "surface")


def opencamlib_folder() -> str | None:
    """The folder of OpenCAMLib's ``ocl`` module (PyPI ``opencamlib``, the ``bench`` extra), which FreeCAD's
    3D surface imports; None when it is not installed."""
    spec = importlib.util.find_spec("opencamlib")
    return None if spec is None or spec.origin is None else str(Path(spec.origin).parent)


@dataclass(frozen=True)
class PeerTools:
    """Which of our op 1's tools FreeCAD's operations use, with their cutting data and stock left."""

    rough: Operation  # our first roughing operation: tool and cutting data of the Adaptive
    finish: Operation  # our first flats-and-walls finish (else the roughing): the face pass and profiles
    ball: Operation | None  # our first ball finish on freeform: the 3D surface; None: no surface
    ball_stepover: float  # our freeform raster's stepover [mm] (0 without a ball)


def peer_tools(job) -> PeerTools:
    """The operations of our op 1 whose tools and cutting data FreeCAD's program takes."""
    rough = next(op for op in job.operations if op.kind == "roughing")
    finish = next((op for op in job.operations if op.kind == "finishing"), rough)
    ball = next((op for op in job.operations if op.kind in ("raster", "waterline") and op.tool.shape == "ball"), None)
    scallop = PlanOptions().freeform_scallop
    stepover = stepover_for(ball.tool, scallop) if ball is not None and scallop is not None else 0.0
    return PeerTools(rough, finish, ball, stepover)


def freecad_program(freecad: str, triangles: np.ndarray, setup: Setup, peer: PeerTools, folder: Path,
                    timeout: float, safe: bool = False) -> tuple[dict[str, str], dict]:
    """FreeCAD's program for the part with our op 1's tools and cutting data (benchmarks/freecad_peer_job.py).

    Returns the posted programs, the whole one under ``"all"`` and each group of operations under its
    name (:data:`GROUPS`), and the job's own report. ``safe``: the variant made safe (:data:`SAFE_LIFT_MM`,
    :data:`SAFE_BALL_STEPDOWN_MM`). ``timeout`` [s] for ``freecadcmd``; RuntimeError when it fails or
    runs out of time, or when the surface needs OpenCAMLib and it is not installed.
    """
    import trimesh

    ocl = opencamlib_folder()
    if peer.ball is not None and ocl is None:
        raise RuntimeError("FreeCAD's 3D surface needs OpenCAMLib: pip install '.[bench]'")
    stl, gcode = folder / "part.stl", folder / "freecad.ngc"
    mesh = trimesh.Trimesh(**trimesh.triangles.to_kwargs(triangles))
    mesh.merge_vertices()
    mesh.export(stl)
    ops = [op for op in (peer.rough, peer.finish, peer.ball) if op is not None]
    tools = {op.tool.number: {"number": op.tool.number, "diameter": op.tool.diameter,
                              "flute_length": op.tool.flute_length, "length": op.tool.length,
                              "spindle_rpm": op.cutting.spindle_rpm, "feed": op.cutting.feed,
                              "plunge_feed": op.cutting.plunge_feed} for op in reversed(ops)}
    job = {"stl": str(stl), "gcode": str(gcode), "stock_min": [float(v) for v in setup.stock_min],
           "stock_max": [float(v) for v in setup.stock_max], "floor_z": float(setup.floor_z),
           "tools": list(tools.values()), "rough": peer.rough.tool.number, "finish": peer.finish.tool.number,
           "ball": None if peer.ball is None else peer.ball.tool.number, "allowance": peer.rough.allowance,
           "ball_stepover": peer.ball_stepover, "ocl": ocl,
           "lift": SAFE_LIFT_MM if safe else 0.0, "ball_stepdown": SAFE_BALL_STEPDOWN_MM if safe else None}
    try:
        run = subprocess.run([freecad, str(JOB_SCRIPT)], env={**os.environ, "FACTORY_PEER_JOB": json.dumps(job)},
                             capture_output=True, text=True, cwd=folder, timeout=timeout)
    except subprocess.TimeoutExpired:
        raise RuntimeError(f"freecadcmd did not finish in {timeout:g} s") from None
    last = [ln for ln in run.stdout.splitlines() if ln.startswith("{")]
    if run.returncode != 0 or not last or not gcode.exists():
        tail = (run.stdout + run.stderr).strip().splitlines()[-3:]
        raise RuntimeError(f"freecadcmd failed: {' | '.join(tail)}")
    texts = {"all": gcode.read_text()}
    for name in GROUPS:
        part = gcode.with_suffix(f".{name}.ngc")
        if part.exists():
            texts[name] = part.read_text()
    return texts, json.loads(last[-1])


def peer_row(freecad: str, triangles: np.ndarray, setup: Setup, peer: PeerTools, tools: dict[int, Tool],
             cell: float, timeout: float, safe: bool, keep: Path | None, stem: str) -> dict:
    """FreeCAD's program for one part timed by our timer (whole and per group [min]) and judged."""
    with tempfile.TemporaryDirectory(prefix="freecad_peer_") as tmp:
        t0 = time.perf_counter()
        texts, made = freecad_program(freecad, triangles, setup, peer, Path(tmp), timeout, safe)
        seconds = time.perf_counter() - t0
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"{stem}{'.safe' if safe else ''}.ngc").write_text(texts["all"])
    used = {op.tool.number: op.tool for op in (peer.rough, peer.finish, peer.ball) if op is not None}
    return {
        "min": round(program_minutes(texts["all"]), 2),
        "groups_min": {name: round(group_minutes(texts[name]), 2) for name in GROUPS if name in texts},
        "ops": [f"{o['group']} {o['name']} Z{o['start_z']:g}>{o['final_z']:g}" for o in made["ops"]],
        "freeform_faces": made["freeform_faces"],
        "judged": judge(texts["all"], {**tools, **used}, setup, triangles, cell),
        "seconds": round(seconds, 1),
    }


def bench_part(path: Path, freecad: str, cell: float, keep: Path | None = None, timeout: float = 900.0) -> dict:
    # Op 1 exactly as `factory plan --no-robot` posts it (two operations: op 1 on the stock that leaves op 2 its
    # holding block), so the figure is the program a machinist would run, not a one-operation variant of it.
    t0 = time.process_time()
    plan = plan_part(dataclasses.replace(PlanRequest.defaults(path, "aluminium"), robot=False))
    plan_cpu = time.process_time() - t0
    job, program, part = plan.planned.job, plan.program, plan.planned.part_work
    setup = job.setup  # op 1's stock and floor: FreeCAD gets the same
    tools = {t.number: t for t in job.tools}
    triangles = np.asarray(part.triangles, dtype=np.float64)
    peer = peer_tools(job)
    rough_s = sum(e.cut_time + e.rapid_time for e, op in zip(program.estimates, job.operations)
                  if op.kind in ROUGHING_KINDS)
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        (keep / f"{path.stem}.nc").write_text(program.text)
    full = peer_row(freecad, triangles, setup, peer, tools, cell, timeout, False, keep, path.stem)
    safe = (peer_row(freecad, triangles, setup, peer, tools, cell, timeout, True, keep, path.stem)
            if peer.ball is not None else None)
    ours_min = program_minutes(program.text)
    bound = lower_bound(path)
    row = {
        "part": path.stem,
        "tools": {role: f"T{op.tool.number} {op.tool.name}, S{round(op.cutting.spindle_rpm)} F{op.cutting.feed:.0f}"
                  for role, op in (("adaptive", peer.rough), ("face+profile", peer.finish), ("surface", peer.ball))
                  if op is not None},
        "ball_stepover_mm": round(peer.ball_stepover, 3),
        "ours_min": round(ours_min, 2),
        "ours_estimate_min": round(program.total_time / 60.0, 2),
        "ours_rough_min": round(rough_s / 60.0, 2),
        "freecad_min": full["min"],
        "ratio": round(ours_min / full["min"], 2),
        "rough_ratio": round(rough_s / 60.0 / full["groups_min"]["adaptive"], 2),
        "bound_min": round(bound, 2),
        "ours_bound_ratio": round(ours_min / bound, 2),
        "freecad_bound_ratio": round(full["min"] / bound, 2),
        "freecad": full,
        "ours_judged": judge(program.text, tools, setup, triangles, cell),
        "plan_cpu_s": round(plan_cpu, 1),
    }
    if safe is not None:
        row.update(freecad_safe_min=safe["min"], ratio_safe=round(ours_min / safe["min"], 2), freecad_safe=safe)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("parts", nargs="*", type=Path)
    ap.add_argument("--cell", type=float, default=0.5, help="grid of verify and the sweep [mm]")
    ap.add_argument("--keep", type=Path, help="folder to write the programs to (PART.nc ours, PART.ngc and PART.safe.ngc FreeCAD's)")
    ap.add_argument("--timeout", type=float, default=900.0, help="for FreeCAD per part [s]")
    args = ap.parse_args()
    freecad = shutil.which("freecadcmd")
    if freecad is None:
        print("freecad_peer: skipped: freecadcmd (Debian's freecad 0.20) is not installed")
        return
    parts = args.parts or [ROOT / "samples" / f"{name}.stl" for name in SAMPLES]
    rows, failed = [], {}
    for p in parts:
        try:
            row = bench_part(p, freecad, args.cell, args.keep, args.timeout)
        except RuntimeError as exc:
            failed[p.stem] = str(exc)
            print(json.dumps({"part": p.stem, "error": str(exc)}), flush=True)
            continue
        rows.append(row)
        print(json.dumps(row), flush=True)
    ratios = [r.get("ratio_safe", r["ratio"]) for r in rows]
    print(json.dumps({"summary": {
        "parts": len(rows), "failed": failed,
        # Against the program made safe where there is one (the target's comparison on the dome).
        "ratio_min": min(ratios, default=None), "ratio_max": max(ratios, default=None),
        "ours_min": round(sum(r["ours_min"] for r in rows), 2),
        "freecad_min": round(sum(r["freecad_min"] for r in rows), 2),
        "freecad_plunges": sum(r["freecad"]["judged"]["plunges"] for r in rows),
        "freecad_rapids_in_stock": sum(r["freecad"]["judged"]["rapids_in_stock"] for r in rows),
        "ours_plunges": sum(r["ours_judged"]["plunges"] for r in rows),
        "ours_rapids_in_stock": sum(r["ours_judged"]["rapids_in_stock"] for r in rows),
    }}), flush=True)


if __name__ == "__main__":
    main()
