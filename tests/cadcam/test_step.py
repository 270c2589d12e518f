"""STEP intake (cadcam.step) and the features read from the B-rep (cadcam.features), on parts modelled with build123d.

Every recognised size is checked against the modelling parameter to 1e-6 mm; the holes then go
through the drilling stage (cadcam.drilling.plan_holes) and must get a drill or a helix of their size.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

pytest.importorskip("build123d")

from cadcam.drilling import DrillingOptions, plan_holes  # noqa: E402
from cadcam.mesh import load_part  # noqa: E402
from cadcam.plan import PlanOptions, choose_tools  # noqa: E402
from cadcam.setup import make_setup  # noqa: E402
from cadcam.step import CAM_TOLERANCE, CHORD_SHARE, chordal_deviation, read_step  # noqa: E402
from cadcam.tools import load_tool_library  # noqa: E402
from cadcam.verify import VerifyOptions  # noqa: E402
from factory.core.errors import FactoryError, MeshError  # noqa: E402
from tests.cadcam.stepparts import (ModelledHole, bored_plates, countersunk_head, dovetail,  # noqa: E402
                                    inclined_hole, pillow_surface, plate, t_slot, two_solids, write_step)

EXACT = 1e-6  # [mm]


def _match(found, modelled: ModelledHole, thickness: float) -> None:
    """``found`` (a RoundHole) is ``modelled`` to 1e-6 mm: place, size, depth, bottom."""
    assert found.source == "step"
    assert abs(found.x - modelled.x) < EXACT and abs(found.y - modelled.y) < EXACT
    assert abs(found.diameter - modelled.diameter) < EXACT
    assert abs(found.top_z) < EXACT
    if modelled.depth is None:
        assert found.bottom == "through"
        assert abs(found.bottom_z + thickness) < EXACT and abs(found.depth - thickness) < EXACT
    else:
        assert found.bottom == modelled.bottom
        assert abs(found.bottom_z + modelled.depth) < EXACT
        assert abs(found.depth - modelled.tip_depth) < EXACT


def _by_place(holes):
    return {(round(h.x, 3), round(h.y, 3)): h for h in holes}


def test_the_cam_tolerance_is_verifys():
    assert CAM_TOLERANCE == VerifyOptions().gouge_tolerance
    assert chordal_deviation(0.01) == pytest.approx(CHORD_SHARE * 0.01)


def test_plate_with_through_and_blind_holes_is_read_exactly(tmp_path):
    modelled = [ModelledHole(-20, -8, 5.0, None), ModelledHole(-20, 8, 3.3, None),
                ModelledHole(0, 0, 6.8, 7.0, "flat"), ModelledHole(18, -8, 4.2, 5.5, "conical"),
                ModelledHole(18, 8, 8.5, 4.0, "conical")]
    path = write_step(plate((60, 40, 10), modelled), tmp_path / "plate.step")
    loaded = load_part(path)
    assert loaded.surface is None and loaded.mesh.is_watertight
    assert loaded.scale == 1.0 and loaded.step.unit in ("MM", "MILLIMETRE")
    assert loaded.step.chordal_deviation == pytest.approx(CHORD_SHARE * CAM_TOLERANCE)
    # the tessellation never lies further than the chordal deviation inside a bore's true wall
    found = _by_place(loaded.step.features.holes)
    assert len(found) == len(modelled)
    for m in modelled:
        _match(found[(m.x, m.y)], m, 10.0)
        v = loaded.mesh.vertices
        r = np.hypot(v[:, 0] - m.x, v[:, 1] - m.y)
        ring = np.abs(r - m.diameter / 2) < 0.05
        assert ring.any() and (r[ring] > m.diameter / 2 - loaded.step.chordal_deviation - 1e-9).all()
    flats = loaded.step.features.flats
    assert [f.z for f in flats if f.facing == "up"][0] == pytest.approx(0.0, abs=EXACT)
    assert any(f.facing == "up" and abs(f.z + 7.0) < EXACT for f in flats)  # the flat-bottom hole's floor
    assert any(f.facing == "down" and abs(f.z + 10.0) < EXACT for f in flats)
    assert loaded.step.features.elsewhere == ()


def test_a_finer_tolerance_tessellates_finer(tmp_path):
    path = write_step(plate((30, 30, 8), [ModelledHole(0, 0, 10.0, None)]), tmp_path / "p.step")
    coarse, fine = load_part(path, tolerance=0.04), load_part(path, tolerance=0.004)
    assert fine.step.chordal_deviation == pytest.approx(0.001)
    assert len(fine.mesh.faces) > len(coarse.mesh.faces)
    # the exact hole does not depend on the tessellation
    assert coarse.step.features.holes == fine.step.features.holes


def _six_holes(tmp_path):
    holes = [ModelledHole(x, y, 6.0, None) for x in (-15, 0, 15) for y in (-8, 8)]
    return write_step(plate((60, 40, 10), holes), tmp_path / "six.step")


def test_a_part_past_the_triangle_bound_is_tessellated_coarser_and_says_so(tmp_path, caplog):
    path = _six_holes(tmp_path)
    free = read_step(path)
    at_tolerance = read_step(path, tolerance=CAM_TOLERANCE / CHORD_SHARE)  # meshed to the whole 0.01 mm
    assert free.coarsened is None and free.chordal_deviation == chordal_deviation(CAM_TOLERANCE)
    assert len(at_tolerance.faces) < len(free.faces)
    limit = (len(free.faces) + len(at_tolerance.faces)) // 2  # trips the bound, within reach of the tolerance
    bounded = read_step(path, max_triangles=limit)
    got = bounded.coarsened
    assert got is not None and len(bounded.faces) <= limit and got.triangles == len(bounded.faces)
    assert free.chordal_deviation == got.asked < bounded.chordal_deviation == got.taken <= CAM_TOLERANCE
    assert got.estimate > limit  # estimated before the fine mesh, from the mesh at the whole tolerance
    assert bounded.features == free.features  # the exact features do not depend on the tessellation
    summary = bounded.to_dict()  # the plan summary's intake
    assert summary["chordal_deviation_mm"] == got.taken and summary["coarsened"]["limit"] == limit
    assert f"not {got.asked:.4g} mm" in summary["coarsened"]["said"] and f"{limit:,} planned" in caplog.text
    # a bound the whole tolerance cannot meet either: the whole tolerance, said
    least = read_step(path, max_triangles=len(at_tolerance.faces) - 1)
    assert least.chordal_deviation == CAM_TOLERANCE and len(least.faces) == len(at_tolerance.faces)


def test_a_part_past_the_refusal_bound_is_refused_in_one_line_before_the_fine_mesh(tmp_path, monkeypatch):
    import cadcam.step

    path = _six_holes(tmp_path)
    meshed = []
    real = cadcam.step._mesh
    monkeypatch.setattr(cadcam.step, "_mesh",
                        lambda shape, chord, tolerance: (meshed.append(chord), real(shape, chord, tolerance)))
    with pytest.raises(MeshError) as e:
        read_step(path, refuse_triangles=100)
    text = _one_line(e.value, path)
    assert "triangles even at the whole CAM tolerance of 0.01 mm, more than the 100 factory plans" in text
    assert "machine a simpler model" in text
    assert meshed == [CAM_TOLERANCE]  # refused from the coarse mesh alone


def test_the_fast_triangulation_keeps_watsons_nodes_and_falls_back_to_it(tmp_path, caplog):
    """Delabella triangulates the planes (here: a top face with five holes) on the same nodes as OpenCASCADE's default,
    Watson; a part it meshes further from the surface than the tolerance is meshed again with Watson."""
    import logging

    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.BRepTools import BRepTools
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_FACE

    import cadcam.step as step

    holes = [ModelledHole(-20, -8, 5.0, None), ModelledHole(0, 0, 6.8, 7.0, "flat"), ModelledHole(18, -8, 4.2, 5.5,
             "conical"), ModelledHole(18, 8, 8.5, 4.0, "conical"), ModelledHole(-20, 8, 3.3, None)]
    reader = STEPControl_Reader()
    reader.ReadFile(str(write_step(plate((60, 40, 10), holes), tmp_path / "plate.step")))
    reader.TransferRoots()
    shape = reader.OneShape()
    faces = step._shapes(shape, TopAbs_FACE)
    chord = chordal_deviation(CAM_TOLERANCE)
    BRepTools.Clean_s(shape)
    BRepMesh_IncrementalMesh(shape, chord, False, step.ANGULAR_DEFLECTION, False)
    watson_nodes, watson_triangles, _ = step._tessellate(faces)
    with caplog.at_level(logging.INFO, logger="cadcam.step"):
        step._mesh(shape, chord, CAM_TOLERANCE)
        fast_nodes, fast_triangles, _ = step._tessellate(faces)
        assert "more than the" not in caplog.text
        step._mesh(shape, chord, 1e-9)  # no mesh is that close: Watson's, said
        again_nodes, again_triangles, _ = step._tessellate(faces)
    # the same nodes (a face's may come in another order) and as many triangles
    assert np.array_equal(np.unique(fast_nodes, axis=0), np.unique(watson_nodes, axis=0))
    assert len(fast_nodes) == len(watson_nodes) and len(fast_triangles) == len(watson_triangles)
    assert "Delabella meshed faces to" in caplog.text and "more than the 1e-09 mm tolerance" in caplog.text
    assert np.array_equal(again_nodes, watson_nodes) and np.array_equal(again_triangles, watson_triangles)


def test_inch_part_takes_its_unit_from_the_file(tmp_path):
    inch = 25.4
    modelled = [ModelledHole(0.5 * inch, 0, 0.25 * inch, None), ModelledHole(-0.5 * inch, 0, 0.125 * inch, 0.3 * inch)]
    part = plate((2 * inch, 1.5 * inch, 0.5 * inch), modelled)
    path = write_step(part, tmp_path / "inch.step", unit="INCH")
    assert "INCH" in path.read_text()
    loaded = load_part(path)
    assert loaded.scale == inch and loaded.step.units == "inch"
    assert np.allclose(loaded.mesh.extents, (2 * inch, 1.5 * inch, 0.5 * inch), atol=EXACT)
    found = _by_place(loaded.step.features.holes)
    for m in modelled:
        _match(found[(round(m.x, 3), round(m.y, 3))], m, 0.5 * inch)
    assert load_part(path, units="inch").scale == inch
    with pytest.raises(MeshError, match="states its unit as INCH: --units mm contradicts it"):
        load_part(path, units="mm")


def test_two_solids_are_refused_with_their_sizes_unless_one_is_picked(tmp_path):
    path = write_step(two_solids(), tmp_path / "two.step")
    with pytest.raises(MeshError) as e:
        load_part(path)
    text = str(e.value)
    assert text.startswith(str(path)) and "\n" not in text
    assert "2 solids" in text and "40.0 x 30.0 x 10.0 mm" in text and "20.0 x 20.0 x 15.0 mm" in text
    assert "--body N" in text
    second = load_part(path, body=2)
    assert np.allclose(second.mesh.extents, (20, 20, 15), atol=EXACT) and second.step.body == 2
    assert np.allclose(load_part(path, body=1).mesh.extents, (40, 30, 10), atol=EXACT)
    with pytest.raises(MeshError, match="--body 3: the file has 2 solids"):
        load_part(path, body=3)


def test_coaxial_bores_with_air_between_are_two_holes(tmp_path):
    # Too Tall Toby 01-06's bearing jig: one 13 mm bore through two 6 mm plates 10 mm apart was read as one
    # hole 22 mm deep, too deep for the helix the mesh's two 6 mm bores got.
    loaded = load_part(write_step(bored_plates(13.0, 6.0, 10.0), tmp_path / "jig.step"))
    holes = sorted(loaded.step.features.holes, key=lambda h: -h.top_z)
    assert [(h.bottom, round(h.top_z, 6), round(h.bottom_z, 6)) for h in holes] == [
        ("through", 0.0, -6.0), ("through", -16.0, -22.0)]
    for h in holes:
        assert abs(h.x) < EXACT and abs(h.y + 4.0) < EXACT and abs(h.diameter - 13.0) < EXACT
        assert abs(h.depth - 6.0) < EXACT
    assert loaded.step.features.elsewhere == ()


def test_a_turned_parts_holes_turn_with_it(tmp_path):
    """A part turned about Z to fit the jaws: each exact hole lands on its bore in the turned mesh."""
    modelled = [ModelledHole(-20, -8, 5.0, None), ModelledHole(18, 8, 8.5, 4.0, "conical")]
    loaded = load_part(write_step(plate((60, 40, 10), modelled), tmp_path / "plate.step"))
    for turned in (False, True):
        setup, part = make_setup(loaded.mesh, turned=turned)
        holes = loaded.step.features.holes_in_work(setup.transform_mesh_to_work, loaded.step.chordal_deviation)
        assert len(holes) == 2
        for h in holes:  # the bore's wall, in work coordinates, rings the hole's axis
            v = part.vertices
            r = np.hypot(v[:, 0] - h.x, v[:, 1] - h.y)
            ring = (np.abs(r - h.diameter / 2) < loaded.step.chordal_deviation + 1e-6) & (v[:, 2] < h.top_z - 0.5)
            assert ring.sum() >= 8, (turned, h)
        assert np.ptp([[h.x, h.y] for h in holes], axis=0).round(6).tolist() == ([38, 16] if not turned else [16, 38])


def test_an_inclined_hole_is_reported_for_another_setup(tmp_path):
    path = write_step(inclined_hole(6.0, 30.0), tmp_path / "inclined.step")
    features = load_part(path).step.features
    assert features.holes == ()
    (hole,) = features.elsewhere
    assert abs(hole.diameter - 6.0) < EXACT and hole.reason == "axis off Z"
    assert np.allclose(hole.direction, (0.0, math.sin(math.radians(30)), math.cos(math.radians(30))), atol=1e-9)
    # the axis passes through the block's centre
    p, d = np.array(hole.point), np.array(hole.direction)
    assert np.linalg.norm(p - np.dot(p, d) * d) < EXACT
    assert "needs another setup" in hole.describe()


def test_a_hole_from_below_is_reported_for_another_setup(tmp_path):
    from build123d import Align, Box, Cylinder, Pos

    block = Box(40, 30, 12, align=(Align.CENTER, Align.CENTER, Align.MAX))
    part = block - Pos(5, 0, -12) * Cylinder(2.5, 6, align=(Align.CENTER, Align.CENTER, Align.MIN))
    features = load_part(write_step(part, tmp_path / "below.step")).step.features
    assert features.holes == ()
    (hole,) = features.elsewhere
    assert hole.reason == "covered from above" and abs(hole.diameter - 5.0) < EXACT and abs(hole.length - 6) < EXACT


def test_a_t_slots_lips_are_reported_as_undercuts(tmp_path):
    """A T-slot (8 mm neck 8 mm deep over an 18 mm head 6 mm tall, through a 60 mm block): each lip's underside looks
    down over the slot's floor, so neither op 1 from the top nor op 2 from below reaches it."""
    features = load_part(write_step(t_slot(), tmp_path / "tslot.step")).step.features
    assert features.holes == () and features.elsewhere == ()
    found = sorted(features.undercuts, key=lambda u: u.point[1])
    assert len(found) == 2 and all(u.source == "step" for u in found)
    for u, y in zip(found, (-6.5, 6.5)):  # the middle of each 60 x 5 mm lip
        assert np.allclose(u.point, (0.0, y, -8.0), atol=EXACT)
        assert np.allclose(u.direction, (0.0, 0.0, -1.0), atol=EXACT)
        assert abs(u.area - 300.0) < 1e-6
        assert "needs another setup or a 4th axis" in u.describe() and f"Y{y:.3f} Z-8.000" in u.describe()


