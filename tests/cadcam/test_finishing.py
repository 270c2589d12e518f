"""Raster and waterline finishing: no gouge, coverage, exact waterline levels."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from cadcam.dropcutter import build_index, drop_profile
from cadcam.finishing import FinishingOptions, _refine, _surface, raster_finishing, stepover_for, waterline_finishing
from cadcam.model import CuttingData, Motion, Setup, Tool
from factory.core.errors import ToolpathError

CUTTING = CuttingData(12000, 1200, 400)
TOL = 0.002
SAFE = 10.0


def tool(shape: str, diameter: float = 6.0) -> Tool:
    rc = {"flat": 0.0, "bull": 1.0, "ball": diameter / 2}[shape]
    return Tool(3, shape, shape, diameter, rc, 25.0, 2, 40.0)


def setup_for(size=(40.0, 30.0, 20.0)) -> Setup:
    return Setup(stock_min=[0, 0, -size[2]], stock_max=[size[0], size[1], 0], transform_mesh_to_work=np.eye(4),
                 safe_z=SAFE)


def box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


@lru_cache(maxsize=None)
def hemisphere_on_block() -> trimesh.Trimesh:
    """A 30 x 20 x 5 block (vertical sides) with a dome of radius 8 on top."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=8.0)
    sphere.apply_translation([20, 15, -15])
    dome = trimesh.boolean.intersection([sphere, box([0, 0, -15], [40, 30, 0])], engine="manifold")
    return trimesh.boolean.union([box([5, 5, -20], [35, 25, -15]), dome], engine="manifold")


@lru_cache(maxsize=None)
def pocket_block() -> trimesh.Trimesh:
    """A 30 x 20 x 10 block with a 14 x 8 x 4 pocket: vertical walls inside and out."""
    return trimesh.boolean.difference(
        [box([5, 5, -20], [35, 25, -10]), box([13, 11, -14], [27, 19, -5])], engine="manifold"
    )


@lru_cache(maxsize=None)
def pyramid() -> trimesh.Trimesh:
    """A square pyramid standing on the stock bottom: 60 degree faces, continuous CL surface."""
    h = 8.0 * math.tan(math.radians(60))
    pts = np.array([[12, 7, -20], [28, 7, -20], [28, 23, -20], [12, 23, -20], [20, 15, -20 + min(h, 13.0)]])
    return trimesh.convex.convex_hull(pts)


@lru_cache(maxsize=None)
def boss_plate() -> trimesh.Trimesh:
    """A round boss (faceted vertical cylinder) on a plate: convex vertical walls, where any
    waterline chord cutting inside the offset curve is a deep gouge."""
    boss = trimesh.creation.cylinder(radius=4.0, height=8.0, sections=40)
    boss.apply_translation([20, 15, -12])
    return trimesh.boolean.union([box([5, 5, -20], [35, 25, -16]), boss], engine="manifold")


PARTS = {"hemisphere": hemisphere_on_block, "pocket": pocket_block, "pyramid": pyramid, "boss": boss_plate}


def worst_gouge(op, part, t, floor, allowance=0.0, step=0.05) -> float:
    """Largest (exact CL z - move z) over samples every ``step`` mm along every move [mm]."""
    idx = build_index(part.triangles)
    a, b = op.points[:-1], op.points[1:]
    n = np.maximum(np.ceil(np.hypot(*(b[:, :2] - a[:, :2]).T) / step).astype(int), 1)
    seg = np.repeat(np.arange(len(a)), n + 1)
    t_ = np.concatenate([np.linspace(0, 1, k + 1) for k in n])
    q = a[seg] + t_[:, None] * (b[seg] - a[seg])
    z = drop_profile(idx, t.radius + allowance, t.corner_radius + allowance, q[:, :2], floor - allowance)
    return float(np.max(z + allowance - q[:, 2]))


def cut_samples(op, step=0.05) -> np.ndarray:
    """Points every ``step`` mm along the CUT moves (n, 3) [mm]."""
    a, b = op.points[:-1], op.points[1:]
    cut = op.motion[1:] == Motion.CUT
    n = np.maximum(np.ceil(np.hypot(*(b[:, :2] - a[:, :2]).T) / step).astype(int), 1)[cut]
    seg = np.repeat(np.flatnonzero(cut), n + 1)
    tt = np.concatenate([np.linspace(0, 1, k + 1) for k in n])
    return a[seg] + tt[:, None] * (b[seg] - a[seg])


