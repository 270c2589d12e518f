"""cadcam.restlinks: rest machining's pieces linked low never feed across the part, between grid points included."""

from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, box

from cadcam.heightmap import Grid
from cadcam.model import Motion
from cadcam.restlinks import FIRST_ASKED, Links, Piece
from cadcam.stock import Simulation, clear_height
from tests.cadcam.test_post import BALL, DRILL, FLAT

#: The part: a block 20.3..59.7 x 20.3..49.7 mm, 10 mm tall (its top at Z0), its corners between the points of a
#: grid of 0.5 mm.
PART_XY = (20.3, 20.3, 59.7, 49.7)
CELL = 0.5


def _links() -> tuple[Links, Simulation]:
    grid = Grid(x0=0.0, y0=0.0, cell=CELL, nx=161, ny=141)
    x, y = np.meshgrid(grid.x0 + CELL * np.arange(grid.nx), grid.y0 + CELL * np.arange(grid.ny))
    on = (x >= PART_XY[0]) & (x <= PART_XY[2]) & (y >= PART_XY[1]) & (y <= PART_XY[3])
    part_top = np.where(on, 0.0, -np.inf)
    # everything round the part already cut to Z-10: only the part stands
    stock = Simulation(grid=grid, stock_top=np.where(on, 0.0, -10.0), part_top=part_top, stock_bottom=-10.0)
    rect = box(-FLAT.radius, -FLAT.radius, 80 + FLAT.radius, 70 + FLAT.radius)
    # where the axis may go at the one level, Z-5: the part grown by the radius, its corners round
    space = rect.difference(box(*PART_XY).buffer(FLAT.radius, quad_segs=16))
    return Links(stock, FLAT, rect, [space]), stock


@settings(max_examples=60, deadline=None)
@given(a=st.floats(0.0, 1.0), b=st.floats(0.0, 1.0), corner=st.sampled_from(range(4)))
def test_a_feed_across_a_corner_never_comes_nearer_the_part_than_the_tool_radius(a, b, corner):
    """Two points on the arc the tool's axis goes round an outside corner of the part (a finishing loop's):
    the feed straight between them is allowed only where the tool's whole way keeps off the part, though the
    part's corner lies between the stock model's grid points."""
    links, _ = _links()
    x0, y0, x1, y1 = PART_XY
    cx, cy = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)][corner]
    start = [np.pi, 1.5 * np.pi, 0.0, 0.5 * np.pi][corner]  # the quarter arc about it facing away from the part
    r = FLAT.radius + 0.0069  # as a finishing loop goes round it, a few microns off
    p, q = (np.array([cx + r * np.cos(start + t * np.pi / 2), cy + r * np.sin(start + t * np.pi / 2)]) for t in (a, b))
    down = links.stays_down(p, q, -5.0, 0)
    nearest = (LineString([p, q]) if np.linalg.norm(q - p) > 1e-9 else Point(p)).distance(box(*PART_XY))
    if down:
        assert nearest >= FLAT.radius - 1e-4
    if abs(a - b) > 0.2:  # a chord that cuts the corner by more than a hundredth of a millimetre: never
        assert not down


def test_a_feed_along_a_wall_off_the_part_stays_down():
    """A way that keeps a radius off the part over stock already cut to the level is fed across."""
    links, _ = _links()
    y = PART_XY[1] - FLAT.radius - 0.5
    assert links.stays_down(np.array([25.0, y]), np.array([55.0, y]), -5.0, 0)


@settings(max_examples=300, deadline=None)
@given(pts=st.lists(st.tuples(st.floats(-5.0, 5.0), st.floats(-5.0, 5.0)), min_size=1, max_size=6),
       radius=st.floats(0.05, 8.0), apart=st.floats(1.85, 2.1), angle=st.floats(0.0, 2.0 * np.pi),
       turn=st.one_of(st.just(0.0), st.floats(0.0, 2.0 * np.pi)))
