"""The verify stage: a program simulated against its part, as ``factory verify`` and ``factory plan`` run it."""

from __future__ import annotations

import dataclasses
import json
import logging
import multiprocessing
import os
import pickle
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cadcam.gcode import parse_gcode
from cadcam.mesh import load_planned_part
from cadcam.relief import machining_surface, surface_footprint
from cadcam.model import Job, Operation, ProgramMoves, Setup, Tool
from cadcam.arcs import fit_segments
from cadcam.parallel import MIN_SPAN, Background, IdleMeter, processors
from cadcam.post import POSTED_PARAMETERS, FitAhead, PostOptions, Program, operations_end, post_process
from cadcam.rest import from_and_to_safe_height
from cadcam.sheet import SheetSetup, read_setup_sheet
from cadcam.preview import deviation_image
from cadcam.cutahead import CutState
from cadcam.stock import FOR_OP2, OUTSIDE_RELIEF, Simulation, flip_stock
from cadcam.verify import (VerifyOptions, VerifyReport, VerifyResult, chip_loads, finishing_moves, simulate,
                           simulate_flipped, verify_ahead, with_op1_left)
from factory.core.atomic import write_bytes, write_text
from factory.core.errors import SetupError
from factory.core.setupsheet import SetupSheet
from factory.pictures import png_bytes
from factory.mcaplog import McapLog
from factory.rosmsgs import triangle_mesh_marker_array
from factory.core.progress import Progress, stage_callback
from factory.views import heightfield_mesh

log = logging.getLogger(__name__)

