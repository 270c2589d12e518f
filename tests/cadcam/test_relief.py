"""Reliefs: open surfaces welded, oriented, judged, planned from above within their boundary.

The surfaces are generated here (tests/cadcam/reliefs.py): heightfield sheets with and without
sides, with holes, inverted, unwelded, overlapping sheets touching at non-manifold edges; a
closed solid stored as unwelded triangles; and one case for each refusal.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.finishing import FinishingOptions
from cadcam.gcode import parse_gcode
from cadcam.mesh import load_part
from cadcam.plan import PlanOptions
from cadcam.post import PostOptions, post_process
from cadcam.relief import ReliefOptions, clip_chains
from cadcam.setup import BREAKTHROUGH_MM, default_holding
from cadcam.verify import VerifyOptions, simulate
from factory.cam import CamRequest, compute_job
from factory.core.errors import MeshError
from tests.cadcam.reliefs import (heightfield_sheet, hollow_ball_open_on_top, inverted, overlapping_sheets,
                                  scattered_strips, stl_bytes, unwelded, wavy)
from tests.cadcam.test_plan import needs_rs274, rs274_accepts

# Coarse finishing keeps these plans quick; gouge-freedom does not depend on the scallop.
QUICK = PlanOptions(finishing=FinishingOptions(scallop=0.03))


def _holes():
    x, y, z = wavy()
    keep = np.ones((len(y) - 1, len(x) - 1), bool)
    keep[6:9, 10:13] = False
    keep[2:4, 3:5] = False
    return heightfield_sheet(x, y, z, keep=keep)


SURFACES = {
    "sheet": lambda: heightfield_sheet(*wavy()),
    "with sides": lambda: heightfield_sheet(*wavy(), sides_to=0.0),
    "with holes": _holes,
    "inverted normals": lambda: inverted(heightfield_sheet(*wavy())),
    "unwelded": lambda: unwelded(heightfield_sheet(*wavy()), noise=2e-5),
    "overlapping sheets": overlapping_sheets,
}


def _write(tmp_path: Path, name: str, mesh: trimesh.Trimesh) -> Path:
    path = tmp_path / f"{name.replace(' ', '_')}.stl"
    path.write_bytes(stl_bytes(mesh))
    return path


# --- intake: weld, orient, judge ----------------------------------------------------------


@pytest.mark.parametrize("name", SURFACES)
def test_open_surfaces_are_found_as_reliefs(tmp_path, name):
    part = load_part(_write(tmp_path, name, SURFACES[name]()))
    found = part.surface
    assert found is not None
    assert found.footprint_mm == pytest.approx((48.0, 32.0), abs=1e-3)
    assert found.shells == 1 and found.boundary_edges > 0 and found.facing_down < 0.01
    # Every triangle that is not a wall faces up, whatever the file's winding.
    nz = part.mesh.face_normals[:, 2]
    assert (nz > -1e-9).all()
    assert found.describe().startswith("open surface, machined from above as a relief: ")


def test_boundary_edges_shells_and_non_manifold_edges_are_counted(tmp_path):
    x, y, z = wavy(13, 9)
    two = trimesh.util.concatenate([heightfield_sheet(x, y, z), heightfield_sheet(x + 60.0, y, z)])
    found = load_part(_write(tmp_path, "two", two)).surface
    assert found.shells == 2 and found.boundary_edges == 2 * 2 * (12 + 8)
    overlap = load_part(_write(tmp_path, "overlap", overlapping_sheets()))
    edges = np.sort(overlap.mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 3  # the sheets meet at non-manifold edges


def test_inverted_sheet_is_turned_over_and_says_so(tmp_path):
    part = load_part(_write(tmp_path, "inv", inverted(heightfield_sheet(*wavy()))))
    assert any("turned 1 of 1 shells over" in r for r in part.repairs)


@pytest.mark.parametrize("noise", [0.0, 1e-4])
def test_a_solid_stored_as_unwelded_triangles_stays_a_solid(tmp_path, noise):
    solid = trimesh.creation.icosphere(subdivisions=2, radius=12.0)
    part = load_part(_write(tmp_path, "ball", unwelded(solid, noise=noise)))
    assert part.surface is None and part.mesh.is_watertight
    assert part.mesh.volume == pytest.approx(solid.volume, rel=1e-3)


# --- refusals: the failed test and its figure ------------------------------------------------


def _refused(path: Path, needle: str) -> MeshError:
    with pytest.raises(MeshError) as e:
        load_part(path)
    assert needle in e.value.message and "\n" not in e.value.message, e.value.message
    assert e.value.source == str(path)
    return e.value


def test_disjoint_triangles_are_refused_as_no_surface(tmp_path):
    from tests.cli.hostile import triangle_soup

    path = tmp_path / "soup.stl"
    path.write_bytes(triangle_soup())
    err = _refused(path, "disjoint triangles, not a surface")
    assert "of 400 triangles share an edge" in err.message


def test_a_surface_facing_down_is_refused(tmp_path):
    err = _refused(_write(tmp_path, "ball", hollow_ball_open_on_top()), "surface faces down over")
    assert "59%" in err.message


def test_an_envelope_with_gaps_over_most_of_its_footprint_is_refused(tmp_path):
    _refused(_write(tmp_path, "strips", scattered_strips()), "envelope has gaps over")


# --- planning ----------------------------------------------------------------------------


def plan_relief(path: Path, relief: ReliefOptions = ReliefOptions(), options: PlanOptions = QUICK):
    req = dataclasses.replace(CamRequest.defaults(path), plan=options, relief=relief)
    planned = compute_job(req)
    job = planned.job
    program = post_process(job, PostOptions())
    moves = parse_gcode(program.text, source=path.name)
    verified = simulate(moves, {t.number: t for t in job.tools}, job.setup, np.asarray(planned.part_work.triangles),
                        VerifyOptions(cell=0.2))
    sim, report = verified.simulation, verified.report
    return planned, program, sim, report


def _cut_outside(planned, sim, reach: float) -> float:
    """Deepest cut [mm] into the stock farther than ``reach`` outside the footprint's outline."""
    g = sim.grid
    x, y = np.meshgrid(g.xs, g.ys)
    near = planned.boundary.outline.buffer(reach + g.cell)
    outside = ~shapely.contains_xy(near, x, y)
    top = float(planned.job.setup.stock_max[2])
    return float(np.max(top - sim.stock_top[outside], initial=0.0))