def test_a_dovetails_flanks_are_reported_as_undercuts_with_their_direction(tmp_path):
    """A dovetail 10 mm wide at the top, 20 mm at its floor 8 mm down: each flank leans over the floor."""
    features = load_part(write_step(dovetail(), tmp_path / "dovetail.step")).step.features
    found = sorted(features.undercuts, key=lambda u: u.point[1])
    assert len(found) == 2
    flank = math.hypot(5.0, 8.0)  # each flank's width in the section [mm]
    for u, side in zip(found, (-1, 1)):
        assert np.allclose(u.point, (0.0, side * 7.5, -4.0), atol=EXACT)
        # out of the material: towards the slot's middle and down, square to the flank
        assert np.allclose(u.direction, (0.0, -side * 8.0 / flank, -5.0 / flank), atol=EXACT)
        assert abs(u.area - 60.0 * flank) < 1e-6


def test_faces_that_op_2_reaches_are_not_undercuts(tmp_path):
    """Faces that look down with nothing of the part under them are op 2's (the plate's underside, a hole's ceiling
    from below, a countersunk head's cone); an inclined hole's wall is reported as its hole, not again."""
    from build123d import Align, Box, Cylinder, Pos

    block = Box(40, 30, 12, align=(Align.CENTER, Align.CENTER, Align.MAX))
    from_below = block - Pos(5, 0, -12) * Cylinder(2.5, 6, align=(Align.CENTER, Align.CENTER, Align.MIN))
    for name, part in (("below", from_below), ("head", countersunk_head()), ("inclined", inclined_hole()),
                       ("plate", plate((40, 30, 8), [ModelledHole(0, 0, 5.0, None)]))):
        assert load_part(write_step(part, tmp_path / f"{name}.step")).step.features.undercuts == (), name


