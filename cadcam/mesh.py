"""Part intake: read a CAD mesh, weld and orient it, judge it a closed solid or a surface, bring it to mm.

:func:`load_part` is the single door through which a part file enters the toolchain: it reads
STL (ASCII and binary), OBJ, PLY and 3MF, welds vertices closer than a tolerance scaled to the
mesh (so a solid stored as unwelded triangles stays a solid), drops degenerate and duplicate
triangles, repairs what can be repaired cheaply (flipped faces, small holes, non-manifold seams
via a manifold3d rebuild), and only then judges what it holds:

* a **closed solid** (watertight, outward-facing): ``PartMesh.surface`` is None;
* else a **coherent open surface** (a relief, a terrain sheet, several sheets touching at
  non-manifold edges), wound consistently and turned to face up, to be machined from above
  (:mod:`cadcam.relief`): ``PartMesh.surface`` says what was found.

It says what it repaired, and refuses with a :class:`~factory.core.errors.MeshError` what it cannot
trust: truncated files, non-finite vertices, implausible sizes, and meshes with no surface to
machine (a soup of disjoint triangles, a surface facing down, an envelope with gaps over most of
its footprint; the criteria are in :func:`cadcam.relief.judge_surface`).

The mesh keeps the file's own axes: only unit scaling is applied here. Placing the part in
the stock is :mod:`cadcam.setup`'s job.
"""

from __future__ import annotations

import hashlib
import io
import logging
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import trimesh

from cadcam.model import MAX_EXTENT_MM
from factory.core.errors import MeshError, SetupError

if TYPE_CHECKING:
    from cadcam.relief import SurfaceFound
    from cadcam.step import StepPart

log = logging.getLogger(__name__)

Units = Literal["auto", "mm", "inch", "m"]

#: Factor from each accepted ``--units`` value to millimetres.
UNIT_SCALE: dict[str, float] = {"mm": 1.0, "inch": 25.4, "m": 1000.0}


def units_of_scale(scale: float, source: str | None = None) -> Units:
    """The ``--units`` value whose factor to mm is ``scale`` (a setup sheet's ``mesh_scale``).

    Raises
    ------
    SetupError
        ``scale`` is not 1, 25.4 or 1000.
    """
    for name, factor in UNIT_SCALE.items():
        if float(scale) == factor:
            return name  # type: ignore[return-value]
    raise SetupError(f"mesh_scale {scale} is not mm, inch or m", source=source)

#: Smallest plausible part extent [mm]: below a millimetre (or above :data:`cadcam.model.MAX_EXTENT_MM`)
#: the file is far more likely in the wrong units than a real job for a milling machine.
MIN_EXTENT_MM = 1.0

def inch_hint(extent: float, units: str, scale: float) -> str | None:
    """The fix to name when a part ``extent`` [mm] across (its largest side) is refused as too small
    (too thin to grip, ...): ``--units inch``, when its units were guessed (``units`` "auto" and no
    unit in the file: ``scale`` 1) and the part read as inches (x25.4) is an ordinary size (at most
    :data:`cadcam.model.MAX_EXTENT_MM`). None when the file's units are known or inches would not help.
    """
    if units != "auto" or scale != 1.0 or not MIN_EXTENT_MM <= extent * UNIT_SCALE["inch"] <= MAX_EXTENT_MM:
        return None
    return "if the file is in inches, give --units inch"


_FORMATS = {".stl": "stl", ".obj": "obj", ".ply": "ply", ".3mf": "3mf", ".step": "step", ".stp": "step"}


# Vertices closer than this fraction of the part size are one vertex (1 um on a 100 mm part: far
# below any machining tolerance, far above the float32 rounding of an STL's coordinates).
_WELD_TOLERANCE = 1e-5

# Triangles with less area than this [file units^2] are slivers that carry no surface.
_DEGENERATE_AREA = 1e-12
#: Least fraction of its bounding box a repaired solid must fill. A thin-walled tube fills a
#: few per cent; a triangle soup "repaired" into slivers fills 1e-17.
MIN_BOX_FILL = 1e-3
#: Least fraction of the file's surface a manifold3d rebuild must keep: welding seams moves
#: vertices by nanometres, it does not discard faces wholesale.
MIN_SURFACE_KEPT = 0.5


