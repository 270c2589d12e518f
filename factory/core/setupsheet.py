"""The setup sheet ``factory.setup/1``: the file through which a part's millimetres reach the cell.

``PART.setup.json`` sits beside ``PART.nc``. CAM writes it (:func:`cadcam.sheet.setup_sheet`); verify,
the robot planner and checkers outside factory read it instead of the G-code. Everything in it is in
millimetres, in work coordinates (see :class:`SetupSheet`); the robot reads its stock box and part
placement and converts them to metres at :func:`robotprog.frames.setup_sheet_to_cell`, the one place
millimetres become metres.

Why the sheet lives on the ground floor: it is a file format shared by two domain packages that may
not import each other (:mod:`cadcam` writes it in millimetres, :mod:`robotprog` reads it and speaks
metres). Here each reads the same typed document, and each converts it into its own types in its own
units: :func:`cadcam.sheet.read_setup_sheet` to a ``Setup`` and tool table [mm],
:func:`robotprog.frames.setup_sheet_to_cell` to a ``StockInVise`` [m]. The other way, the cell's vise
[m] reaches CAM [mm] through the pipeline (:func:`factory.cam.vise_jaws`), the one module that sees
both a cell and a CAM setup. The alternative, moving the sheet-to-cell crossing up into the pipeline
too, would make the robot planner take a ``StockInVise`` rather than a sheet; its callers (the robot's
tests and benchmarks, ``factory robot``) all speak in sheets, so the crossing stays beside them.

Format ``factory.setup/1``::

    {
      "format": "factory.setup/1",
      "part": "bracket", "program": "bracket.nc", "dialect": "linuxcnc",
      "source_sha256": "…",              # of the part mesh file
      "units": "mm",
      "work_origin": "top-front-left",   # X0 Y0 Z0 on the stock
      "material": "aluminium",
      "stock": {"min": [x, y, z], "max": [x, y, z], "size": [x, y, z]},   # work coordinates [mm]
      "transform_mesh_to_work": [[4×4]],  # mesh file coordinates (scaled to mm) → work [mm]
      "mesh_scale": 1.0,                  # mesh file units → mm
      "safe_z": 5.0,                      # retract height [mm]
      "clearance": 1.0,                   # gap above cut material for short retracts [mm]
      "floor_z": -22.5,                   # lowest feed [mm]: part bottom minus the breakthrough
      "jaws": [{"name": "front jaw", "lo": [x, y, z], "hi": [x, y, z]}, …],   # vise boxes [mm, work];
                                          # null: workholding unknown (older sheets)
      "tools": [{"number": 1, "name": …, "shape": "flat", "diameter": 6.0,
                 "corner_radius": 0.0, "flute_length": 18.0, "flutes": 3, "length": 30.0,
                 "shank_diameter": 6.0,       # body between flutes and holder [mm]
                 "holder": [{"diameter": 22.0, "length": 10.0, "top_diameter": 28.0}, …]}],
                                              # from the gauge line up [mm]; sheets without
                                              # them read as cadcam.model.DEFAULT_HOLDER
      "operations": [{"name": "rough z-level", "kind": "roughing", "tool": 1,
                      "spindle_rpm": …, "feed_mm_min": …, "plunge_feed_mm_min": …, "allowance_mm": …,
                      "cut_mm": …, "rapid_mm": …, "estimated_s": …}],
      "estimated_cycle_s": …,
      "gcode_lines": …,
      "unreached": [{"x": …, "y": …, "size_x": …, "size_y": …, "depth": …, "z_bottom": …}],
      "relief": {…},                      # a relief only (cadcam.relief)
      "intake": {"format": "step", "unit": "CM", "scale": 10.0, "body": 2, "tolerance_mm": 0.01,
                 "features": {"holes": […], "elsewhere": […], "flats": […], "corners": […], "undercuts": […]}},
                                          # a STEP part only: how to read it again as planned, and
                                          # what its B-rep gave (each feature with its source)
      "op": 1, "work_offset": "G54",      # in a plan's output set
      "after": {…}, "flip": {…}, "face_z": …, "holding_mm": …, "held_in": …,   # op 2 (cadcam.op2)
      "next": {"program": …, "setup_sheet": …}   # op 1 of two: what runs after it
    }

``unreached`` lists stock no tool in the library could reach [mm, work coordinates]: the
program leaves it, finishing does not enter it (see :func:`cadcam.rest.unreached`).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from factory.core.errors import SetupError, clipped

FORMAT = "factory.setup/1"

#: A JSON object of the sheet kept as written (a tool, an operation, a jaw box, ...).
Record = Mapping[str, Any]


def _read_only(values: Any, shape: tuple[int, ...]) -> np.ndarray:
    a = np.array(values, dtype=np.float64, copy=True).reshape(shape)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class SetupSheet:
    """One operation's setup sheet: what the machinist, verify and the robot need to run its program.

    Every length is in millimetres, in the operation's work coordinates (X right, Y away from the
    operator, Z up the spindle; origin as ``work_origin`` names it). Nested objects (tools,
    operations, jaw boxes, ...) are kept as the JSON records the format above describes; their
    keys name their units.

    Attributes
    ----------
    stock_min, stock_max : (3,) float
        Stock box corners [mm] (read-only).
    transform_mesh_to_work : (4, 4) float
        Mesh file coordinates (scaled to mm by ``mesh_scale``) → work coordinates [mm] (read-only).
    tools : tuple of Record
        The tool table, in first-use order (:meth:`cadcam.model.Tool.to_dict` records; lengths [mm]).
    part, program, dialect : str
        Part name, G-code file name, controller dialect (``""``: not recorded).
    source_sha256 : str
        Hash of the part mesh file (``""``: not recorded).
    work_origin : str
        ``top-front-left`` or ``top-centre``: where X0 Y0 Z0 sits on the stock.
    material : str
        Stock material, a key into the tool library's cutting data.
    mesh_scale : float
        Mesh file units → mm (1 for mm, 25.4 for inch, 1000 for m).
    safe_z : float
        Retract height [mm].
    clearance : float
        Gap above already-cut material for short retracts [mm].
    floor_z : float or None
        Lowest feed [mm]; None: the stock's bottom (sheets from before workholding).
    jaws : tuple of Record or None
        The vise's jaws and parallels as boxes ``{"name", "lo", "hi"}`` [mm]; None: unknown.
    operations : tuple of Record
        Per operation: tool, spindle [rpm], feeds [mm/min], allowance, cut and rapid lengths [mm],
        estimated time [s].
    estimated_cycle_s : float or None
        The program's estimated run time [s].
    gcode_lines : int or None
        Lines of the program.
    unreached : tuple of Record
        Stock no tool reaches [mm].
    relief : Record or None
        A relief's description (what was found, its floor and boundary [mm]); None: a solid part.
    intake : Record or None
        A STEP part's reading (:meth:`cadcam.mesh.PartMesh.sheet_record`): its format, unit and scale
        [mm per unit], the solid taken (``body``, 1-based, None for a file of one) and the CAM
        tolerance of its tessellation [mm]; verify, the robot and the cell simulation read the file
        again with them. Its ``features`` are those read from the B-rep (holes with their counterbores
        and countersinks, holes for another setup, flats, inside corners [mm, the file's axes]).
        None: a mesh file (``mesh_scale`` says all).
    op, work_offset : int or None, str or None
        Which operation of a plan this is, and its work offset (``G54``, ``G55``); None: not part of a plan.
    after, flip, face_z, holding_mm, held_in
        Op 2 only (:func:`cadcam.op2.op2_sheet_fields`): op 1's program and sheet, the turnover and its
        transform [mm], the part's original bottom [mm], the allowance faced off [mm], what holds the
        part. ``after`` None: not op 2 (the others unused).
    next : Record or None
        Op 1 of two: op 2's program and sheet file names.
    """

    stock_min: np.ndarray
    stock_max: np.ndarray
    transform_mesh_to_work: np.ndarray
    tools: tuple[Record, ...]
    part: str = ""
    program: str = ""
    dialect: str = ""
    source_sha256: str = ""
    work_origin: str = "top-front-left"
    material: str = "aluminium"
    mesh_scale: float = 1.0
    safe_z: float = 10.0
    clearance: float = 1.0
    floor_z: float | None = None
    jaws: tuple[Record, ...] | None = None
    operations: tuple[Record, ...] = ()
    estimated_cycle_s: float | None = None
    gcode_lines: int | None = None
    unreached: tuple[Record, ...] = ()
    relief: Record | None = None
    intake: Record | None = None
    op: int | None = None
    work_offset: str | None = None
    after: Any = None
    flip: Any = None
    face_z: float | None = None
    holding_mm: float | None = None
    held_in: str | None = None
    next: Record | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "stock_min", _read_only(self.stock_min, (3,)))
        object.__setattr__(self, "stock_max", _read_only(self.stock_max, (3,)))
        object.__setattr__(self, "transform_mesh_to_work", _read_only(self.transform_mesh_to_work, (4, 4)))
        for name in ("tools", "operations", "unreached"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        if self.jaws is not None:
            object.__setattr__(self, "jaws", tuple(self.jaws))

    @property
    def stock_size(self) -> np.ndarray:
        """Stock box extents (x, y, z) [mm]."""
        return self.stock_max - self.stock_min

    def to_json(self) -> dict[str, Any]:
        """The JSON document (a fresh dict: changing it changes nothing here)."""
        doc: dict[str, Any] = {
            "format": FORMAT,
            "part": self.part,
            "program": self.program,
            "dialect": self.dialect,
            "source_sha256": self.source_sha256,
            "units": "mm",
            "work_origin": self.work_origin,
            "material": self.material,
            "stock": {"min": self.stock_min.tolist(), "max": self.stock_max.tolist(),
                      "size": self.stock_size.tolist()},
            "transform_mesh_to_work": self.transform_mesh_to_work.tolist(),
            "mesh_scale": self.mesh_scale,
            "safe_z": self.safe_z,
            "clearance": self.clearance,
            # workholding: the lowest feed, and the vise's jaws and parallels as boxes [mm, work]
            "floor_z": self.floor_z,
            "jaws": None if self.jaws is None else list(self.jaws),
            "tools": list(self.tools),
            "operations": list(self.operations),
            "estimated_cycle_s": self.estimated_cycle_s,
            "gcode_lines": self.gcode_lines,
            "unreached": list(self.unreached),
        }
        if self.relief is not None:
            doc["relief"] = self.relief
        if self.intake is not None:
            doc["intake"] = self.intake
        if self.op is not None:
            doc.update(op=self.op, work_offset=self.work_offset)
        if self.after is not None:
            doc.update(after=self.after, flip=self.flip, face_z=self.face_z, holding_mm=self.holding_mm,
                       held_in=self.held_in)
        if self.next is not None:
            doc["next"] = self.next
        return copy.deepcopy(doc)

    @classmethod
    def from_json(cls, data: Any, source: str | None = None) -> "SetupSheet":
        """The sheet a ``factory.setup/1`` document describes (``json.loads`` of the file).

        Only the stock box, the transform and the tool list are required; the rest take the
        defaults above (sheets from older versions and from outside factory). Keys the format does
        not name are dropped.

        Raises
        ------
        SetupError
            Not a ``factory.setup/1`` document, or a field is missing or malformed.
        """
        if not isinstance(data, Mapping) or data.get("format") != FORMAT:
            raise SetupError(f"not a factory setup sheet (expected format {FORMAT!r})", source=source)
        try:
            return cls._parsed(copy.deepcopy(dict(data)))
        except (KeyError, TypeError, ValueError) as e:
            raise SetupError(f"malformed setup sheet: {type(e).__name__}: {clipped(str(e))}", source=source) from None

    @classmethod
    def _parsed(cls, d: dict[str, Any]) -> "SetupSheet":
        for name in ("tools", "operations", "unreached"):
            if name in d and not _records(d[name]):
                raise TypeError(f"{name} must be a list of objects, got {clipped(repr(d[name]))}")
        jaws = d.get("jaws")
        if jaws is not None:
            jaws = tuple(_jaw(b) for b in jaws)
        optional = {f.name for f in dataclasses.fields(cls)} - {
            "stock_min", "stock_max", "transform_mesh_to_work", "tools", "mesh_scale", "safe_z", "clearance",
            "floor_z", "jaws", "work_origin"}
        return cls(
            stock_min=d["stock"]["min"],
            stock_max=d["stock"]["max"],
            transform_mesh_to_work=d["transform_mesh_to_work"],
            tools=tuple(d["tools"]),
            work_origin=d.get("work_origin", "top-front-left"),
            mesh_scale=float(d.get("mesh_scale", 1.0)),
            safe_z=float(d.get("safe_z", 10.0)),
            clearance=float(d.get("clearance", 1.0)),
            floor_z=None if d.get("floor_z") is None else float(d["floor_z"]),
            jaws=jaws,
            **{k: d[k] for k in optional if d.get(k) is not None},
        )


def _records(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, Mapping) for v in value)


def _jaw(box: Any) -> Record:
    """A jaw box record checked: a name and two corners of three numbers [mm]."""
    return {"name": str(box["name"]), "lo": _read_only(box["lo"], (3,)).tolist(),
            "hi": _read_only(box["hi"], (3,)).tolist()}
