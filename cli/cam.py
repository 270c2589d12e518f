"""Command-line options of the CAM commands (`factory toolpath`, `factory plan`), defined once."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cadcam.plan import PlanOptions
from cadcam.relief import ReliefOptions
from cadcam.setup import check_stock_size
from cli.common import parse_triple
from factory.cam import (ALLOWANCE, CELL, FINISH_TOOL, HOLDING, MATERIAL, ORIGIN, ROUGH_TOOL, SCALLOP, UNITS,
                         CamRequest, Origin, Units)
from factory.core.errors import SetupError

__all__ = ["ALLOWANCE", "CELL", "FINISH_TOOL", "HOLDING", "MATERIAL", "ORIGIN", "ROUGH_TOOL", "SCALLOP", "UNITS",
           "cam_request"]

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
ScallopOpt = Annotated[float, typer.Option("--scallop", help=f"Scallop height the ball end mill leaves [mm]; default: {PlanOptions.freeform_scallop:g} on a solid's freeform faces, {SCALLOP:g} over a relief.", min=1e-4, show_default=False)]
StepdownOpt = Annotated[float | None, typer.Option("--stepdown", help="Roughing depth per level [mm].", min=0.01)]
WaterlineOpt = Annotated[bool, typer.Option("--waterline/--no-waterline", help="Finish steep walls with waterline loops.")]
FloorOpt = Annotated[float, typer.Option("--floor", help="Relief (open surface) only: stock left under its lowest point [mm].", min=0.0)]
BoundaryOpt = Annotated[str, typer.Option("--boundary", help="Relief only: the tool inside, centre on, or outside the footprint's outline: inside, on or outside.")]
FLOOR = ReliefOptions.floor
BOUNDARY = ReliefOptions.boundary


def cam_request(part: Path, tools: Path | None, stock: str | None, material: str, units: Units, origin: Origin,
                rough_tool: int | None, finish_tool: int | None, allowance: float, scallop: float, stepdown: float | None,
                waterline: bool, holding: float | None = HOLDING, cell: Path | None = CELL, floor: float = FLOOR,
                boundary: str = BOUNDARY) -> CamRequest:
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
                                   ReliefOptions(floor=floor, boundary=boundary))  # type: ignore[arg-type]
