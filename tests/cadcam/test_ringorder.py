"""cadcam.ringorder: a region's loops in the order a machinist takes them, each meeting the stock it met before;
rest machining's loops that meet no stock left out (not the loop round a rest pocket's rim), and an open region
entered onto a loop that is cut; the bracket's flank pass round the part once a level."""

from __future__ import annotations

import math

import numpy as np
import shapely
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiLineString, MultiPoint, Point, box
from shapely.ops import unary_union

from cadcam.gridregion import cells_region, near_cells
from cadcam.heightmap import Grid, grid_over, upper_envelope
from cadcam.model import Motion
from cadcam.rest import rest_mask
from cadcam.ringorder import LoopChoice, LoopOrder
from cadcam.roughing import RoughingOptions, _resolve, _rings, zlevel_roughing
from cadcam.setup import make_setup
from cadcam.stock import Simulation
from cadcam.tools import load_tool_library
from tests.cadcam.test_plan import sample_op1
from tests.cadcam.test_post import FLAT

#: A floor 200 x 60 mm round islands (the bracket's top between its bosses, drawn out).
FLOOR = box(0.0, 0.0, 200.0, 60.0)
LIBRARY = load_tool_library()


def _params():
    """Floor finishing with a 10 mm end mill at 0.85 D (the bracket's), over a block holding the floor."""
    setup, _ = make_setup(trimesh.creation.box(extents=(200.0, 60.0, 20.0)))
    return _resolve(RoughingOptions(stepover=0.85 * FLAT.diameter, allowance=0.005), FLAT, setup)


def _order(region, inside_out: bool, diameter: float):
    """Loops of ``region`` in the order :class:`LoopOrder` takes them from the first (the outermost), each time
    with the tool where the last loop ended; and the way it rapids to each link's start [mm]."""
    p = _params()
    rings = _rings(region, p)
    order = LoopOrder.of([r.line for r in rings], np.array([r.k for r in rings]), inside_out, diameter)
    first = int(np.argmax([r.line.length for r in rings])) if not inside_out else int(np.argmax([r.k for r in rings]))
    done, uncut, here, way = [first], [j for j in range(len(rings)) if j != first], rings[first].coords[0], 0.0
    covered = region.buffer(1e-5)
    while uncut:
        j, src, q = order.next(uncut, MultiLineString([rings[i].line for i in done]), covered, here, p.link_max)
        way += float(np.hypot(*(src - here[:2])))
        uncut.remove(j)
        done.append(j)
        here = q
    return rings, done, way


@settings(max_examples=25, deadline=None)
@given(holes=st.lists(st.tuples(st.floats(20.0, 180.0), st.floats(15.0, 45.0), st.floats(3.0, 9.0)),
                      min_size=1, max_size=4))
def test_a_loop_waits_for_every_loop_of_a_lower_index_its_sweep_may_meet_and_every_loop_is_cut(holes):
    """Round any islands: a loop waits for exactly the loops of a lower erosion index less than a diameter from it
    (whose sweeps may meet its own: checked pair by pair), so where the tool takes a ready loop, two loops whose
    sweeps meet go in the strict outside-in order and each meets the stock it met before; every loop is cut
    once."""
    region = FLOOR.difference(unary_union([Point(x, y).buffer(r) for x, y, r in holes]))
    if region.geom_type != "Polygon":
        return
    rings = _rings(region, _params())
    lines = [r.line for r in rings]
    order = LoopOrder.of(lines, np.array([r.k for r in rings]), False, FLAT.diameter)
    for b in range(len(rings)):
        expected = {a for a in range(len(rings))
                    if rings[a].k < rings[b].k and shapely.distance(lines[a], lines[b]) <= FLAT.diameter}
        assert set(order.waits[b].tolist()) == expected
    _, done, _ = _order(region, False, FLAT.diameter)
    assert sorted(done) == list(range(len(rings)))


