"""STEP intake: read a STEP (ISO 10303-21) B-rep, pick its solid, tessellate it, recognise its exact features.

:func:`read_step` is called by :func:`cadcam.mesh.load_part` for ``.step``/``.stp`` files, so
every command that takes a part takes STEP. It returns the triangles that the rest of the
toolchain machines and verifies against, and the features read from the exact geometry
(:mod:`cadcam.features`): round holes along Z with their exact diameter, depth and bottom
(which feed the drilling stage instead of the mesh's guess), holes that need another setup,
faces that look down with the part under them (undercuts: no tool from the top or from below
reaches them), flat faces at their exact Z, and inside corner radii.

* **Units** come from the file: OpenCASCADE converts the file's length unit to millimetres;
  the unit it declared is kept (:attr:`StepPart.unit`, :attr:`StepPart.scale`).
* **Tessellation**: the chordal deviation is :data:`CHORD_SHARE` of the CAM tolerance (the
  gouge tolerance ``factory verify`` judges by, 0.01 mm by default, so 0.0025 mm): a tool of a
  hole's exact size then cuts at most that far into the tessellated wall, well inside what
  verify accepts. The triangle count is bounded before the fine mesh is made: the part is
  meshed first at the whole tolerance (cheap), the count at the finer deviation estimated
  from it, and a part that would exceed :data:`MAX_TRIANGLES` (the public 11752.stp: 748k
  triangles, 473 s to read) is tessellated coarser, never past the CAM tolerance, and says so
  (:class:`Coarsened`); one that exceeds :data:`REFUSE_TRIANGLES` even at the whole tolerance is
  refused in one line.
* **Bodies**: a file with several solids is refused, naming each with its size, unless
  ``body`` picks one; a file with no solid, only surfaces, gives its faces as an open
  surface (the relief path, :mod:`cadcam.relief`); a file with neither is refused.

Reader: OpenCASCADE through ``cadquery-ocp-novtk`` (the OCP bindings without VTK), chosen over
``cascadio``. Both wrap the same OpenCASCADE 7.8/8.0 STEP reader and mesher, and read and
tessellate a 116-face plate in about the same time (0.49 s OCP, 0.57 s cascadio, measured on
this 2-core machine). cascadio hands back a GLB, in metres, with each face's analytic
primitive, but not the topology: which faces bound a bore, whether its bottom edge meets a
floor, a drill-point cone or the part's underside, which solid a face belongs to, whether a
shell is closed. Those decide through or blind, the bottom's shape, ``--body`` and the relief
path, and from cascadio they would have to be guessed back from the triangles. OCP gives the
B-rep itself, so each of them is read exactly; build123d, with which the tests model their
parts, uses the same package, so the test and runtime OpenCASCADE are one.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cadcam.drilling import Countersink
from cadcam.features import Counterbore, FlatFace, InsideCorner, PartFeatures, RoundHole, SetupHole, Undercut
from factory.core.errors import MeshError

log = logging.getLogger(__name__)

#: Share of the CAM tolerance the tessellation may deviate from the exact surface [1].
CHORD_SHARE = 0.25
#: Angular deflection of the tessellation [rad]: what bounds the facets of large, gentle curves.
ANGULAR_DEFLECTION = 0.5
#: The CAM tolerance without one given: ``factory verify``'s default gouge tolerance [mm].
CAM_TOLERANCE = 0.01
#: Triangles a STEP part is tessellated to at most before its chordal deviation grows (up to the
#: CAM tolerance): reading, planning and verifying grow with them [1].
MAX_TRIANGLES = 250_000
#: Triangles at the whole CAM tolerance past which a STEP part is refused: no coarsening the
#: tolerance allows brings it within bounded time and memory [1].
REFUSE_TRIANGLES = 1_000_000
#: How a B-rep's triangle count grows as the chordal deviation shrinks: about as its -0.8th power
#: (11752.stp: 93,760, 247,512 and 748,408 triangles at 0.04, 0.01 and 0.0025 mm) [1].
COUNT_EXPONENT = 0.8

#: Factor from the length units a STEP file may declare (as OpenCASCADE names them) to mm.
_UNITS_MM: dict[str, float] = {
    "MM": 1.0, "MILLIMETRE": 1.0, "MILLIMETER": 1.0, "INCH": 25.4, "IN": 25.4, "M": 1000.0, "METRE": 1000.0,
    "METER": 1000.0, "CM": 10.0, "CENTIMETRE": 10.0, "FOOT": 304.8, "FT": 304.8, "UM": 1e-3, "MICROMETRE": 1e-3,
}
#: The ``--units`` names of the factors (:data:`cadcam.mesh.UNIT_SCALE`).
_UNIT_NAMES = {1.0: "mm", 25.4: "inch", 1000.0: "m"}

# A wall closes round when its faces cover the full turn to this [rad].
_FULL_TURN = 2 * math.pi - 1e-6
# An axis along Z: its direction's Z component is 1 to this.
_ALONG_Z = 1e-9
# A triangle looks down when its unit normal's Z component is below minus this (0.06 deg) [1].
_LOOKS_DOWN = 1e-3
# Centroids of a face's down-looking triangles tested for material under them [1].
_UNDERCUT_SAMPLES = 32


def chordal_deviation(tolerance: float) -> float:
    """Largest distance [mm] of the tessellation from the exact surface for a CAM ``tolerance`` [mm]."""
    return CHORD_SHARE * float(tolerance)


@dataclass(frozen=True)
class StepSolid:
    """One solid of a STEP file: ``index`` (1-based, as ``--body`` counts), its box ``size`` X, Y, Z [mm], its faces."""

    index: int
    size: tuple[float, float, float]
    faces: int

    def describe(self) -> str:
        x, y, z = self.size
        return f"{self.index}: {x:.1f} x {y:.1f} x {z:.1f} mm, {self.faces} faces"


@dataclass(frozen=True)
class Coarsened:
    """A tessellation made coarser than the tolerance asked for, to stay within :data:`MAX_TRIANGLES`.

    ``asked``: the chordal deviation the CAM tolerance asks for [mm]; ``estimate``: the triangles
    it would give, estimated from the mesh at the whole tolerance; ``taken``: the deviation used
    [mm]; ``triangles``: what that gave; ``limit``: :data:`MAX_TRIANGLES` at the time."""

    asked: float
    estimate: int
    taken: float
    triangles: int
    limit: int

    def describe(self) -> str:
        return (f"tessellated to {self.taken:.4g} mm, not {self.asked:.4g} mm: about {self.estimate:,} triangles "
                f"there, more than the {self.limit:,} planned in bounded time ({self.triangles:,} taken)")

    def to_dict(self) -> dict[str, Any]:
        return {"asked_mm": self.asked, "estimate": self.estimate, "taken_mm": self.taken,
                "triangles": self.triangles, "limit": self.limit, "said": self.describe()}


@dataclass(frozen=True)
class StepPart:
    """A STEP file read, tessellated and recognised.

    Attributes
    ----------
    vertices : (n, 3) float
        Tessellation nodes [mm], in the file's axes; each B-rep face's nodes separately (the
        nodes of a shared edge coincide, so welding joins the faces).
    faces : (m, 3) int
        Triangles, wound so that their normals point out of the material.
    unit : str
        The length unit the file declares, as OpenCASCADE names it (``"MM"``, ``"INCH"``, ...).
    scale : float
        Factor from that unit to mm [mm per unit]; the coordinates are already in mm.
    chordal_deviation : float
        Largest distance of the triangles from the exact surface [mm].
    tolerance : float
        The CAM tolerance the chordal deviation was derived from [mm].
    brep_faces : int
        B-rep faces of what was taken (the chosen solid, or every face of a surfaces-only file).
    solids : tuple of StepSolid
        Every solid in the file.
    body : int or None
        The solid taken (1-based), None for a file of one solid or of surfaces only.
    closed : bool
        True: a solid; False: only surfaces (machined from above as a relief).
    features : PartFeatures
        What was recognised on the exact B-rep (nothing for surfaces).
    coarsened : Coarsened or None
        Set when the part was tessellated coarser than :data:`CHORD_SHARE` of ``tolerance``.
    """

    vertices: np.ndarray
    faces: np.ndarray
    unit: str
    scale: float
    chordal_deviation: float
    tolerance: float
    brep_faces: int
    solids: tuple[StepSolid, ...]
    body: int | None
    closed: bool
    features: PartFeatures = field(default_factory=PartFeatures)
    coarsened: Coarsened | None = None

    @property
    def units(self) -> str | None:
        """The ``--units`` name of the file's unit (``mm``, ``inch``, ``m``), None for another unit."""
        return _UNIT_NAMES.get(self.scale)

    def sheet_record(self) -> dict[str, Any]:
        """The setup sheet's ``intake``: what reading the file again needs (its format, unit and scale
        [mm per unit], the solid taken, ``body``, and the CAM tolerance of its tessellation [mm]), and
        the features read from its B-rep (each with its ``source``), for the machinist."""
        return {"format": "step", "unit": self.unit, "scale": self.scale, "body": self.body,
                "tolerance_mm": self.tolerance, "features": self.features.to_dict()}

    def to_dict(self) -> dict[str, Any]:
        """The intake's figures and features for the plan summary."""
        return {"format": "step", "unit": self.unit, "units": self.units, "scale": self.scale,
                "tolerance_mm": self.tolerance,
                "chordal_deviation_mm": self.chordal_deviation,
                "chord_share": round(self.chordal_deviation / self.tolerance, 6),
                "coarsened": None if self.coarsened is None else self.coarsened.to_dict(),
                "brep_faces": self.brep_faces, "triangles": int(len(self.faces)),
                "solids": [s.describe() for s in self.solids], "body": self.body, "closed": self.closed,
                "features": self.features.to_dict()}