def _allowed_outside(planned, mode: str) -> float:
    r = max(op.tool.radius for op in planned.job.operations)
    return {"inside": 0.0, "on": r, "outside": 2 * r}[mode]


@needs_rs274
@pytest.mark.parametrize("mode", ["inside", "on", "outside"])
def test_a_relief_plans_within_its_boundary_without_gouge(tmp_path, mode):
    path = _write(tmp_path, "relief", heightfield_sheet(*wavy()))
    planned, program, sim, report = plan_relief(path, ReliefOptions(boundary=mode))
    assert report.ok, report.to_dict()
    assert report.max_gouge <= 0.01
    assert _cut_outside(planned, sim, _allowed_outside(planned, mode)) <= 1e-6
    # The stock: the footprint's box + 2 mm sides, from the lowest point less the floor and the
    # holding allowance under it to the top + 1 mm.
    lo, hi = planned.loaded.mesh.bounds
    holding = default_holding(CamRequest.defaults(path).jaws())
    assert planned.job.setup.stock_size == pytest.approx([52.0, 36.0, hi[2] - lo[2] + 2.0 + holding + 1.0])
    assert planned.job.setup.floor_z == pytest.approx(planned.job.setup.stock_min[2] + holding - BREAKTHROUGH_MM)
    relief = planned.job.parameters["relief"]
    assert relief["boundary"]["mode"] == mode and relief["floor"] == 2.0
    nc = tmp_path / "relief.nc"
    nc.write_text(program.text)
    rs274_accepts(nc, planned.job, tmp_path)


@needs_rs274
@pytest.mark.parametrize("name", ["with sides", "with holes", "inverted normals", "overlapping sheets"])
def test_every_generated_surface_plans_with_defaults(tmp_path, name):
    planned, program, sim, report = plan_relief(_write(tmp_path, name, SURFACES[name]()))
    assert report.ok and report.max_gouge <= 0.01, report.to_dict()
    assert _cut_outside(planned, sim, 0.0) <= 1e-6


@needs_rs274
@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**31 - 1), mode=st.sampled_from(["inside", "on", "outside"]),
       amp=st.floats(0.5, 6.0))
def test_random_heightfields_never_gouge_and_stay_in_bounds(tmp_path, seed, mode, amp):
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 30.0, 7)
    y = np.linspace(0.0, 24.0, 6)
    z = 1.0 + amp * rng.random((len(y), len(x)))
    path = _write(tmp_path, f"hf{seed}", heightfield_sheet(x, y, z))
    planned, program, sim, report = plan_relief(path, ReliefOptions(boundary=mode))
    assert report.max_gouge <= 0.01, report.to_dict()
    assert report.ok, report.to_dict()
    assert _cut_outside(planned, sim, _allowed_outside(planned, mode)) <= 1e-6
    nc = tmp_path / "hf.nc"
    nc.write_text(program.text)
    rs274_accepts(nc, planned.job, tmp_path)


