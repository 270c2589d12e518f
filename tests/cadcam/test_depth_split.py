"""A part deeper than the tools reach: op 1 machines down to their reach, op 2 the rest from below (issue 34).

The tool choice by reach need: long-reach end mills only where the standard ones do not reach.
"""

from __future__ import annotations

import dataclasses

import manifold3d
import numpy as np
import pytest
from scipy import ndimage
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.finishing import FinishingOptions
from cadcam.model import Job
from cadcam.op2 import (Op2Options, TURN_OVER, _reachable_floor, choose_face_up, flip_part, op2_jaws, op2_setup,
                        plan_op2, sides_reach)
from cadcam.seam import seam_faults, seams
from cadcam.plan import PlanOptions, by_need, choose_tools, deepest_reach, plan_job, rest_tools, split_depth
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from cadcam.verify import VerifyOptions
from tests.cadcam.test_op2 import JAWS, verify_both
from tests.conftest import manifold_to_trimesh
from tests.gallery.parts import web_in_tube

LIBRARY = load_tool_library()
#: A shop with short tools only: the 6 mm flat (32 mm below its holder), the 10 mm flat (45) and the 6 mm ball (32).
SHORT = dataclasses.replace(LIBRARY, tools=tuple(LIBRARY.tool(n) for n in (1, 2, 3)), feed_factors=())
PLAN = PlanOptions(finishing=FinishingOptions(scallop=0.05), waterline=False)


def _tower() -> manifold3d.Manifold:
    """A 40 x 30 base 12 mm thick under a 24 x 16 block to 50 mm: prismatic, 50 mm tall."""
    base = manifold3d.Manifold.cube((40.0, 30.0, 12.0))
    return base + manifold3d.Manifold.cube((24.0, 16.0, 38.5)).translate((8.0, 7.0, 11.5))


def test_the_reach_is_the_longest_mill_and_no_deeper_than_a_ball_for_freeform():
    assert deepest_reach(SHORT) == 45.0
    assert deepest_reach(SHORT, freeform=True) == 32.0  # the 6 mm ball reaches 32
    assert deepest_reach(LIBRARY) == max(t.length for t in LIBRARY.tools if t.shape in ("flat", "bull"))


def test_a_setup_the_tools_reach_is_left_alone_and_a_deeper_one_is_cut_short():
    setup, _ = make_setup(manifold_to_trimesh(manifold3d.Manifold.cube((40.0, 30.0, 20.0))), jaws=JAWS)
    assert split_depth(setup, SHORT).setup is setup
    deep, _ = make_setup(manifold_to_trimesh(_tower()), jaws=JAWS)
    split = split_depth(deep, SHORT)
    assert split.setup.floor_z == pytest.approx(float(deep.stock_max[2]) - 45.0)
    assert split.short == pytest.approx(split.setup.floor_z - deep.floor_z) and split.short > 0


def test_long_reach_tools_are_chosen_only_where_reach_needs_them():
    long_reach = {t.number for t in LIBRARY.tools if LIBRARY.feed_factor(t) < 1.0}
    assert long_reach, "the default library has long-reach end mills"
    shallow, _ = make_setup(manifold_to_trimesh(manifold3d.Manifold.cube((90.0, 60.0, 16.0))), jaws=JAWS)
    rough, finish = choose_tools(LIBRARY, shallow, PlanOptions())
    assert rough.number not in long_reach and finish.number not in long_reach
    widest = max(LIBRARY.tools, key=lambda t: t.diameter)
    assert not {t.number for t in rest_tools(LIBRARY, widest, 16.0)} & long_reach
    # 60 mm deep: no standard end mill reaches; the long-reach ones do, and are the rest tools too
    deep, _ = make_setup(manifold_to_trimesh(manifold3d.Manifold.cube((90.0, 70.0, 60.0))), jaws=JAWS)
    depth = float(deep.stock_max[2] - deep.floor_z)
    rough, _ = choose_tools(LIBRARY, deep, PlanOptions())
    assert rough.number in long_reach and rough.length >= depth
    assert by_need(LIBRARY, [LIBRARY.tool(2), rough]) == [LIBRARY.tool(2)]
    assert {t.number for t in rest_tools(LIBRARY, widest, depth)} & long_reach


def test_a_long_reach_tool_runs_slower_than_its_diameters_feed():
    t15 = LIBRARY.tool(15)
    plain = dataclasses.replace(LIBRARY, feed_factors=())
    assert LIBRARY.cutting_data(t15, "aluminium").feed == pytest.approx(
        LIBRARY.feed_factor(t15) * plain.cutting_data(t15, "aluminium").feed, abs=0.1)


@pytest.fixture(scope="module")
def tower_jobs():
    """The tower planned with the short tools: op 1 to their reach, op 2 the rest from below."""
    part = manifold_to_trimesh(_tower())
    setup, part_work = make_setup(part, jaws=JAWS)
    job1 = plan_job(part_work, setup, SHORT, part_name="tower", options=PLAN).job
    job2, part2 = plan_op2(part_work, job1, SHORT, options=Op2Options(plan=PLAN), jaws=JAWS)
    return part_work, job1, job2, part2