def read_step(path: str | Path, tolerance: float = CAM_TOLERANCE, body: int | None = None, *,
              max_triangles: int = MAX_TRIANGLES, refuse_triangles: int = REFUSE_TRIANGLES) -> StepPart:
    """Read a STEP file, choose its solid, tessellate it to ``CHORD_SHARE * tolerance`` and recognise its features.

    Parameters
    ----------
    path : str or Path
        The STEP file (AP203, AP214, AP242).
    tolerance : float
        The CAM tolerance [mm]; the tessellation deviates at most :data:`CHORD_SHARE` of it.
    body : int, optional
        The solid to take (1-based) when the file has several.
    max_triangles, refuse_triangles : int
        The tessellation's bounds (:data:`MAX_TRIANGLES`, :data:`REFUSE_TRIANGLES`).

    Raises
    ------
    MeshError
        With ``source=path``: not a STEP file (an IGES file named ``.step`` says so), damaged or
        truncated, no geometry, several solids and no ``body`` (lists them with their sizes), a
        ``body`` the file does not have, a tolerance that is not positive, more than
        ``refuse_triangles`` triangles even at the whole tolerance.
    """
    path = Path(path)
    if not tolerance > 0:
        raise MeshError(f"tolerance must be positive, got {tolerance!r} mm", source=path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise MeshError(f"cannot read file: {e.strerror or e}", source=path) from None
    _check_frame(data, path)
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.OCP.collections import Sequence_TCollection_AsciiString
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_FACE, TopAbs_SOLID

    reader = STEPControl_Reader()
    with _quiet_stdout():  # OpenCASCADE prints its statistics to the process's stdout
        status = reader.ReadFile(str(path))
        if status != IFSelect_ReturnStatus.IFSelect_RetDone:
            raise MeshError(f"damaged STEP file: OpenCASCADE cannot parse it ({status.name})", source=path)
        if reader.NbRootsForTransfer() == 0:
            raise MeshError("STEP file holds no geometry (no shape to transfer)", source=path)
        reader.TransferRoots()
        shape = reader.OneShape()
    if shape is None or shape.IsNull():
        raise MeshError("STEP file holds no geometry (its shapes transfer to nothing)", source=path)
    names = Sequence_TCollection_AsciiString()
    reader.FileUnits(names, Sequence_TCollection_AsciiString(), Sequence_TCollection_AsciiString())
    unit = names.Value(1).ToCString().upper() if names.Length() else "MM"
    if unit not in _UNITS_MM:
        raise MeshError(f"STEP file's length unit {unit!r} is not one factory knows", source=path)

    solids = _shapes(shape, TopAbs_SOLID)
    listed = tuple(StepSolid(i + 1, _box_size(s), len(_shapes(s, TopAbs_FACE))) for i, s in enumerate(solids))
    if body is not None and not 1 <= body <= len(solids):
        have = f"{len(solids)} solid{'s' if len(solids) != 1 else ''}"
        raise MeshError(f"--body {body}: the file has {have}", source=path)
    if len(solids) > 1 and body is None:
        raise MeshError(f"{len(solids)} solids in the file ({'; '.join(s.describe() for s in listed)}): "
                        "pick one with --body N", source=path)
    if solids:
        taken = solids[(body or 1) - 1]
    else:
        taken = shape
    faces = _shapes(taken, TopAbs_FACE)
    if not faces:
        raise MeshError("STEP file holds no geometry: no solid and no surface", source=path)
    chord, coarsened = _bounded_mesh(taken, faces, float(tolerance), max_triangles, refuse_triangles, path)
    vertices, triangles, owner = _tessellate(faces)
    if not len(triangles):
        raise MeshError("STEP file's faces tessellate to no triangles", source=path)
    features = recognise(taken, faces, vertices, triangles, chord, owner) if solids else PartFeatures()
    return StepPart(vertices=vertices, faces=triangles, unit=unit, scale=_UNITS_MM[unit], chordal_deviation=chord,
                    tolerance=float(tolerance), brep_faces=len(faces), solids=listed,
                    body=body if len(solids) > 1 else None, closed=bool(solids), features=features,
                    coarsened=coarsened)


def _check_frame(data: bytes, path: Path) -> None:
    """Refuse what is not a whole ISO 10303-21 file before OpenCASCADE sees it.

    OpenCASCADE reads what it can of a cut-off file and transfers whatever solids survive; the
    standard's end line is the one sign that the file is whole.
    """
    text = data[:4096].lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"ISO-10303-21"):
        if not data.rstrip().endswith(b"END-ISO-10303-21;"):
            raise MeshError("truncated STEP file: it does not end with END-ISO-10303-21;", source=path)
        return
    first = text.split(b"\n", 1)[0].rstrip(b"\r")
    if len(first) == 80 and first[72:73] == b"S" and first[73:80].strip().isdigit():
        raise MeshError("an IGES file, not STEP (its first line is an IGES start record); factory reads STEP",
                        source=path)
    if not text:
        raise MeshError("file is empty", source=path)
    raise MeshError("not a STEP file: it does not start with ISO-10303-21", source=path)


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Send what OpenCASCADE writes to file descriptor 1 nowhere, so that stdout stays the command's data."""
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no stdout to protect
        yield
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        try:
            yield
        finally:
            sys.stdout.flush()
            _flush_c_stdio()  # what OpenCASCADE left in C's buffers goes to the sink, not to stdout later
            os.dup2(saved, 1)
            os.close(saved)


