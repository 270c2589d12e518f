"""Part intake: every format reads back the same solid, and every bad file is refused clearly."""

from __future__ import annotations

import hashlib
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.mesh import load_part
from factory.core.errors import MeshError

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
SAMPLE_NAMES = ["bracket", "plate_bosses", "dome_mould", "stepped_wall"]


def box(extents=(20.0, 30.0, 10.0), at=(5.0, -3.0, 2.0)) -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=extents)
    b.apply_translation(np.asarray(at) + np.asarray(extents) / 2)
    return b


def write_3mf(path: Path, mesh: trimesh.Trimesh, unit: str = "millimeter", item_transform: str | None = None) -> None:
    """A minimal core-spec 3MF package (what slicers and CAD write, without extensions)."""
    ns = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
    verts = "".join(f'<vertex x="{x!r}" y="{y!r}" z="{z!r}"/>' for x, y, z in mesh.vertices.tolist())
    tris = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in mesh.faces.tolist())
    tf = f' transform="{item_transform}"' if item_transform else ""
    model = (
        f'<?xml version="1.0" encoding="UTF-8"?><model unit="{unit}" xmlns="{ns}"><resources>'
        f'<object id="1" type="model"><mesh><vertices>{verts}</vertices><triangles>{tris}</triangles></mesh></object>'
        f'<object id="2" type="model"><components><component objectid="1"/></components></object>'
        f'</resources><build><item objectid="2"{tf}/></build></model>'
    )
    rels = (
        '<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
        '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
        'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/></Relationships>'
    )
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", '<?xml version="1.0"?><Types/>')
        z.writestr("_rels/.rels", rels)
        z.writestr("3D/3dmodel.model", model)


def expect_error(path: Path, *words: str, **kw) -> MeshError:
    with pytest.raises(MeshError) as info:
        load_part(path, **kw)
    err = info.value
    assert err.source == str(path)
    assert str(path) in str(err)
    assert "\n" not in err.message
    for w in words:
        assert w in err.message, err.message
    return err


# --- the shipped samples ---------------------------------------------------------------


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_sample_parts_are_clean_machinable_solids(name):
    path = SAMPLES / f"{name}.stl"
    part = load_part(path)
    mesh = part.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert part.repairs == ()  # CSG output needs no repair
    assert part.scale == 1.0
    assert part.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    size = np.ptp(mesh.vertices, axis=0)
    assert 40 <= size[:2].max() <= 120
    assert len(mesh.faces) <= 20_000
    # No undercuts: a ray straight down from above hits the part at most once in every
    # column except on vertical walls, i.e. no face looks down except the bottom at z = 0.
    down = mesh.face_normals[:, 2] < -1e-6
    assert np.allclose(mesh.triangles_center[down, 2], mesh.bounds[0, 2])


def test_samples_script_is_deterministic(tmp_path):
    import runpy

    script = runpy.run_path(str(SAMPLES / "make_samples.py"))
    script["main"](tmp_path)
    for name in SAMPLE_NAMES:
        assert (tmp_path / f"{name}.stl").read_bytes() == (SAMPLES / f"{name}.stl").read_bytes(), name


# --- formats ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "suffix, writer",
    [
        (".stl", lambda m, p: p.write_bytes(trimesh.exchange.stl.export_stl(m))),
        (".stl", lambda m, p: p.write_text(trimesh.exchange.stl.export_stl_ascii(m))),
        (".obj", lambda m, p: m.export(p, file_type="obj")),
        (".ply", lambda m, p: m.export(p, file_type="ply", encoding="binary")),
        (".ply", lambda m, p: m.export(p, file_type="ply", encoding="ascii")),
        (".3mf", lambda m, p: write_3mf(p, m)),
        (".STL", lambda m, p: p.write_bytes(trimesh.exchange.stl.export_stl(m))),
    ],
    ids=["stl-binary", "stl-ascii", "obj", "ply-binary", "ply-ascii", "3mf", "upper-case-suffix"],
)
def test_every_format_reads_back_the_same_solid(tmp_path, suffix, writer):
    original = box()
    path = tmp_path / f"part{suffix}"
    writer(original, path)
    part = load_part(path)
    assert part.mesh.is_watertight
    assert part.mesh.volume == pytest.approx(original.volume, rel=1e-6)
    np.testing.assert_allclose(part.mesh.bounds, original.bounds, atol=1e-5)


def test_multi_body_file_is_merged(tmp_path):
    path = tmp_path / "two.stl"
    two = trimesh.util.concatenate([box(at=(0, 0, 0)), box(at=(50, 0, 0))])
    path.write_bytes(trimesh.exchange.stl.export_stl(two))
    assert load_part(path).mesh.volume == pytest.approx(2 * 20 * 30 * 10)


