"""Setup: size the stock around the part and put the work origin where the machinist touches off.

The part keeps its file's +Z as the spindle axis (it is cut from the top) and, as long as the
stock fits the vise that way, its file orientation; a stock that fits the jaws (and the robot's
gripper) only turned 90 degrees about Z is turned (:func:`orient_setup`). The stock is either
the part's bounding box grown by :class:`StockMargins` or a
block of given size; the part sits centred in X and Y, its bottom a *holding allowance* above
the stock's bottom. The work origin is the top of the stock, either at its front-left corner
or at its centre.

Workholding (op 1): the vise grips the stock's lowest ``grip_depth`` between its jaws. Op 1
machines everything it reaches from the top down to the part's bottom minus a breakthrough
(:data:`BREAKTHROUGH_MM`: through-holes and outer walls break out into the holding allowance),
which must stay :data:`JAW_CLEARANCE_MM` above the jaws' top and leave at least
:data:`MIN_HOLDING_LEFT_MM` under the part; op 2, flipped, faces the allowance off.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from cadcam.model import MAX_EXTENT_MM, Setup, ViseJaws, WorkOrigin
from factory.core.errors import FactoryError, SetupError

log = logging.getLogger(__name__)

_ORIGINS = ("top-front-left", "top-centre")
# Stock this much smaller than the part [mm] is rounding noise, not a misfit.
_FIT_TOLERANCE = 1e-6

#: Longest stock side [mm]: the same bound as a part mesh's extent.
MAX_STOCK_MM = MAX_EXTENT_MM
#: Largest stock top area [mm^2]. Roughing levels and the verify grid grow with the area the
#: tools sweep; at the default 0.2 mm verify grid this is 25 million cells, under the
#: simulation's 60 million, so no plan does its CAM work only for verify to refuse it.
MAX_STOCK_AREA_MM2 = 1000.0 * 1000.0
#: How far op 1 cuts below the part's bottom, so walls and through-holes come out clean [mm].
BREAKTHROUGH_MM = 0.5
#: Holding allowance op 1 leaves under the part at the least (what op 2 faces off) [mm].
MIN_HOLDING_LEFT_MM = 3.0
#: Gap between op 1's deepest feed and the jaws' top [mm].
JAW_CLEARANCE_MM = 1.0
#: Turning the part a quarter turn counterclockwise about Z (seen from above): file X goes to
#: work Y, file Y to work -X.
TURN_ABOUT_Z = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def check_stock_size(size: tuple[float, float, float] | np.ndarray, source: str | None = None) -> np.ndarray:
    """The stock size X, Y, Z [mm] as an array, if it is one this toolchain can plan within bounded
    time and memory.

    Raises
    ------
    SetupError
        Not three finite positive lengths, a side longer than :data:`MAX_STOCK_MM`, or a top
        larger than :data:`MAX_STOCK_AREA_MM2`.
    """
    size = np.asarray(size, dtype=np.float64).reshape(-1)
    if size.shape != (3,) or not np.isfinite(size).all() or (size <= 0).any():
        raise SetupError(f"stock size must be three positive lengths X, Y, Z [mm], got {size.tolist()}",
                         source=source)
    if (size > MAX_STOCK_MM).any():
        axis = "XYZ"[int(np.argmax(size))]
        raise SetupError(f"stock {axis} of {size.max():g} mm is longer than {MAX_STOCK_MM:g} mm", source=source)
    if size[0] * size[1] > MAX_STOCK_AREA_MM2:
        raise SetupError(f"stock top {size[0]:g} x {size[1]:g} mm is larger than {MAX_STOCK_AREA_MM2:g} mm^2",
                         source=source)
    return size


@dataclass(frozen=True)
class StockMargins:
    """Extra stock around the part's bounding box when the stock is sized from the part.

    Attributes
    ----------
    sides : float
        Added on each of the four sides (X-, X+, Y-, Y+) [mm]. Default 2.
    across : float or None
        Added on each Y side (across the vise's jaws) instead of ``sides`` [mm]; None: ``sides``.
        A relief's block takes less where the gripper needs its room (:func:`cadcam.relief.block_margins`).
    top : float
        Added above the part's highest point, to be faced off [mm]. Default 1.
    bottom : float or None
        The holding allowance: stock under the part's bottom, gripped by the vise in op 1
        and faced off in op 2 [mm]. Also used with an explicit stock size (the part's bottom
        sits this far above the stock's bottom). None: :func:`default_holding`.
    breakthrough : float
        How far op 1 cuts below the part's bottom [mm]. Default :data:`BREAKTHROUGH_MM`.
    """

    sides: float = 2.0
    top: float = 1.0
    bottom: float | None = None
    breakthrough: float = BREAKTHROUGH_MM
    across: float | None = None

    @property
    def sides_xy(self) -> np.ndarray:
        """(2,) [mm]: what is added on each X side and on each Y side."""
        return np.array([self.sides, self.sides if self.across is None else self.across], dtype=np.float64)


def default_holding(jaws: ViseJaws | None, breakthrough: float = BREAKTHROUGH_MM) -> float:
    """The least holding allowance [mm]: the breakthrough plus :data:`MIN_HOLDING_LEFT_MM`, and with a
    vise, the jaws' grip depth plus the breakthrough plus :data:`JAW_CLEARANCE_MM`."""
    need = breakthrough + MIN_HOLDING_LEFT_MM
    if jaws is not None:
        need = max(need, jaws.grip_depth + breakthrough + JAW_CLEARANCE_MM)
    return float(need)


def check_holding(holding: float, stock_size: np.ndarray, jaws: ViseJaws | None,
                  breakthrough: float = BREAKTHROUGH_MM, source: str | None = None) -> None:
    """Check the vise can hold the stock with ``holding`` [mm] under the part, op 1 cutting
    ``breakthrough`` [mm] below the part.

    Raises
    ------
    SetupError
        The allowance leaves less than :data:`MIN_HOLDING_LEFT_MM` under the part, op 1's
        deepest feed would come within :data:`JAW_CLEARANCE_MM` of the jaws' top, or the
        stock is wider (work Y) than the vise opens; the message gives the figures.
    """
    if not (np.isfinite(holding) and holding >= 0):
        raise SetupError(f"holding allowance must be >= 0 mm, got {holding}", source=source)
    if not (np.isfinite(breakthrough) and breakthrough >= 0):
        raise SetupError(f"breakthrough must be >= 0 mm, got {breakthrough}", source=source)
    need = default_holding(jaws, breakthrough)
    left = holding - breakthrough
    if left < MIN_HOLDING_LEFT_MM - 1e-9:
        raise SetupError(f"holding allowance {holding:g} mm leaves {left:g} mm under the part after op 1's "
                         f"{breakthrough:g} mm breakthrough, under {MIN_HOLDING_LEFT_MM:g} mm: give --holding "
                         f"{need:g} or more", source=source)
    if jaws is None:
        return
    if left < jaws.grip_depth + JAW_CLEARANCE_MM - 1e-9:
        raise SetupError(f"holding allowance {holding:g} mm is below the jaws' grip depth {jaws.grip_depth:g} mm "
                         f"plus {breakthrough:g} mm breakthrough and {JAW_CLEARANCE_MM:g} mm clearance: the tool "
                         f"would reach the jaws; give --holding {need:g} or more", source=source)
    width = float(stock_size[1])
    if not jaws.opening_min - 1e-9 <= width <= jaws.opening_max + 1e-9:
        raise SetupError(f"stock {width:.1f} mm wide (Y) does not fit the vise opening "
                         f"{jaws.opening_min:g}..{jaws.opening_max:g} mm", source=source)


def _stock_size(part_size: np.ndarray, stock_size: tuple[float, float, float] | np.ndarray | None,
                margins: StockMargins, holding: float, jaws: ViseJaws | None, source: str | None) -> np.ndarray:
    """The stock block (X, Y, Z) [mm]: the part's box plus ``margins`` and the holding allowance, or the
    given ``stock_size`` checked to hold the part (``part_size`` [mm]) with ``holding`` [mm] under it.

    Raises
    ------
    SetupError
        A negative margin, a non-positive stock size, a part that does not fit the given stock, or
        stock the vise cannot hold (:func:`check_holding`).
    """
    if stock_size is None:
        for name in ("sides", "top", "across"):
            v = getattr(margins, name)
            if v is not None and not (np.isfinite(v) and v >= 0):
                raise SetupError(f"stock margin {name} must be >= 0 mm, got {v}", source=source)
        sides = margins.sides_xy
        check_holding(holding, part_size + 2 * np.append(sides, 0.0), jaws, margins.breakthrough, source)
        return check_stock_size(
            part_size + np.array([2 * sides[0], 2 * sides[1], margins.top + holding]), source)
    size = check_stock_size(stock_size, source)
    check_holding(holding, size, jaws, margins.breakthrough, source)
    for axis, s, p in zip("XYZ", size, part_size):
        if s < p - _FIT_TOLERANCE:
            raise SetupError(f"part does not fit the stock in {axis}: part is {p:.3f} mm, stock is {s:.3f} mm",
                             source=source)
    if size[2] < part_size[2] + holding - _FIT_TOLERANCE:
        raise SetupError(
            f"part {part_size[2]:.3f} mm tall with {holding:g} mm holding allowance under it needs stock "
            f"{part_size[2] + holding:.3f} mm tall, stock is {size[2]:.3f} mm (--stock, --holding)",
            source=source,
        )
    return size


def make_setup(
    part: trimesh.Trimesh,
    *,
    stock_size: tuple[float, float, float] | None = None,
    margins: StockMargins = StockMargins(),
    origin: WorkOrigin = "top-front-left",
    material: str = "aluminium",
    safe_height: float = 5.0,
    mesh_scale: float = 1.0,
    jaws: ViseJaws | None = None,
    turned: bool = False,
    source: str | None = None,
) -> tuple[Setup, trimesh.Trimesh]:
    """Size the stock, place the part in it and express both in work coordinates.

    Parameters
    ----------
    part : trimesh.Trimesh
        The part in millimetres, in the file's axes (``PartMesh.mesh``: already scaled).
    stock_size : (3,) float, optional
        Explicit stock block (X, Y, Z) [mm], along the file's axes (``turned`` turns it with the
        part: its X then lies along work Y). The part is centred in X and Y and its bottom
        put ``margins.bottom`` (the holding allowance) above the stock bottom. None: part
        bounding box plus ``margins``.
    margins : StockMargins
        Sides and top used only when ``stock_size`` is None; the holding allowance and
        breakthrough always [mm].
    origin : {"top-front-left", "top-centre"}
        Work origin: stock top (z = 0) at the front-left corner (stock in x >= 0, y >= 0) or
        at the centre of the stock top (stock centred on x = y = 0).
    material : str
        Stock material, the key into the tool library's cutting data.
    safe_height : float
        Height of ``safe_z`` above the stock top [mm], > 0.
    mesh_scale : float
        Units factor already applied to ``part`` (recorded in the setup, not applied again).
    jaws : ViseJaws, optional
        The vise holding the stock (from the cell file): sets the default holding allowance,
        is checked against the stock, and is placed in the setup as obstacles. None: no vise
        known (the setup's ``jaws`` is None).
    turned : bool
        Turn the part (and an explicit stock) 90 degrees about Z (:data:`TURN_ABOUT_Z`) before
        placing it: what :func:`orient_setup` does when only that fits the vise.
    source : str, optional
        Name for error messages (usually the part file).

    Returns
    -------
    setup : Setup
        ``transform_mesh_to_work`` (4, 4) maps the *scaled* mesh (scaling happened at load time,
        ``mesh_scale``) into work coordinates: a pure translation, after :data:`TURN_ABOUT_Z` when
        ``turned`` (the part is always cut along its file's Z).
    part_work : trimesh.Trimesh
        A new mesh: the part in work coordinates [mm].

    Raises
    ------
    SetupError
        Negative margins, non-positive stock size or safe height, unknown origin, a part
        that does not fit the given stock with its holding allowance (names the axis and
        both sizes), or stock the vise cannot hold (:func:`check_holding`).
    """
    if origin not in _ORIGINS:
        raise SetupError(f"unknown work origin {origin!r}: expected one of {', '.join(_ORIGINS)}", source=source)
    if not (np.isfinite(safe_height) and safe_height > 0):
        raise SetupError(f"safe height must be > 0 mm, got {safe_height}", source=source)
    turn = TURN_ABOUT_Z if turned else np.eye(4)
    if turned:
        part = part.copy()
        part.apply_transform(turn)
        if stock_size is not None:
            stock_size = check_stock_size(stock_size, source)[[1, 0, 2]]
    lo, hi = np.asarray(part.bounds, dtype=np.float64)
    part_size = hi - lo
    holding = default_holding(jaws, margins.breakthrough) if margins.bottom is None else float(margins.bottom)

    size = _stock_size(part_size, stock_size, margins, holding, jaws, source)

    # Part centre in XY and part bottom, in file coordinates, go to where the stock puts them.
    part_centre_xy = (lo[:2] + hi[:2]) / 2
    if origin == "top-front-left":
        stock_min = np.array([0.0, 0.0, -size[2]])
    else:
        stock_min = np.array([-size[0] / 2, -size[1] / 2, -size[2]])
    stock_max = stock_min + size
    target_centre_xy = (stock_min[:2] + stock_max[:2]) / 2
    shift = np.empty(3)
    shift[:2] = target_centre_xy - part_centre_xy
    shift[2] = stock_min[2] + holding - lo[2]

    place = np.eye(4)
    place[:3, 3] = shift
    part_work = part.copy()
    part_work.apply_transform(place)
    transform = place @ turn

    setup = Setup(
        stock_min=stock_min,
        stock_max=stock_max,
        transform_mesh_to_work=transform,
        mesh_scale=float(mesh_scale),
        origin=origin,
        material=material,
        safe_z=float(stock_max[2] + safe_height),
        floor_z=float(stock_min[2] + holding - margins.breakthrough),
        jaws=None if jaws is None else jaws.place(stock_min, stock_max),
    )
    log.debug("stock %s mm, part shifted by %s mm%s", size.round(3).tolist(), shift.round(3).tolist(),
              " after a quarter turn about Z" if turned else "")
    return setup, part_work


def orient_setup(part: trimesh.Trimesh, *, fits: Callable[[Setup, trimesh.Trimesh], None] | None = None,
                 source: str | None = None, **options) -> tuple[Setup, trimesh.Trimesh]:
    """:func:`make_setup` in the file's orientation, or turned 90 degrees about Z when only that
    fits: the vise clamps across work Y, so a part too long that way may fit turned.

    ``fits`` is called with each candidate setup and the part placed in it [mm], and raises :class:`FactoryError` for one the rest
    of the cell cannot take (the robot's gripper, ...); ``options`` are :func:`make_setup`'s. The file's
    orientation is kept whenever it fits, so a part that fits as given is placed exactly as before.

    Raises
    ------
    FactoryError
        Neither orientation fits: the error of the file's orientation when turning changes
        nothing, else one :class:`SetupError` giving both orientations' figures.
    """
    def attempt(turned: bool) -> tuple[Setup, trimesh.Trimesh]:
        setup, part_work = make_setup(part, turned=turned, source=source, **options)
        if fits is not None:
            fits(setup, part_work)
        return setup, part_work

    try:
        return attempt(False)
    except FactoryError as given:
        try:
            setup, part_work = attempt(True)
        except FactoryError as turned:
            if turned.message == given.message:  # not a matter of orientation
                raise given from None
            raise SetupError(f"fits the cell in no orientation: {_both(_said(given, source), _said(turned, source))}",
                             source=source) from None
        size = setup.stock_size
        log.warning("%s: turned 90 degrees about Z to fit the cell: stock %.1f x %.1f mm (X x Y); as given, %s",
                    source or "part", size[0], size[1], _said(given, source))
        return setup, part_work


def _both(given: str, turned: str) -> str:
    """The errors of both orientations in one clause, an advice both end with (``: give ...``) said once."""
    tail = os.path.commonprefix([given[::-1], turned[::-1]])[::-1]
    tail = tail[tail.find(": "):] if ": " in tail else ""
    return f"as given, {given[:len(given) - len(tail)]}; turned 90 degrees about Z, {turned}"


def _said(error: FactoryError, source: str | None) -> str:
    """``error`` within another message: its text, and where it is unless that is ``source``."""
    return error.message if error.source in (None, source) else str(error)