def test_free_form_faces_are_counted_so_their_bores_are_left_to_the_mesh(tmp_path):
    """A bore made of B-spline faces (the public as1-oc-214's holes are extrusions) is no round hole on the B-rep:
    the free-form faces are counted, and ``factory`` then finds the holes in the mesh."""
    from build123d import Solid
    from OCP.BRepBuilderAPI import BRepBuilderAPI_NurbsConvert

    part = plate((40, 30, 8), [ModelledHole(0, 0, 5.0, None)])
    exact = load_part(write_step(part, tmp_path / "exact.step")).step.features
    assert len(exact.holes) == 1 and exact.freeform == 0
    nurbs = Solid(BRepBuilderAPI_NurbsConvert(part.wrapped, True).Shape())
    converted = load_part(write_step(nurbs, tmp_path / "nurbs.step")).step.features
    assert converted.holes == () and converted.freeform == 7  # the block's six faces and the bore's wall


def test_inside_corner_radii_are_read(tmp_path):
    from build123d import Align, Box, Pos, fillet, Axis

    block = Box(60, 40, 15, align=(Align.CENTER, Align.CENTER, Align.MAX))
    pocket = Pos(0, 0, 0) * Box(30, 20, 6, align=(Align.CENTER, Align.CENTER, Align.MAX))
    pocket = fillet(pocket.edges().filter_by(Axis.Z), 1.5)
    features = load_part(write_step(block - pocket, tmp_path / "pocket.step")).step.features
    assert len(features.corners) == 4
    assert all(abs(c.radius - 1.5) < EXACT and abs(c.bottom_z + 6) < EXACT and abs(c.top_z) < EXACT
               for c in features.corners)
    assert len(features.unreachable_corners(1.0)) == 0 and len(features.unreachable_corners(2.0)) == 4