def test_3mf_declared_unit_and_build_transform(tmp_path):
    path = tmp_path / "inch.3mf"
    # 2 x 1 x 0.5 inch block, moved by the build item's transform (row-vector convention).
    write_3mf(path, box((2, 1, 0.5), at=(0, 0, 0)), unit="inch", item_transform="1 0 0 0 1 0 0 0 1 3 0 0")
    part = load_part(path)
    assert part.scale == 25.4
    np.testing.assert_allclose(part.mesh.bounds, [[76.2, 0, 0], [127.0, 25.4, 12.7]], atol=1e-6)
    # An explicit --units overrides what the file declares.
    as_mm = load_part(path, units="mm")
    assert as_mm.scale == 1.0
    assert as_mm.mesh.volume == pytest.approx(1.0)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    extents=st.tuples(*[st.floats(1.5, 500) for _ in range(3)]),
    at=st.tuples(*[st.floats(-1000, 1000) for _ in range(3)]),
)
def test_binary_stl_round_trip_keeps_volume_and_bounds(tmp_path, extents, at):
    original = box(extents, at)
    path = tmp_path / "b.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(original))
    part = load_part(path)
    # STL stores float32: relative precision ~1e-7 of the coordinates.
    atol = 1e-6 * (np.abs(original.bounds).max() + 1)
    np.testing.assert_allclose(part.mesh.bounds, original.bounds, atol=atol)
    assert part.mesh.volume > 0


# --- units ----------------------------------------------------------------------------


@pytest.mark.parametrize("units, scale", [("mm", 1.0), ("inch", 25.4), ("m", 1000.0)])
def test_explicit_units_scale_to_mm(tmp_path, units, scale):
    size = {"mm": 50.0, "inch": 2.0, "m": 0.05}[units]
    path = tmp_path / "p.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(box((size, size, size / 2), at=(0, 0, 0))))
    part = load_part(path, units=units)
    assert part.scale == scale
    np.testing.assert_allclose(np.ptp(part.mesh.vertices, axis=0), [size * scale, size * scale, size * scale / 2], rtol=1e-6)


def test_tiny_part_is_refused_as_wrong_units(tmp_path):
    path = tmp_path / "metres.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(box((0.05, 0.03, 0.01), at=(0, 0, 0))))
    expect_error(path, "0.05 mm", "--units m", "--units inch")
    assert load_part(path, units="m").mesh.volume == pytest.approx(50 * 30 * 10, rel=1e-5)


def test_huge_part_is_refused_as_wrong_units(tmp_path):
    path = tmp_path / "huge.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(box((5000, 300, 100), at=(0, 0, 0))))
    expect_error(path, "5000 mm", "units")
    # Already-mm file declared as inches becomes implausibly large: suggest --units mm.
    ok = tmp_path / "mm.stl"
    ok.write_bytes(trimesh.exchange.stl.export_stl(box((100, 80, 20), at=(0, 0, 0))))
    expect_error(ok, "--units mm", units="inch")


# --- bad files -------------------------------------------------------------------------


def test_missing_file(tmp_path):
    expect_error(tmp_path / "nope.stl", "no such file")


def test_unknown_extension(tmp_path):
    path = tmp_path / "part.iges"
    path.write_text("ISO-10303-21;")
    expect_error(path, "unknown part format", ".iges")


@pytest.mark.parametrize("content", [b"", b"   \n"])
def test_empty_file(tmp_path, content):
    path = tmp_path / "empty.stl"
    path.write_bytes(content)
    expect_error(path, "empty")


def test_truncated_binary_stl(tmp_path):
    path = tmp_path / "cut.stl"
    data = trimesh.exchange.stl.export_stl(box())
    path.write_bytes(data[: len(data) - 70])
    expect_error(path, "truncated", "12 triangles")
    path.write_bytes(data[:50])
    expect_error(path, "truncated")


def test_binary_stl_with_trailing_bytes_reads_declared_triangles(tmp_path):
    path = tmp_path / "padded.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(box()) + b"\0" * 37)
    assert load_part(path).mesh.volume == pytest.approx(6000)


def test_binary_stl_whose_header_starts_with_solid_is_still_binary(tmp_path):
    # Some exporters (SolidWorks among them) begin the binary header with "solid".
    data = bytearray(trimesh.exchange.stl.export_stl(box()))
    data[:80] = b"solid part exported by CAD".ljust(80, b" ")
    path = tmp_path / "solidheader.stl"
    path.write_bytes(bytes(data))
    assert load_part(path).mesh.volume == pytest.approx(6000)