@dataclass(frozen=True)
class PartMesh:
    """A part as read from its file: a closed solid or an open surface, in millimetres.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        A solid: watertight, consistently wound, outward normals (positive volume). A surface
        (``surface`` is not None): welded, each shell wound consistently and facing up. In
        millimetres, in the file's own axes (only scaled, never moved or rotated).
    scale : float
        Factor applied to go from file units to mm (1, 25.4 or 1000; or the 3MF unit).
    sha256 : str
        Hex SHA-256 of the file's bytes, for traceability into the job and G-code header.
    repairs : tuple of str
        Human-readable notes of what was repaired, e.g. ``"merged 12 duplicate vertices"``.
        Empty when the file was clean.

    surface : SurfaceFound or None
        None for a closed solid; for an open surface, what was found (boundary edges, shells,
        footprint [mm]): it is machined from above as a relief.
    step : StepPart or None
        For a STEP file (:mod:`cadcam.step`): its unit, tessellation and the features read from
        its exact B-rep; None for a mesh file.
    """

    mesh: trimesh.Trimesh
    scale: float
    sha256: str
    repairs: tuple[str, ...]
    surface: SurfaceFound | None = None
    step: StepPart | None = None

    def sheet_record(self) -> dict | None:
        """A STEP part's ``intake`` for the setup sheet (:meth:`cadcam.step.StepPart.sheet_record`): what
        :func:`load_planned_part` needs to read it again as planned; None for a mesh (its sheet's
        ``mesh_scale`` says all)."""
        return None if self.step is None else self.step.sheet_record()

    def intake_summary(self) -> dict:
        """``{"intake": ...}`` for the plan summary of a STEP part (unit, chordal deviation, features); {} for a mesh."""
        return {} if self.step is None else {"intake": self.step.to_dict()}


def load_part(path: str | Path, units: Units = "auto", *, tolerance: float | None = None,
              body: int | None = None) -> PartMesh:
    """Read a part file, check and repair it, and scale it to millimetres.

    Parameters
    ----------
    path : str or Path
        STL (ASCII or binary), OBJ, PLY, 3MF or STEP (``.step``, ``.stp``) file. Multi-body
        mesh files (scenes) are merged into one mesh; a STEP file's solid is chosen by ``body``.
    units : {"auto", "mm", "inch", "m"}
        Units of the file's coordinates. ``"auto"`` takes the unit a 3MF or STEP file declares,
        and millimetres for every other format. A STEP file's own unit always holds: another
        ``units`` is refused.
    tolerance : float, optional
        STEP only: the CAM tolerance [mm] its tessellation's chordal deviation is a share of
        (:func:`cadcam.step.chordal_deviation`); default :data:`cadcam.step.CAM_TOLERANCE`.
    body : int, optional
        STEP only: which solid (1-based) of a file with several.

    Returns
    -------
    PartMesh

    Raises
    ------
    MeshError
        With ``source=path``: missing or unreadable file, unknown extension, empty or
        truncated file, no triangles, NaN/inf vertices, only degenerate triangles, a mesh
        that is neither a closed solid nor a surface to machine from above (names the test
        that failed and its figure), or a size that is implausible in the given units
        (suggests ``--units``).
    """
    path = Path(path)
    if units not in ("auto", *UNIT_SCALE):
        raise MeshError(f"unknown units {units!r}: expected auto, mm, inch or m", source=path)
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise MeshError(
            f"unknown part format {path.suffix or '(no extension)'!r}: expected .stl, .obj, .ply, .3mf, .step or .stp",
            source=path,
        )
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise MeshError("no such file", source=path) from None
    except IsADirectoryError:
        raise MeshError("is a directory, not a mesh file", source=path) from None
    except OSError as e:
        raise MeshError(f"cannot read file: {e.strerror or e}", source=path) from None
    if not data.strip():
        raise MeshError("file is empty", source=path)
    sha = hashlib.sha256(data).hexdigest()

    step = None
    if fmt == "step":
        from cadcam.step import CAM_TOLERANCE, read_step  # OpenCASCADE loads only for STEP files

        step = read_step(path, CAM_TOLERANCE if tolerance is None else tolerance, body)
        if units not in ("auto", step.units):
            raise MeshError(f"the STEP file states its unit as {step.unit}: --units {units} contradicts it",
                            source=path)
        vertices, faces, declared_scale = step.vertices, step.faces, step.scale
    else:
        if fmt == "stl":
            data = _check_stl_size(data, path)
        vertices, faces, declared_scale = _read_with_trimesh(data, fmt, path)

    if units == "auto":
        scale = declared_scale if declared_scale is not None else 1.0
    else:
        scale = UNIT_SCALE[units]

    # A shell enclosing no volume makes trimesh divide by zero for its centre of mass: the
    # check below reports that in one line, numpy's warnings would add six more.
    with np.errstate(divide="ignore", invalid="ignore"):
        mesh, repairs = _make_solid(vertices, faces, fmt, path)
    surface = None
    if not (mesh.is_watertight and mesh.is_winding_consistent):
        from cadcam.relief import judge_surface  # the relief module needs shapely; solids do not

        mesh, surface, notes = judge_surface(mesh, scale if step is None else 1.0, source=str(path))
        repairs += notes
    if scale != 1.0 and step is None:  # OpenCASCADE gives a STEP file's coordinates in mm already
        mesh.apply_scale(scale)
    _check_size(mesh, units, path)
    for note in repairs:
        log.info("%s: %s", path, note)
    return PartMesh(mesh=mesh, scale=float(scale), sha256=sha, repairs=tuple(repairs), surface=surface, step=step)