def _flush_c_stdio() -> None:
    import ctypes

    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to flush: nothing buffered there
        pass


def _shapes(shape, kind) -> list:
    """The distinct sub-shapes of ``kind`` of ``shape``, in the file's order."""
    from OCP.OCP.collections import IndexedMap_TopoDS_Shape_TopTools_ShapeMapHasher as ShapeMap
    from OCP.TopExp import TopExp

    found = ShapeMap()
    TopExp.MapShapes_s(shape, kind, found)
    return [found.FindKey(i) for i in range(1, found.Extent() + 1)]


def _box_size(shape) -> tuple[float, float, float]:
    """Size of the tight bounding box of ``shape`` [mm]."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib

    box = Bnd_Box()
    BRepBndLib.AddOptimal_s(shape, box, False, False)
    lo, hi = box.CornerMin(), box.CornerMax()
    return (hi.X() - lo.X(), hi.Y() - lo.Y(), hi.Z() - lo.Z())


def _mesh(shape, chord: float, tolerance: float) -> None:
    """Mesh ``shape`` afresh to chordal deviation ``chord`` [mm]; OpenCASCADE keeps the mesh on its faces.

    First with OpenCASCADE's Delabella algorithm, which triangulates a plane with many holes
    several times faster than its default, Watson (the 500-face plate: 0.24 s against 1.18 s, its
    top face of 97 wires alone 0.90 s with Watson). On planes and cylinders both give the same
    nodes; on other curved faces Delabella's triangles can stray further from the surface (the
    public screw.step's thread run-out cone: 0.076 mm against Watson's 0.011 mm). So the part is
    meshed again with Watson when a face comes out unmeshed or deviating more than the CAM
    ``tolerance`` [mm] as OpenCASCADE measured it (``math.inf``: a mesh that is only counted).
    Meshing the faces apart instead, curved ones with Watson on the nodes Delabella left on their
    edges, lost the mesh's closure (nist_ftc_10).
    """
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.BRepTools import BRepTools
    from OCP.IMeshTools import IMeshTools_MeshAlgoType, IMeshTools_Parameters
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    for algo in (IMeshTools_MeshAlgoType.IMeshTools_MeshAlgoType_Delabella,
                 IMeshTools_MeshAlgoType.IMeshTools_MeshAlgoType_Watson):
        BRepTools.Clean_s(shape)  # a mesh already there, coarser or finer, would be kept
        params = IMeshTools_Parameters()
        params.Deflection, params.Angle, params.Relative, params.MeshAlgo = chord, ANGULAR_DEFLECTION, False, algo
        BRepMesh_IncrementalMesh(shape, params)
        meshes = [BRep_Tool.Triangulation_s(TopoDS.Face(f), TopLoc_Location()) for f in _shapes(shape, TopAbs_FACE)]
        worst = max((math.inf if m is None else m.Deflection() for m in meshes), default=0.0)
        if worst <= max(chord, tolerance):
            return
        log.info("%s meshed %s to %.4g mm, more than the %g mm tolerance", algo.name, "faces" if worst < math.inf
                 else "some faces not at all, others", worst, tolerance)


def _triangle_count(faces: list) -> int:
    """Triangles of the faces' current meshes."""
    from OCP.BRep import BRep_Tool
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    meshes = (BRep_Tool.Triangulation_s(TopoDS.Face(f), TopLoc_Location()) for f in faces)
    return sum(m.NbTriangles() for m in meshes if m is not None)