def test_surfaces_only_go_to_the_relief_path(tmp_path):
    loaded = load_part(write_step(pillow_surface(), tmp_path / "sheet.step"))
    assert not loaded.step.closed and loaded.surface is not None
    assert loaded.surface.footprint_mm == pytest.approx((50.0, 40.0), abs=1e-6)
    assert loaded.step.features.holes == ()


# --- bad files -------------------------------------------------------------------------

HEADER = ("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('x'),'2;1');\n"
          "FILE_NAME('p.step','2026-01-01T00:00:00',(''),(''),'','','');\n"
          "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n")


def _one_line(e: FactoryError, path) -> str:
    text = str(e)
    assert text.startswith(str(path)) and "\n" not in text and len(text) < len(str(path)) + 400, text
    return text


@pytest.mark.parametrize("name, content, needle", [
    ("empty.step", HEADER + "ENDSEC;\nEND-ISO-10303-21;\n", "no geometry"),
    ("cut.step", HEADER + "#1 = CARTESIAN_POINT('',(0.,0.,0.));\n#2 = AXIS2_PLACEMENT_3D('',#1,", "truncated"),
    ("points.step", HEADER + "#1 = CARTESIAN_POINT('',(0.,0.,0.));\nENDSEC;\nEND-ISO-10303-21;\n", "no geometry"),
    ("garbage.step", HEADER + "#1 = NOT_AN_ENTITY(((;\nENDSEC;\nEND-ISO-10303-21;\n", "STEP"),
    ("iges.step", f"{'IGES part':<72}S{1:7d}\n{'1H,,1H;':<72}G{1:7d}\n", "an IGES file, not STEP"),
    ("text.stp", "solid x\nendsolid x\n", "not a STEP file"),
    ("nothing.stp", "", "empty"),
])
def test_bad_step_files_are_one_line_errors(tmp_path, capfd, name, content, needle):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(MeshError) as e:
        load_part(path)
    assert needle in _one_line(e.value, path)
    assert capfd.readouterr().out == ""  # OpenCASCADE's chatter never reaches stdout