def load_planned_part(path: str | Path, mesh_scale: float, intake: Mapping[str, Any] | None = None, *,
                      tolerance: float | None = None, source: str | None = None) -> PartMesh:
    """The part file a setup sheet was made for, read as it was planned.

    A mesh is read in the units of the sheet's ``mesh_scale``. A STEP file is read in its own
    unit, with the solid (``body``) and tessellation tolerance of the sheet's ``intake``
    (:meth:`PartMesh.sheet_record`); ``tolerance`` [mm], when given and positive, tessellates to that
    CAM tolerance instead (verify's gouge tolerance: its chordal deviation a share of what is judged).

    Raises
    ------
    MeshError
        The file cannot be read (:func:`load_part`).
    SetupError
        With ``source`` (the sheet): ``mesh_scale`` is no unit a mesh is read in, or a STEP file's
        unit is not the sheet's: not the part the program was made for.
    """
    path = Path(path)
    if _FORMATS.get(path.suffix.lower()) != "step":
        return load_part(path, units_of_scale(mesh_scale, source))
    intake = intake or {}
    if tolerance is None or not tolerance > 0:
        tolerance = intake.get("tolerance_mm")
    body = intake.get("body")
    loaded = load_part(path, "auto", tolerance=None if tolerance is None else float(tolerance),
                       body=None if body is None else int(body))
    if loaded.scale != float(mesh_scale):
        raise SetupError(f"{path} is in {loaded.step.unit} (x{loaded.scale:g} to mm), the sheet's mesh_scale is "
                         f"{float(mesh_scale):g}: not the part the program was made for", source=source)
    return loaded


def _check_stl_size(data: bytes, path: Path) -> bytes:
    """Refuse a binary STL whose declared triangle count does not fit the file size.

    A truncated binary STL is otherwise read as fewer triangles, garbage, or a confusing
    ASCII-parser error; the header's count is the only way to tell. Returns the bytes to
    parse: ASCII files unchanged, binary files cut to the declared triangles.
    """
    if len(data) >= 84:
        (count,) = struct.unpack_from("<I", data, 80)
        expected = 84 + 50 * count
        if len(data) == expected:
            return data
    else:
        count, expected = None, None
    if _looks_ascii_stl(data):
        return data
    if count is None:
        raise MeshError(f"truncated binary STL: {len(data)} bytes, shorter than the 84-byte header", source=path)
    if len(data) < expected:
        raise MeshError(
            f"truncated binary STL: header declares {count} triangles ({expected} bytes) "
            f"but the file has {len(data)} bytes",
            source=path,
        )
    # Some exporters pad or append data after the triangles; the declared count still rules.
    log.warning("%s: %d bytes after the %d declared triangles ignored", path, len(data) - expected, count)
    return data[:expected]