def test_the_tool_finishes_round_one_island_before_crossing_to_the_next():
    """Two islands 120 mm apart on the floor: strict outside-in order (every loop waiting for every loop of a
    lower index) crosses between them for each index; the tool now goes round one, then the other, and its
    rapids to the links' starts are shorter."""
    region = FLOOR.difference(unary_union([box(30, 20, 50, 40), box(150, 20, 170, 40)]))
    rings, done, way = _order(region, False, FLAT.diameter)
    _, strict, strict_way = _order(region, False, math.inf)

    def crossings(order):
        side = [rings[j].line.bounds for j in order]
        sides = [0 if b[2] < 100 else 1 if b[0] > 100 else None for b in side]
        sides = [s for s in sides if s is not None]
        return sum(a != b for a, b in zip(sides, sides[1:]))

    assert crossings(done) < crossings(strict), (crossings(done), crossings(strict))
    assert way < strict_way


def _flat_stock(grid: Grid, stock_top: np.ndarray, part_top: np.ndarray) -> Simulation:
    return Simulation(grid=grid, stock_top=stock_top, part_top=part_top, stock_bottom=-30.0)


def _points_of(mask: np.ndarray, grid: Grid):
    j, i = np.nonzero(mask)
    return shapely.points(grid.x0 + grid.cell * i, grid.y0 + grid.cell * j)


def test_a_loop_sweeping_no_rest_material_is_left_out():
    """A band of skin 0.6 mm thick on a wall, the floor beside it cut: the loop along the wall passes within the
    radius of the skin's grid points; the one round the band's outer edge (the skin's cells grown by the radius:
    a radius and half a cell off its points) is tangent to the skin and left out. One a radius and a hair off the
    points passes through the skin's last cells, stock standing between its grid points: it is cut. With no rest
    material, nothing is cut."""
    grid = Grid(x0=0.0, y0=0.0, cell=0.2, nx=301, ny=301)
    x, y = np.meshgrid(grid.xs, grid.ys)
    wall = (x < 20.0) & (y >= 10.0) & (y <= 50.0)
    skin = (x >= 20.0) & (x <= 20.6) & (y >= 10.0) & (y <= 50.0)  # the part at X < 20, air beyond 20.6
    stock = _flat_stock(grid, np.where(wall | skin, 10.0, 0.0), np.where(wall, 10.0, -np.inf))
    cuts = LoopChoice.of(stock, 0.0, FLAT.radius).at(skin, 5.0)
    along = shapely.LineString([(20.0 + FLAT.radius + 0.005, 10.0), (20.0 + FLAT.radius + 0.005, 50.0)])
    edge = shapely.LineString([(20.7 + FLAT.radius, 10.0), (20.7 + FLAT.radius, 50.0)])
    between = shapely.LineString([(20.6 + FLAT.radius + 0.004, 10.0), (20.6 + FLAT.radius + 0.004, 50.0)])
    assert list(cuts([along, edge, between])) == [True, False, True]
    bare = _flat_stock(grid, np.where(wall, 10.0, 0.0), np.where(wall, 10.0, -np.inf))
    assert not LoopChoice.of(bare, 0.0, FLAT.radius).at(np.zeros_like(skin), 5.0)([along, edge, between]).any()


def test_the_loop_round_a_rest_pocket_s_rim_is_cut():
    """Gallery relief_to_edge's bowl, which the 2 mm end mill rest-roughs at Z-6.677: the stock stands at Z-6.27
    over the bowl (the wider tool could not enter it), the rest material (more than 1.5 mm over the part and its
    allowance) is the bowl's middle, and the region's outer loop, a radius and half a cell off those points,
    passes over none of them. It meets the rim round them, which the inner loops do not reach: left out
    (e2d6531's rule), the rim stood 0.35 mm over the finished bowl, deeper than the ball's raster takes."""
    grid = Grid(x0=0.25, y0=0.25, cell=0.5, nx=40, ny=40)
    x, y = np.meshgrid(grid.xs, grid.ys)
    bowl = -8.04 + 0.045 * ((x - 10.0) ** 2 + (y - 10.0) ** 2)  # its rim 1.5 mm up 5.8 mm from the middle
    stock = _flat_stock(grid, np.full(grid.shape, -6.27), bowl)
    z, allowance, tool = -6.677, 0.3, LIBRARY.tool(6)
    rest = rest_mask(stock, z, 1.5, allowance)
    assert rest.any() and not rest.all()
    p = _resolve(RoughingOptions(allowance=allowance), tool, make_setup(trimesh.creation.box(extents=(20, 20, 10)))[0])
    region = cells_region(rest, grid).buffer(tool.radius, quad_segs=8)
    lines = [r.line for r in _rings(region, p)]
    outer = int(np.argmax([line.length for line in lines]))
    assert shapely.distance(_points_of(rest, grid), lines[outer]).min() > tool.radius  # e2d6531 left it out
    cut = LoopChoice.of(stock, allowance, tool.radius).at(rest, z)(lines)
    assert cut[outer] and cut.all(), cut