@pytest.fixture(scope="module")
def good_step(tmp_path_factory):
    path = tmp_path_factory.mktemp("good") / "plate.step"
    return write_step(plate((40, 30, 8), [ModelledHole(0, 0, 5.0, None), ModelledHole(10, 5, 3.3, 4.0, "conical")]),
                      path).read_bytes()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.floats(0.0, 1.0), flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 255)), max_size=8))
def test_damaged_step_reads_or_fails_in_one_line(tmp_path, good_step, cut, flips):
    data = bytearray(good_step[:max(1, int(len(good_step) * cut))] if cut < 1.0 else good_step)
    for where, byte in flips:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    path = tmp_path / "damaged.step"
    path.write_bytes(bytes(data))
    try:
        load_part(path)
    except FactoryError as e:
        _one_line(e, path)


# --- holes into the drilling stage -----------------------------------------------------------

LIBRARY = load_tool_library()
DRILLS = sorted({t.diameter for t in LIBRARY.drills("aluminium")})
OPTIONS = DrillingOptions()


def _planned(loaded):
    setup, part = make_setup(loaded.mesh)
    holes = loaded.step.features.holes_in_work(setup.transform_mesh_to_work, loaded.step.chordal_deviation)
    rough = choose_tools(LIBRARY, setup, PlanOptions(), np.asarray(part.triangles))[0]
    return setup, holes, rough, plan_holes(part, setup, LIBRARY, rough, OPTIONS, None, 0.3, holes)