def check_frame(op):
    """Starts and ends at safe height, rapids only at safe height, plunges only downward."""
    p, m = op.points, op.motion
    assert p[0, 2] == SAFE and p[-1, 2] == SAFE
    assert np.all(p[1:][m[1:] == Motion.RAPID][:, 2] == SAFE)
    # A rapid either climbs straight up or travels at safe height.
    rapid = np.flatnonzero(m[1:] == Motion.RAPID)
    vertical = np.all(p[rapid, :2] == p[rapid + 1, :2], axis=1)
    assert np.all(vertical | (p[rapid, 2] == SAFE))
    plunge = np.flatnonzero(m[1:] == Motion.PLUNGE)
    assert np.all(p[plunge, :2] == p[plunge + 1, :2])


@pytest.mark.parametrize("name", list(PARTS))
def test_raster_ball_no_gouge(name):
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    op = raster_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.02, tolerance=TOL))
    assert op.kind == "raster" and len(op.points) > 10
    check_frame(op)
    assert worst_gouge(op, part, t, setup.stock_min[2]) <= TOL + 1e-6


@pytest.mark.parametrize("shape", ["flat", "bull"])
def test_raster_everywhere_with_vertical_walls_no_gouge(shape):
    """steep_angle=90 makes the raster cross vertical walls: cliffs become over-then-down steps."""
    part, setup, t = pocket_block(), setup_for(), tool(shape)
    op = raster_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.02, steep_angle=90.0, angle=30.0))
    check_frame(op)
    assert worst_gouge(op, part, t, setup.stock_min[2]) <= TOL + 1e-6


def test_raster_allowance_leaves_stock():
    part, setup, t = hemisphere_on_block(), setup_for(), tool("ball")
    al = 0.3
    op = raster_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.02, allowance=al))
    assert op.allowance == al
    assert worst_gouge(op, part, t, setup.stock_min[2], allowance=al) <= TOL + 1e-6
    # On the flat top of the block, far from the dome, the tip rides allowance above it.
    cut = cut_samples(op)
    flat = (np.abs(cut[:, 0] - 7) < 1.3) & (np.abs(cut[:, 1] - 15) < 4)
    assert flat.sum() > 20
    np.testing.assert_allclose(cut[flat, 2], -15 + al, atol=1e-9)


@pytest.mark.parametrize("name", ["hemisphere", "pocket"])
def test_raster_covers_shallow_footprint(name):
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    opts = FinishingOptions(scallop=0.02, steep_angle=50.0)
    op = raster_finishing(part, setup, t, CUTTING, opts)
    idx = build_index(part.triangles)
    lo, hi = part.bounds[0, :2], part.bounds[1, :2]
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], 0.5), np.arange(lo[1], hi[1], 0.5))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    floor = setup.stock_min[2]
    # Shallow with a margin, judged on a neighbourhood so region borders are left out.
    d = stepover_for(t, opts.scallop)
    offs = np.array([[0, 0], [d, 0], [-d, 0], [0, d], [0, -d]])
    shallow = np.ones(len(xy), bool)
    for o in offs:
        c = xy + o
        z = [drop_profile(idx, t.radius, t.corner_radius, c + e, floor) for e in ([0.05, 0], [-0.05, 0], [0, 0.05], [0, -0.05])]
        slope = np.hypot((z[0] - z[1]) / 0.1, (z[2] - z[3]) / 0.1)
        shallow &= slope < math.tan(math.radians(40.0))
    assert shallow.sum() > 50
    # Path sampled densely: every shallow point is within half a stepover of it.
    dist, _ = cKDTree(cut_samples(op)[:, :2]).query(xy[shallow])
    assert np.max(dist) <= d / 2 + 0.05