@settings(max_examples=25, deadline=None)
@given(blobs=st.lists(st.tuples(st.floats(11.0, 19.0), st.floats(11.0, 19.0), st.floats(0.5, 3.0)), min_size=1,
                      max_size=3),
       standing=st.floats(0.0, 3.0), far=st.floats(3.5, 9.0))
def test_a_loop_left_out_meets_no_stock_and_one_over_the_rest_material_is_cut(blobs, standing, far):
    """Rest material in random blobs, stock standing round them out to ``standing`` mm and again from ``far`` mm
    on, the loops of the region the rest tool cuts: a loop within the radius of the rest material is cut, and a
    loop left out has no stock above the level within its radius, at a grid point or in its cell (so no loop cut
    meets more stock than it did with every loop); a loop tangent to the cells is left out. The choice asks only
    the stock near the rest material: it is the one every stock cell's distance gives."""
    grid = Grid(x0=0.0, y0=0.0, cell=0.25, nx=121, ny=121)
    x, y = np.meshgrid(grid.xs, grid.ys)
    near = np.min([np.hypot(x - cx, y - cy) - r for cx, cy, r in blobs], axis=0)
    rest, stands = near <= 0.0, (near <= standing) | (near >= far)
    stock = _flat_stock(grid, np.where(stands, 5.0, -1.0), np.full(grid.shape, -np.inf))
    region = cells_region(rest, grid).buffer(FLAT.radius, quad_segs=8)
    lines = [r.line for r in _rings(region, _params())]
    cut = LoopChoice.of(stock, 0.0, FLAT.radius).at(rest, 0.0)(lines)
    rest_points, stock_points = _points_of(rest, grid), _points_of(stands, grid)
    half = 0.5 * grid.cell
    j, i = np.nonzero(stands)
    cx, cy = grid.x0 + grid.cell * i, grid.y0 + grid.cell * j
    stock_cells = shapely.box(cx - half, cy - half, cx + half, cy + half)
    sag = FLAT.radius * (1.0 - math.cos(math.pi / 32))  # the region's arcs: 8 chords a quarter
    for line, c in zip(lines, cut):
        if shapely.distance(rest_points, line).min() <= FLAT.radius:
            assert c
        to_points = shapely.distance(stock_points, line)
        by = to_points <= FLAT.radius + grid.cell  # a cell farther off than its point less a cell meets nothing
        into = by.any() and shapely.distance(stock_cells[by], line).min() < FLAT.radius - sag - 1e-6
        assert c == (into or to_points.min() <= FLAT.radius)


def test_the_bracket_flank_pass_goes_round_the_part_once_at_its_floor():
    """The bracket's flats and walls at its floor level: one loop round the part (its outline grown by the tool
    radius), not a second one a radius off the skin, sweeping air (on main: 697 mm for a 347 mm loop)."""
    setup, part, job = sample_op1("bracket")
    op = next(o for o in job.operations if o.name.startswith("finish flats+walls"))
    floor = float(np.min(op.points[:, 2]))
    at = (np.abs(op.points[1:, 2] - floor) < 1e-6) & (np.abs(op.points[:-1, 2] - floor) < 1e-6) \
        & (op.motion[1:] != int(Motion.RAPID))
    fed = float(np.sum(np.linalg.norm(np.diff(op.points[:, :2], axis=0)[at], axis=1)))
    # the bracket's outline is its outermost extent, a rounded rectangle: its hull
    loop = MultiPoint(part.vertices[:, :2]).convex_hull.buffer(op.tool.radius).exterior.length
    assert fed < 1.2 * loop, (fed, loop)


