"""Z-level roughing: no gouge, no plunge into stock, rapids in the clear, floors covered.

The checks are independent of the implementation: the part is sectioned with trimesh
(not projected triangle by triangle), and a coarse heightfield simulation of the flat end
mill tells where stock is before each move.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math

import numpy as np
import pytest
import shapely
import trimesh
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from scipy.ndimage import maximum_filter
from scipy.spatial import cKDTree

import cadcam.roughing as roughing
from cadcam.levelskim import LevelReach
from cadcam.model import CuttingData, Motion, Setup, Tool
from cadcam.stock import excess
from cadcam.roughing import RoughingOptions, zlevel_roughing
from cadcam.stock import stock_after
from factory.core.errors import ToolError, ToolpathError

TOOL = Tool(1, "6 mm flat 3FL carbide", "flat", 6.0, 0.0, 15.0, 3, 30.0)
CUTTING = CuttingData(spindle_rpm=10000, feed=1200, plunge_feed=300)
CELL = 0.2  # heightfield resolution [mm]


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def difference(a, *b) -> trimesh.Trimesh:
    return trimesh.boolean.difference([a, *b], engine="manifold")


def union(*a) -> trimesh.Trimesh:
    return trimesh.boolean.union(list(a), engine="manifold")


def make_setup(size=(40.0, 30.0, 12.0)) -> Setup:
    sx, sy, sz = size
    return Setup(stock_min=(0, 0, -sz), stock_max=(sx, sy, 0), transform_mesh_to_work=np.eye(4))


@functools.cache
def pocket_part() -> trimesh.Trimesh:
    """Block with 2 mm margins and a 20 x 14 x 5 mm pocket, floor at z = -5."""
    return difference(box((2, 2, -12), (38, 28, 0)), box((10, 8, -5), (30, 22, 1)))


@functools.cache
def hole_part() -> trimesh.Trimesh:
    """Block with through-holes: 12 mm (full helix fits), 9.2 mm (a smaller helix fits)
    and 7 mm (nothing fits)."""
    holes = []
    for r, x, y in ((6.0, 14, 15), (4.6, 24, 7), (3.5, 30, 15)):
        c = trimesh.creation.cylinder(radius=r, height=20, sections=64)
        c.apply_translation((x, y, -6))
        holes.append(c)
    return difference(box((2, 2, -12), (38, 28, 0)), *holes)


@functools.cache
def boss_part() -> trimesh.Trimesh:
    """Plate filling the whole stock footprint (no margins) with a 16 x 10 boss on top."""
    return union(box((0, 0, -12), (40, 30, -6)), box((12, 10, -6.5), (28, 20, -1)))


@functools.cache
def dome_part() -> trimesh.Trimesh:
    """Hemisphere of radius 7 on a block; dome top at z = -1."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=7.0)
    sphere.apply_translation((20, 15, -8))
    return union(box((2, 2, -12), (38, 28, -8)), difference(sphere, box((0, 0, -30), (40, 30, -8))))


@functools.cache
def slot_part() -> trimesh.Trimesh:
    """Closed 30 x 7.5 mm slot, 4 mm deep: too narrow for the helix, long enough to ramp."""
    return difference(box((2, 2, -12), (38, 28, 0)), box((5, 11, -4), (35, 18.5, 1)))


@functools.cache
def rough(name: str, **opts) -> tuple:
    part = {"pocket": pocket_part, "hole": hole_part, "boss": boss_part, "dome": dome_part,
            "slot": slot_part}[name]()
    setup = make_setup()
    options = RoughingOptions(**opts)
    op = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    return part, setup, op, options


# --------------------------------------------------------------------------- checks


def sections(part: trimesh.Trimesh):
    """Material polygon of the part's section at height z (even-odd of the section loops)."""

    @functools.cache
    def at(z: float):
        segs = trimesh.intersections.mesh_plane(part, [0, 0, 1], [0, 0, z])
        if len(segs) == 0:
            return shapely.Polygon()
        # Join loop ends computed from different triangles exactly.
        ends = segs[:, :, :2].reshape(-1, 2)
        near = cKDTree(ends).query_ball_point(ends, 1e-6)
        ends = ends[[min(n) for n in near]]
        lines = shapely.linestrings(ends.reshape(-1, 2, 2))
        faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(shapely.union_all(lines))))
        material = shapely.Polygon()
        for f in faces:
            material = material.symmetric_difference(shapely.Polygon(f.exterior))
        return material

    return at