@pytest.mark.parametrize("name", list(PARTS))
def test_waterline_no_gouge_and_levels(name):
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    op = waterline_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.05, tolerance=TOL))
    assert op.kind == "waterline" and len(op.points) > 10
    check_frame(op)
    assert worst_gouge(op, part, t, setup.stock_min[2]) <= TOL + 1e-6
    # Each loop is flat: every cut move stays at the z its plunge reached.
    m, p = op.motion, op.points
    loop_id = np.cumsum(m == Motion.PLUNGE)
    cut = m == Motion.CUT
    plunge_z = p[m == Motion.PLUNGE, 2]
    np.testing.assert_array_equal(p[cut, 2], plunge_z[loop_id[cut] - 1])
    levels = np.unique(plunge_z)
    assert len(levels) >= 3
    np.testing.assert_allclose(np.diff(levels), np.diff(levels)[0], atol=1e-9)
    assert np.diff(levels)[0] <= stepover_for(t, 0.05) + 1e-9


@pytest.mark.parametrize("name", ["hemisphere", "pyramid"])
def test_waterline_vertices_on_iso_line(name):
    """Where the CL surface is continuous (no vertical walls) loop vertices are on the level."""
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    op = waterline_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.05))
    p = op.points[op.motion == Motion.CUT]
    z = drop_profile(build_index(part.triangles), t.radius, t.corner_radius, p[:, :2], setup.stock_min[2])
    if name == "hemisphere":
        # The dome meets the block top at a horizontal crease; the block's sides are vertical.
        keep = p[:, 2] > -15 + 1e-6
        p, z = p[keep], z[keep]
    assert len(p) > 20
    assert np.max(np.abs(z - p[:, 2])) <= 1e-4


def test_waterline_bull_no_gouge():
    part, setup, t = pocket_block(), setup_for(), tool("bull")
    op = waterline_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.05))
    check_frame(op)
    assert worst_gouge(op, part, t, setup.stock_min[2]) <= TOL + 1e-6


def test_stepover_formulas():
    assert stepover_for(tool("ball"), 0.005) == pytest.approx(2 * math.sqrt(2 * 3 * 0.005 - 0.005**2))
    assert stepover_for(tool("bull"), 0.005) == pytest.approx(2 * math.sqrt(2 * 1 * 0.005 - 0.005**2))
    assert stepover_for(tool("flat"), 0.005) == pytest.approx(0.6)


@pytest.mark.parametrize(
    "bad", [dict(scallop=0.0), dict(tolerance=-1.0), dict(step_along=0.0), dict(steep_angle=0.0), dict(allowance=-0.1)]
)
def test_bad_options_raise(bad):
    with pytest.raises(ToolpathError):
        raster_finishing(pyramid(), setup_for(), tool("ball"), CUTTING, FinishingOptions(**bad))


def test_part_outside_stock_raises():
    part = pyramid().copy()
    part.apply_translation([500, 0, 0])
    with pytest.raises(ToolpathError):
        waterline_finishing(part, setup_for(), tool("ball"), CUTTING)


@lru_cache(maxsize=None)
def shallow_cap_on_block() -> trimesh.Trimesh:
    """A 30 x 20 x 5 block with a low spherical cap (at most ~27 deg steep) on top."""
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=20.0)
    sphere.apply_translation([20, 15, -15 - 20 + 3])  # cap 3 mm high, 2*sqrt(20^2-17^2) ~ 21 mm wide
    cap = trimesh.boolean.intersection([sphere, box([5, 5, -15], [35, 25, 0])], engine="manifold")
    return trimesh.boolean.union([box([5, 5, -20], [35, 25, -15]), cap], engine="manifold")


def test_waterline_leaves_shallow_areas_to_the_raster():
    """The cap never reaches steep_angle - overlap: its slopes get no waterline, the walls do."""
    part, t = shallow_cap_on_block(), tool("ball")
    op = waterline_finishing(part, setup_for(), t, CUTTING, FinishingOptions(scallop=0.05))
    cut = op.points[op.motion == Motion.CUT]
    assert len(cut) > 0
    # Every cutting point hugs the block's vertical walls (tool axis R away from them) ...
    x, y = cut[:, 0], cut[:, 1]
    to_wall = np.minimum.reduce([np.abs(x - 5), np.abs(x - 35), np.abs(y - 5), np.abs(y - 25)])
    outside = (x < 5) | (x > 35) | (y < 5) | (y > 25)
    assert np.all(outside | (to_wall < 1e-6)), "waterline cut on the shallow cap"
    # ... and every level of the walls is still there.
    levels = np.unique(np.round(cut[:, 2], 6))
    assert levels.min() < -19.0 + 1.0 and levels.max() > -15.5
    assert worst_gouge(op, part, t, setup_for().stock_min[2]) <= TOL + 1e-6