def test_chains_are_cut_where_they_leave_the_region():
    region = shapely.box(0, 0, 10, 10)
    chain = np.array([[-5.0, 5, 1], [5, 5, 2], [15, 5, 3], [20, 5, 3], [5, 6, 1], [6, 6, 1]])
    out = clip_chains([chain], region)
    assert len(out) == 2
    assert out[0][0, 0] == pytest.approx(0.0, abs=1e-6) and out[0][-1, 0] == pytest.approx(10.0, abs=1e-6)
    assert out[0][0, 2] == pytest.approx(1.5, abs=1e-6)  # on the original move
    assert all(shapely.contains_xy(region, c[:, 0], c[:, 1]).all() for c in out)


def test_a_move_through_the_region_keeps_its_pieces_inside_though_both_ends_lie_outside():
    """A raster line over a flat is one move from edge to edge: op 2's across a plate whose ends lie in the
    jaws' keep-out was dropped whole (issue 34, OpenCAMLib's sphere_on_plate). Each piece inside stays, on the
    move, and nothing of the gap between them."""
    region = shapely.box(2, 0, 42, 10).difference(shapely.box(20, 0, 22, 10))
    out = clip_chains([np.array([[0.0, 5, -1], [44, 5, -3]]), np.array([[0.0, 20, 0], [44, 20, 0]])], region)
    assert len(out) == 2
    assert [(c[0, 0], c[-1, 0]) for c in out] == [pytest.approx((2, 20), abs=1e-6), pytest.approx((22, 42), abs=1e-6)]
    for c in out:
        assert shapely.contains_xy(region, *c[1:-1, :2].T).all()
        assert c[:, 2] == pytest.approx(-1 - 2 * c[:, 0] / 44)  # on the original move


def test_the_sample_relief_is_made_by_its_script_and_is_a_relief(tmp_path):
    import runpy

    from tests.cadcam.reliefs import SAMPLES

    runpy.run_path(str(SAMPLES / "make_relief.py"))["main"](tmp_path)
    assert (tmp_path / "relief.stl").read_bytes() == (SAMPLES / "relief.stl").read_bytes()
    found = load_part(SAMPLES / "relief.stl").surface
    assert found.describe() == ("open surface, machined from above as a relief: 400 boundary edges, 1 shell, "
                                "footprint 120.0 \u00d7 80.0 mm")


def _found(fx: float, fy: float):
    """What intake finds of a relief whose footprint is ``fx`` x ``fy`` mm."""
    from cadcam.relief import SurfaceFound
    return SurfaceFound(40, 1, (fx, fy), 0.0, 0.0, shapely.box(0.0, 0.0, fx, fy))


@pytest.mark.parametrize("footprint, gripped, across", [
    ((120.0, 80.0), 69.0, 0.0),  # the sample relief in the sample cell's 85 mm gripper: the footprint's own width
    ((120.0, 66.0), 69.0, 1.5),  # trimmed to what leaves the fingers' clearance
    ((120.0, 60.0), 69.0, None),  # 64 mm leaves it already
    ((60.0, 80.0), 69.0, None),  # the fingers close across X, where the rim holds the seat: not trimmed
    ((120.0, 80.0), None, None),  # no cell, no gripper
])
def test_a_reliefs_rim_across_the_jaws_gives_way_to_the_grippers_room(footprint, gripped, across):
    from cadcam.relief import block_margins
    from cadcam.setup import StockMargins

    margins = block_margins(_found(*footprint), StockMargins(bottom=7.5), gripped)
    assert margins.across == across and margins.sides == 2.0 and margins.bottom == 7.5


def test_the_sample_cells_relief_block_leaves_the_gripper_its_room(tmp_path):
    """A relief 90 x 75 mm: with 2 mm of rim the block is 79 mm across the jaws, 4 mm open beside it in the
    sample cell's 85 mm gripper, not the 8 mm its fingers open beside a box; the rim across the jaws goes
    (the jaws square the blank up there), along them it stays for the seat."""
    from robotprog.cell import load_cell
    from robotprog.grasp import finger_room

    x, y = np.linspace(0.0, 90.0, 10), np.linspace(0.0, 75.0, 9)
    path = _write(tmp_path, "wide", heightfield_sheet(x, y, 2.0 + 0.1 * np.add.outer(y, x) / 10.0))
    req = CamRequest.defaults(path)
    assert req.gripped() == pytest.approx(69.0)
    seen = []

    class Placed(Exception):
        pass

    def stop(setup, part_work):  # before any toolpath
        seen.append(setup)
        raise Placed

    with pytest.raises(Placed):
        compute_job(req, check_setup=stop)
    size = seen[0].stock_size
    assert size[:2] == pytest.approx([94.0, 75.0])
    gripper = load_cell(req.cell, check_robot=False)
    assert finger_room(gripper, size[1] / 1000) == pytest.approx(0.005)
