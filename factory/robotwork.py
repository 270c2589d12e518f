"""The robot's share of a plan, worked out in a second process while the CAM plans the toolpaths.

What the robot does with a part depends on the cell, the stock box, where the part sits in it (the
setup) and the part's mesh, not on any toolpath. So :class:`BackgroundRobot` starts as soon as the setup
is made, in a forked process (:class:`cadcam.parallel.Background`): the cell's roadmap read, the load,
turnover and unload planned and proven, the robot program posted and proven, and then the robot's meshes
for the log read (0.4 s for the UR5's): the CAM's share is the longer now (issue 35), so they are read
where they cost the plan no wall time. Its stages show as they run
(:class:`factory.core.progress.ProgressRelay`).
:meth:`BackgroundRobot.result` takes the work once the setup sheet is posted; the robot is planned again
here if the sheet's stock is not the one the work was started for, so the answer is always the one
planning after the CAM would give.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cadcam.model import Setup
from cadcam.parallel import Background
from factory.core.errors import PlanningError
from factory.core.progress import Progress, ProgressRelay, Stopwatch
from factory.core.setupsheet import SetupSheet
from factory.tending import plan_in_cell
from robotprog.cell import Cell, load_cell
from robotprog.collision import CollisionWorld, collision_world
from robotprog.programs import PostedProgram, post_program
from robotprog.tending import TendingPlan
from robotprog.visuals import LinkVisual, robot_visuals

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RobotWork:
    """The robot's share of a plan, as its process hands it back (no collision world: it does not pickle).

    Attributes
    ----------
    ops : int
        The operations it was planned for: the ones asked, or 1 when none were asked and the robot
        cannot turn the part over (``dropped_op2`` says why).
    plan : TendingPlan
        The timed, proven moves.
    program : PostedProgram
        The robot program, its posted path proven.
    visuals : tuple of LinkVisual
        The robot's meshes for the log (:func:`robotprog.visuals.robot_visuals`).
    seconds : dict
        Wall time of its stages (``roadmap``, ``robot plan``, ``robot program``, ``robot visuals``) [s].
    dropped_op2 : str or None
        Why op 2 was dropped (the turnover's planning error), None when it was not.
    """

    ops: int
    plan: TendingPlan
    program: PostedProgram
    visuals: tuple[LinkVisual, ...]
    seconds: dict[str, float]
    dropped_op2: str | None = None


def stock_sheet(setup: Setup) -> SetupSheet:
    """The setup sheet of ``setup`` as far as the robot reads it (stock box, part placement, mesh scale
    [mm]), before any program is posted."""
    return SetupSheet(stock_min=setup.stock_min, stock_max=setup.stock_max,
                      transform_mesh_to_work=setup.transform_mesh_to_work, mesh_scale=setup.mesh_scale, tools=())


def same_stock(a: SetupSheet, b: SetupSheet) -> bool:
    """Whether the robot reads the same stock box and part placement from both sheets."""
    return (np.array_equal(a.stock_min, b.stock_min) and np.array_equal(a.stock_max, b.stock_max)
            and np.array_equal(a.transform_mesh_to_work, b.transform_mesh_to_work) and a.mesh_scale == b.mesh_scale)


@dataclass(frozen=True)
class RobotTask:
    """What the robot's share of a plan is worked out from (see :func:`robot_work`).

    Attributes
    ----------
    cell_path : Path
        The cell file (named in messages).
    sheet : SetupSheet
        Op 1's setup sheet, or :func:`stock_sheet` of its setup.
    sheet_source : str
        The sheet's file name, for messages.
    part_vertices : (n, 3) float or None
        The part (a relief: its block's corners) in mesh file units; None: the robot grips the stock box.
    ops : int
        1 or 2 setups.
    may_drop_op2 : bool
        With 2: plan op 1 alone if the robot cannot turn the part over (the user asked for no number of operations).
    lang : str
        Robot program language.
    program_path : Path
        The robot program's file (its name names the program).
    """

    cell_path: Path
    sheet: SetupSheet
    sheet_source: str
    part_vertices: np.ndarray | None
    ops: int
    may_drop_op2: bool
    lang: str
    program_path: Path


def robot_work(cell: Cell, world: CollisionWorld, task: RobotTask, progress: Progress | None = None) -> RobotWork:
    """Plan, post and prove the robot's load, turnover and unload of ``task``'s part in ``cell``, and read
    the robot's meshes for the log; stages into ``progress``.

    Raises
    ------
    PlanningError
        A move or the posted program cannot be planned collision-free (with ``may_drop_op2``: not the turnover).
    CellError
        The cell's robot cannot run the program's language, a visual mesh cannot be read.
    """
    watch = Stopwatch(progress)
    ops, dropped = task.ops, None
    try:
        plan = plan_in_cell(cell, world, task.cell_path, task.sheet, task.sheet_source, task.part_vertices, watch,
                            setups=ops)
    except PlanningError as e:
        if not (task.may_drop_op2 and ops == 2):
            raise
        # the robot cannot turn this part over on the cell's flip station: op 1 alone (said by the plan)
        ops, dropped = 1, e.message
        plan = plan_in_cell(cell, world, task.cell_path, task.sheet, task.sheet_source, task.part_vertices, watch)
    with watch("robot program"):
        program = post_program(task.lang, task.program_path, cell, world, plan)
    with watch("robot visuals"):
        visuals = robot_visuals(world.robot)
    return RobotWork(ops, plan, program, visuals, dict(watch.seconds), dropped)


class BackgroundRobot:
    """:func:`robot_work` started now in a forked process, beside the caller's CAM work.

    The cell is loaded here first (stage ``cell``), so its collision world serves the log too;
    the child inherits it. Where no second process can be had the work runs in :meth:`result`.
    """

    def __init__(self, task: RobotTask, watch: Stopwatch) -> None:
        with watch("cell"):
            self.cell = load_cell(task.cell_path)
            self.world = collision_world(self.cell)
        self.task = task
        self._watch = watch
        self._relay = ProgressRelay(watch.progress)
        self._background: Background | None = Background(robot_work, self.cell, self.world, task, self._relay)

    def result(self, sheet: SetupSheet) -> RobotWork:
        """The work, for op 1's posted setup sheet ``sheet`` (planned again here for it when its stock is
        not the one the work started with); its stages' seconds added to the caller's watch.

        Raises
        ------
        PlanningError, CellError
            As :func:`robot_work`, the same as planning it here.
        """
        background, self._background = self._background, None
        assert background is not None, "the robot's work was taken or cancelled before"
        try:
            if same_stock(self.task.sheet, sheet):
                work = background.result()
            else:  # a CAM stage changed the setup after it was made: the robot plans for the sheet's stock
                background.cancel()
                log.info("%s: the posted sheet's stock is not the setup's: the robot is planned again", sheet.part)
                work = robot_work(self.cell, self.world, dataclasses.replace(self.task, sheet=sheet), self._relay)
        finally:
            self._relay.close()
        for stage, s in work.seconds.items():
            self._watch.seconds[stage] = self._watch.seconds.get(stage, 0.0) + s
        return work

    def cancel(self) -> None:
        """End the work (the plan failed meanwhile)."""
        if self._background is not None:
            self._background.cancel()
            self._background = None
            self._relay.close()