def test_op_1_stops_at_its_reach_and_op_2_machines_the_rest(tower_jobs):
    part_work, job1, job2, part2 = tower_jobs
    assert job1.setup.floor_z == pytest.approx(float(job1.setup.stock_max[2]) - 45.0)
    assert float(job1.setup.floor_z) > float(part_work.bounds[0][2])  # short of the part's bottom
    kinds = [op.kind for op in job2.operations]
    assert kinds[0] == "facing" and "finishing" in kinds, kinds
    # op 2 never goes deeper than its tools reach from the turned-over stock top
    for op in job2.operations:
        assert float(op.points[:, 2].min()) >= -op.tool.length - 1e-6, op.name
    # nothing left unreached: the walls below op 1's floor were op 2's
    assert job1.parameters["unreached"] == [] and job2.parameters["unreached"] == []


def test_the_seam_between_op_1_and_op_2_is_within_the_finishing_tolerance(tower_jobs):
    part_work, job1, job2, _ = tower_jobs
    found = seams(part_work, job1, job2)
    assert found and any(abs(s.z - float(job1.setup.floor_z)) < 1e-9 for s in found)
    tolerance = VerifyOptions().left_above
    for seam in found:
        # both walls finished (a wall left at the roughing allowance would show 0.3 mm) and flush
        assert -0.02 <= seam.above <= tolerance and -0.02 <= seam.below <= tolerance, seam
        assert seam.step <= tolerance, seam


def test_the_seam_check_sees_a_wall_op_2_left_unfinished(tower_jobs):
    """The check can fail: op 2 without its wall finishing leaves the roughing allowance below the seam."""
    part_work, job1, job2, _ = tower_jobs
    rough_only = dataclasses.replace(job2, operations=tuple(op for op in job2.operations if op.kind != "finishing"))
    seam = min(seams(part_work, job1, rough_only), key=lambda s: abs(s.z - float(job1.setup.floor_z)))
    assert seam.below == pytest.approx(PLAN.roughing.allowance, abs=0.06)
    assert seam.step > VerifyOptions().left_above


@pytest.fixture(scope="module")
def web_jobs(tmp_path_factory):
    """A tube 50 mm tall with a web across it 8 to 13 mm up, planned with the short tools and verified: op 1
    reaches 45 mm from the top, its floor 6 mm up the part, under the web it never sees."""
    part = manifold_to_trimesh(web_in_tube(50.0, (8.0, 13.0)))
    setup, part_work = make_setup(part, jaws=JAWS)
    job1 = plan_job(part_work, setup, SHORT, part_name="web", options=PLAN).job
    job2, part2 = plan_op2(part_work, job1, SHORT, options=Op2Options(plan=PLAN), jaws=JAWS)
    return part_work, verify_both(job1, job2, part_work, part2, "web", tmp_path_factory.mktemp("web"), 0.5)


def test_op_2_finishes_the_pocket_under_a_web_past_op_1s_floor(web_jobs):
    """The pocket under the web goes 2 mm past where the walls of op 1 and op 2 overlap (OpenCAMLib's
    wheel_in_box: the rim under the wheel's plate). Op 2 finishes it to the web, its walls flush with op 1's."""
    part_work, (job1, job2, part2, _, (_, r1), (sim2, r2), _) = web_jobs
    bottom = float(part_work.bounds[0][2])
    web = bottom + 8.0  # the web's underside in op 1's work coordinates
    assert bottom < float(job1.setup.floor_z) < web - 1.0  # a depth split; op 1 ends beside the pocket, under the web
    # op 2 reaches the web's underside: its floor turned back into op 1's coordinates is no lower
    flip_z = float(job1.setup.stock_min[2])
    assert flip_z - float(job2.setup.floor_z) >= web - 1e-6
    assert seam_faults(job2) == ()
    found = seams(part_work, job1, job2)
    assert found and all(s.step <= VerifyOptions().left_above for s in found), found
    assert job2.parameters["unreached"] == []
    assert r1.max_gouge <= 0.01 and r2.ok, r2.to_dict()
    # the web's underside, seen from below, is finished (away from the pocket's walls, where a cell sees the wall)
    ceiling = np.isclose(sim2.part_top, flip_z - web, atol=1e-6)
    inner = ndimage.binary_erosion(ceiling, iterations=2)
    assert inner.sum() > 100
    assert float(sim2.remaining[inner].max()) <= VerifyOptions().left_above