def test_garbage_file(tmp_path):
    path = tmp_path / "junk.obj"
    path.write_text("this is not a mesh\n")
    expect_error(path)


def test_nan_vertex(tmp_path):
    m = box()
    data = bytearray(trimesh.exchange.stl.export_stl(m))
    struct.pack_into("<f", data, 84 + 12, float("nan"))  # first vertex x of the first triangle
    path = tmp_path / "nan.stl"
    path.write_bytes(bytes(data))
    expect_error(path, "NaN or infinite")


def test_degenerate_only(tmp_path):
    path = tmp_path / "flat.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    expect_error(path, "degenerate")


def test_no_triangles(tmp_path):
    path = tmp_path / "points.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "end_header\n0 0 0\n1 0 0\n0 1 0\n")
    expect_error(path)


def test_open_mesh_is_a_surface_with_its_boundary_edge_count(tmp_path):
    m = box().subdivide().subdivide()  # each side is 16 edges around
    m.update_faces(m.face_normals[:, 0] < 0.5)  # drop the whole +X side: an open box
    path = tmp_path / "open.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(m))
    part = load_part(path)  # not a solid: machined from above as a relief (tests/cadcam/test_relief.py)
    assert part.surface is not None and part.surface.boundary_edges == 16 and part.surface.shells == 1


def test_single_missing_triangle_is_filled(tmp_path):
    m = box()
    m.update_faces(np.arange(len(m.faces)) != 3)
    path = tmp_path / "hole.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(m))
    part = load_part(path)
    assert part.mesh.is_watertight and part.mesh.volume == pytest.approx(6000)
    assert any("filled" in r for r in part.repairs)


def test_inside_out_mesh_is_flipped(tmp_path):
    m = box()
    m.invert()
    path = tmp_path / "inverted.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(m))
    part = load_part(path)
    assert part.mesh.volume == pytest.approx(6000)
    assert any("flipped" in r for r in part.repairs)


def test_seam_with_near_coincident_vertices_is_welded(tmp_path):
    m = box()
    v, f = m.vertices.copy(), m.faces.copy()
    # Give the +X face its own vertices, 1e-5 mm off: an exporter's seam, open to exact merging.
    side = np.flatnonzero(m.face_normals[:, 0] > 0.5)
    idx = np.unique(f[side])
    remap = np.arange(len(v))
    remap[idx] = len(v) + np.arange(len(idx))
    f[side] = remap[f[side]]
    v = np.vstack([v, v[idx] + 1e-5])
    path = tmp_path / "seam.obj"
    trimesh.Trimesh(v, f, process=False).export(path)
    part = load_part(path)
    assert part.mesh.is_watertight and part.surface is None
    assert part.mesh.volume == pytest.approx(6000, rel=1e-5)
    assert any(r.startswith("welded 4 vertices closer than") for r in part.repairs), part.repairs


def test_duplicate_vertices_in_indexed_format_are_reported(tmp_path):
    m = box()
    # Unmerge: every face gets its own three vertices, as some OBJ exporters write.
    v = m.vertices[m.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    path = tmp_path / "soup.obj"
    path.write_text("".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in v.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f.tolist()))
    part = load_part(path)
    assert part.mesh.volume == pytest.approx(6000)
    assert f"merged {len(v) - 8} duplicate vertices" in part.repairs


def test_bad_units_argument(tmp_path):
    path = tmp_path / "b.stl"
    path.write_bytes(trimesh.exchange.stl.export_stl(box()))
    expect_error(path, "units", units="furlong")


@pytest.mark.parametrize("seed", range(6))
def test_triangle_soup_is_refused_not_repaired_into_slivers(tmp_path, seed):
    """Random triangles in a 30 mm cube once came out "repaired" as a 3e-13 mm^3 solid."""
    from tests.cli.hostile import triangle_soup

    path = tmp_path / "soup.stl"
    path.write_bytes(triangle_soup(seed=seed))
    import warnings

    with pytest.raises(MeshError, match="disjoint triangles|no volume|of its bounding box|of the surface") as e, \
            warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's divide-by-zero warnings would be lines beside the error
        load_part(path)
    assert e.value.source == str(path) and "\n" not in e.value.message


def test_thin_walled_tube_fills_enough_of_its_box(tmp_path):
    """A 50 mm tube with a 1 mm wall fills about 8 % of its box: a real part, kept."""
    tube = trimesh.creation.annulus(r_min=24.0, r_max=25.0, height=100.0, sections=64)
    tube.export(tmp_path / "tube.stl")
    part = load_part(tmp_path / "tube.stl")
    assert part.mesh.volume == pytest.approx(tube.volume, rel=1e-6)