@st.composite
def hole_patterns(draw):
    """1 to 4 holes on a 4 x 2 grid of 16 mm cells in a 64 x 32 x 12 mm plate, through or blind with a flat or
    drill-point bottom, each one the library can cut to size: a drill's size at any depth; between drill sizes,
    what an end mill can helix (the 2 mm flat reaches 5 mm under the stock top, the 6 mm one 18 mm)."""
    cells = draw(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 1)), min_size=1, max_size=4, unique=True))
    blind = st.floats(2.0, 9.0).map(lambda v: round(v, 3))
    holes = []
    for i, j in cells:
        d, depth = draw(st.one_of(
            st.tuples(st.sampled_from(DRILLS), st.one_of(st.none(), blind)),
            st.tuples(st.floats(2.7, 7.7).map(lambda v: round(v, 3)), st.floats(2.0, 4.0).map(lambda v: round(v, 3))),
            # the 6 mm end mill helixes a bore of 7.8 mm or more as tessellated, and the tessellation lies up to
            # its chordal deviation inside the true wall: the true bore is two chords more (7.805 was found)
            st.tuples(st.floats(7.8 + 2 * chordal_deviation(CAM_TOLERANCE) + 1e-3, 8.3).map(lambda v: round(v, 3)),
                      st.one_of(st.none(), blind))))
        bottom = draw(st.sampled_from(["flat", "conical"]))
        dx, dy = draw(st.floats(-2.0, 2.0)), draw(st.floats(-2.0, 2.0))
        holes.append(ModelledHole(round(-24 + 16 * i + dx, 3), round(-8 + 16 * j + dy, 3), d, depth, bottom))
    return holes


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                  HealthCheck.too_slow])
@given(modelled=hole_patterns())
# CI found it: an 8.5 mm flat-bottomed hole 2 mm deep, which the 6 mm roughing tool helixes into
@example(modelled=[ModelledHole(-24.0, -8.0, 3.3, None, "flat"), ModelledHole(-24.0, 8.0, 8.5, 2.0, "flat"),
                   ModelledHole(-8.0, -9.0, 8.0, None, "flat")])