def test_stock_round_a_part_open_to_the_stock_s_sides_is_swept_to_the_wall_allowance():
    """Op 2's stock round a block below what op 1 reached (the gallery's random block, 60 x 36.57 mm in stock 2 mm
    wider each side), rest-roughed with the 2 mm end mill: the region reaches the stock's sides, and its outline, a
    radius outside them, sweeps air and is left out. The entry from outside goes onto the loop along the wall;
    entered at a point off that loop (on main with op 2's ``every_loop`` flag removed), the loop was cut from that
    point, a chord through the air: 48 mm2 of the front wall's stock left at full height, which the finishing end
    mill then met 4.81 mm deep."""
    tool = LIBRARY.tool(6)
    part = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [60.0, 36.57, 5.0]])
    setup, work = make_setup(part, stock_size=(64.0, 40.57, 11.5))
    grid = grid_over(setup.stock_min, setup.stock_max, 0.5)
    (x0, y0, z0), (x1, y1, z1) = work.bounds
    stock = _flat_stock(grid, np.full(grid.shape, z1), upper_envelope(np.asarray(work.triangles), grid))
    allowance = RoughingOptions().allowance
    op = zlevel_roughing(work, setup, tool, LIBRARY.cutting_data(tool, setup.material), RoughingOptions(), rest=stock,
                         rest_above=1.0)
    ring = box(*setup.stock_min[:2], *setup.stock_max[:2]).difference(
        box(x0, y0, x1, y1).buffer(allowance + 0.05, join_style="mitre"))
    pts = op.points
    fed = (op.motion[1:] != int(Motion.RAPID)) & (np.abs(np.diff(pts[:, 2])) < 1e-9) & (pts[1:, 2] < z1 - 1e-6)
    levels = np.unique(np.round(pts[1:, 2][fed], 6))
    assert len(levels)
    for z in levels:
        at = np.nonzero(fed & (np.abs(pts[1:, 2] - z) < 1e-6))[0]
        swept = shapely.union_all(shapely.buffer(shapely.linestrings(np.stack([pts[at, :2], pts[at + 1, :2]], 1)),
                                                 tool.radius))
        assert ring.difference(swept).area < 1e-3, (z, ring.difference(swept).bounds)


def _cuts_by_point_tree(xy: np.ndarray, lines: list, radius: float, cell: float) -> np.ndarray:
    """The loop choice as afa326e made it: an STRtree of every stock point, asked ``dwithin`` the radius, then
    the cells of those within the radius and half a cell diagonal."""
    out = np.zeros(len(lines), dtype=bool)
    if not len(xy):
        return out
    half = 0.5 * cell
    stock = shapely.STRtree(shapely.points(xy))
    out[np.unique(stock.query(lines, predicate="dwithin", distance=radius)[0])] = True
    rest = np.nonzero(~out)[0]
    if len(rest):
        left = np.array(lines, dtype=object)[rest]
        a, b = stock.query(left, predicate="dwithin", distance=radius + half * math.sqrt(2.0))
        cells = shapely.box(xy[b, 0] - half, xy[b, 1] - half, xy[b, 0] + half, xy[b, 1] + half)
        into = shapely.distance(left[a], cells) < radius * math.cos(math.pi / 32) - 1e-6
        out[np.unique(rest[a[into]])] = True
    return out


@settings(max_examples=60, deadline=None)
@given(blobs=st.lists(st.tuples(st.floats(3.0, 12.0), st.floats(3.0, 12.0), st.floats(0.2, 3.0)), min_size=1,
                      max_size=3),
       cell=st.sampled_from([0.2, 0.25, 0.5]), radius=st.sampled_from([0.5, 1.5, 3.0, 4.0]),
       shift=st.floats(-0.15, 0.05), stray=st.lists(st.tuples(st.floats(-5.0, 20.0), st.floats(-5.0, 20.0)),
                                                  min_size=2, max_size=6),
       standing=st.sampled_from([0.0, 0.0, 0.7]))
