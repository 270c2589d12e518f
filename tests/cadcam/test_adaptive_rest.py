"""Rest roughing with the adaptive engine (cadcam.adaptive_rest): a smaller end mill takes a bigger one's leftovers.

A pocketed block is roughed by a bigger end mill (z-level roughing, the stock model after it); the smaller one's
pieces are then cut by the engine with no time comparison (``levels=None``), so that every piece it holds the band
in is taken, and checked by the independent replay of tests/cadcam/test_adaptive.py: a pixel grid of the rest made
from the pocket's own outline less what the bigger tool's disc can reach (not the stock model the engine reads),
cut by the moves sample by sample. The engagement stays within the tool's band but on a helix entry; nothing is cut
below a band's floor or into the part's allowance; descents are in the air. The rest roughing by levels that
follows the engine (on the stock it left) ends with the stock no higher anywhere than rest roughing by levels alone
leaves it: everything the old rest roughing cleared is cleared.
"""

from __future__ import annotations

import math

import manifold3d
import numpy as np
import shapely
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from shapely.geometry import box

from cadcam.adaptive_rest import adaptive_rest_roughing, plan_rest_cuts
from cadcam.model import Motion
from cadcam.roughing import RoughingOptions, zlevel_roughing
from cadcam.setup import make_setup
from cadcam.stock import stock_after
from cadcam.tools import load_tool_library
from tests.cadcam.test_adaptive import ALLOW, Replay, held_to, replay
from tests.conftest import manifold_to_trimesh

LIBRARY = load_tool_library()
#: Rest thinner than this is finishing's [mm] (the plan's finishing engagement).
ABOVE = 0.5
#: Replay raster as a share of the radius, and the cells its reading may pass the band by (as test_adaptive_pockets).
CELL_SHARE = 0.04
#: The stock model's grid [mm] (the plan's).
CELL = 0.5
BLOCK = (44.0, 32.0, 16.0)


def pocketed(pocket: tuple[float, float, float], island: tuple[float, float] | None):
    """The block with a sharp-cornered pocket ``(width, length, depth)`` in its middle, and optionally a square
    island ``(side, height under the top)`` in the pocket's middle; its XY outline of material at the pocket's depth."""
    w, h, d = pocket
    x0, y0 = (BLOCK[0] - w) / 2, (BLOCK[1] - h) / 2
    body = manifold3d.Manifold.cube(BLOCK) - manifold3d.Manifold.cube((w, h, d + 1.0)).translate(
        (x0, y0, BLOCK[2] - d))
    walls = box(0, 0, BLOCK[0], BLOCK[1]).difference(box(x0, y0, x0 + w, y0 + h))
    if island is not None:
        side, below = island
        cx, cy = BLOCK[0] / 2 - side / 2, BLOCK[1] / 2 - side / 2
        body = body + manifold3d.Manifold.cube((side, side, d - below)).translate((cx, cy, BLOCK[2] - d))
        walls = walls.union(box(cx, cy, cx + side, cy + side))
    return manifold_to_trimesh(body), walls


