"""Z-level roughing's links along the paths a level has cut (cadcam.levelpath).

The way found runs on the cut paths only (checked against their union, not the graph); a roughing whose links
stay down takes the same stock as one that lifts (its extra feed moves meet none, by the tests' own heightfield),
keeps off the part, and takes less time by the program's clock, the moves in the air at the air feed.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import shapely
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, MultiLineString

from cadcam.levelpath import SAME_POINT, CutPaths, LevelPath, down_budget
from cadcam.model import CuttingData, Motion, Setup, Tool
from cadcam.post import PostOptions
from cadcam.roughing import RoughingOptions, zlevel_roughing
from tests.cadcam.test_roughing import HeightField, assert_no_gouge, box, motion_basics, simulate, union

TOOL = Tool(2, "10 mm flat 3FL carbide", "flat", 10.0, 0.0, 30.0, 3, 45.0)
CUTTING = CuttingData(spindle_rpm=9549, feed=2292, plunge_feed=688)
AIR_FEED = 10000.0  # [mm/min], the library machine's


@st.composite
def nested_rings(draw):
    """Rectangles one inside the other, each joined to the next by a link from a point on its side (not a
    corner), as a level's loops and links are cut; and a point on the last."""
    rings, links = [], []
    x0, y0, x1, y1 = 0.0, 0.0, draw(st.floats(40, 80)), draw(st.floats(40, 80))
    for _ in range(draw(st.integers(1, 4))):
        rings.append(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]))
        step = draw(st.floats(2, 6))
        if x1 - x0 < 2 * step + 2 or y1 - y0 < 2 * step + 2:
            break
        t = draw(st.floats(0.1, 0.9))
        x = x0 + step + t * (x1 - x0 - 2 * step)
        links.append(np.array([[x, y0], [x, y0 + step]]))
        x0, y0, x1, y1 = x0 + step, y0 + step, x1 - step, y1 - step
    return rings, links


@settings(max_examples=40, deadline=None)
@given(nested_rings(), st.floats(0, 1), st.floats(0, 1))
def test_a_way_runs_on_the_cut_paths_from_one_point_of_them_to_another(drawn, s, t):
    rings, links = drawn
    paths = CutPaths()
    for ring in rings:
        paths.add(ring)
    for link in links[:len(rings) - 1]:
        paths.add(link)
    union_lines = MultiLineString([LineString(q) for q in [*rings, *links[:len(rings) - 1]]])
    outer, inner = LineString(rings[0]), LineString(rings[-1])
    a = np.array(shapely.get_coordinates(outer.interpolate(s, normalized=True))[0])
    b = np.array(shapely.get_coordinates(inner.interpolate(t, normalized=True))[0])
    way = paths.way(a, b)
    assert way is not None
    assert np.allclose(way[0], a) and np.allclose(way[-1], b)
    # every stretch of it lies on the paths
    for p, q in zip(way[:-1], way[1:]):
        for f in (0.0, 0.25, 0.5, 0.75, 1.0):
            assert union_lines.distance(shapely.Point(p + f * (q - p))) < 1e-6
    length = float(np.linalg.norm(np.diff(way, axis=0), axis=1).sum())
    assert length >= float(np.linalg.norm(b - a)) - 1e-9
    # no longer than the way round the outer ring to the links and down them
    assert length <= outer.length / 2 + sum(inner_ring_len / 2 + 6 for inner_ring_len in
                                             (LineString(q).length for q in rings[1:])) + 1e-6
    # a point off the paths has no way
    assert paths.way(a, np.array([-5.0, -5.0])) is None


def test_the_air_feed_buys_as_much_way_as_the_rapids_take_time():
    rapid = PostOptions().rapid_rate
    assert down_budget(30.0, None) == 30.0
    assert math.isclose(down_budget(30.0, 2 * rapid), 60.0)


@functools.cache
def plate_with_bosses() -> tuple[trimesh.Trimesh, Setup]:
    """A plate with three round bosses and a short one (plate_bosses' layout, smaller): the stock round them is
    one region per level, and the corners the loops leave lie apart round the bosses."""
    plate = box((2, 2, -20), (78, 62, -12))
    bosses = [trimesh.creation.cylinder(radius=9, height=12, sections=64,
                                        transform=trimesh.transformations.translation_matrix((x, y, -6)))
              for x, y in ((20, 18), (60, 18), (40, 44))]
    short = trimesh.creation.cylinder(radius=6, height=6, sections=64,
                                      transform=trimesh.transformations.translation_matrix((68, 50, -9)))
    part = union(plate, *bosses, short)
    return part, Setup(stock_min=(0, 0, -20), stock_max=(80, 64, 0), transform_mesh_to_work=np.eye(4))


def seconds_and_cut(op, setup) -> tuple[float, float]:
    """The program's seconds of ``op`` with its feed moves that meet no stock at the air feed (as the chip feeds
    give them), the others at the cutting feed, plunges at the plunge feed, rapids at the post's rapid rate; and
    the length of the feed moves that meet stock [mm] (the tests' heightfield, the cells surely under the
    tool)."""
    hf = HeightField(setup, TOOL.radius)
    inner = TOOL.radius - 1.5 * hf.cell
    P, M = op.points, op.motion
    seconds, cutting = 0.0, 0.0
    for i in range(1, len(P)):
        a, b = P[i - 1], P[i]
        length = float(np.linalg.norm(b - a))
        if M[i] == Motion.RAPID:
            seconds += 60.0 * length / PostOptions().rapid_rate
            continue
        n = max(1, math.ceil(length / (0.5 * hf.cell)))
        samples = a + np.linspace(0, 1, n + 1)[:, None] * (b - a)
        meets = any(hf.highest(s[:2], inner) > s[2] + 0.02 for s in samples)
        for s in samples:
            hf.cut(s[:2], s[2], TOOL.radius)
        feed = CUTTING.plunge_feed if M[i] == Motion.PLUNGE else (CUTTING.feed if meets else AIR_FEED)
        seconds += 60.0 * length / feed
        cutting += length if meets else 0.0
    return seconds, cutting