def material_above(part, at, z: float):
    """Part material at heights >= z, projected (sections at z and at every vertex height above)."""
    zmin = float(part.bounds[0][2])
    heights = {max(z, zmin) + 1e-4}
    heights |= {float(v) - 1e-4 for v in np.unique(part.vertices[:, 2].round(6)) if v - 1e-4 > z + 1e-4}
    return shapely.union_all([at(round(h, 6)) for h in heights])


def sample_moves(op, kinds, step):
    """Tool tip samples along the moves of the given kinds: (n, 3) points and whether the
    move they lie on is horizontal."""
    P, M = op.points, op.motion
    out, idx = [], []
    for i in np.flatnonzero(np.isin(M[1:], kinds)) + 1:
        a, b = P[i - 1], P[i]
        n = max(1, math.ceil(np.linalg.norm(b - a) / step))
        t = np.linspace(0, 1, n + 1)[:, None]
        out.append(a + t * (b - a))
        idx.append(np.full(n + 1, abs(b[2] - a[2]) < 1e-9))
    if not out:
        return np.empty((0, 3)), np.empty(0, bool)
    return np.vstack(out), np.concatenate(idx)


def assert_no_gouge(part, op, allowance, radius=TOOL.radius, tol=0.01):
    """The flat tool's cylinder keeps `allowance` from material above its tip, radially,
    and its flat bottom keeps `allowance` above material below it."""
    at = sections(part)
    pts, exact = sample_moves(op, [Motion.CUT, Motion.PLUNGE], step=0.3)
    z = pts[:, 2]
    # Horizontal moves are checked at their exact z; descending ones (helices, ramps),
    # to keep the number of sections small, on a 0.05 mm grid (rounded up: material up
    # to 0.05 mm above their tip is not seen).
    zq = np.where(exact, np.round(z, 6), np.ceil(z / 0.05 - 1e-9) * 0.05)
    z_wall, z_floor = zq, zq - allowance + tol
    for zs, need in ((z_wall, radius + allowance - tol), (z_floor, radius - tol)):
        for zk in np.unique(zs):
            sel = zs == zk
            mat = material_above(part, at, float(zk))
            if mat.is_empty:
                continue
            d = shapely.distance(shapely.points(pts[sel, :2]), mat)
            worst = int(np.argmin(d))
            assert d[worst] >= need, (
                f"gouge at {pts[sel][worst]}: {d[worst]:.4f} mm from material above z={zk:.3f}, need {need:.4f}"
            )


class HeightField:
    """Stock top height on a grid; the flat tool lowers it to its tip inside its radius."""

    def __init__(self, setup: Setup, radius: float, cell: float = CELL):
        lo, hi = setup.stock_min, setup.stock_max
        pad = radius + 6.0
        self.x = np.arange(lo[0] - pad, hi[0] + pad, cell) + cell / 2
        self.y = np.arange(lo[1] - pad, hi[1] + pad, cell) + cell / 2
        X, Y = np.meshgrid(self.x, self.y, indexing="ij")
        inside = (X > lo[0]) & (X < hi[0]) & (Y > lo[1]) & (Y < hi[1])
        self.h = np.where(inside, hi[2], -np.inf)
        self.cell = cell
        self.x0, self.y0 = self.x[0], self.y[0]

    def _window(self, xy, r):
        i0 = max(int((xy[0] - r - self.x0) / self.cell), 0)
        i1 = min(int((xy[0] + r - self.x0) / self.cell) + 2, len(self.x))
        j0 = max(int((xy[1] - r - self.y0) / self.cell), 0)
        j1 = min(int((xy[1] + r - self.y0) / self.cell) + 2, len(self.y))
        dx = self.x[i0:i1, None] - xy[0]
        dy = self.y[None, j0:j1] - xy[1]
        return (slice(i0, i1), slice(j0, j1)), dx * dx + dy * dy <= r * r

    def highest(self, xy, r) -> float:
        win, disc = self._window(xy, r)
        sub = self.h[win][disc]
        return float(sub.max()) if sub.size else -np.inf

    def cut(self, xy, z, r):
        win, disc = self._window(xy, r)
        sub = self.h[win]
        sub[disc] = np.minimum(sub[disc], z)

    def height_at(self, x, y) -> float:
        return float(self.h[int((x - self.x0) / self.cell), int((y - self.y0) / self.cell)])