def _looks_ascii_stl(data: bytes) -> bool:
    head = data[:2048].lstrip()
    if not head[:5].lower() == b"solid":
        return False
    try:
        head.decode("ascii")
    except UnicodeDecodeError:
        return False
    return b"facet" in head or b"endsolid" in head


def _read_with_trimesh(data: bytes, fmt: str, path: Path) -> tuple[np.ndarray, np.ndarray, float | None]:
    """Vertices, faces and, for 3MF, the factor from the unit the file declares to mm."""
    try:
        # process=False: we merge and repair ourselves so that we can report what changed.
        loaded = trimesh.load(io.BytesIO(data), file_type=fmt, process=False)
        declared_scale = None
        if fmt == "3mf":
            # 3MF is the one format that declares its unit (default millimetre).
            declared_scale = trimesh.units.unit_conversion(loaded.units or "millimeters", "millimeters")
        if isinstance(loaded, trimesh.Scene):
            loaded = loaded.to_geometry()  # applies build and component transforms
    except Exception as e:  # trimesh raises anything from ValueError to IndexError on bad files
        raise MeshError(f"cannot read {fmt.upper()} file: {_one_line(e)}", source=path) from None
    if isinstance(loaded, list):  # older trimesh returns a list for multi-body files
        loaded = trimesh.util.concatenate(loaded) if loaded else trimesh.Trimesh()
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{fmt.upper()} file holds no triangle mesh", source=path)
    return (np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64),
            declared_scale)