def _bounded_mesh(shape, faces: list, tolerance: float, limit: int, refuse: int,
                  path: Path) -> tuple[float, Coarsened | None]:
    """Mesh ``shape`` to :data:`CHORD_SHARE` of ``tolerance`` [mm], or coarser (up to ``tolerance``)
    when that would give more than ``limit`` triangles; the chordal deviation taken [mm], and how
    it was coarsened (None: not).

    The count is estimated before the fine mesh is made, from a mesh at the whole tolerance (a
    few seconds on 11752.stp, where the fine mesh alone takes 20 s and reading its triangles
    minutes) and :data:`COUNT_EXPONENT`; each coarser try aims where the last count says.

    Raises
    ------
    MeshError
        More than ``refuse`` triangles even at the whole tolerance (the figures and the fix).
    """
    asked = chordal_deviation(tolerance)
    _mesh(shape, tolerance, math.inf)  # only counted: Delabella's count is Watson's to a few in a thousand
    coarse = _triangle_count(faces)
    if coarse > refuse:
        raise MeshError(f"{len(faces)} B-rep faces tessellate to {coarse:,} triangles even at the whole CAM "
                        f"tolerance of {tolerance:g} mm, more than the {refuse:,} factory plans in bounded time and "
                        "memory: machine a simpler model (threads, lettering and fine fillets removed) or one solid "
                        "of it", source=path)
    estimate = round(coarse * (tolerance / asked) ** COUNT_EXPONENT)
    chord, count = tolerance, coarse
    want = asked if estimate <= limit else min(tolerance, asked * (estimate / limit) ** (1 / COUNT_EXPONENT))
    while want < tolerance:
        _mesh(shape, want, tolerance)
        chord, count = want, _triangle_count(faces)
        if count <= limit:
            break
        want = min(tolerance, want * (count / limit) ** (1 / COUNT_EXPONENT) * 1.05)  # 5 % more each try
    else:  # every finer try was too many: the whole tolerance, now held to it
        _mesh(shape, tolerance, tolerance)
        chord, count = tolerance, _triangle_count(faces)
    if chord <= asked:
        return chord, None
    coarsened = Coarsened(asked=asked, estimate=estimate, taken=chord, triangles=count, limit=limit)
    log.warning("%s: %s", path, coarsened.describe())
    return chord, coarsened