def simulate(op, setup, ramp_angle, radius=TOOL.radius):
    """Run the moves through a heightfield; return it and the list of violations."""
    hf = HeightField(setup, radius)
    bad = []
    clear_z = setup.stock_max[2] + setup.clearance
    P, M = op.points, op.motion
    tan_ramp = math.tan(math.radians(ramp_angle + 0.01))
    inner = radius - 1.5 * hf.cell  # cells surely under the tool, whatever the grid
    for i in range(1, len(P)):
        a, b = P[i - 1], P[i]
        horiz = np.linalg.norm(b[:2] - a[:2])
        n = max(1, math.ceil(np.linalg.norm(b - a) / (0.5 * hf.cell)))
        samples = a + np.linspace(0, 1, n + 1)[:, None] * (b - a)
        if M[i] == Motion.RAPID:
            # Rapid descents below the clearance plane are fine through air; so are links across below it
            # (rest machining lifts only over the stock it knows), but those clear the stock with the whole
            # tool, not just the cells surely under it.
            low = horiz > 1e-9 and min(a[2], b[2]) < clear_z - 1e-9
            for s in samples:
                if hf.highest(s[:2], radius if low else inner) > s[2] + (0.0 if low else 0.02):
                    bad.append(f"move {i}: {'horizontal ' if low else ''}rapid touches stock at {s}")
                    break
            continue
        steep = a[2] - b[2] > 1e-9 and a[2] - b[2] > horiz * tan_ramp
        for s in samples:
            if steep and hf.highest(s[:2], inner) > s[2] + 0.02:
                bad.append(f"move {i}: descends at {math.degrees(math.atan2(a[2] - b[2], horiz)):.1f} deg "
                           f"into stock at {s} (stock top {hf.highest(s[:2], inner):.3f})")
                break
            hf.cut(s[:2], s[2], radius)
    return hf, bad


def motion_basics(op, setup):
    P, M = op.points, op.motion
    assert op.kind == "roughing" and op.name == "rough z-level"
    assert P[0, 2] == pytest.approx(setup.safe_z) and P[-1, 2] == pytest.approx(setup.safe_z)
    assert np.all(P[:, 2] >= setup.stock_min[2] - 1e-9), "cuts below the stock bottom"
    # Every descent that is not a ramp/helix is a PLUNGE (at the plunge feed), never a CUT.
    d = np.diff(P, axis=0)
    steep_cut = (M[1:] == Motion.CUT) & (-d[:, 2] > np.linalg.norm(d[:, :2], axis=1) * 0.06)
    assert not steep_cut.any(), "steep descent at the cutting feed"


ALL_PARTS = ["pocket", "hole", "boss", "dome", "slot"]


# --------------------------------------------------------------------------- tests


@pytest.mark.parametrize("name", ALL_PARTS)
def test_no_gouge(name):
    part, setup, op, options = rough(name)
    assert len(op.points) > 10
    motion_basics(op, setup)
    assert_no_gouge(part, op, options.allowance)


@pytest.mark.parametrize("name", ALL_PARTS)
def test_no_plunge_into_stock_and_rapids_clear(name):
    _, setup, op, options = rough(name)
    _, bad = simulate(op, setup, options.ramp_angle)
    assert not bad, "\n".join(bad[:5])


def floor_cells(hf, region: shapely.Geometry):
    X, Y = np.meshgrid(hf.x, hf.y, indexing="ij")
    inside = shapely.contains_xy(region, X, Y)
    return hf.h[inside]


def test_pocket_floor_and_margins_cleared():
    part, setup, op, options = rough("pocket")
    hf, _ = simulate(op, setup, options.ramp_angle)
    a, reach = options.allowance, TOOL.radius + options.allowance + 2 * CELL
    pocket_floor = shapely.box(10, 8, 30, 22).buffer(-reach, join_style="mitre")
    h = floor_cells(hf, pocket_floor)
    assert h.size > 50
    assert np.all(h <= -5 + a + 0.05) and np.all(h >= -5 + a - 0.01), (h.min(), h.max())
    # The 2 mm margins around the block are cut to the stock bottom beyond the allowance.
    margin = shapely.box(0, 0, 40, 30).difference(shapely.box(2, 2, 38, 28).buffer(a + 2 * CELL, join_style="mitre"))
    h = floor_cells(hf, margin)
    assert h.size > 100 and np.all(h <= setup.stock_min[2] + 1e-9), h.max()
    # Pocket walls: stock left at mid-depth of the pocket is the allowance, give or take a cell.
    x_wall = 10 + a + CELL
    assert hf.height_at(x_wall + 0.5 * CELL, 15) <= -5 + a + 0.05
    assert hf.height_at(10 - CELL, 15) == pytest.approx(0.0)  # the wall itself is never touched