def _make_solid(
    vertices: np.ndarray, faces: np.ndarray, fmt: str, path: Path
) -> tuple[trimesh.Trimesh, list[str]]:
    """Weld raw triangles and make them a closed, outward-facing solid where they are one.

    Returns the mesh as welded and cleaned, but open, when it is not a closed solid and
    cannot be repaired into one: :func:`cadcam.relief.judge_surface` decides what it is.
    """
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError("no triangles in file", source=path)
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices).all(axis=1)).sum())
        raise MeshError(f"{bad} vertices are NaN or infinite", source=path)
    repairs: list[str] = []
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)

    n0 = len(mesh.vertices)
    mesh.merge_vertices()
    merged = n0 - len(mesh.vertices)
    # STL stores every triangle's corners separately: merging is reading, not repairing.
    if merged and fmt not in ("stl", "step"):
        repairs.append(f"merged {merged} duplicate vertices")
    tol = _WELD_TOLERANCE * float(np.ptp(mesh.vertices, axis=0).max())
    mesh, welded = _weld(mesh, tol)
    if welded:
        repairs.append(f"welded {welded} vertices closer than {tol:.2g} file units")

    area = mesh.area_faces
    keep = area > _DEGENERATE_AREA * max(1.0, float(np.ptp(mesh.vertices, axis=0).max()) ** 2)
    # Also drop faces whose corners coincide after merging (zero area, possibly index-equal).
    f = mesh.faces
    keep &= (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    if not keep.any():
        raise MeshError(f"all {len(f)} triangles are degenerate (zero area)", source=path)
    if not keep.all():
        repairs.append(f"removed {int((~keep).sum())} degenerate triangles")
        mesh.update_faces(keep)
    n_faces = len(mesh.faces)
    mesh.update_faces(mesh.unique_faces())
    if len(mesh.faces) != n_faces:
        repairs.append(f"removed {n_faces - len(mesh.faces)} duplicate triangles")
    mesh.remove_unreferenced_vertices()

    if not (mesh.is_watertight and mesh.is_winding_consistent):
        from cadcam.relief import check_sheet

        # Disjoint triangles are neither a solid to repair nor a surface: say so before trying.
        check_sheet(mesh.faces, source=str(path))
        unfilled = mesh.copy()
        fix_winding(unfilled)
        filled = 0
        if _boundary_edges(mesh):
            before = len(mesh.faces)
            trimesh.repair.fill_holes(mesh)
            filled = len(mesh.faces) - before
        if mesh.is_watertight:  # reversing faces never closes a mesh: an open one is dropped below unwound
            fix_winding(mesh)
        if mesh.is_watertight and mesh.is_winding_consistent:
            repairs.append(f"filled small holes with {filled} triangles" if filled else "made face winding consistent")
        else:
            # Hole filling only helps real holes; seams of near-coincident vertices are
            # manifold3d's job, and the sliver triangles fill_holes may have added would
            # only get in its way.
            mesh = unfilled
            area_before = float(mesh.area)
            rebuilt = _manifold_rebuild(mesh)
            if rebuilt is None:
                # Not a solid: an open surface, judged by the caller (cadcam.relief.judge_surface).
                return mesh, repairs
            kept = float(rebuilt.area) / area_before
            if kept < MIN_SURFACE_KEPT:
                raise MeshError(f"repair kept {kept:.1%} of the surface (less than {MIN_SURFACE_KEPT:.0%}): not a "
                                "closed shell; close it in CAD and re-export", source=path)
            mesh = rebuilt
            repairs.append("rebuilt with manifold3d")

    if mesh.volume < 0:
        mesh.invert()
        repairs.append("flipped inside-out normals")
    if not mesh.volume > 0:
        raise MeshError("mesh encloses no volume", source=path)
    box = float(np.prod(np.ptp(mesh.vertices, axis=0)))
    fill = float(mesh.volume) / box if box > 0 else 0.0
    if fill < MIN_BOX_FILL:
        raise MeshError(f"solid fills {fill:.2g} of its bounding box (less than {MIN_BOX_FILL:g}): "
                        f"{float(mesh.volume):.3g} mm^3 in {box:.3g} mm^3; not a solid part", source=path)
    return mesh, repairs


def fix_winding(mesh: trimesh.Trimesh) -> None:
    """Make each connected piece's faces wound alike, in place: :func:`trimesh.repair.fix_winding`'s result.

    trimesh walks every piece breadth-first from a start face, reversing (``[a, b, c]`` to
    ``[c, b, a]``) each face whose shared edge with its parent runs the same way, one pair at a
    time in Python (3.7 s on a 100k-triangle relief). Where a piece can be wound consistently,
    that winding is unique once the start face keeps its own, so it is found here at once: faces
    and their two windings are nodes of one graph, joined where the windings agree across a
    shared edge, and a face is reversed when its own winding is not joined to its start face's.
    The start faces are trimesh's (the same networkx calls pick them). A piece that cannot be
    wound consistently (one-sided, or faces crossing a seam twice) has a walk-dependent answer:
    the mesh is then left to trimesh itself.
    """
    if mesh.is_winding_consistent:
        return
    import networkx as nx
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(mesh.faces, dtype=np.int64)
    n = len(faces)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    pairs = trimesh.grouping.group_rows(np.sort(edges, axis=1), require_count=2)
    if len(pairs) == 0:
        return
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    a, b = pairs[:, 0] // 3, pairs[:, 1] // 3
    # The same direction along the shared edge: the two faces disagree.
    disagree = (edges[pairs[:, 0], 0] == edges[pairs[:, 1], 0]).astype(np.int64)
    # Node 2f is face f as it is, 2f + 1 reversed; agreeing windings are joined.
    rows = np.concatenate([2 * a, 2 * a + 1])
    cols = np.concatenate([2 * b + disagree, 2 * b + 1 - disagree])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(2 * n, 2 * n))
    _, label = connected_components(graph, directed=False)
    as_is, reversed_ = label[0::2], label[1::2]
    if np.any(as_is == reversed_):
        trimesh.repair.fix_winding(mesh)  # not orientable: the walk decides, as before
        return
    graph_all = nx.from_edgelist(mesh.face_adjacency)
    roots = np.array([next(iter(graph_all.subgraph(c).nodes())) for c in nx.connected_components(graph_all)],
                     dtype=np.int64)
    # Each piece's start face keeps its winding: its label is the piece's "as is".
    keep = np.zeros(2 * n, dtype=bool)  # indexed by label (at most 2n of them)
    keep[as_is[roots]] = True
    flip = ~keep[as_is]
    flip[~np.isin(np.arange(n), np.asarray(mesh.face_adjacency).ravel())] = False  # faces with no neighbour
    if flip.any():
        fixed = faces.copy()
        fixed[flip] = fixed[flip][:, ::-1]
        mesh.faces = fixed