def test_the_face_up_first_is_the_one_that_leaves_less_unreached():
    """A tall boss on a thin flange: boss up, op 1's 45 mm reach the boss and op 2 the flange; flange up,
    the flange shadows the boss's foot from op 2 and op 1 cannot reach it. Both ways are weighed; as given
    wins only when it is not worse."""
    boss = manifold3d.Manifold.cube((60.0, 50.0, 4.0)) + manifold3d.Manifold.cylinder(
        52.0, 12.0, 12.0, 64).translate((30.0, 25.0, 3.5))
    part = manifold_to_trimesh(boss)
    upside_down = part.copy()
    upside_down.apply_transform(TURN_OVER)
    upside_down.apply_translation([0.0, 0.0, -upside_down.bounds[0][2]])

    def place(mesh):
        return make_setup(mesh, jaws=JAWS)

    left_given = sides_reach(place(part)[1], place(part)[0], SHORT).unreached_volume
    left_turned = sides_reach(place(upside_down)[1], place(upside_down)[0], SHORT).unreached_volume
    assert left_turned != left_given
    setup, part_work = choose_face_up(upside_down, place, SHORT)
    best = min(left_given, left_turned)
    assert sides_reach(part_work, setup, SHORT).unreached_volume == pytest.approx(best)
    # the setup's transform takes the file's mesh to the part it planned
    moved = upside_down.copy()
    moved.apply_transform(setup.transform_mesh_to_work)
    np.testing.assert_allclose(moved.bounds, part_work.bounds, atol=1e-6)


def test_a_part_the_tools_reach_from_the_top_is_placed_as_given():
    part = manifold_to_trimesh(manifold3d.Manifold.cube((40.0, 30.0, 20.0)))
    setup, part_work = choose_face_up(part, lambda m: make_setup(m, jaws=JAWS), SHORT)
    np.testing.assert_allclose(setup.transform_mesh_to_work[:3, :3], np.eye(3))
    assert sides_reach(part_work, setup, SHORT).unreached_volume == 0.0


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(size=st.tuples(st.floats(20.0, 120.0), st.floats(15.0, 120.0), st.floats(30.0, 160.0)),
       boss=st.floats(0.2, 0.9), base=st.floats(0.05, 0.5), turned=st.booleans())
def test_no_part_that_fits_the_vise_is_refused_for_its_depth(size, boss, base, turned):
    """Random tall blocks (a base and a boss on it, 30-160 mm tall) that fit the vise: the CAM stage's tool
    choice for op 1 and for op 2 never refuses them for their depth; what neither side reaches is left."""
    sx, sy, sz = size
    body = manifold3d.Manifold.cube((sx, sy, base * sz)) + manifold3d.Manifold.cube(
        (boss * sx, boss * sy, (1.0 - base) * sz + 0.5)).translate(((1 - boss) * sx / 2, (1 - boss) * sy / 2,
                                                                     base * sz - 0.5))
    part = manifold_to_trimesh(body)
    if turned:
        part.apply_transform(TURN_OVER)
        part.apply_translation([0.0, 0.0, -part.bounds[0][2]])
    for library in (LIBRARY, SHORT):
        setup, part_work = choose_face_up(part, lambda m: make_setup(m, jaws=JAWS), library)
        split = split_depth(setup, library)
        rough, finish = choose_tools(library, split.setup, PlanOptions(), np.asarray(part_work.triangles))
        assert rough.length >= float(split.setup.stock_max[2] - split.setup.floor_z)
        assert finish.length >= float(split.setup.stock_max[2] - split.setup.floor_z)
        left = sides_reach(part_work, setup, library)
        # op 1 stops short exactly when its floor lies deeper than the tools reach
        assert (split.short > 0) == (float(setup.stock_max[2] - setup.floor_z) > split.reach + 1e-9)
        if float(setup.stock_size[2]) <= left.reach:  # one side reaches through the stock: nothing left
            assert left.unreached_volume == 0
        # op 2's side: its floor within the tools' reach from the turned-over stock, the tools chosen for it
        job1 = Job(part_name="p", setup=split.setup, operations=())
        part2 = flip_part(part_work, setup)
        setup2 = _reachable_floor(dataclasses.replace(op2_setup(setup), floor_z=float(part2.bounds[0][2]),
                                                      jaws=op2_jaws(JAWS, op2_setup(setup), part2,
                                                                    float(part2.bounds[1][2]))),
                                  job1.setup, library, part2, PlanOptions())
        choose_tools(library, setup2, PlanOptions())


def test_what_neither_side_reaches_is_reported_with_its_place_and_size_not_refused():
    """A block 100 mm tall: op 1 reaches 45 mm from the top, op 2 45 mm from the bottom; the band of the
    2 mm side margin between them is left, reported by op 2 where it is, all round the block."""
    part = manifold_to_trimesh(manifold3d.Manifold.cube((30.0, 24.0, 100.0)))
    setup, part_work = make_setup(part, jaws=JAWS)
    job1 = plan_job(part_work, setup, SHORT, part_name="tall", options=PLAN).job
    job2, part2 = plan_op2(part_work, job1, SHORT, options=Op2Options(plan=PLAN), jaws=JAWS)
    (band,) = [u for u in job2.parameters["unreached"] if u["depth"] > 5.0]
    # from op 2's floor (45 below its top) down to op 1's floor turned over, less the breakthrough
    op1_floor = float(setup.stock_min[2]) - float(job1.setup.floor_z) - 0.5
    assert band["depth"] == pytest.approx(float(job2.setup.floor_z) - op1_floor, abs=0.6)
    assert band["size_x"] == pytest.approx(float(setup.stock_size[0]), abs=1.0)
    assert band["size_y"] == pytest.approx(float(setup.stock_size[1]), abs=1.0)
    assert band["z_bottom"] == pytest.approx(op1_floor, abs=0.6)