def test_random_hole_patterns_are_recognised_exactly_and_cut_to_size(tmp_path, modelled):
    loaded = load_part(write_step(plate((64, 32, 12), modelled), tmp_path / "pattern.step", ))
    found = _by_place(loaded.step.features.holes)
    assert len(found) == len(modelled)
    for m in modelled:
        _match(found[(m.x, m.y)], m, 12.0)
    setup, holes, rough, plan = _planned(loaded)
    # a flat-bottomed hole the roughing tool can helix into is left to the roughing (its floor needs an end
    # mill, and roughing clears it with the pocket); every other hole is drilled or helixed to size
    roughed = {(round(h.x, 3), round(h.y, 3)) for h in holes
               if h.bottom == "flat" and h.inscribed - 2 * 0.3 - rough.diameter >= 0.3 * rough.diameter}
    assert {(round(h.x, 3), round(h.y, 3)) for h in plan.left} <= roughed, (rough.diameter, plan.left)
    assert len(plan.drilled) + len(plan.helixed) + len(plan.left) == len(modelled), (plan.undersize, plan.left)
    cut: dict[tuple[float, float], list[tuple[str, float]]] = {}
    for op in plan.operations:
        if op.kind == "drill":
            for x, y, _ in op.cycle.holes.tolist():
                cut.setdefault((round(x, 3), round(y, 3)), []).append(("drill", op.tool.diameter))
        elif op.kind == "helix":
            x, y = op.points[-1][:2]
            cut.setdefault((round(x, 3), round(y, 3)), []).append(("helix", op.tool.diameter))
    for h in holes:
        if (round(h.x, 3), round(h.y, 3)) in {(round(l.x, 3), round(l.y, 3)) for l in plan.left}:
            continue
        (how, d), = cut[(round(h.x, 3), round(h.y, 3))]
        if how == "drill":  # a drill of the hole's exact size (never one guessed from facets)
            assert h.diameter - OPTIONS.drill_undersize - 1e-9 <= d <= h.diameter + OPTIONS.drill_oversize
        else:  # a helix whose end mill fits the bore with room for its path
            assert d * (1 + OPTIONS.helix_share) <= h.inscribed + 1e-9
            assert not any(abs(t - h.diameter) <= 0.016 for t in DRILLS) or h.bottom == "flat"


