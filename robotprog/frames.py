"""Where CAM's millimetres become the robot's metres: the stock and the part, read from the setup sheet.

The CAM stages speak millimetres in work coordinates (X right, Y away from the operator,
Z up the spindle; origin per the setup sheet's ``work_origin``). The robot planner speaks
metres in ROS frames. :func:`setup_sheet_to_cell` is the one place the part crosses from
CAM to the cell: it reads the setup sheet, the file format both sides share on the ground
floor (:mod:`factory.core.setupsheet`, which says why it lives there), into
:class:`StockInVise`. The vise crosses the other way, cell → CAM, in the pipeline
(:func:`factory.cam.vise_jaws`), since only the pipeline may see both a cell and a CAM setup.
Nothing else in ``robotprog`` converts the sheet's millimetres; nothing in ``cadcam`` multiplies.

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
from collections.abc import Mapping
from typing import Any

import numpy as np

from factory.core.errors import CellError
from factory.core.setupsheet import SetupSheet
from factory.core.units import MM_PER_M


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


def setup_sheet_to_cell(sheet: SetupSheet | Mapping[str, Any], source: str | None = None) -> StockInVise:
    """Convert a setup sheet's stock box and part placement (mm, work) to metres in the vise frame.

    Parameters
    ----------
    sheet : SetupSheet or dict
        A ``factory.setup/1`` setup sheet, or its JSON document (``PART.setup.json`` loaded).
    source : str, optional
        File name for error messages.

    Raises
    ------
    SetupError
        Not a setup sheet, or malformed.
    """
    if not isinstance(sheet, SetupSheet):
        sheet = SetupSheet.from_json(sheet, source)
    smin = np.asarray(sheet.stock_min, dtype=float)
    smax = np.asarray(sheet.stock_max, dtype=float)
    anchor_mm = np.array([(smin[0] + smax[0]) / 2, (smin[1] + smax[1]) / 2, smin[2]])
    t_vw = np.eye(4)
    t_vw[:3, 3] = -anchor_mm / MM_PER_M
    t_mw = np.array(sheet.transform_mesh_to_work, dtype=float)
    t_mw[:3, 3] /= MM_PER_M
    out = [t_vw, (smin - anchor_mm) / MM_PER_M, (smax - anchor_mm) / MM_PER_M, (smax - smin) / MM_PER_M, t_mw]
    for a in out:
        a.setflags(write=False)
    return StockInVise(*out, mesh_scale_m=float(sheet.mesh_scale) / MM_PER_M)


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
