"""Pockets, slots, necks and open-sided pockets taken deep by fronts (cadcam.adaptive.front_cut_moves), checked by
the independent replay of tests/cadcam/test_adaptive.py: a pixel grid of the band's material made from the
part's own outline, cut by the moves sample by sample, the engagement read off the cutter's leading half.

A helix entry clears its own disc and is the one place the band need not hold (issue 32); everywhere else the
radial engagement stays within (target + band) x D, so nowhere a full-width cut. What the fronts cannot reach
is the corners sharper than their rounding and the cusps beside islands: the stock left lies within
:data:`LEFT_DEPTH` of the radius of what the tool can reach at all.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from shapely.geometry import Point, Polygon, box

from cadcam.adaptive import AdaptiveOptions, BandGeometry, front_cut_moves
from cadcam.model import Motion
from tests.cadcam.test_adaptive import ALLOW, OPTIONS, Z, Z_TOP, Replay, held_to, replay, tool

BaseGeometry = shapely.Geometry
RAMP = 3.0  # the roughing's ramp angle [deg]
#: Raster pitch of the replay here, as a share of the radius: twice test_adaptive's, for time; its reading is
#: allowed two cells over the band.
CELL_SHARE = 0.04
#: How deep the stock the fronts leave may lie inside what the tool can reach, as a share of its radius: the
#: corners sharper than the fronts' rounding and the cusps beside an island a cutter cannot pass (issue 32:
#: rest roughing's to take).
LEFT_DEPTH = 0.7


def regions(part: BaseGeometry, stock: Polygon, r: float) -> tuple[list[Polygon], Polygon]:
    """The tool-centre regions beside ``part`` within the box the levels keep to (not the slivers at its corners,
    beyond the stock's), and that box."""
    axis_box = box(*stock.buffer(r, join_style="mitre").bounds)
    grown = part.buffer(r + ALLOW, quad_segs=32)
    inner = stock.buffer(-1e-3)
    return [q for q in shapely.get_parts(axis_box.difference(grown)) if q.area > 1e-4 and q.intersects(inner)], axis_box


def cut(part: BaseGeometry, stock: Polygon, d: float) -> tuple[np.ndarray, np.ndarray, list[Polygon]]:
    """Every region beside ``part`` taken by fronts, one after the other (all must be taken): the moves and the
    regions."""
    t = tool(d)
    comps, axis_box = regions(part, stock, t.radius)
    points, motion = [], []
    for region in comps:
        g = BandGeometry(levels=(Z,), spaces=(region,), top=Z_TOP, stock=stock, axis_box=axis_box, allowance=ALLOW,
                         clear_z=5.0, lead_gap=1.0, tan_ramp=math.tan(math.radians(RAMP)))
        moves = front_cut_moves(region, g, Z, Z_TOP, t, OPTIONS)
        assert moves is not None, f"a region of {region.area:.1f} mm² refused"
        points.append(moves[0])
        motion.append(moves[1])
    return np.vstack(points), np.concatenate(motion), comps


def helix_moves(points: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """(n,) bool per move (from point i to i+1): fed down and across, the helix."""
    step = np.diff(points, axis=0)
    return (motion[1:] == Motion.PLUNGE) & (step[:, 2] < -1e-9) & (np.hypot(step[:, 0], step[:, 1]) > 1e-9)


def assert_fronts_hold(part: BaseGeometry, stock: Polygon, d: float) -> tuple[np.ndarray, np.ndarray]:
    """The fronts' moves beside ``part``: the band held (but on a helix), descents in the air, nothing below the
    floor or into the part (the replay), helices at most 3 deg within the tool-centre region, and the stock
    left only in corners the fronts' rounding cannot reach. Returns the moves."""
    points, motion, comps = cut(part, stock, d)
    r = d / 2
    rp = Replay(part, stock, r, CELL_SHARE)
    ae = replay(points, motion, rp)
    limit = held_to(tool(d))
    assert ae.max() <= limit + 2 * rp.cell, (ae.max(), limit)
    helix = helix_moves(points, motion)
    if helix.any():
        step = np.diff(points, axis=0)[helix]
        slope = -step[:, 2] / np.hypot(step[:, 0], step[:, 1])
        assert slope.max() <= math.tan(math.radians(RAMP)) * 1.001, math.degrees(math.atan(slope.max()))
        inside = shapely.union_all(comps).buffer(1e-6)
        assert shapely.contains_xy(inside, points[1:][helix, 0], points[1:][helix, 1]).all()
    # what the tool can reach at all, less LEFT_DEPTH of its radius: nothing left there
    reach = shapely.union_all(comps).buffer(r - LEFT_DEPTH * r - 2 * rp.cell, quad_segs=32)
    deep = rp.solid & shapely.contains_xy(reach, rp.gx, rp.gy)
    assert deep.sum() * rp.cell ** 2 < 0.05, f"{deep.sum() * rp.cell ** 2:.2f} mm² left inside the reach"
    return points, motion


STOCK = box(0, 0, 48, 32)


def test_closed_pocket_from_a_helix():
    """A rounded pocket in a block: a helix at most 3 deg, then fronts at the held engagement."""
    part = STOCK.difference(box(6, 6, 42, 26).buffer(-3).buffer(3))
    points, motion = assert_fronts_hold(part, STOCK, 10.0)
    assert helix_moves(points, motion).any()


def test_narrowest_slot_a_helix_enters():
    """A slot 1.4 D wide (+ the allowances): a helix fits (0.3 D across), the rest are trochoidal arcs at its
    ends, never a full-width cut. A slot exactly one D wide has no room for the tool's centre to move across:
    no region, the levels' (and no engine can cut it but at full width)."""
    d = 10.0
    w = 1.4 * d + 2 * ALLOW
    part = STOCK.difference(box(10, 16 - w / 2, 36, 16 + w / 2))
    points, motion = assert_fronts_hold(part, STOCK, d)
    assert helix_moves(points, motion).any()
    one_d = STOCK.difference(box(10, 16 - d / 2 - ALLOW, 36, 16 + d / 2 + ALLOW))
    assert regions(one_d, STOCK, d / 2)[0] == []


def test_open_sided_pocket_enters_from_the_air():
    """A pocket open on one side: no helix, the fronts grow in from the air beyond the stock's edge."""
    part = STOCK.difference(box(14, 8, 60, 24))
    points, motion = assert_fronts_hold(part, STOCK, 10.0)
    assert not helix_moves(points, motion).any()


def test_island_and_a_neck_past_it():
    """An island leaving a neck narrower than the fronts' rounding between it and the wall: the fronts do not
    pass it, the far side gets a helix of its own; no full-width cut anywhere."""
    part = STOCK.difference(box(4, 4, 36, 24)).union(Point(20, 9).buffer(3.7))
    assert len(regions(part, STOCK, 5.0)[0]) == 1
    points, motion = assert_fronts_hold(part, STOCK, 10.0)
    helix = helix_moves(points, motion)
    assert np.count_nonzero(helix[1:] & ~helix[:-1]) + int(helix[0]) == 2


pockets = st.tuples(st.floats(4, 20), st.floats(4, 12), st.floats(14, 30), st.floats(14, 20))


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(pockets, min_size=1, max_size=2), st.booleans())
@example([(6.0, 6.0, 30.0, 20.0)], True)
def test_random_pockets_hold_the_band(boxes, island):
    """Unions of boxes cut into a block (with a round island in the first), any that leave a 10 mm tool room:
    the band held, the helices at 3 deg, nothing into the part, no stock left but in corners and cusps."""
    d = 10.0
    hole = shapely.union_all([box(x, y, min(x + w, 44), min(y + h, 28)) for x, y, w, h in boxes])
    part = STOCK.difference(hole)
    if island:
        x, y, w, h = boxes[0]
        part = part.union(Point(x + w / 2, y + h / 2).buffer(min(w, h) / 6))
    comps, _ = regions(part, STOCK, d / 2)
    if not comps or min(shapely.maximum_inscribed_circle(c, 1e-3).length for c in comps) < 0.16 * d:
        return  # no room for the least helix: the levels'
    assert_fronts_hold(part, STOCK, d)