def read_sheet(path: Path) -> SheetSetup:
    """The sheet, its setup and its tool table, of a setup sheet file."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SetupError(f"cannot read setup sheet: {e}", source=path) from None
    return read_setup_sheet(SetupSheet.from_json(data, source=str(path)), source=str(path))


def part_triangles(part: Path, setup: Setup, expected_sha256: str = "", intake: Mapping[str, Any] | None = None,
                   tolerance: float | None = None) -> np.ndarray:
    """The part's triangles in work coordinates [mm], placed as the setup sheet says (a relief on its base).

    ``intake``: the sheet's (a STEP part's unit, solid and tessellation tolerance); ``tolerance``
    [mm]: a STEP part is tessellated to this CAM tolerance instead (verify's gouge tolerance), see
    :func:`cadcam.mesh.load_planned_part`."""
    loaded = load_planned_part(part, setup.mesh_scale, intake, tolerance=tolerance, source="setup sheet")
    if expected_sha256 and loaded.sha256 != expected_sha256:
        log.warning("%s differs from the part the program was made for (sha256 mismatch)", part)
    mesh = loaded.mesh.copy()
    mesh.apply_transform(setup.transform_mesh_to_work)
    if loaded.surface is not None:  # a relief: the surface on its base, as it was planned against
        mesh = machining_surface(mesh, setup)
    return np.asarray(mesh.triangles)


def run_verify(gcode_text: str, gcode_source: str, setup: Setup, tools: dict[int, Tool],
               triangles: np.ndarray, options: VerifyOptions, progress: Progress | None = None,
               operations: Sequence[Mapping[str, Any]] = (), resume: CutState | None = None,
               moves: ProgramMoves | None = None) -> VerifyResult:
    """Parse and simulate a program against the part (``triangles`` in work coordinates [mm]);
    ``operations`` are the setup sheet's, which tell finishing tools from roughing ones where the
    program's own operation comments do not, and each tool's chip load (:func:`cadcam.verify.chip_loads`).
    ``resume``: the program's first moves cut already
    (:class:`VerifyAhead`), gone on from where they are this program's; the result is the same.
    ``moves``: this text parsed already (:meth:`VerifyAhead.posted`), read as from ``gcode_source``.

    Raises
    ------
    GcodeError
        The program cannot be parsed.
    VerifyError
        The simulation cannot run on its inputs (a tool missing from ``tools``, ...).
    """
    moves = (parse_gcode(gcode_text, source=gcode_source) if moves is None
             else dataclasses.replace(moves, source=gcode_source))
    finishing = finishing_moves(gcode_text, moves, operations)
    return simulate(moves, tools, setup, triangles, options, progress=stage_callback(progress, "verify"),
                    finishing=finishing, resume=resume, chips=chip_loads(operations))


#: Niceness added to a round of :class:`VerifyAhead`: it takes a processor the planning leaves idle, not one
#: the planner, its arc fitting or the robot's planning would use.
AHEAD_NICENESS = 5
#: Processors the machine must have left idle since the last look (:class:`cadcam.parallel.IdleMeter`) for a
#: round of :class:`VerifyAhead` to begin: half of one, so at least half a processor's time is there for it.
AHEAD_IDLE = 0.5
#: A round verify waits for that runs on less than this share of a processor [processors] is ended and verify
#: cuts its operations itself (:meth:`VerifyAhead.state`): the share a round begins with (:data:`AHEAD_IDLE`).
OVERTAKE_BELOW = AHEAD_IDLE


class VerifyAhead:
    """Op 1's verify begun while the planner plans its later operations, on a processor it leaves idle.

    Each time more operations are planned (:func:`cadcam.plan.plan_job`'s ``on_operations``) and no round
    is under way, a round starts in a forked process of lower priority (:data:`AHEAD_NICENESS`): it fits
    the arcs of the operations new since the last round (kept for posting, :meth:`cadcam.post.FitAhead.know`:
    they are not fitted twice), posts the operations so far, and cuts that program's moves into verify's
    stock model, on from the last round's state (:func:`cadcam.verify.verify_ahead`). The last ones (planned
    as the rapid check starts, :meth:`offer_all`) start a round too. Operations planned while a round is
    under way are fitted as :class:`cadcam.post.FitAhead` fits them, each in a process of its own.

    Verify resumes from the last state whose operations the job still holds as they were (:meth:`state`);
    :func:`cadcam.stock.cut_stock` checks it move by move and cuts from the first move where it does not
    hold (the rapid check changed an operation): the outputs are those of verify from the first move.
    With one processor (``FACTORY_THREADS=1``) or no ``fork`` nothing is begun ahead, and a round starts only
    where the machine left :data:`AHEAD_IDLE` processors idle since the last look (:class:`IdleMeter`: the
    seconds before, not the load average's minute, which counts the plan's own robot and workers a minute
    after they end); the rounds' own time counts idle. A round runs at lower priority, so on a machine other
    work keeps busy it would hardly advance: verify waits for it only while it runs (:meth:`_keeps_up`).
    """

    def __init__(self, fits: FitAhead, post: PostOptions, options: VerifyOptions, triangles: np.ndarray,
                 part_name: str = "ahead", source_sha256: str = ""):
        self.fits, self.post, self.options, self.triangles = fits, post, options, triangles
        self.part_name, self.source_sha256 = part_name, source_sha256  # the job's, posted as it will be
        self._setup: Setup | None = None  # the setup of the round under way
        self._posted: tuple[Setup, Program, ProgramMoves] | None = None  # the last round's program, its moves
        self.enabled = processors() >= 2 and "fork" in multiprocessing.get_all_start_methods()
        self._covered: list[Operation] = []  # the operations of the rounds made and under way, in order
        self._states: list[tuple[int, CutState]] = []  # (operations cut, state after them), in order
        self._round: Background | None = None
        self._from = 0  # the first operation new in the round under way
        self._meter = IdleMeter()
        self._spent = 0.0  # processor time [s] of the rounds ended since the meter's last look

    def offer(self, operations: Sequence[Operation], setup: Setup) -> None:
        """More operations planned (all so far, in cutting order): a round on the new ones when none is
        under way; the rest fitted in processes of their own."""
        # as the rapid check hands them on, without those the job drops
        ops = [from_and_to_safe_height(op, setup.safe_z) for op in operations if len(op.points) >= 2]
        if self.enabled:
            self._collect(wait=False)
            if self._round is None:
                self._start(ops, setup)
        self.fits.offer(ops[len(self._covered):])

    def offer_all(self, operations: Sequence[Operation], setup: Setup) -> None:
        """Every operation planned, the rapid check next: offered as :meth:`offer` does. A round begun here
        holds up the post (it fits the operations it cuts), but it cuts them while the rapid check runs, and
        the rapid check rarely changes an operation (none of the samples'): the cut verify would make after
        the post is made meanwhile on the processor the rapid check leaves idle."""
        self.offer(operations, setup)

    def state(self, operations: Sequence[Operation]) -> CutState | None:
        """The state verify of the job's ``operations`` (as posted) resumes from: the round under way waited
        for when the job holds its operations as they were and the round keeps up (:meth:`_keeps_up`; else it
        is ended and verify cuts its operations), then the last state whose operations it holds; None without
        one."""
        if self._round is not None:
            if _holds(operations, self._covered) and self._keeps_up():
                self._collect(wait=True)
            else:  # not these operations, or verify cuts them sooner itself: the round's are cut by verify
                self.cancel()
                self._covered = self._covered[:self._from]
        for n, state in reversed(self._states):
            if _holds(operations, self._covered[:n]):
                return state
        return None

    def posted(self, job: Job) -> tuple[Program, ProgramMoves] | None:
        """The program the last round posted and its moves, where they are ``job``'s (after :meth:`state`): a
        round of all its operations, the same to the bit, its name, source and setup, and no parameter the post
        reads (:data:`cadcam.post.POSTED_PARAMETERS`); None otherwise, and the post and verify make them."""
        if self._posted is None or self._round is not None:
            return None
        setup, program, moves = self._posted
        ops = self._covered
        if (job.setup is not setup or job.part_name != self.part_name or job.source_sha256 != self.source_sha256
                or any(k in job.parameters for k in POSTED_PARAMETERS) or len(job.operations) != len(ops)
                or any(a is not b and pickle.dumps(a) != pickle.dumps(b) for a, b in zip(job.operations, ops))):
            return None
        return program, moves

    def _keeps_up(self) -> bool:
        """Whether the round under way answers, waited for while it runs on :data:`OVERTAKE_BELOW` processor or
        more: its work is the work verify would do (and the post: it fits the operations), begun earlier. One
        that gets less (the machine's other work came back, and it runs niced) would keep verify waiting longer
        than verify takes to fit and cut its operations itself: False then, within :data:`MIN_SPAN`."""
        had, at = self._round.processor_time(), time.monotonic()
        while not self._round.ready(wait=MIN_SPAN):
            now, then = self._round.processor_time(), time.monotonic()
            if had is not None and now is not None and now - had < OVERTAKE_BELOW * (then - at):
                log.info("verify ahead ended: it ran on %.2f processor; verify cuts its operations itself",
                         (now - had) / (then - at))
                return False
            had, at = now, then
        return True

    def cancel(self) -> None:
        """End the round under way (the plan failed, or it is not wanted)."""
        if self._round is not None:
            self._round.cancel()
            self._round = None

    def _start(self, ops: list[Operation], setup: Setup) -> None:
        idle = self._meter.idle(own=self._spent)
        if idle is None:  # too soon to tell: the next offer looks again
            return
        self._spent = 0.0
        if idle < AHEAD_IDLE:  # no processor to run it on: the next offer looks again
            return
        n0 = len(self._covered)
        if not _holds(ops, self._covered):  # an operation changed after it was cut ahead: no more rounds
            self.enabled = False
            return
        new: list[Operation] = []
        known = []
        for op in ops[n0:]:
            fit = self.fits.fitted(op)
            if fit is None and self.fits.started(op):
                break  # being fitted in a process of its own: the next round takes it, fitted
            new.append(op)
            known.append(fit)
        if not new:
            return
        last = self._states[-1][1] if self._states else None
        self._covered = ops[:n0 + len(new)]
        self._from = n0
        self._setup = setup
        self._round = Background(_verify_round, tuple(self._covered), n0, tuple(known), setup, self.fits, self.post,
                                 self.options, self.triangles, last, self.part_name, self.source_sha256)

    def _collect(self, wait: bool) -> None:
        if self._round is None or not (wait or self._round.ready()):
            return
        ok, value = self._round.outcome()
        self._round = None
        new = self._covered[self._from:]
        if not ok:  # the round failed: its operations are fitted as the others, and no more rounds
            log.info("verify ahead of %d operation(s) failed: verify cuts them itself", len(new))
            self._covered = self._covered[:self._from]
            self.enabled = False
            return
        fitted, cut, spent, posted = value
        self._spent += spent
        for op, seg in zip(new, fitted):
            self.fits.know(op, seg)
        if cut is not None:
            self._states.append((len(self._covered), cut))
        self._posted = (self._setup, *posted)


def _holds(operations: Sequence[Operation], cut: Sequence[Operation]) -> bool:
    """``operations`` begin with ``cut``, each with the same tool, cutter locations and motion."""
    return len(operations) >= len(cut) and all(
        a.tool.number == b.tool.number and a.points.shape == b.points.shape and np.array_equal(a.points, b.points)
        and np.array_equal(a.motion, b.motion) for a, b in zip(operations, cut))


def _verify_round(ops: tuple[Operation, ...], n0: int, known: tuple, setup: Setup, fits: FitAhead,
                  post: PostOptions, options: VerifyOptions, triangles: np.ndarray, state: CutState | None,
                  part_name: str, source_sha256: str
                  ) -> tuple[list, CutState | None, float, tuple[Program, ProgramMoves]]:
    """One round of :class:`VerifyAhead`, in its process: the fits of ``ops[n0:]`` and the verify cut of the
    program of ``ops`` (on from ``state``), up to the end of its last operation; the processor time it took [s];
    the program of ``ops`` posted as the job named so (``part_name``, ``source_sha256``) is, and its moves: the
    job's own, where ``ops`` are all of its operations."""
    os.nice(AHEAD_NICENESS)
    began = time.process_time()
    fitted = []
    for op, fit in zip(ops[n0:], known):
        if fit is None:
            fit = fit_segments(op.points, op.motion, fits.fit)
        fits.know(op, fit)  # this process's copy: posted below without fitting again
        fitted.append(fit)
    program = post_process(Job(part_name, setup, ops, source_sha256), post, ahead=fits)
    moves = parse_gcode(program.text, source="verify ahead")
    # the moves of the program's ending (a longer job's would be elsewhere) are not cut ahead
    before = int(np.searchsorted(moves.line, operations_end(program, post), side="right"))
    tools = {op.tool.number: op.tool for op in ops}
    cut = verify_ahead(moves, tools, setup, triangles, options, before=before, resume=state)
    return fitted, cut, time.process_time() - began, (program, moves)


def run_verify_after(before: Simulation, flip: np.ndarray, gcode_text: str, gcode_source: str, setup: Setup,
                     tools: dict[int, Tool], triangles: np.ndarray, options: VerifyOptions,
                     progress: Progress | None = None,
                     operations: Sequence[Mapping[str, Any]] = (), op1: VerifyReport | None = None) -> VerifyResult:
    """:func:`run_verify` of op 2: starting from ``before`` (op 1's simulated stock, on a grid of
    ``options.cell``) turned over by ``flip`` (op-1 -> op-2 work transform [mm]) into ``setup``. With
    ``op1``, op 1's verdict, the stock op 1 left on the part and op 2 did not cut away is op 2's too
    (:func:`cadcam.verify.with_op1_left`): op 2's verdict is the finished part's.

    Raises
    ------
    GcodeError, VerifyError
        As :func:`run_verify`; VerifyError also when the stock does not turn over onto ``setup``.
    """
    moves = parse_gcode(gcode_text, source=gcode_source)
    finishing = finishing_moves(gcode_text, moves, operations)
    start = flip_stock(before, flip, setup)
    verified = simulate_flipped(moves, tools, setup, triangles, start, options,
                                progress=stage_callback(progress, "verify op 2"), finishing=finishing,
                                chips=chip_loads(operations))
    if op1 is None:
        return verified
    return VerifyResult(verified.simulation, with_op1_left(verified.report, op1, verified.simulation, flip))


def op1_of(sheet: SetupSheet, sheet_path: Path, after: Path | None) -> tuple[Path, Path] | None:
    """Op 1's program and setup sheet an op-2 setup sheet runs after, or None for an op-1 sheet.

    The op-2 sheet names them (``after``) relative to its own folder; ``after`` (the command
    line's ``--after``) overrides the program, its sheet staying the named one.

    Raises
    ------
    SetupError
        ``after`` given for a sheet that is not op 2's, or an op-2 sheet without ``after``.
    """
    if sheet.op != 2:
        if after is not None:
            raise SetupError("--after is for op 2: this setup sheet is op 1's", source=sheet_path)
        return None
    named = sheet.after
    if not isinstance(named, Mapping) or not isinstance(named.get("setup_sheet"), str):
        raise SetupError("op-2 setup sheet does not name op 1's setup sheet ('after')", source=sheet_path)
    program = after if after is not None else sheet_path.parent / str(named.get("program", ""))
    return program, sheet_path.parent / named["setup_sheet"]


def flip_of(sheet: SetupSheet, sheet_path: Path) -> np.ndarray:
    """The op-1 -> op-2 work transform an op-2 setup sheet records [mm], (4, 4).

    Raises
    ------
    SetupError
        Missing or not a 4 x 4 matrix.
    """
    try:
        t = np.asarray(sheet.flip["transform_op1_to_op2"], dtype=np.float64).reshape(4, 4)
    except (KeyError, TypeError, ValueError):
        raise SetupError("op-2 setup sheet lacks the flip transform ('flip.transform_op1_to_op2')",
                         source=sheet_path) from None
    return t


def log_simulation(mcap: McapLog, sim: Simulation) -> None:
    """The simulated stock as a mesh in work coordinates (metres) on ``/verify/stock``."""
    top = sim.stock_top if sim.stock_under is None else np.where(np.isfinite(sim.stock_top), sim.stock_top,
                                                                   sim.stock_under)  # cut through: drawn at its bottom
    vertices, faces = heightfield_mesh(sim.grid.xs, sim.grid.ys, top)
    stock = triangle_mesh_marker_array("verify_stock", 0, vertices / 1000.0, faces, (0.75, 0.75, 0.8, 1.0), "work", 0)
    mcap.write_cdr("/verify/stock", stock.typename, stock.cdr, 0, stock.make, latched=True)


#: Regions of stock left that :func:`report_text` names one by one; the report lists them all.
LEFT_SHOWN = 5


def report_text(report: VerifyReport) -> str:
    """The verdict in a few lines: gouge, remaining stock, rapid crashes, each fault with its lines, and
    each region of stock left with its place and size. Its first line never says OK over stock left: stock op 2
    takes from below is named as such after op 1's OK."""
    if not report.ok:
        verdict = "verify FAILED"
    elif report.on_part:
        n = len(report.on_part)
        verdict = (f"verify: no gouge or crash, but stock left in {n} region{'s' if n > 1 else ''}, up to "
                   f"{report.on_part[0].depth:.2f} mm")
    else:
        verdict = f"verify OK, finished to {report.left_above:g} mm"
    # op 1 is done with what op 2 machines from below, but the part is not: said, not hidden
    for_op2 = sum(u.why == FOR_OP2 for u in report.left)
    if report.ok and for_op2:
        verdict += f" except {for_op2} region{'s' if for_op2 > 1 else ''} left for op 2"
    # The grid's figures are named as the grid's: a corner's sliver is finer than a cell, so beside
    # "stock left up to 12 mm" a bare "remaining stock max 0.005" read as a contradiction.
    text = (f"{verdict}: max gouge {report.max_gouge:.4f} mm, stock over the {report.cell:g} mm grid max "
            f"{report.remaining_max:.3f} / mean {report.remaining_mean:.3f} / p95 {report.remaining_p95:.3f} mm, "
            f"{len(report.rapid_crashes)} rapid crash(es)")
    # a relief's uncut rim is the block round it, left by design: in the JSON report, named, not listed here
    shown = [u for u in report.left if u.why != OUTSIDE_RELIEF]
    for u in shown[:LEFT_SHOWN]:
        text += f"\n  left: {u.describe()}"
    if len(shown) > LEFT_SHOWN:
        text += f"\n  and {len(shown) - LEFT_SHOWN} more regions of stock left (all in the report)"
    if report.gouged and report.gouge_line is not None:
        text += f"\n  gouge: {report.max_gouge:.3f} mm into the part, line {report.gouge_line}"
    for f in report.faults:
        text += f"\n  {f.kind}: {f.message}" + (f", line(s) {line_ranges(f.lines)}" if f.lines else "")
    for e in report.engagement:
        text += f"\n  engagement {e.describe()}"
    return text


def line_ranges(lines: Sequence[int], most: int = 12) -> str:
    """``1203-1210, 1304`` for program lines; at most ``most`` runs, then how many more lines."""
    runs: list[list[int]] = []
    for n in lines:
        if runs and n <= runs[-1][1] + 1:
            runs[-1][1] = n
        else:
            runs.append([n, n])
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:most])
    rest = sum(b - a + 1 for a, b in runs[most:])
    return text + (f" and {rest} more" if rest else "")


def write_verify_outputs(sim: Simulation, report: VerifyReport, *, png: Path | None, json_path: Path | None,
                         mcap: Path | None, overwrite: bool, inputs: dict[str, str],
                         relief: np.ndarray | None = None) -> None:
    """The report as JSON, the deviation picture, the simulated stock in MCAP: each where asked.

    ``relief``: the (m, 3, 3) triangles [mm, work] a relief was verified against (its machining
    surface): the picture's colour scale is clipped to the relief's own surface."""
    if png is not None:
        on_part = None if relief is None else surface_footprint(relief, sim.grid)
        write_bytes(png, png_bytes(deviation_image(sim, report, on_part=on_part)), overwrite=overwrite)
    if mcap is not None:
        with McapLog(mcap, stage="verify", overwrite=overwrite, inputs=inputs) as m:
            log_simulation(m, sim)
    if json_path is not None:
        write_text(json_path, json.dumps(report.to_dict(), indent=2) + "\n", overwrite=overwrite)