def test_the_loop_choice_asks_geos_only_near_the_loop_and_gives_the_point_tree_s_answer(blobs, cell, radius, shift,
                                                                                        stray, standing):
    """:meth:`LoopChoice.at` finds the stock points that may be within reach of a loop from the loop's samples and
    asks GEOS only about those: its answer is the STRtree's of every point (afa326e), on the loops of rest regions
    (tangent to cells, a radius off their corners), the outlines of discs a radius round the points (at the
    radius at their vertices), each moved a little either way (into the band of points within the radius of the
    loop but not of its samples, and into the cells' corners), and stray lines."""
    grid = Grid(x0=0.1, y0=-0.3, cell=cell, nx=int(16.0 / cell), ny=int(16.0 / cell))
    x, y = np.meshgrid(grid.xs, grid.ys)
    near = np.min([np.hypot(x - cx, y - cy) - r for cx, cy, r in blobs], axis=0)
    rest = near <= 0.0
    stock = _flat_stock(grid, np.where(near <= standing, 5.0, -1.0), np.full(grid.shape, -np.inf))
    region = cells_region(rest, grid).buffer(radius, quad_segs=8)
    discs = shapely.union_all(shapely.buffer(_points_of(rest, grid), radius, quad_segs=8))  # a radius off points
    outlines = [region, region.buffer(shift, quad_segs=8), region.buffer(-0.5 * radius, quad_segs=8), discs,
                discs.buffer(shift, quad_segs=8)]
    lines = [*shapely.get_parts(shapely.line_merge(shapely.boundary(outlines))), shapely.LineString(stray)]
    choice = LoopChoice.of(stock, 0.0, radius)
    j, i = np.nonzero(near_cells(rest, 2.0 * radius + cell * math.sqrt(2.0) + 1e-3, cell)
                      & (rest | (choice.over & (stock.stock_top > 1e-3))))
    xy = np.column_stack([grid.x0 + grid.cell * i, grid.y0 + grid.cell * j])
    assert list(choice.at(rest, 0.0)(lines)) == list(_cuts_by_point_tree(xy, lines, radius, cell))


@settings(max_examples=80, deadline=None)
@given(corners=st.lists(st.tuples(st.floats(0.0, 10.0), st.floats(0.0, 10.0)), min_size=2, max_size=6),
       seed=st.integers(0, 2**31 - 1), distance=st.sampled_from([0.5, 1.5, 3.0]), cell=st.sampled_from([0.2, 0.5]),
       off=st.sampled_from([-1e-7, 0.0, 1e-7, 0.01, 0.05, 0.1]))
def test_the_points_near_a_loop_found_from_its_samples_are_geos_points_within_the_distance(corners, seed, distance,
                                                                                           cell, off):
    """:func:`cadcam.ringorder._near` finds the points near a loop from the loop's samples in the points' k-d tree
    (issue 35): exactly the points GEOS puts within the distance of the line (``dwithin``, every point asked), and
    with ``first`` one of them exactly when one lies within the distance less a hair. The points lie on and about
    the distance from the line (``off`` [mm] beyond it: the band between the line and its samples' reach)."""
    from scipy.spatial import cKDTree

    from cadcam.ringorder import _SAMPLE_STEP, _SURE_TOL, _near, _samples

    line = shapely.LineString(corners)
    if line.length < 1e-3:
        return
    rng = np.random.default_rng(seed)
    at = shapely.get_coordinates(shapely.line_interpolate_point(line, rng.uniform(0, line.length, 200)))
    turn = rng.uniform(0, 2 * np.pi, 200)
    xy = np.concatenate([at + (distance + off) * np.column_stack([np.cos(turn), np.sin(turn)]),
                         rng.uniform(-5.0, 15.0, (100, 2))])
    step = _SAMPLE_STEP * cell
    samples = _samples(line, step)
    within = np.flatnonzero(shapely.dwithin(line, shapely.points(xy), distance))
    got = _near(line, xy, cKDTree(xy), distance, step, samples)
    assert np.array_equal(got, within)
    one = _near(line, xy, cKDTree(xy), distance, step, samples, first=True)
    assert set(one.tolist()) <= set(within.tolist()) and (len(one) > 0) == (len(within) > 0)
    sure = shapely.distance(line, shapely.points(xy)) <= distance - 2 * _SURE_TOL
    assert len(one) == 1 or not sure.any()
