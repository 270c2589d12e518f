"""Where CAM's millimetres and the robot's metres cross: the ONE conversion, both ways.

The CAM stages speak millimetres in work coordinates (X right, Y away from the operator,
Z up the spindle; origin per the setup sheet's ``work_origin``). The robot planner speaks
metres in ROS frames. :func:`setup_sheet_to_cell` (the stock and part, CAM → cell) and
:func:`vise_jaws` (the vise, cell → CAM) are the only places that convert one into the
other; nothing else in ``robotprog`` divides by 1000, nothing in ``cadcam`` multiplies.

Convention (how the stock sits in the vise)
-------------------------------------------
The vise frame (``cell.vise.pose``) has its origin at the centre of the jaw gap on the
top of the parallels, X along the jaws, Y the clamping direction, Z up. The stock box is
clamped centred in the vise: its bottom face rests on the parallels (vise z = 0) and its
centre in X and Y is the vise origin. Work axes are parallel to vise axes (work X along the
jaws, work Y across them), so::

    p_vise [m] = (p_work [mm] - (cx, cy, z_min)) / 1000

with ``(cx, cy)`` the centre of the stock box and ``z_min`` its bottom, in work
coordinates. For the default origin (top-front-left, stock in x >= 0, y >= 0, z <= 0) the
work origin therefore lies at ``(-sx/2, -sy/2, sz)`` in the vise frame, ``s`` the stock size.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cadcam.model import SoftJaws, ViseJaws
from cadcam.sheet import read_setup_sheet
from factory.core.errors import CellError
from robotprog.cell import Vise

#: Millimetres per metre: the CAM → robot unit factor.
MM_PER_M = 1000.0


@dataclass(frozen=True)
class StockInVise:
    """The stock clamped in the vise, in metres.

    Attributes
    ----------
    transform_vise_to_work : (4, 4) float
        Pose of the CAM work frame in the vise frame (translation [m]).
    stock_min, stock_max : (3,) float
        Stock box corners in the vise frame [m] (``stock_min[2] == 0``).
    size : (3,) float
        Stock edge lengths [m].
    transform_mesh_to_work : (4, 4) float
        The setup sheet's mesh → work transform with its translation in metres (the
        mesh file scaled to metres by ``mesh_scale / 1000``).
    mesh_scale_m : float
        Mesh file units → metres.
    """

    transform_vise_to_work: np.ndarray
    stock_min: np.ndarray
    stock_max: np.ndarray
    size: np.ndarray
    transform_mesh_to_work: np.ndarray
    mesh_scale_m: float


def setup_sheet_to_cell(sheet: dict[str, Any], source: str | None = None) -> StockInVise:
    """Convert a setup sheet's stock box and part placement (mm, work) to metres in the vise frame.

    Parameters
    ----------
    sheet : dict
        A ``factory.setup/1`` setup sheet (``PART.setup.json`` loaded).
    source : str, optional
        File name for error messages.

    Raises
    ------
    SetupError
        Not a setup sheet, or malformed.
    """
    setup, _tools = read_setup_sheet(sheet, source)
    smin = np.asarray(setup.stock_min, dtype=float)
    smax = np.asarray(setup.stock_max, dtype=float)
    anchor_mm = np.array([(smin[0] + smax[0]) / 2, (smin[1] + smax[1]) / 2, smin[2]])
    t_vw = np.eye(4)
    t_vw[:3, 3] = -anchor_mm / MM_PER_M
    t_mw = np.array(setup.transform_mesh_to_work, dtype=float)
    t_mw[:3, 3] /= MM_PER_M
    out = [t_vw, (smin - anchor_mm) / MM_PER_M, (smax - anchor_mm) / MM_PER_M, (smax - smin) / MM_PER_M, t_mw]
    for a in out:
        a.setflags(write=False)
    return StockInVise(*out, mesh_scale_m=float(setup.mesh_scale) / MM_PER_M)


def vise_jaws(vise: Vise) -> ViseJaws:
    """The cell's vise [m] as CAM's :class:`cadcam.model.ViseJaws` [mm] (the pose stays in the cell:
    CAM places the jaws around the stock, the robot places the stock in the vise)."""
    soft = vise.soft_jaws
    return ViseJaws(
        jaw_height=vise.jaw_height * MM_PER_M,
        jaw_width=vise.jaw_width * MM_PER_M,
        jaw_thickness=vise.jaw_thickness * MM_PER_M,
        parallels_height=vise.parallels_height * MM_PER_M,
        opening_min=vise.jaw_opening_min * MM_PER_M,
        opening_max=vise.jaw_opening_max * MM_PER_M,
        soft_jaws=None if soft is None else SoftJaws(soft.kind, soft.depth * MM_PER_M),
    )


def check_stock_fits(size: np.ndarray, jaw_opening_min: float, jaw_opening_max: float, grip_depth: float,
                     gripper_opening_max: float) -> None:
    """Check the vise can clamp a stock of edge lengths ``size`` (3,) and the gripper hold it (all [m]).

    The vise clamps across vise Y; the gripper grips the stock across the same width.
    ``grip_depth`` is the jaws' top above the parallels (:attr:`robotprog.cell.Vise.grip_depth`):
    the stock must stand above it for the fingers to reach it.

    Raises
    ------
    CellError
        The stock is too wide or narrow for the vise, too wide for the gripper, or not
        taller than the jaws.
    """
    width = float(size[1])
    if not jaw_opening_min <= width <= jaw_opening_max:
        raise CellError(
            f"stock {width * MM_PER_M:.1f} mm wide does not fit the vise jaw opening "
            f"{jaw_opening_min * MM_PER_M:.1f}..{jaw_opening_max * MM_PER_M:.1f} mm",
            source="vise.jaw_opening",
        )
    if width > gripper_opening_max:
        raise CellError(
            f"stock {width * MM_PER_M:.1f} mm wide exceeds the gripper opening "
            f"{gripper_opening_max * MM_PER_M:.1f} mm",
            source="gripper.opening.max",
        )
    if size[2] <= grip_depth:
        raise CellError(
            f"stock {size[2] * MM_PER_M:.1f} mm tall does not stand above the jaws "
            f"{grip_depth * MM_PER_M:.1f} mm over the parallels",
            source="vise.jaw_height",
        )