def test_links_stay_down_on_the_cut_paths_where_quicker_and_cut_nothing_more():
    part, setup = plate_with_bosses()
    lifting = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions())
    down = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(air_feed=AIR_FEED))
    motion_basics(down, setup)
    assert_no_gouge(part, down, 0.3, radius=TOOL.radius)
    hf_down, bad = simulate(down, setup, 3.0, radius=TOOL.radius)
    assert not bad, "\n".join(bad[:5])
    hf_lift, _ = simulate(lifting, setup, 3.0, radius=TOOL.radius)
    # the same stock left: the ways along the cut paths took nothing (cells at a disc's rim may round apart)
    assert np.mean(~np.isclose(hf_down.h, hf_lift.h, rtol=0.0, atol=0.02)) < 1e-3

    def lifts(op) -> int:
        """Rapids up from below the stock top that come back down below it."""
        z, top = op.points[:, 2], setup.stock_max[2]
        up = np.flatnonzero((op.motion[1:] == Motion.RAPID) & (z[:-1] < top - 1e-6) & (z[1:] > top))
        return int(sum(1 for i in up if np.any(z[i + 1:] < top - 1e-6)))

    assert lifts(down) < lifts(lifting)
    t_lift, cut_lift = seconds_and_cut(lifting, setup)
    t_down, cut_down = seconds_and_cut(down, setup)
    assert cut_down <= cut_lift * 1.01 + 1.0, "a way along the cut paths met stock"
    assert t_down < t_lift - 1.0, (t_down, t_lift)


def level_moves_round_the_stock(op, setup) -> float:
    """Length [mm] of the level feed moves below the stock top whose tool keeps off the stock box all along
    (the centre at least a radius from it), by shapely on the moves themselves."""
    stock = shapely.box(*setup.stock_min[:2], *setup.stock_max[:2])
    a, b = op.points[:-1], op.points[1:]
    level = ((op.motion[1:] != Motion.RAPID) & (np.abs(a[:, 2] - b[:, 2]) < 1e-9)
             & (a[:, 2] < setup.stock_max[2] - 1e-6))
    lines = [LineString([p[:2], q[:2]]) for p, q in zip(a[level], b[level])]
    off = shapely.distance(np.array(lines, dtype=object), stock) >= TOOL.radius - 1e-6
    return float(sum(line.length for line, o in zip(lines, off) if o))


def test_roughing_from_the_block_runs_no_loop_round_the_stock_and_cuts_what_it_did(monkeypatch):
    """Each level's outer loop was the stock grown by the radius: its disc only touched the stock's sides. It
    is left out (:func:`cadcam.levelpath.round_the_stock`); the levels cut everything they cut with it, no
    gouge, no plunge, rapids clear, in less cutting path, and no level move keeps off the stock all along."""
    from cadcam import roughing
    from tests.cadcam.test_roughing import assert_cuts_what_it_cuts_in_less_path

    part, setup = plate_with_bosses()
    options = RoughingOptions(air_feed=AIR_FEED)
    op = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    with monkeypatch.context() as m:  # as before: every loop cut
        m.setattr(roughing, "round_the_stock", lambda loops, box, radius: np.zeros(len(loops), bool))
        every = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    motion_basics(op, setup)
    assert level_moves_round_the_stock(every, setup) > 100.0  # the loops round the stock, every level
    assert level_moves_round_the_stock(op, setup) == 0.0
    assert_cuts_what_it_cuts_in_less_path(part, setup, op, every, options, 0.9)
    assert seconds_and_cut(op, setup)[0] < seconds_and_cut(every, setup)[0] - 1.0


@settings(max_examples=80, deadline=None)
@given(steps=st.lists(st.tuples(st.sampled_from([0.0, 0.4, 0.9, 1.0, 1.1, 2.0, 2.1, 1e6]), st.integers(0, 2),
                                st.sampled_from(list(Motion))), min_size=0, max_size=12),
       start=st.booleans(), one_kind=st.booleans())
def test_moves_added_at_once_are_those_added_one_by_one(steps, start, one_kind):
    """:meth:`LevelPath.add_many` (a loop, a piece of rest machining) emits the moves :meth:`LevelPath.add` emits
    one by one, points and kinds: moves shorter than :data:`SAME_POINT` skipped, also in a row of them that
    drifts past it, and after the point the path stood at."""
    xyz, kinds, q = [], [], np.array([3.0, -2.0, 1.0])
    for length, axis, kind in steps:  # each point a multiple of SAME_POINT along an axis from the one before
        q = q.copy()
        q[axis] += length * SAME_POINT
        xyz.append(q)
        kinds.append(int(kind))
    xyz = np.array(xyz).reshape(-1, 3)
    kind = Motion.CUT if one_kind else np.array(kinds, dtype=np.int8)
    one, many = LevelPath(), LevelPath()
    if start:
        for path in (one, many):
            path.add([3.0, -2.0, 1.0 + 0.5 * SAME_POINT], Motion.RAPID)
    for p, k in zip(xyz, [kind] * len(xyz) if one_kind else kinds):
        one.add(p, Motion(int(k)))
    many.add_many(xyz, kind)
    assert many.motion == one.motion and all(type(k) is int for k in many.motion)
    assert np.array_equal(np.array(many.points).reshape(-1, 3), np.array(one.points).reshape(-1, 3))
