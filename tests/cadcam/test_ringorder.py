"""cadcam.ringorder: a region's loops in the order a machinist takes them, each meeting the stock it met before."""

from __future__ import annotations

import math

import numpy as np
import shapely
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import MultiLineString, Point, box
from shapely.ops import unary_union

from cadcam.ringorder import LoopOrder
from cadcam.roughing import RoughingOptions, _resolve, _rings
from cadcam.setup import make_setup
from tests.cadcam.test_post import FLAT

#: A floor 200 x 60 mm round islands (the bracket's top between its bosses, drawn out).
FLOOR = box(0.0, 0.0, 200.0, 60.0)


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