def _weld(mesh: trimesh.Trimesh, tol: float) -> tuple[trimesh.Trimesh, int]:
    """Merge vertices closer than ``tol`` [file units]; the mesh and how many vertices went.

    Exporters that write every triangle on its own (or round each one's corners separately)
    leave a solid's neighbours a float's rounding apart: exact merging leaves it open.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    if tol <= 0 or len(vertices) < 2:
        return mesh, 0
    pairs = cKDTree(vertices).query_pairs(tol, output_type="ndarray")
    if not len(pairs):
        return mesh, 0
    n = len(vertices)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    first = np.full(count, -1)
    first[label[::-1]] = np.arange(n)[::-1]  # each group takes its first member's position
    welded = trimesh.Trimesh(vertices=vertices[first], faces=label[np.asarray(mesh.faces)], process=False,
                             validate=False)
    return welded, n - count


def _boundary_edges(mesh: trimesh.Trimesh) -> int:
    """Number of edges used by exactly one triangle."""
    return int(len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)))


def _manifold_rebuild(mesh: trimesh.Trimesh) -> trimesh.Trimesh | None:
    """Weld near-coincident open seams, let manifold3d rebuild the solid; None if it fails.

    CAD exporters often write a seam's two sides with vertices a few nanometres apart, so
    exact vertex merging leaves open edges there. Vertices on open edges closer than the
    weld tolerance are merged, then manifold3d checks that the result is a closed
    2-manifold (its status) and returns it cleanly triangulated.
    """
    import manifold3d
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    tol = _WELD_TOLERANCE * float(np.ptp(vertices, axis=0).max())
    open_edges = mesh.edges_sorted[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    seam = np.unique(open_edges)
    if len(seam):
        pairs = cKDTree(vertices[seam]).query_pairs(tol, output_type="ndarray")
        if len(pairs):
            n = len(vertices)
            graph = coo_matrix((np.ones(len(pairs)), (seam[pairs[:, 0]], seam[pairs[:, 1]])), shape=(n, n))
            _, label = connected_components(graph, directed=False)
            faces = label[faces]
            faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
            # Each welded vertex takes the position of its group's first member.
            first = np.full(label.max() + 1, -1)
            first[label[::-1]] = np.arange(n)[::-1]
            vertices = vertices[first]
    try:
        solid = manifold3d.Manifold(
            manifold3d.Mesh(
                vert_properties=np.ascontiguousarray(vertices, dtype=np.float32),
                tri_verts=np.ascontiguousarray(faces, dtype=np.uint32),
            )
        )
    except Exception as e:  # pragma: no cover - depends on manifold3d internals
        log.debug("manifold3d rebuild failed: %s", e)
        return None
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        log.debug("manifold3d rebuild: status %s", solid.status())
        return None
    out = solid.to_mesh()
    result = trimesh.Trimesh(
        vertices=np.asarray(out.vert_properties[:, :3], dtype=np.float64),
        faces=np.asarray(out.tri_verts, dtype=np.int64),
        process=True,
    )
    if not (result.is_watertight and result.is_winding_consistent):
        return None
    return result


def _check_size(mesh: trimesh.Trimesh, units: str, path: Path) -> None:
    extent = float(np.ptp(mesh.vertices, axis=0).max())
    shown = f"{extent:.0f}" if extent >= 100 else f"{extent:.1f}" if extent >= 1 else f"{extent:.3g}"
    size = f"{shown} mm across"
    if extent < MIN_EXTENT_MM:
        if units in ("auto", "mm"):
            hint = "probably in metres or inches; pass --units m or --units inch"
        elif units == "inch":
            hint = "probably in metres; pass --units m"
        else:
            hint = "too small to machine even in metres"
        raise MeshError(f"part is {size}: {hint}", source=path)
    if extent > MAX_EXTENT_MM:
        if units in ("auto", "mm"):
            hint = (
                f"larger than {MAX_EXTENT_MM:g} mm, probably not in millimetres (micrometres?); "
                "re-export it in mm, inch or m units"
            )
        else:
            hint = "probably already in millimetres; pass --units mm"
        raise MeshError(f"part is {size}: {hint}", source=path)


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__