def _tessellate(faces: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The faces' meshes (:func:`_bounded_mesh`): nodes (n, 3) [mm], triangles (m, 3) and the index
    into ``faces`` of each triangle's face (m,).

    Each node and triangle crosses from OpenCASCADE one call at a time (the bindings give no array
    of them); list comprehensions over bound methods keep that to the calls themselves, and a
    face's placement is applied to its nodes as one matrix product.
    """
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_REVERSED
    from OCP.TopLoc import TopLoc_Location
    from OCP.TopoDS import TopoDS

    nodes, tris, owner = [], [], []
    base = 0
    for k, f in enumerate(faces):
        face = TopoDS.Face(f)
        loc = TopLoc_Location()
        mesh = BRep_Tool.Triangulation_s(face, loc)
        if mesh is None:
            continue
        node, triangle = mesh.Node, mesh.Triangle
        pts = np.array([node(i).Coord() for i in range(1, mesh.NbNodes() + 1)], dtype=np.float64).reshape(-1, 3)
        if not loc.IsIdentity():
            t = loc.Transformation()
            m = np.array([[t.Value(r, c) for c in range(1, 5)] for r in range(1, 4)])
            pts = pts @ m[:, :3].T + m[:, 3]
        tri = np.array([triangle(i).Get() for i in range(1, mesh.NbTriangles() + 1)], dtype=np.int64).reshape(-1, 3) - 1
        if face.Orientation() == TopAbs_REVERSED:  # the face's material lies on the surface's other side
            tri = tri[:, ::-1]
        nodes.append(pts)
        tris.append(tri + base)
        owner.append(np.full(len(tri), k, dtype=np.int64))
        base += len(pts)
    if not tris:
        return np.empty((0, 3)), np.empty((0, 3), dtype=np.int64), np.empty(0, dtype=np.int64)
    return np.concatenate(nodes), np.concatenate(tris), np.concatenate(owner)


# --------------------------------------------------------------------------- recognition


@dataclass(frozen=True)
class _Face:
    """What recognition needs of one B-rep face: its kind, geometry and outward normal at its middle."""

    index: int
    kind: str  # "plane", "cylinder", "cone", "other" (sphere, torus), "freeform" (B-spline, extrusion, ...)
    normal: np.ndarray  # (3,) outward unit normal at the middle of the face's parameters
    point: np.ndarray  # (3,) [mm] the point there
    u: tuple[float, float]
    v: tuple[float, float]
    location: np.ndarray  # (3,) [mm] axis location (cylinder, cone) or a point of the plane
    axis: np.ndarray  # (3,) unit axis direction (cylinder, cone) or plane normal as stored
    radius: float = 0.0  # [mm] cylinder radius; a cone's at its location
    apex: np.ndarray | None = None  # (3,) [mm] cone apex
    semi_angle: float = 0.0  # [rad] cone
    area: float = 0.0  # [mm^2]


def _face_info(index: int, f) -> _Face:
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepGProp import BRepGProp, BRepGProp_Face
    from OCP.GeomAbs import GeomAbs_SurfaceType
    from OCP.GProp import GProp_GProps
    from OCP.gp import gp_Pnt, gp_Vec
    from OCP.TopoDS import TopoDS

    face = TopoDS.Face(f)
    s = BRepAdaptor_Surface(face)
    u = (s.FirstUParameter(), s.LastUParameter())
    v = (s.FirstVParameter(), s.LastVParameter())
    p, n = gp_Pnt(), gp_Vec()
    BRepGProp_Face(face).Normal(sum(u) / 2, sum(v) / 2, p, n)  # oriented: out of the material
    length = n.Magnitude()
    normal = np.array(n.Coord()) / length if length > 0 else np.zeros(3)
    point = np.array(p.Coord())
    props = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, props)
    t = s.GetType()
    common = dict(index=index, normal=normal, point=point, u=u, v=v, area=float(props.Mass()))
    if t == GeomAbs_SurfaceType.GeomAbs_Cylinder:
        c = s.Cylinder()
        ax = c.Axis()
        return _Face(kind="cylinder", location=np.array(ax.Location().Coord()),
                     axis=np.array(ax.Direction().Coord()), radius=float(c.Radius()), **common)
    if t == GeomAbs_SurfaceType.GeomAbs_Cone:
        c = s.Cone()
        ax = c.Axis()
        return _Face(kind="cone", location=np.array(ax.Location().Coord()), axis=np.array(ax.Direction().Coord()),
                     radius=float(c.RefRadius()), apex=np.array(c.Apex().Coord()), semi_angle=float(c.SemiAngle()),
                     **common)
    if t == GeomAbs_SurfaceType.GeomAbs_Plane:
        pl = s.Plane()
        return _Face(kind="plane", location=np.array(pl.Location().Coord()),
                     axis=np.array(pl.Axis().Direction().Coord()), **common)
    analytic = (GeomAbs_SurfaceType.GeomAbs_Sphere, GeomAbs_SurfaceType.GeomAbs_Torus)
    return _Face(kind="other" if t in analytic else "freeform", location=point, axis=normal, **common)


class _Adjacency:
    """Which faces share an edge with a face: OpenCASCADE's edge-to-faces map, asked only for the faces that need it."""

    def __init__(self, shape, faces: list) -> None:
        from OCP.OCP.collections import IndexedDataMap_TopoDS_Shape_List_TopoDS_Shape_TopTools_ShapeMapHasher as EdgeFaces
        from OCP.OCP.collections import IndexedMap_TopoDS_Shape_TopTools_ShapeMapHasher as ShapeMap
        from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
        from OCP.TopExp import TopExp

        self._faces = faces
        self._index = ShapeMap()
        for f in faces:
            self._index.Add(f)
        self._edges = EdgeFaces()
        TopExp.MapShapesAndAncestors_s(shape, TopAbs_EDGE, TopAbs_FACE, self._edges)

    def of(self, i: int) -> set[int]:
        """Indices (into ``faces``) of the faces sharing an edge with face ``i``."""
        from OCP.TopAbs import TopAbs_EDGE

        out: set[int] = set()
        for edge in _shapes(self._faces[i], TopAbs_EDGE):
            for f in self._edges.FindFromKey(edge):
                out.add(self._index.FindIndex(f) - 1)
        out.discard(-1)
        out.discard(i)
        return out


def recognise(shape, faces: list, vertices: np.ndarray, triangles: np.ndarray, chord: float,
              owner: np.ndarray | None = None) -> PartFeatures:
    """The features of one solid from its exact B-rep faces.

    ``vertices`` (n, 3) [mm] and ``triangles`` (m, 3) are the solid's tessellation, used only
    to tell whether anything of the part lies over a bore or under a face that looks down;
    ``chord`` [mm] its chordal deviation; ``owner`` (m,) the index into ``faces`` of each
    triangle's face (None: no undercuts are looked for).
    """
    info = [_face_info(i, f) for i, f in enumerate(faces)]
    near = _Adjacency(shape, faces)
    span = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 1.0
    eps = 1e-7 * max(span, 1.0)  # geometric coincidence [mm]
    over = _Over.of(vertices, triangles)
    holes: list[RoundHole] = []
    elsewhere: list[SetupHole] = []
    corners: list[InsideCorner] = []
    reported: set[int] = set()  # faces of the holes for another setup: not undercuts too
    for group in _bores(info, eps):
        walls = [info[i] for i in group]
        w = walls[0]
        concave = all(float(np.dot(f.normal, _radial(f))) < 0 for f in walls)
        if not concave:
            continue  # a boss or a convex round edge: nothing to drill
        turn = sum(f.u[1] - f.u[0] for f in walls)
        along_z = abs(abs(float(w.axis[2])) - 1.0) < _ALONG_Z
        if turn < _FULL_TURN:
            if along_z:
                z0, z1 = _z_range(walls)
                corners.append(InsideCorner(x=float(w.location[0]), y=float(w.location[1]), radius=w.radius,
                                            bottom_z=z0, top_z=z1, source="step"))
            continue
        if not along_z:
            elsewhere.append(_setup_hole(walls, "axis off Z"))
            reported.update(group)
            continue
        hole = _round_hole(walls, group, info, near, eps)
        if not _open_above(hole, over, chord, eps):
            elsewhere.append(_setup_hole(walls, "covered from above"))
            reported.update(group)
            continue
        holes.append(hole)
    holes = _with_counterbores(holes, eps)
    flats = [FlatFace(z=float(f.point[2]), area=f.area, facing="up" if f.normal[2] > 0 else "down", source="step")
             for f in info if f.kind == "plane" and abs(abs(float(f.normal[2])) - 1.0) < _ALONG_Z]
    undercuts = () if owner is None else _undercuts(info, vertices, triangles, owner, over, reported,
                                                     max(eps, chord))
    features = PartFeatures(
        holes=tuple(sorted(holes, key=lambda h: (round(h.x, 6), round(h.y, 6), -h.top_z))),
        elsewhere=tuple(elsewhere), flats=tuple(sorted(flats, key=lambda f: (-f.z, f.facing))),
        corners=tuple(sorted(corners, key=lambda c: (c.radius, c.x, c.y))), undercuts=tuple(undercuts),
        freeform=sum(f.kind == "freeform" for f in info))
    log.info("recognised on the B-rep: %d round holes, %d for another setup, %d flat faces, %d inside corners, "
             "%d undercut faces", len(features.holes), len(features.elsewhere), len(features.flats),
             len(features.corners), len(features.undercuts))
    return features


def _undercuts(info: list[_Face], vertices: np.ndarray, triangles: np.ndarray, owner: np.ndarray, over: "_Over",
               skip: set[int], gap: float) -> list[Undercut]:
    """The faces that look down with the part under them (not those in ``skip``).

    A face that looks down has the material over it, so no tool from the top touches it; once the
    part is turned over (op 2) a tool from below reaches it only if nothing of the part lies under
    it. Each face's down-looking triangles are tested at up to :data:`_UNDERCUT_SAMPLES` of their
    centroids (the largest triangles first): covered when a triangle of the part that is not
    vertical lies more than ``gap`` [mm] under the centroid. Faces on the part's underside are not
    looked at. ``over``: the tessellation as :func:`_covered_below` reads it.
    """
    tri = vertices[triangles]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # length: twice the area
    double = np.linalg.norm(normal, axis=1)
    nz = normal[:, 2] / np.maximum(double, 1e-300)
    down = nz < -_LOOKS_DOWN
    if not down.any():
        return []
    centroid = tri.mean(axis=1)
    bottom = float(vertices[:, 2].min())
    flat = np.abs(nz) > _LOOKS_DOWN  # a vertical triangle covers nothing
    found = []
    for face in np.unique(owner[down]).tolist():
        pick = np.flatnonzero(down & (owner == face))
        if face in skip or centroid[pick, 2].max() <= bottom + gap:
            continue  # its own report, or the underside op 2 faces
        sample = pick[np.argsort(-double[pick], kind="stable")[:_UNDERCUT_SAMPLES]]
        lo, hi = centroid[sample, :2].min(axis=0), centroid[sample, :2].max(axis=0)
        under = np.flatnonzero(flat & (over.zmin < centroid[sample, 2].max() - gap)
                               & np.all(over.lo <= hi, axis=1) & np.all(over.hi >= lo, axis=1))
        hit = np.array([_covered_below(p, over, under, gap) for p in centroid[sample]])
        if not hit.any():
            continue
        weight = double[sample] * hit
        share = float(weight.sum() / double[sample].sum())  # of the sampled area, how much is covered
        point = (centroid[sample] * weight[:, None]).sum(axis=0) / weight.sum()
        f = info[face]
        direction = f.normal if f.kind == "plane" else (normal[sample] * hit[:, None]).sum(axis=0)
        direction = direction / np.linalg.norm(direction)
        found.append(Undercut(point=tuple(float(c) for c in point), direction=tuple(float(c) for c in direction),
                              area=float(double[pick].sum() / 2 * share), face=face, source="step"))
    return found


def _covered_below(p: np.ndarray, over: "_Over", under: np.ndarray, gap: float) -> bool:
    """Whether one of the triangles ``under`` (indices into ``over``: not vertical, and low enough to
    be) lies more than ``gap`` [mm] under the point ``p`` (3,) [mm]."""
    pick = under[(over.zmin[under] < p[2] - gap) & np.all(over.lo[under] <= p[:2], axis=1)
                 & np.all(over.hi[under] >= p[:2], axis=1)]
    if not len(pick):
        return False
    t = over.xy[pick] - p[:2]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    wa, wb, wc = _cross(b, c), _cross(c, a), _cross(a, b)  # twice the signed areas opposite each corner
    total = wa + wb + wc
    inside = ((wa >= 0) & (wb >= 0) & (wc >= 0)) | ((wa <= 0) & (wb <= 0) & (wc <= 0))
    inside &= np.abs(total) > 1e-300
    if not inside.any():
        return False
    z = (wa * over.z[pick][:, 0] + wb * over.z[pick][:, 1] + wc * over.z[pick][:, 2])[inside] / total[inside]
    return bool((z < p[2] - gap).any())


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Z of the cross products of 2D vectors ``u`` and ``v`` (k, 2) (k,)."""
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def _radial(f: _Face) -> np.ndarray:
    """Unit vector from a cylinder's axis to the middle point of its face."""
    d = f.point - f.location
    d = d - np.dot(d, f.axis) * f.axis
    return d / max(float(np.linalg.norm(d)), 1e-300)


def _bores(info: list[_Face], eps: float) -> list[list[int]]:
    """Cylindrical faces grouped by their axis line and radius: the pieces of one bore or one fillet."""
    groups: list[tuple[float, tuple[float, ...], tuple[float, ...], list[int]]] = []
    for f in info:
        if f.kind != "cylinder":
            continue
        # Plain floats: a part has hundreds of fillets, and numpy's per-call cost would dominate.
        ax, loc = tuple(float(c) for c in f.axis), tuple(float(c) for c in f.location)
        for radius, axis, origin, members in groups:
            if abs(f.radius - radius) > eps or abs(abs(sum(a * b for a, b in zip(ax, axis))) - 1) >= 1e-9:
                continue
            off = [p - q for p, q in zip(loc, origin)]
            along = sum(o * a for o, a in zip(off, axis))
            if math.dist(off, [along * a for a in axis]) <= eps:
                members.append(f.index)
                break
        else:
            groups.append((f.radius, ax, loc, [f.index]))
    return [run for _, axis, origin, members in groups for run in _runs_along(info, members, axis, origin, eps)]


def _runs_along(info: list[_Face], members: list[int], axis: tuple[float, ...], origin: tuple[float, ...],
                eps: float) -> list[list[int]]:
    """``members`` (cylinder faces on one axis line) split where their spans along it leave a gap wider than
    ``eps`` [mm]: coaxial bores of one size in two plates with air between are two holes, not one through both.

    A face's span is its V range (the point at parameter v lies ``v`` along its own axis from its location),
    measured along ``axis`` from ``origin``."""
    spans = []
    for i in members:
        f = info[i]
        start = sum((p - q) * a for p, q, a in zip((float(c) for c in f.location), origin, axis))
        along = sum(float(b) * a for b, a in zip(f.axis, axis))  # +1 or -1
        ends = [start + along * float(v) for v in f.v]
        spans.append((min(ends), max(ends), i))
    spans.sort()
    runs: list[list[int]] = []
    reach = -math.inf
    for lo, hi, i in spans:
        if lo > reach + eps:
            runs.append([])
        runs[-1].append(i)
        reach = max(reach, hi)
    return runs


def _z_range(walls: list[_Face]) -> tuple[float, float]:
    """Lowest and highest Z of cylinder faces along Z [mm]: exact, from their V parameters."""
    zs = [float(f.location[2] + f.axis[2] * v) for f in walls for v in f.v]
    return min(zs), max(zs)


def _setup_hole(walls: list[_Face], reason: str) -> SetupHole:
    w = walls[0]
    axis = w.axis / np.linalg.norm(w.axis)
    ts = [float(v) for f in walls for v in f.v]  # the axis point at parameter v is location + v * axis
    t0, t1 = min(ts), max(ts)
    mid = w.location + axis * (t0 + t1) / 2
    direction = axis if (axis[2], axis[1], axis[0]) > (0, 0, 0) else -axis
    return SetupHole(point=tuple(float(c) for c in mid), direction=tuple(float(c) for c in direction),
                     diameter=2 * w.radius, length=t1 - t0, reason=reason, source="step")


def _round_hole(walls: list[_Face], group: list[int], info: list[_Face], near: _Adjacency,
                eps: float) -> RoundHole:
    """A full bore along Z: its exact size and what ends it at the bottom."""
    w = walls[0]
    bottom, top = _z_range(walls)
    x, y, r = float(w.location[0]), float(w.location[1]), w.radius
    end, tip = "other", bottom
    for j in set().union(*(near.of(i) for i in group)) - set(group):
        n = info[j]
        if n.kind == "plane" and abs(abs(float(n.normal[2])) - 1) < _ALONG_Z and abs(float(n.point[2]) - bottom) <= eps:
            if n.normal[2] < 0:
                end = "through"  # the bore's bottom edge lies on a face looking down: it opens below
            else:
                disk = math.pi * r * r
                end = "flat" if abs(n.area - disk) <= 1e-6 * disk else "stepped"
            break
        if n.kind == "cone" and n.apex is not None and abs(abs(float(n.axis[2])) - 1) < _ALONG_Z \
                and math.hypot(n.apex[0] - x, n.apex[1] - y) <= eps and n.apex[2] < bottom - eps:
            end, tip = "conical", float(n.apex[2])
            break
    sink = None
    for j in set().union(*(near.of(i) for i in group)) - set(group):
        n = info[j]
        if n.kind == "cone" and n.apex is not None and abs(abs(float(n.axis[2])) - 1) < _ALONG_Z \
                and math.hypot(n.apex[0] - x, n.apex[1] - y) <= eps and n.point[2] > top - eps:
            sink = _countersink(n)  # a cone over the bore's mouth, widening upwards
            break
    return RoundHole(x=x, y=y, diameter=2 * r, top_z=top, bottom_z=bottom, tip_z=tip,
                     bottom=end, source="step", countersink=sink)  # type: ignore[arg-type]


def _countersink(cone: _Face) -> Countersink:
    """The countersink a cone face along Z is: its diameter and height at its upper edge, its included angle.

    OpenCASCADE's cone: at parameter v the radius is ``R + v sin(a)`` and the point lies ``v cos(a)``
    along the axis from its location (``a`` the semi-angle)."""
    a = cone.semi_angle
    ends = [(float(cone.location[2] + cone.axis[2] * v * math.cos(a)), cone.radius + v * math.sin(a)) for v in cone.v]
    top_z, radius = max(ends)
    return Countersink(diameter=2 * abs(radius), angle=math.degrees(2 * abs(a)), top_z=top_z)


def _with_counterbores(holes: list[RoundHole], eps: float) -> list[RoundHole]:
    """Each stepped bore whose floor is the mouth of a narrower bore on its axis becomes that bore's counterbore."""
    stepped = [h for h in holes if h.bottom == "stepped"]
    taken: set[int] = set()
    out = []
    for h in holes:
        if h.bottom == "stepped":
            continue
        for k, wide in enumerate(stepped):
            if k not in taken and math.hypot(wide.x - h.x, wide.y - h.y) <= eps and wide.diameter > h.diameter \
                    and abs(wide.bottom_z - h.top_z) <= eps:
                taken.add(k)
                h = dataclasses.replace(h, counterbore=Counterbore(wide.diameter, wide.top_z, wide.bottom_z))
                break
        out.append(h)
    return out + [w for k, w in enumerate(stepped) if k not in taken]


def _open_above(hole: RoundHole, over: "_Over", chord: float, eps: float) -> bool:
    """Nothing of the part over the bore: no triangle above its top reaches into its circle (less the chord)."""
    reach = hole.diameter / 2 - 2 * chord
    pick = (over.zc > hole.top_z + max(eps, chord)) & np.all(over.lo <= (hole.x + reach, hole.y + reach), axis=1) \
        & np.all(over.hi >= (hole.x - reach, hole.y - reach), axis=1)
    if not pick.any():
        return True
    t = over.xy[pick] - np.array([hole.x, hole.y])
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    # The disk meets a triangle when its centre is inside it or an edge passes within reach.
    s1, s2, s3 = _cross(a, b - a), _cross(b, c - b), _cross(c, a - c)
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))

    def dist(p, q):
        d = q - p
        length2 = np.maximum((d * d).sum(axis=1), 1e-300)
        k = np.clip(-(p * d).sum(axis=1) / length2, 0.0, 1.0)
        return np.hypot(*(p + k[:, None] * d).T)

    near = np.minimum(np.minimum(dist(a, b), dist(b, c)), dist(c, a)) < reach
    return not bool((inside | near).any())


@dataclass(frozen=True)
class _Over:
    """The tessellation as :func:`_open_above` and :func:`_covered_below` look at it: triangles' XY
    corners (m, 3, 2) [mm], their XY boxes (m, 2) [mm], their corners' Z (m, 3) [mm], the Z of their
    centroids (m,) [mm] and their lowest Z (m,) [mm]."""

    xy: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    z: np.ndarray
    zc: np.ndarray
    zmin: np.ndarray

    @classmethod
    def of(cls, vertices: np.ndarray, triangles: np.ndarray) -> "_Over":
        tri = vertices[triangles]
        xy, z = tri[:, :, :2], tri[:, :, 2]
        return cls(xy=xy, lo=xy.min(axis=1), hi=xy.max(axis=1), z=z, zc=z.mean(axis=1), zmin=z.min(axis=1))