def test_boss_plate_top_even_allowance():
    part, setup, op, options = rough("boss")
    hf, _ = simulate(op, setup, options.ramp_angle)
    a = options.allowance
    plate = shapely.box(0, 0, 40, 30).difference(
        shapely.box(12, 10, 28, 20).buffer(TOOL.radius + a + 2 * CELL, join_style="mitre"))
    h = floor_cells(hf, plate)
    assert h.size > 1000
    assert np.all(h <= -6 + a + 0.05) and np.all(h >= -6 + a - 0.01), (h.min(), h.max())
    # The boss top (z = -1) is left alone: it is less than a stepdown below the stock top.
    assert hf.height_at(20, 15) >= -1 + a - 0.01


def test_dome_block_top_and_staircase():
    part, setup, op, options = rough("dome")
    hf, _ = simulate(op, setup, options.ramp_angle)
    a = options.allowance
    top = shapely.box(2, 2, 38, 28).difference(shapely.Point(20, 15).buffer(7 + TOOL.radius + a + 2 * CELL))
    h = floor_cells(hf, top)
    assert h.size > 1000 and np.all(h <= -8 + a + 0.05) and np.all(h >= -8 + a - 0.01)
    # On the dome, z-levels leave steps: at most a stepdown plus the allowance above the surface,
    # measured where the dome is steep enough for the flat tool to reach its foot.
    stepdown = 0.5 * TOOL.diameter
    for r in (5.0, 6.0):
        zs = -8 + math.sqrt(49 - r * r)
        assert hf.height_at(20 + r, 15) <= zs + a + stepdown + 0.05


def test_through_hole_helix_and_small_hole_skipped(caplog):
    with caplog.at_level(logging.WARNING, logger="cadcam.roughing"):
        part, setup, op, options = rough.__wrapped__("hole")
    assert any("too small to enter" in r.message for r in caplog.records)
    hf, bad = simulate(op, setup, options.ramp_angle)
    assert not bad
    # The 12 and 9.2 mm holes are cleared to the stock bottom; the 7 mm one is untouched.
    assert hf.height_at(14, 15) <= setup.stock_min[2] + 1e-9
    assert hf.height_at(24, 7) <= setup.stock_min[2] + 1e-9
    assert hf.height_at(24 + 4.6 - 0.3 - 2 * CELL, 7) <= setup.stock_min[2] + 1e-9
    assert hf.height_at(30, 15) == pytest.approx(0.0)
    # Every descent into the big hole is a helix turning clockwise (climb, stock outside).
    P, M = op.points, op.motion
    near = np.linalg.norm(P[:, :2] - (14, 15), axis=1) < 3
    helix = np.flatnonzero((M[1:] == Motion.PLUNGE) & near[1:] & near[:-1]
                           & (np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1) > 1e-6)) + 1
    assert len(helix) > 100
    v0, v1 = P[helix - 1, :2] - (14, 15), P[helix, :2] - (14, 15)
    assert np.all(v0[:, 0] * v1[:, 1] - v0[:, 1] * v1[:, 0] < 0)


def test_narrow_slot_is_ramped_not_plunged():
    part, setup, op, options = rough("slot")
    hf, bad = simulate(op, setup, options.ramp_angle)
    assert not bad
    assert hf.height_at(20, 14.75) <= -4 + options.allowance + 0.05
    P, M = op.points, op.motion
    horiz = np.linalg.norm(np.diff(P[:, :2], axis=0), axis=1)
    ramp = (M[1:] == Motion.PLUNGE) & (np.abs(P[1:, 1] - 14.75) < 1.0) & (horiz > 1e-6)
    slope = -np.diff(P[:, 2])[ramp] / np.maximum(np.linalg.norm(np.diff(P[:, :2], axis=0)[ramp], axis=1), 1e-12)
    assert ramp.sum() > 0 and np.all(slope <= math.tan(math.radians(options.ramp_angle)) + 1e-9)


def test_levels_hit_floors_and_respect_stepdown():
    _, setup, op, options = rough("pocket")
    z = np.unique(op.points[op.motion == Motion.CUT, 2].round(6))
    assert -5 + options.allowance in z  # pocket floor level
    assert z.min() == setup.stock_min[2]
    assert np.all(np.diff(np.concatenate([z, [setup.stock_max[2]]])) <= 0.5 * TOOL.diameter + 1e-9)