@pytest.mark.parametrize("name", ["hemisphere", "pocket"])
def test_onto_level_keeps_the_gouge_free_end_and_locates_the_crossing(name):
    """Brackets shrink onto the level: the outside end never above it, the bracket tiny or on it."""
    from cadcam.finishing import _Surface
    from cadcam.isoline import _ISO_RESOLUTION, _ISO_Z_RESOLUTION, onto_level

    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    surface = _Surface(build_index(part.triangles), t.radius, t.corner_radius, 0.0, float(setup.stock_min[2]))
    rng = np.random.default_rng(7)
    a = rng.uniform([2, 2], [38, 28], size=(400, 2))
    b = a + rng.normal(scale=1.5, size=(400, 2))
    za, zb = surface.z(a), surface.z(b)
    lv = np.minimum(za, zb) + rng.uniform(0.05, 0.95, 400) * np.abs(za - zb)
    inside_a = za > lv
    keep = inside_a != (zb > lv)
    pi0 = np.where(inside_a[:, None], a, b)[keep]
    po0 = np.where(inside_a[:, None], b, a)[keep]
    assert len(pi0) > 100
    pi, po, lv = onto_level(surface, pi0, po0, lv[keep])
    zi, zo = surface.z(pi), surface.z(po)
    assert np.all(zo <= lv)
    assert np.all(zi > lv)
    done = (np.hypot(*(po - pi).T) <= 2 * _ISO_RESOLUTION) | (
        (zo >= lv - _ISO_Z_RESOLUTION) & (zi <= lv + _ISO_Z_RESOLUTION))
    assert done.all()
    # Both ends stay on the segment they started on.
    d = po0 - pi0
    cross = d[:, 0] * (po - pi0)[:, 1] - d[:, 1] * (po - pi0)[:, 0]
    assert np.max(np.abs(cross)) <= 1e-9 * (1 + np.max(np.abs(d)) ** 2)


@pytest.mark.parametrize("name", ["boss", "pocket", "hemisphere"])
def test_waterline_chords_within_half_tolerance_and_the_margin(name):
    """Sampled every 0.01 mm, no move rises into the CL surface by more than the chord test's
    tolerance/2 plus its margin (tolerance/8): the bound of _tighten_chords' argument, which
    holds whatever its sample spacing, on vertical walls (boss, pocket) and a dome."""
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    op = waterline_finishing(part, setup, t, CUTTING, FinishingOptions(scallop=0.05, tolerance=TOL))
    # The margin is the exact sagitta, a hair over TOL / 8.
    assert worst_gouge(op, part, t, setup.stock_min[2], step=0.01) <= TOL / 2 + 1.001 * TOL / 8


class _Unfloored:
    """A CL surface that answers every height exactly, whatever floor it is asked from."""

    def __init__(self, surface):
        self.surface, self.radius = surface, surface.radius

    def z(self, xy, progress=None, *, floor=None):
        return self.surface.z(xy)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(["pocket", "boss", "hemisphere"]), st.sampled_from([0.0, 0.3]),
       st.floats(1e-4, 0.05), st.integers(0, 2**31 - 1))
def test_refining_from_floors_makes_the_points_of_exact_heights(name, allowance, tol, seed):
    """_refine asks its chord tests' heights from just under the chord (less tol): the points, cliffs and
    sources it makes are those of exact heights to the bit, over walls (pocket, boss) and a dome."""
    part, setup, t = PARTS[name](), setup_for(), tool("ball")
    surface = _surface(part, setup, t, FinishingOptions(allowance=allowance))
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.uniform(-2.0, 4.0, (60, 2)), axis=0) % [40.0, 30.0]
    z = surface.z(xy)
    joined = rng.random(59) < 0.9
    got = _refine(surface, xy, z, joined, tol)
    want = _refine(_Unfloored(surface), xy, z, joined, tol)
    assert len(got[0]) > len(xy)  # something was split
    for a, b in zip(got, want):
        assert np.array_equal(a, b)