def assert_rest_by_the_engine_holds(pocket, island, big: int, small: int, engine_takes: bool = False) -> None:
    mesh, walls = pocketed(pocket, island)
    setup, part = make_setup(mesh)
    # the outline in work coordinates: make_setup moves the part into the stock
    shift = np.asarray(setup.transform_mesh_to_work)[:2, 3]
    walls = shapely.affinity.translate(walls, *shift)
    t_big, t = LIBRARY.tool(big), LIBRARY.tool(small)
    tri = np.asarray(part.triangles)
    rough = zlevel_roughing(part, setup, t_big, LIBRARY.cutting_data(t_big, setup.material))
    rest = stock_after([rough], setup, tri, CELL)
    cutting = LIBRARY.cutting_data(t, setup.material)
    options = RoughingOptions(allowance=ALLOW)
    cuts = plan_rest_cuts(part, setup, t, cutting, LIBRARY.max_feed, rest, ABOVE, None, options)
    if engine_takes:
        assert cuts, "the engine took none of the rest"
    # the rest, independently: the pocket less what the bigger tool's disc reaches in it (its centre kept the
    # radius and the allowance from the walls), less the part grown by the allowance
    stock = box(*shapely.affinity.translate(box(0, 0, BLOCK[0], BLOCK[1]), *shift).bounds)
    reach_big = stock.difference(walls.buffer(t_big.radius + ALLOW, quad_segs=32)).buffer(t_big.radius, quad_segs=32)
    floor = float(part.bounds[1][2]) - pocket[2] + ALLOW
    for cut in cuts:
        assert cut.z >= floor - 1e-6, f"band floor {cut.z} below the pocket's {floor}"
        rp = Replay(walls, stock, t.radius, CELL_SHARE)
        rp.solid &= ~shapely.contains_xy(reach_big, rp.gx, rp.gy)
        ae = replay(cut.points, cut.motion, rp, cut.z, cut.z_top)
        assert cut.z_top - cut.z <= min(2.0 * t.diameter, t.flute_length) + 1e-6
        if len(ae):
            assert ae.max() <= held_to(t) + 2 * rp.cell, (ae.max(), held_to(t))
        step = np.diff(cut.points, axis=0)
        helix = (cut.motion[1:] == Motion.PLUNGE) & (step[:, 2] < -1e-9) & (np.hypot(step[:, 0], step[:, 1]) > 1e-9)
        if helix.any():
            slope = -step[helix, 2] / np.hypot(step[helix, 0], step[helix, 1])
            assert slope.max() <= math.tan(math.radians(options.ramp_angle)) * 1.001
    # the levels after the engine, on the stock it left: nowhere more stock than the levels alone leave
    old = zlevel_roughing(part, setup, t, cutting, options, rest=rest, rest_above=ABOVE)
    op = adaptive_rest_roughing(part, setup, t, cutting, LIBRARY.max_feed, rest, ABOVE, None, options)
    assert (op is None) == (not cuts)
    if op is None:
        return
    assert op.cutting.feed >= cutting.feed  # thinned for its engagement
    after = zlevel_roughing(part, setup, t, cutting, options, rest=stock_after([rough, op], setup, tri, CELL),
                            rest_above=ABOVE)
    by_levels = stock_after([rough, old], setup, tri, CELL).stock_top
    both = stock_after([rough, op, after], setup, tri, CELL).stock_top
    higher = both - by_levels > 0.05
    assert not higher.any(), f"{int(higher.sum())} grid points keep stock rest roughing by levels clears"


def test_the_corners_a_wider_tool_left_are_taken_in_one_band():
    """A 10 mm end mill's corners in a 12 mm deep pocket, taken by the 6 mm one in one band (its 12 mm axial depth)
    by fronts growing out of the pocket the 10 mm one cleared: no helix, no full-width cut."""
    assert_rest_by_the_engine_holds((30.0, 18.0, 12.0), None, 2, 1, engine_takes=True)


pockets = st.tuples(st.floats(22.0, 34.0), st.floats(14.0, 22.0), st.floats(5.0, 13.0))


@settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pockets, st.one_of(st.none(), st.tuples(st.floats(4.0, 6.0), st.floats(1.0, 4.0))),
       st.sampled_from([(2, 1), (14, 2)]))
@example((28.0, 16.0, 9.0), (5.0, 2.0), (2, 1))
def test_random_pockets_rest_by_the_engine_hold_the_band(pocket, island, tools):
    assert_rest_by_the_engine_holds(pocket, island, *tools)


def test_the_plan_keeps_the_levels_where_they_are_faster():
    """With the levels' own time to beat, the engine takes a piece only where it is faster: the corners a 10 mm end
    mill left are a few arcs a level for the 6 mm one, and the engine's fronts are not."""
    mesh, _ = pocketed((30.0, 18.0, 12.0), None)
    setup, part = make_setup(mesh)
    t_big, t = LIBRARY.tool(2), LIBRARY.tool(1)
    rough = zlevel_roughing(part, setup, t_big, LIBRARY.cutting_data(t_big, setup.material))
    rest = stock_after([rough], setup, np.asarray(part.triangles), CELL)
    cutting = LIBRARY.cutting_data(t, setup.material)
    old = zlevel_roughing(part, setup, t, cutting, RoughingOptions(), rest=rest, rest_above=ABOVE)
    assert len(old.points) > 1
    assert adaptive_rest_roughing(part, setup, t, cutting, LIBRARY.max_feed, rest, ABOVE, old) is None