def test_zero_allowance_and_other_options():
    part, setup, op, options = rough("pocket", allowance=0.0, stepover=1.5, stepdown=2.0, ramp_angle=2.0)
    assert op.allowance == 0.0
    assert_no_gouge(part, op, 0.0)
    hf, bad = simulate(op, setup, 2.0)
    assert not bad
    h = floor_cells(hf, shapely.box(10, 8, 30, 22).buffer(-TOOL.radius - 2 * CELL, join_style="mitre"))
    assert np.all(np.abs(h + 5) <= 0.05)


def test_bad_inputs():
    setup = make_setup()
    ball = Tool(2, "ball", "ball", 6.0, 3.0, 15.0, 2, 30.0)
    with pytest.raises(ToolError):
        zlevel_roughing(pocket_part(), setup, ball, CUTTING)
    for bad in (dict(stepover=6.0), dict(stepover=0.0), dict(stepdown=0.0), dict(stepdown=20.0), dict(allowance=-0.1),
                dict(ramp_angle=0.0), dict(helix_diameter=0.0), dict(min_helix_diameter=5.0)):
        with pytest.raises(ToolpathError):
            zlevel_roughing(pocket_part(), setup, TOOL, CUTTING, RoughingOptions(**bad))


def test_progress_reports_every_level():
    calls = []
    zlevel_roughing(pocket_part(), make_setup(), TOOL, CUTTING, progress=lambda d, t: calls.append((d, t)))
    assert calls and calls[-1][0] == calls[-1][1] and [c[0] for c in calls] == list(range(1, len(calls) + 1))


@st.composite
def random_parts(draw):
    sx = draw(st.floats(28, 45))
    sy = draw(st.floats(24, 36))
    sz = draw(st.floats(6, 12))
    m = draw(st.floats(0, 4))
    block = box((m, m, -sz), (sx - m, sy - m, 0))
    kind = draw(st.sampled_from(["pocket", "boss", "both"]))
    parts = [block]
    x0 = draw(st.floats(m + 2, sx / 2 - 2))
    y0 = draw(st.floats(m + 2, sy / 2 - 2))
    x1 = draw(st.floats(sx / 2 + 2, sx - m - 2))
    y1 = draw(st.floats(sy / 2 + 2, sy - m - 2))
    depth = draw(st.floats(0.5, sz - 1))
    if kind in ("pocket", "both"):
        parts = [difference(block, box((x0, y0, -depth), (x1, y1, 1)))]
    if kind in ("boss", "both"):
        bw, bh = draw(st.floats(2, 8)), draw(st.floats(2, 8))
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        top = draw(st.floats(-depth + 0.2, 0))
        parts = [union(parts[0], box((cx - bw / 2, cy - bh / 2, -depth - 0.5), (cx + bw / 2, cy + bh / 2, top)))]
    return parts[0], make_setup((sx, sy, sz))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_parts(), st.sampled_from([4.0, 6.0]), st.sampled_from([0.0, 0.3, 0.5]))
def test_random_blocks_no_gouge_no_plunge(part_setup, diameter, allowance):
    part, setup = part_setup
    tool = Tool(1, "flat", "flat", diameter, 0.0, 12.0, 3, 30.0)
    op = zlevel_roughing(part, setup, tool, CUTTING, RoughingOptions(allowance=allowance))
    motion_basics(op, setup)
    assert_no_gouge(part, op, allowance, radius=tool.radius)
    _, bad = simulate(op, setup, 3.0, radius=tool.radius)
    assert not bad, "\n".join(bad[:5])


def dish_part(a: float, b: float, depth: float, floor: float) -> trimesh.Trimesh:
    """The stock block 40 x 30 x 12 with a dish in its top: a half-ellipsoid (semi-axes a, b, depth)
    cut off by a flat floor ``floor`` [mm] down."""
    bowl = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    bowl.apply_scale((a, b, depth))
    bowl.apply_translation((20.0, 15.0, 0.0))
    dish = difference(bowl, box((0, 0, -20), (40, 30, -floor)))
    return difference(box((0, 0, -12), (40, 30, 0)), dish)