def test_counterbores_and_countersinks_are_sized_and_cut(tmp_path):
    """An M6 counterbore (11 x 6.5 over a 6.6 through bore) and a 90 deg countersink of 9 mm over a 4.5 bore: sized
    exactly from the coaxial cylinders and cone; the counterbore is helixed to its floor, the spot drill cuts the
    countersink to size."""
    modelled = [ModelledHole(-15, 0, 6.6, None, counterbore=(11.0, 6.5)), ModelledHole(15, 0, 4.5, None, countersink=9.0)]
    loaded = load_part(write_step(plate((60, 30, 14), modelled), tmp_path / "seats.step"))
    found = _by_place(loaded.step.features.holes)
    assert len(found) == 2
    bored, sunk = found[(-15.0, 0.0)], found[(15.0, 0.0)]
    assert abs(bored.diameter - 6.6) < EXACT and bored.bottom == "through" and bored.countersink is None
    cb = bored.counterbore
    assert abs(cb.diameter - 11.0) < EXACT and abs(cb.top_z) < EXACT and abs(cb.floor_z + 6.5) < EXACT
    assert abs(bored.top_z + 6.5) < EXACT and abs(bored.bottom_z + 14) < EXACT
    cs = sunk.countersink
    assert abs(sunk.diameter - 4.5) < EXACT and sunk.counterbore is None and sunk.bottom == "through"
    assert abs(cs.diameter - 9.0) < EXACT and abs(cs.angle - 90.0) < EXACT and abs(cs.top_z) < EXACT
    assert abs(sunk.top_z + (9.0 - 4.5) / 2) < EXACT  # the bore starts where the cone ends
    assert "counterbore 11.000 mm x 6.500 mm deep" in bored.describe() and "countersink 9.000 mm x 90 deg" in sunk.describe()
    setup, holes, rough, plan = _planned(loaded)
    dz = float(setup.transform_mesh_to_work[2, 3])
    assert sorted(round(h.diameter, 6) for h in holes) == [4.5, 6.6, 11.0]
    seat = next(h for h in holes if abs(h.diameter - 11.0) < EXACT)
    assert seat.bottom == "flat" and abs(seat.bottom_z - (dz - 6.5)) < EXACT
    helixed = {round(h.diameter, 6) for h in plan.helixed} | {round(h.diameter, 6) for h in plan.left}
    assert 11.0 in helixed  # helixed, or wide enough for the roughing end mill
    spot = next(op for op in plan.operations if op.kind == "spot")
    tips = {(round(x, 3), round(y, 3)): z for x, y, z in spot.cycle.holes.tolist()}
    sunk_work = next(h for h in holes if abs(h.diameter - 4.5) < EXACT)
    # the 90 deg spot drill's tip where the countersink's cone meets the axis: 4.5 mm under its top
    assert tips[(round(sunk_work.x, 3), round(sunk_work.y, 3))] == pytest.approx(dz - 4.5, abs=EXACT)


def test_a_public_two_solid_file_in_metres():
    """CadQuery's red_cube_blue_cylinder.step (Apache-2.0): two 10 mm solids, written in metres."""
    from pathlib import Path

    path = Path(__file__).parents[1] / "data" / "step" / "red_cube_blue_cylinder.step"
    with pytest.raises(MeshError, match=r"2 solids in the file \(1: 10\.0 x 10\.0 x 10\.0 mm, 3 faces; "
                                        r"2: 10\.0 x 10\.0 x 10\.0 mm, 6 faces\): pick one with --body N"):
        load_part(path)
    cylinder, cube = load_part(path, body=1), load_part(path, body=2)
    assert cylinder.step.units == cube.step.units == "m" and cylinder.scale == 1000.0
    assert np.allclose(cube.mesh.extents, 10.0, atol=EXACT) and abs(cube.mesh.volume - 1000.0) < 1e-6
    assert abs(cylinder.mesh.volume - math.pi * 25 * 10) < 0.5  # tessellated within 0.0025 mm
    assert [round(f.z, 6) for f in cube.step.features.flats] == [round(float(cube.mesh.bounds[1][2]), 6),
                                                                  round(float(cube.mesh.bounds[0][2]), 6)]
