"""Command-line options of the CAM commands (`factory toolpath`, `factory plan`), defined once: :class:`CamFlags`."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import typing
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from cadcam.plan import PlanOptions
from cadcam.relief import ReliefOptions
from cadcam.setup import check_stock_size
from cli.common import parse_triple
from factory.cam import (ALLOWANCE, CELL, FINISH_TOOL, HOLDING, MATERIAL, ORIGIN, ROUGH_TOOL, SCALLOP, UNITS,
                         CamRequest, Origin, Units)
from factory.core.errors import SetupError

__all__ = ["ALLOWANCE", "CELL", "FINISH_TOOL", "HOLDING", "MATERIAL", "ORIGIN", "ROUGH_TOOL", "SCALLOP", "UNITS",
           "CamFlags", "cam_options", "cam_request"]

C = TypeVar("C", bound=Callable[..., Any])

ToolsOpt = Annotated[Path | None, typer.Option("--tools", help="Tool library YAML (default: fixtures/tools.yaml).", exists=True, dir_okay=False)]
StockOpt = Annotated[str | None, typer.Option("--stock", help="Stock size X,Y,Z [mm]; default: part box + 2 mm sides, 1 mm top, the holding allowance below.")]
HoldingOpt = Annotated[float | None, typer.Option("--holding", help="Holding allowance: stock under the part the vise grips in op 1 [mm]; default: the jaws' grip depth + 1.5 mm, at least 3.5 mm.", min=0.0)]
CellOpt = Annotated[Path, typer.Option("--cell", help="Cell file whose vise holds the stock.", exists=True, dir_okay=False)]
MaterialOpt = Annotated[str, typer.Option("--material", help="Stock material, a key of the tool library's cutting data.")]
UnitsOpt = Annotated[Units, typer.Option("--units", help="Units of the mesh file; auto assumes mm and checks the size.")]
OriginOpt = Annotated[Origin, typer.Option("--origin", help="Work origin: top of stock at its front-left corner or its centre.")]
RoughToolOpt = Annotated[int | None, typer.Option("--rough-tool", help="Tool number for roughing (flat or bull-nose); default: chosen by reach and size.")]
FinishToolOpt = Annotated[int | None, typer.Option("--finish-tool", help="Tool number for finishing; default: chosen by reach and size.")]
AllowanceOpt = Annotated[float, typer.Option("--allowance", help="Stock roughing leaves for finishing [mm].", min=0.0)]
ScallopOpt = Annotated[float | None, typer.Option("--scallop", help=f"Scallop height the ball end mill leaves [mm]; default: {PlanOptions.freeform_scallop:g} on a solid's freeform faces, {SCALLOP:g} over a relief.", min=1e-4, show_default=False)]
StepdownOpt = Annotated[float | None, typer.Option("--stepdown", help="Roughing depth per level [mm].", min=0.01)]
WaterlineOpt = Annotated[bool, typer.Option("--waterline/--no-waterline", help="Finish steep walls with waterline loops.")]
BodyOpt = Annotated[int | None, typer.Option("--body", help="STEP file with several solids: the one to machine (1-based).", min=1)]
FloorOpt = Annotated[float, typer.Option("--floor", help="Relief (open surface) only: stock left under its lowest point [mm].", min=0.0)]
BoundaryOpt = Annotated[str, typer.Option("--boundary", help="Relief only: the tool inside, centre on, or outside the footprint's outline: inside, on or outside.")]
FLOOR = ReliefOptions.floor
BOUNDARY = ReliefOptions.boundary


@dataclass(frozen=True)
class CamFlags:
    """The CAM options of one command line, defined once for every command that plans toolpaths.

    A command takes them as one parameter ``cam_flags: CamFlags`` and is decorated with
    :func:`cam_options`, which gives it each field as its own option (``--tools``, ``--stock``, ...).
    Lengths in millimetres.
    """

    tools: ToolsOpt = None
    stock: StockOpt = None
    holding: HoldingOpt = HOLDING
    material: MaterialOpt = MATERIAL
    units: UnitsOpt = UNITS
    origin: OriginOpt = ORIGIN
    rough_tool: RoughToolOpt = ROUGH_TOOL
    finish_tool: FinishToolOpt = FINISH_TOOL
    allowance: AllowanceOpt = ALLOWANCE
    scallop: ScallopOpt = None
    stepdown: StepdownOpt = None
    waterline: WaterlineOpt = True
    floor: FloorOpt = FLOOR
    boundary: BoundaryOpt = BOUNDARY
    body: BodyOpt = None

    def request(self, part: Path, cell: Path | None) -> CamRequest:
        """The request for ``part`` held in ``cell``'s vise (see :func:`cam_request`)."""
        return cam_request(part, self.tools, self.stock, self.material, self.units, self.origin, self.rough_tool,
                           self.finish_tool, self.allowance, self.scallop, self.stepdown, self.waterline, self.holding,
                           cell, self.floor, self.boundary, self.body)


def cam_options(command: C) -> C:
    """Give ``command`` the options of :class:`CamFlags` in place of its parameter ``cam_flags: CamFlags``.

    Typer reads a command's options from its signature: the one the returned function shows has each
    field of :class:`CamFlags` where ``cam_flags`` stood; called with them, it calls ``command`` with
    them gathered into ``cam_flags``.
    """
    signature = inspect.signature(command, eval_str=True)
    if "cam_flags" not in signature.parameters:
        raise TypeError(f"{command.__name__} has no parameter cam_flags: CamFlags")
    hints = typing.get_type_hints(CamFlags, include_extras=True)
    names = [f.name for f in dataclasses.fields(CamFlags)]
    group = [inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=f.default, annotation=hints[f.name])
             for f in dataclasses.fields(CamFlags)]
    params: list[inspect.Parameter] = []
    for p in signature.parameters.values():
        if p.name == "cam_flags":
            params += group
        else:
            params.append(p.replace(kind=inspect.Parameter.KEYWORD_ONLY))

    @functools.wraps(command)
    def with_cam(**kwargs: Any) -> Any:
        flags = CamFlags(**{n: kwargs.pop(n) for n in names})
        return command(**kwargs, cam_flags=flags)

    with_cam.__signature__ = signature.replace(parameters=params)  # type: ignore[attr-defined]
    with_cam.__annotations__ = {p.name: p.annotation for p in params}
    return with_cam  # type: ignore[return-value]


def cam_request(part: Path, tools: Path | None, stock: str | None, material: str, units: Units, origin: Origin,
                rough_tool: int | None, finish_tool: int | None, allowance: float, scallop: float | None, stepdown: float | None,
                waterline: bool, holding: float | None = HOLDING, cell: Path | None = CELL, floor: float = FLOOR,
                boundary: str = BOUNDARY, body: int | None = None) -> CamRequest:
    """The request of one command line; a malformed or unmachinable ``--stock`` or an unknown
    ``--boundary`` is a usage error before any work."""
    if boundary not in ("inside", "on", "outside"):
        raise typer.BadParameter(f"expected inside, on or outside, got {boundary!r}", param_hint="--boundary")
    size = parse_triple(stock, "--stock")
    if size is not None:
        try:
            check_stock_size(size)
        except SetupError as e:
            raise typer.BadParameter(e.message, param_hint="--stock") from None
    return CamRequest.from_options(part, tools, size, material, units, origin, rough_tool, finish_tool, allowance,
                                   scallop, stepdown, waterline, holding, cell,
                                   ReliefOptions(floor=floor, boundary=boundary), body)  # type: ignore[arg-type]