def joined(*ops):
    """One operation running the moves of ``ops`` in turn (for the heightfield simulation)."""
    return dataclasses.replace(ops[0], points=np.vstack([op.points for op in ops]),
                               motion=np.concatenate([op.motion for op in ops]))


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(12.0, 17.0), st.floats(9.0, 13.0), st.floats(7.0, 10.0), st.floats(0.5, 0.8))
def test_rest_terraces_in_a_dish_are_entered_from_the_air_beside_them(a, b, depth, share):
    # The terraces z-level roughing leaves on a dish's sides are strips too narrow for a helix,
    # closed all round: rest roughing enters each from the air the earlier levels cleared
    # beside it, instead of skipping it (and leaving it to a narrower, slower tool).
    part, setup = dish_part(a, b, depth, share * depth), make_setup()
    first = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepdown=3.0))
    stock = stock_after([first], setup, np.asarray(part.triangles))
    logger = logging.getLogger("cadcam.roughing")
    seen: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda record: seen.append(record.getMessage())
    logger.addHandler(handler)
    try:
        terraces = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepdown=0.7), rest=stock,
                                   rest_above=0.7)
    finally:
        logger.removeHandler(handler)
    assert not [m for m in seen if "skipped" in m or "left uncut" in m], seen[:3]
    assert len(terraces.points) > 1
    after = stock_after([first, terraces], setup, np.asarray(part.triangles))
    assert float(excess(after, 0.3).max()) <= 1.5  # what the finishing tool may meet
    assert_no_gouge(part, terraces, 0.3)
    _, bad = simulate(joined(first, terraces), setup, 3.0)
    assert not bad, "\n".join(bad[:5])


def left_beyond(hf, reference):
    """Height [mm] ``hf`` leaves above what ``reference`` cut, per cell. A cell on the edge of the reference's
    cut (the allowance's envelope along a wall) may fall either side of a micrometre's difference in the
    loops, so it is held to the deepest cut among its neighbours; everywhere else the cell is held to itself."""
    with np.errstate(invalid="ignore"):  # -inf - -inf outside the stock
        left = hf.h - maximum_filter(reference.h, size=3)
    left[~np.isfinite(left)] = 0.0
    return left


def assert_cuts_what_it_cuts_in_less_path(part, setup, op, reference, options, share: float = 1.0) -> None:
    """``op`` gouges nothing, plunges nowhere, cuts everything ``reference`` cuts (to 0.05 mm, :func:`left_beyond`)
    and its cutting path is at most ``share`` of the reference's; each simulated with the tool that made it."""
    assert_no_gouge(part, op, options.allowance, radius=op.tool.radius)
    hf, bad = simulate(op, setup, options.ramp_angle, radius=op.tool.radius)
    assert not bad, "\n".join(bad[:5])
    left = left_beyond(hf, simulate(reference, setup, options.ramp_angle, radius=reference.tool.radius)[0])
    assert left.max() <= 0.05, np.unravel_index(np.argmax(left), left.shape)
    cut = [np.linalg.norm(np.diff(o.points, axis=0), axis=1)[o.motion[1:] == Motion.CUT].sum() for o in (op, reference)]
    assert cut[0] <= share * cut[1] + 1e-6, cut


#: A stepover of at most a radius, which leaves no gap between loops: what a wider one is held to.
NARROW = 0.4 * TOOL.diameter


@pytest.mark.parametrize("name", ["pocket", "boss", "slot"])
@pytest.mark.parametrize("share", [0.6, 0.75, 0.89])
def test_a_wide_stepover_leaves_no_island_a_narrow_one_cuts(name, share):
    # Loops more than a radius apart leave cusps between them; the loops added over those gaps
    # must cut everything a stepover of at most a radius (no gaps) cuts.
    part, setup, wide, options = rough(name, stepover=share * TOOL.diameter)
    _, _, usual, _ = rough(name, stepover=NARROW)
    motion_basics(wide, setup)
    assert_cuts_what_it_cuts_in_less_path(part, setup, wide, usual, options)


@pytest.mark.parametrize("name", ["boss", "dome"])  # open levels wide enough for loops (a pocket's fill with gaps)
def test_the_default_levels_take_the_stock_wide_in_less_path(name):
    # A level is no deeper than the full-width limit, so the default step is wide (the chip is fz either
    # way): the same stock in much less cutting path, everything a narrow step cuts cut, no plunge or gouge.
    part, setup, op, options = rough(name)
    _, _, narrow, _ = rough(name, stepover=NARROW)
    assert_cuts_what_it_cuts_in_less_path(part, setup, op, narrow, options, 0.85)  # boss 0.67, dome 0.79
    depth = np.diff(np.unique(op.points[op.motion == Motion.CUT, 2].round(6)))
    assert np.all(depth <= TOOL.full_width_limit + 1e-9)