@example(pts=[(0.0, 0.0)], radius=1.0, apart=1.97, angle=np.pi / 16, turn=0.0)  # two 16-gons' edges, just apart
def test_pieces_meet_exactly_where_their_footprints_do(pts, radius, apart, angle, turn):
    """Stacking decides most pairs of pieces from their ways' distance alone; it must agree with the grown
    footprints themselves, near the grow distance too (the pieces' order, so the program, depends on it)."""
    way = np.array(pts)
    c, s = np.cos(turn), np.sin(turn)
    # the other way turned about this one's start, then moved off by about the footprints' width (apart x radius)
    other = (way - way[0]) @ np.array([[c, s], [-s, c]]) + way[0] + apart * radius * np.array([np.cos(angle),
                                                                                              np.sin(angle)])
    p, q = (Piece(0, 0.0, xy[0], np.zeros((1, 3)), np.zeros(1, dtype=np.int8), _way(xy), radius)
            for xy in (way, other))
    assert p.meets(q) == p.way.buffer(radius, quad_segs=4).intersects(q.way.buffer(radius, quad_segs=4))


def _way(xy: np.ndarray) -> LineString | Point:
    return LineString(xy) if len(xy) > 1 and np.ptp(xy, axis=0).any() else Point(xy[0])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tool=st.sampled_from([FLAT, BALL, DRILL]), cell=st.sampled_from([0.2, 0.5]),
       ways=st.lists(st.tuples(st.floats(-12.0, 32.0), st.floats(-12.0, 27.0), st.floats(-12.0, 32.0),
                               st.floats(-12.0, 27.0)), min_size=1, max_size=4),
       cuts=st.lists(st.tuples(st.floats(0.0, 20.0), st.floats(0.0, 15.0), st.floats(-3.0, 1.0)), max_size=3))
def test_a_links_height_is_the_highest_clearance_along_its_way(seed, tool, cell, ways, cuts):
    """The height a link lifts to, asked only where the stock can lift it (:data:`FIRST_ASKED` samples first),
    is the highest clearance of every sample of its way to the bit, and no sample's bound lies under its
    clearance: over random stock with empty columns, for a flat end mill, a ball and a drill, on and off the
    grid, before and after pieces lowered the stock."""
    rng = np.random.default_rng(seed)
    grid = Grid(x0=0.0, y0=0.0, cell=cell, nx=int(20 / cell) + 1, ny=int(15 / cell) + 1)
    top = rng.normal(0.0, 2.0, grid.shape) + np.where(rng.random(grid.shape) < 0.01, 5.0, 0.0)
    top[rng.random(grid.shape) < 0.1] = -np.inf  # columns cut through
    stock = Simulation(grid=grid, stock_top=top, part_top=np.full(grid.shape, -np.inf), stock_bottom=-10.0)
    rect = box(-30.0, -30.0, 50.0, 45.0)
    links = Links(stock, tool, rect, [rect])
    for k, (x0, y0, x1, y1) in enumerate(ways):
        a, b = np.array([x0, y0]), np.array([x1, y1])
        xy = links._way(a, b)
        each = clear_height(links.stock, tool, xy)
        assert np.all(links._bounds(xy) >= each)  # what leaves a sample unasked: never under its clearance
        assert np.array_equal(links.height(a, b), float(np.max(each)))
        if k < len(cuts):  # a piece cuts at its level along a line: the stock under it lowered
            x, y, z = cuts[k]
            pts = np.array([[x, y, 5.0], [x, y, z], [x + 3.0, y + 1.0, z]])
            links.cut(Piece.of(0, z, pts, np.array([Motion.RAPID, Motion.PLUNGE, Motion.CUT], np.int8), 5.0,
                               tool.radius))
    assert len(links._way(np.array([-12.0, -12.0]), np.array([32.0, 27.0]))) > FIRST_ASKED
