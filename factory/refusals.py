"""What ``factory plan`` can refuse without CAM work, refused before it: each error names the fix.

:func:`check_request` runs first in :func:`factory.plan.plan_part`: the cell file, its robot, and
the robot program language against the arm. :func:`check_setup` runs once the part is placed in
its stock, before any toolpath (``check_setup`` of :func:`factory.cam.compute_job`): the verify
grid over the stock, and the stock in the cell's vise and gripper. Both would otherwise fail
only after all the CAM work.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import trimesh

from cadcam.mesh import inch_hint
from cadcam.model import Setup, ViseJaws
from cadcam.op2 import check_op2_grip as check_grip
from cadcam.stock import check_grid_size
from cadcam.tools import MaterialData, load_tool_library
from factory.core.errors import CellError, PlanningError, SetupError
from factory.core.resources import FIXTURES
from factory.core.units import MM_PER_M
from robotprog.cell import Cell, load_cell
from robotprog.frames import check_stock_fits
from robotprog.grasp import GraspOptions, tcp_above_bottom
from robotprog.programs import LANG_MAKER, check_language
from robotprog.robots import load_robot

def check_request(cell_path: Path | None, lang: str) -> None:
    """Refuse, before any CAM work, a plan the robot half would refuse: a malformed cell file, an
    unknown robot or a home it cannot take, a program language for another maker's arm.
    ``cell_path`` None: the plan has no robot half, nothing to refuse.

    Raises
    ------
    CellError
        The cell file or its robot (the robot is loaded once: later loads are cached).
    PlanningError
        ``lang`` is another maker's; the message names the shipped cells with an arm that
        speaks it and the language this arm speaks.
    """
    if cell_path is None:
        return
    cell = load_cell(cell_path)
    robot = load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame)
    try:
        check_language(lang, robot)
    except PlanningError as e:
        fixes = [f"--cell {_shown(c)}" for c in shipped_cells(LANG_MAKER[lang])]
        fixes += [f"--lang {lang}" for lang, maker in LANG_MAKER.items() if maker == robot.maker]
        raise PlanningError(f"{e}: plan with {' or '.join(fixes) or 'a cell with such an arm'}",
                            source=_shown(cell_path)) from None


def check_setup(setup: Setup, grid: float, part: Path, cell_path: Path | None,
                part_work: trimesh.Trimesh | None = None, units: str = "mm", tools: Path | None = None) -> None:
    """Refuse, once the part is placed in its stock and before any toolpath, what verify and the
    robot would refuse: a verify grid too fine for the stock, a stock the cell's vise cannot clamp,
    its gripper cannot hold or its robot cannot carry (:func:`check_stock_mass`), a part
    (``part_work`` [mm], None for a relief, which leaves in its block) too thin for the gripper to
    take out. ``grid``: verify's cell size [mm]; ``cell_path`` None: no robot; ``units``: the
    ``--units`` the part was read in (a part too small when its units were guessed gets the hint
    to give ``--units inch``); ``tools``: the tool library holding the material's density (None:
    the bundled one).

    Raises
    ------
    VerifyError
        Too many verify grid cells over the stock (the message gives the figure).
    CellError
        The stock [mm] does not fit the vise's jaw opening or the gripper, or does not stand above
        the jaws; the message names the cell's field and the options that change the stock.
    PlanningError
        The part is too thin to grip (``source`` the part file).
    """
    check_grid_size(setup, grid, source=str(part))
    if cell_path is None:
        return
    cell = load_cell(cell_path, check_robot=False)
    try:
        check_stock_fits(np.asarray(setup.stock_size, dtype=float) / MM_PER_M, cell.vise.jaw_opening_min,
                         cell.vise.jaw_opening_max, cell.vise.grip_depth, cell.gripper.opening_max)
    except CellError as e:
        raise CellError(f"{e}: give a --stock (or --holding) that fits, or a --cell whose vise and gripper take it",
                        source=_shown(cell_path)) from None
    check_stock_mass(setup, cell, load_tool_library(tools).material(setup.material), cell_path)
    if part_work is None:
        return
    size = np.ptp(np.asarray(part_work.vertices), axis=0)
    try:
        # the unload's grasp (robotprog.tending), with the options plan_cell takes by default
        tcp_above_bottom(cell, float(size[2]) / MM_PER_M, GraspOptions(), "part")
    except PlanningError as e:
        hint = inch_hint(float(size.max()), units, setup.mesh_scale)
        raise PlanningError(f"{e.message}; {hint}" if hint else e.message, source=str(part)) from None


def check_op2_grip(setup: Setup, part_work: trimesh.Trimesh | None, jaws: ViseJaws | None, part: Path,
                   tools: Path | None = None) -> None:
    """Refuse, before any toolpath, a part op 2 would have to cut where its jaws hold it
    (:func:`cadcam.op2.check_op2_grip`). Nothing is checked without op 2's vise (``jaws`` None:
    no cell, or op 1 only) or for a relief (``part_work`` None: it stays in its block).

    Raises
    ------
    SetupError
        With the figures and the fixes, ``source`` the part file.
    """
    if jaws is None or part_work is None:
        return
    try:
        check_grip(part_work, setup, jaws, load_tool_library(tools))
    except SetupError as e:
        raise SetupError(e.message, source=str(part)) from None


def check_stock_mass(setup: Setup, cell: Cell, material: MaterialData, cell_path: Path) -> None:
    """Refuse a stock block heavier than the robot carries with its gripper: the cell's
    ``robot.payload`` [kg] less ``gripper.mass`` [kg], the stock's mass from its size [mm] and the
    material's density [g/cm³]. Nothing is checked without a payload or a density.

    Raises
    ------
    CellError
        The stock is too heavy; the message gives its size, density, mass and what the robot carries.
    """
    mass = material.mass_kg(float(np.prod(setup.stock_size)))
    payload = cell.robot.payload
    if mass is None or payload is None:
        return
    carries = payload - cell.gripper.mass
    if mass > carries:
        x, y, z = (float(v) for v in setup.stock_size)
        raise CellError(f"robot.payload: stock {x:.1f} x {y:.1f} x {z:.1f} mm of {material.name} "
                        f"({material.density:g} g/cm³) weighs {mass:.2f} kg, over the {carries:.2f} kg the robot "
                        f"carries ({payload:g} kg payload less the {cell.gripper.mass:g} kg gripper): give a smaller "
                        f"--stock, a lighter --material, or a --cell whose robot carries it", source=_shown(cell_path))


def shipped_cells(maker: str) -> list[Path]:
    """The cell files shipped in ``fixtures/`` whose arm is ``maker``'s (``"ABB"``, ...)."""
    found = []
    for path in sorted(FIXTURES.glob("cell*.yaml")):
        cell = load_cell(path, check_robot=False)
        if load_robot(cell.robot.model, flange_frame=cell.robot.flange_frame).maker == maker:
            found.append(path)
    return found


def _shown(path: Path) -> str:
    """``path`` as a user would type it here: relative to the working folder when inside it."""
    path = Path(path)
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)