def cut_heights(op) -> np.ndarray:
    return np.unique(op.points[op.motion == Motion.CUT, 2].round(6))


def test_a_skin_on_the_top_floor_within_the_skim_is_left_whole_to_the_finishing():
    # The top floor 1 mm under the stock top, a pocket in it: its 0.7 mm level is not cut; the level under
    # it cuts no deeper than the full-width limit; nothing is left that the level did not leave but its skin.
    part = difference(box((2, 2, -12), (38, 28, -1)), box((10, 8, -5), (30, 22, 1)))
    setup = make_setup()
    plain = zlevel_roughing(part, setup, TOOL, CUTTING)
    options = RoughingOptions(skim=1.2)
    skimmed = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    assert -0.7 in cut_heights(plain) and -0.7 not in cut_heights(skimmed)
    assert setup.stock_max[2] - cut_heights(skimmed).max() <= TOOL.full_width_limit + 1e-9
    assert_no_gouge(part, skimmed, options.allowance)
    hf, bad = simulate(skimmed, setup, options.ramp_angle)
    assert not bad, "\n".join(bad[:5])
    hf_plain, _ = simulate(plain, setup, options.ramp_angle)
    assert left_beyond(hf, hf_plain).max() <= 0.7 + 0.05  # the top floor's skin, nothing deeper


def test_the_top_level_is_kept_where_only_it_enters_a_gap():
    # Two bosses 4 mm apart, their tops the top floor 1 mm under the stock top: the 6 mm end mill enters the
    # gap at the top level only, so that level stays (else a rest tool would meet the gap's stock from the top).
    part = union(box((0, 0, -12), (40, 30, -8)), box((4, 4, -8), (18, 26, -1)), box((22, 4, -8), (36, 26, -1)))
    skimmed = zlevel_roughing(part, make_setup(), TOOL, CUTTING, RoughingOptions(skim=1.2))
    assert -0.7 in cut_heights(skimmed)


def test_the_top_level_kept_for_a_gap_leaves_the_bosses_tops_to_the_finishing():
    # As above, but 2 mm tall (plate_bosses' counterbored bosses on its plate): the level on the plate's top is
    # within a stepdown of the stock top, so the top level is cut only where that one cannot reach (the gap
    # between the bosses, x 18..22), and no longer over the bosses' tops: only their skin lies there, which the
    # finishing takes whole. So every tool centre of that level lies within the tool's radius (and a little)
    # of the gap.
    part = union(box((0, 0, -12), (40, 30, -3)), box((4, 4, -3), (18, 26, -1)), box((22, 4, -3), (36, 26, -1)))
    setup, options = make_setup(), RoughingOptions(skim=1.2)
    skimmed = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    top = skimmed.points[(skimmed.motion == Motion.CUT) & (np.abs(skimmed.points[:, 2] + 0.7) < 1e-9)]
    assert len(top)
    assert top[:, 0].min() >= 18 - options.allowance - TOOL.radius - 0.5
    assert top[:, 0].max() <= 22 + options.allowance + TOOL.radius + 0.5
    assert_no_gouge(part, skimmed, options.allowance)
    hf, bad = simulate(skimmed, setup, options.ramp_angle)
    assert not bad, "\n".join(bad[:5])
    hf_plain, _ = simulate(zlevel_roughing(part, setup, TOOL, CUTTING), setup, options.ramp_angle)
    assert left_beyond(hf, hf_plain).max() <= 0.7 + 0.05  # the bosses' tops' skin, nothing deeper


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(random_parts(), st.floats(0.55, 0.89))
# `make explore` found it: along the pocket's wall the two plans' loops differ by 2 um at a cell's centre
@example((difference(box((0, 0, -6), (28, 24, 0)), box((2, 2, -1), (20.402036666870117, 18.75, 1))),
          make_setup((28, 24, 6))), 0.75)
def test_random_blocks_wide_stepover_cuts_what_a_narrow_one_cuts(part_setup, share):
    part, setup = part_setup
    wide = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepover=share * TOOL.diameter))
    usual = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepover=NARROW))
    assert_no_gouge(part, wide, 0.3)
    hf_wide, bad = simulate(wide, setup, 3.0)
    assert not bad, "\n".join(bad[:5])
    hf_usual, _ = simulate(usual, setup, 3.0)
    left = left_beyond(hf_wide, hf_usual)
    assert left.max() <= 0.05


@functools.cache
def three_domes_part() -> trimesh.Trimesh:
    """Three hemispheres of radius 7 on a plate 90 x 30 mm, 30 mm apart; their tops at z = -1."""
    domes = []
    for x in DOMES:
        sphere = trimesh.creation.icosphere(subdivisions=3, radius=7.0)
        sphere.apply_translation((x, 15.0, -8.0))
        domes.append(difference(sphere, box((0, 0, -30), (90, 30, -8))))
    return union(box((0, 0, -12), (90, 30, -8)), *domes)


#: X of the three domes' centres [mm] (:func:`three_domes_part`).
DOMES = (15.0, 45.0, 75.0)


def test_rest_terraces_are_cut_dome_by_dome_and_linked_low():
    # The terraces round three domes: each dome's levels top down before the next dome's, instead of going
    # round every dome on every level.
    part, setup = three_domes_part(), make_setup((90.0, 30.0, 12.0))
    first = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepdown=3.0))
    stock = stock_after([first], setup, np.asarray(part.triangles))
    terraces = zlevel_roughing(part, setup, TOOL, CUTTING, RoughingOptions(stepdown=0.7), rest=stock,
                               rest_above=0.7)
    P, M = terraces.points, terraces.motion
    clear_z = setup.stock_max[2] + setup.clearance
    levels = sorted({round(float(z), 6) for z, m in zip(P[1:, 2], M[1:]) if m == Motion.CUT})
    assert len(levels) >= 4  # terraces on several levels round each dome
    # a link over the stock only (the simulation below holds every low rapid to the whole tool): from one
    # dome to the next over the floor between them, not by the clearance height
    low = ((M[1:] == Motion.RAPID) & (np.abs(np.diff(P[:, 0])) > 10.0)
           & (np.maximum(P[1:, 2], P[:-1, 2]) < clear_z - 1e-9))
    assert low.any()
    # each dome's cuts in one run: the nearest dome of the cut moves changes only twice
    cut = P[1:][M[1:] == Motion.CUT]
    dome = np.argmin(np.abs(cut[:, 0, None] - np.array(DOMES)), axis=1)
    assert int(np.count_nonzero(np.diff(dome))) == 2
    after = stock_after([first, terraces], setup, np.asarray(part.triangles))
    assert float(excess(after, 0.3).max()) <= 1.5
    assert_no_gouge(part, terraces, 0.3)
    _, bad = simulate(joined(first, terraces), setup, 3.0)
    assert not bad, "\n".join(bad[:5])


def test_a_floors_level_within_the_stepdown_of_the_next_is_cut_only_round_that_floor(monkeypatch):
    # A boss whose top (-1) holds a pocket (floor -3), an island (top -4) beside it, on a plate (top -7), the
    # stepdown 5: the pocket's level (-2.7) lies within the stepdown of the island's (-3.7) from the stock top,
    # so it cuts only in the pocket, and the top level (-0.7) only round the boss; the island's level takes
    # the rest from the top, 3.7 mm, within the full-width limit. Everything the levels cut whole (main before
    # issue 32's local levels) is cut, in less path, with no gouge and no plunge.
    boss = difference(box((4, 8, -7), (18, 22, -1)), box((6, 10, -3), (16, 20, 1)))
    part = union(box((0, 0, -12), (40, 30, -7)), boss, box((26, 12, -7), (32, 18, -4)))
    setup, options = make_setup(), RoughingOptions(stepdown=5.0)
    local = zlevel_roughing(part, setup, TOOL, CUTTING, options)

    def whole(levels, spaces, top, stepdown, radius, taken=None, skin=None):
        floors = [float(top), *(float(z) for z in levels[:-1])]
        return LevelReach(spaces=tuple(spaces), floor_above=tuple(floors), local=(False,) * len(levels))

    monkeypatch.setattr(roughing, "local_levels", whole)
    levels = zlevel_roughing(part, setup, TOOL, CUTTING, options)
    at = {z: local.points[(local.motion == Motion.CUT) & np.isclose(local.points[:, 2], z), :2] for z in (-0.7, -2.7)}
    assert len(at[-2.7]) and shapely.box(6, 10, 16, 20).contains(shapely.MultiPoint(at[-2.7]))
    # round the boss: the stock the island's level cannot reach, the tool within its radius
    near = shapely.box(4, 8, 18, 22).buffer(TOOL.radius + options.allowance + 0.1)
    assert len(at[-0.7]) and near.contains(shapely.MultiPoint(at[-0.7]))
    assert_cuts_what_it_cuts_in_less_path(part, setup, local, levels, options, 0.8)
