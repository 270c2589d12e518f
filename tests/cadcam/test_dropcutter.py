"""Exact drop-cutter against a brute-force sandwich and closed-form cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadcam.dropcutter import build_index, drop_cutter, drop_profile, shared_index
from cadcam.model import Tool
from factory.core.errors import MeshError, ToolpathError

R = 3.0
SHAPES = {"flat": 0.0, "bull": 1.0, "ball": R}


def tool(shape: str, radius: float = R) -> Tool:
    rc = {"flat": 0.0, "bull": radius / 3, "ball": radius}[shape]
    return Tool(1, shape, shape, 2 * radius, rc, 20.0, 2, 40.0)


def height(r, radius, rc):
    d = np.clip(r - (radius - rc), 0.0, None)
    return rc - np.sqrt(np.clip(rc * rc - d * d, 0.0, None))


def samples(tri: np.ndarray, k: int = 50, edge_k: int = 2000) -> tuple[np.ndarray, float]:
    """Dense points of one triangle and delta: every triangle point is within delta of one."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    m = i + j <= k
    b = np.stack([i[m] / k, j[m] / k], axis=1)
    t = np.linspace(0.0, 1.0, edge_k + 1)
    b = np.concatenate([b, np.stack([t, 0 * t], 1), np.stack([0 * t, t], 1), np.stack([t, 1 - t], 1)])
    p = tri[0] + b[:, :1] * (tri[1] - tri[0]) + b[:, 1:] * (tri[2] - tri[0])
    longest = max(np.linalg.norm(tri[a] - tri[b_]) for a, b_ in ((0, 1), (1, 2), (2, 0)))
    return p, longest / k


def sandwich(tris, radius, rc, xy, floor):
    """Lower bound (max over samples) and rigorous upper bound (samples relaxed by delta)."""
    lower = np.full(len(xy), floor)
    upper = np.full(len(xy), floor)
    for tri in tris:
        p, delta = samples(tri)
        r = np.hypot(p[None, :, 0] - xy[:, None, 0], p[None, :, 1] - xy[:, None, 1])
        z = np.where(r <= radius, p[None, :, 2] - height(np.minimum(r, radius), radius, rc), -np.inf)
        lower = np.maximum(lower, z.max(axis=1))
        # Any triangle point is within delta (3D) of a sample s, and h is nondecreasing.
        zu = np.where(
            r <= radius + delta,
            p[None, :, 2] + delta - height(np.clip(r - delta, 0.0, radius), radius, rc),
            -np.inf,
        )
        upper = np.maximum(upper, zu.max(axis=1))
    return lower, upper


coord = st.floats(-5.0, 5.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    tris=st.lists(st.lists(st.tuples(coord, coord, coord), min_size=3, max_size=3), min_size=1, max_size=3),
    pts=st.lists(st.tuples(coord, coord), min_size=1, max_size=8),
    shape=st.sampled_from(["flat", "bull", "ball"]),
    vertical=st.booleans(),
)
def test_matches_brute_force_sandwich(tris, pts, shape, vertical):
    tri = np.array(tris, dtype=float)
    if vertical:
        # Put the first triangle's corners on one XY line: a vertical wall.
        tri[0, 2, :2] = tri[0, 0, :2] + 0.37 * (tri[0, 1, :2] - tri[0, 0, :2])
    xy = np.array(pts, dtype=float)
    rc = SHAPES[shape]
    floor = -50.0
    z = drop_profile(build_index(tri), R, rc, xy, floor)
    lower, upper = sandwich(tri, R, rc, xy, floor)
    assert np.all(z >= lower - 1e-9)
    assert np.all(z <= upper + 1e-9)


def test_random_batch_against_sampling():
    """Many triangles and points at once: exercises buckets, culling and batching."""
    rng = np.random.default_rng(7)
    centres = rng.uniform(0, 20, (16, 1, 3))
    tri = centres + rng.normal(0, 2.0, (16, 3, 3))
    xy = rng.uniform(-3, 23, (160, 2))
    idx = build_index(tri, cell=1.0)
    for shape, rc in SHAPES.items():
        z = drop_profile(idx, R, rc, xy, -50.0)
        lower, upper = sandwich(tri, R, rc, xy, -50.0)
        assert np.all(z >= lower - 1e-9), shape
        assert np.all(z <= upper + 1e-9), shape
        # The bisection-based bull-nose edge search agrees with the sampling closely.
        assert np.max(z - lower) < 0.05, shape


def big_triangle(z_of_xy) -> np.ndarray:
    corners = np.array([[-100.0, -100.0], [100.0, -100.0], [0.0, 150.0]])
    return np.array([[[x, y, z_of_xy(x, y)] for x, y in corners]])


POINTS = np.array([[0.0, 0.0], [3.3, -7.1], [-12.0, 5.5]])


def test_ball_on_horizontal_plane():
    z = drop_cutter(build_index(big_triangle(lambda x, y: 5.0)), tool("ball"), POINTS, -10.0)
    np.testing.assert_allclose(z, 5.0, atol=1e-12)


def test_ball_on_45_degree_plane():
    z = drop_cutter(build_index(big_triangle(lambda x, y: x)), tool("ball"), POINTS, -1000.0)
    # The ball centre sits R above the plane along its normal: R*sqrt(2) above it vertically.
    np.testing.assert_allclose(z, POINTS[:, 0] + R * (math.sqrt(2) - 1), atol=1e-9)


def test_flat_on_sloped_plane_touches_with_its_rim():
    m = 0.3
    z = drop_cutter(build_index(big_triangle(lambda x, y: m * x)), tool("flat"), POINTS, -1000.0)
    np.testing.assert_allclose(z, m * (POINTS[:, 0] + R), atol=1e-9)


def test_bull_on_sloped_plane():
    m = 0.7
    t = tool("bull")
    a, rc = t.radius - t.corner_radius, t.corner_radius
    nz = 1 / math.sqrt(1 + m * m)
    z = drop_cutter(build_index(big_triangle(lambda x, y: m * x)), t, POINTS, -1000.0)
    expected = m * (POINTS[:, 0] + a + rc * m * nz) - rc * (1 - nz)
    np.testing.assert_allclose(z, expected, atol=1e-9)


def test_bull_on_vertex():
    # A steep spike: only its apex can be touched.
    tri = np.array([[[0.0, 0.0, 0.0], [0.1, -30.0, -100.0], [0.2, 30.0, -100.0]]])
    t = tool("bull")
    d = np.array([0.0, 1.0, 2.0, 2.5, 2.9, 2.999])
    xy = np.stack([-d, 0 * d], axis=1)
    z = drop_cutter(build_index(tri), t, xy, -1000.0)
    np.testing.assert_allclose(z, -t.profile_height(d), atol=1e-9)


def sphere_cl(d, sphere, radius, rc):
    """Analytic CL on a sphere of radius ``sphere`` centred at the origin."""
    a = radius - rc
    z = np.sqrt((sphere + rc) ** 2 - np.maximum(d - a, 0.0) ** 2) - rc
    return np.where(d <= a, sphere, z)


@pytest.mark.parametrize("shape", ["flat", "bull", "ball"])
def test_shapes_on_sphere_between_inscribed_and_circumscribed(shape):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    inradius = float(np.min(np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles[:, 0])))
    t = tool(shape)
    rng = np.random.default_rng(3)
    ang = rng.uniform(0, 2 * np.pi, 300)
    d = rng.uniform(0, 13.0, 300)
    xy = np.stack([d * np.cos(ang), d * np.sin(ang)], axis=1)
    z = drop_cutter(build_index(mesh.triangles), t, xy, -100.0)
    lo = sphere_cl(d, inradius, t.radius, t.corner_radius)
    hi = sphere_cl(d, 20.0, t.radius, t.corner_radius)
    assert np.all(z >= lo - 1e-9)
    assert np.all(z <= hi + 1e-9)
    assert 20.0 - inradius < 0.2  # the sandwich is tight enough to mean something


def test_ball_on_sphere_exact_at_vertices_of_fine_mesh():
    # With a fine mesh the analytic formula holds to the faceting error.
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=20.0)
    d = np.linspace(0, 15, 40)
    xy = np.stack([d, 0.3 * d], axis=1)
    z = drop_cutter(build_index(mesh.triangles), tool("ball"), xy, -100.0)
    expected = sphere_cl(np.hypot(xy[:, 0], xy[:, 1]), 20.0, R, R)
    assert np.all(np.abs(z - expected) < 0.02)


def test_floor_and_empty_index():
    idx = build_index(np.zeros((0, 3, 3)))
    z = drop_cutter(idx, tool("ball"), np.array([[0.0, 0.0], [5.0, 5.0]]), -7.0)
    np.testing.assert_array_equal(z, [-7.0, -7.0])
    far = drop_cutter(build_index(big_triangle(lambda x, y: 1.0)), tool("ball"), np.array([[500.0, 0.0]]), -7.0)
    assert far[0] == -7.0


def test_progress_reaches_total():
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    calls = []
    xy = np.random.default_rng(0).uniform(-12, 12, (5000, 2))
    drop_cutter(build_index(mesh.triangles), tool("ball"), xy, -20.0, progress=lambda d, t: calls.append((d, t)))
    assert calls and calls[-1] == (5000, 5000)
    assert all(b[0] >= a[0] for a, b in zip(calls, calls[1:]))


def test_bad_input_raises():
    with pytest.raises(MeshError):
        build_index(np.zeros((2, 3)))
    with pytest.raises(MeshError):
        build_index(np.full((1, 3, 3), np.nan))
    idx = build_index(big_triangle(lambda x, y: 0.0))
    with pytest.raises(ToolpathError):
        drop_cutter(idx, tool("ball"), np.zeros((3, 3)), 0.0)
    with pytest.raises(ToolpathError):
        drop_cutter(idx, tool("ball"), np.array([[np.nan, 0.0]]), 0.0)


@pytest.mark.parametrize("shape", ["flat", "bull", "ball"])
def test_threads_give_the_single_thread_answer(shape, monkeypatch):
    """Points split across worker threads get exactly the CL z one thread computes, progress to the total."""
    import cadcam.dropcutter as dc

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=10.0)
    tris = np.asarray(sphere.triangles)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-14, 14, size=(20000, 2))
    t = tool(shape)
    monkeypatch.setenv("FACTORY_THREADS", "1")
    one = drop_cutter(build_index(tris), t, xy, -20.0)
    monkeypatch.setenv("FACTORY_THREADS", "3")
    monkeypatch.setattr(dc, "_THREAD_MIN_CANDIDATES", 64)
    seen = []
    many = drop_cutter(build_index(tris), t, xy, -20.0, progress=lambda done, total: seen.append((done, total)))
    assert dc._threads_for(10**6) == 3
    np.testing.assert_array_equal(many, one)
    assert seen and seen[-1] == (len(xy), len(xy))
    assert all(total == len(xy) and 0 < done <= total for done, total in seen)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    count=st.integers(1, 60),
    spread=st.floats(0.2, 4.0),
    shape=st.sampled_from(["flat", "bull", "ball"]),
    radius=st.floats(0.3, 6.0),
)
def test_the_query_buckets_change_which_candidates_are_tried_never_the_answer(seed, count, spread, shape, radius):
    """Fine buckets (issue 35: a waterline's queries on steep walls), the old half-radius ones, and fine ones
    coarsened by the entry budget and made in chunks give the same CL z to the bit: buckets only cull. So does
    a floor per point (a waterline comparing heights with its levels): above it every CL z is the one the
    plain floor gives, bit for bit; at or under it, the floor itself."""
    import cadcam.dropcutter as dc

    rng = np.random.default_rng(seed)
    tri = rng.uniform(0, 20, (count, 1, 3)) + rng.normal(0, spread, (count, 3, 3))
    xy = rng.uniform(-3, 23, (300, 2))
    rc = {"flat": 0.0, "bull": radius / 3, "ball": radius}[shape]

    def drop() -> np.ndarray:
        return drop_profile(build_index(tri), radius, rc, xy, -50.0)  # a fresh index: nothing prepared

    fine = drop()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dc, "_CELL_PER_RADIUS", 0.5)
        assert np.array_equal(drop(), fine)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dc, "_MAX_ENTRIES", 50)
        mp.setattr(dc, "_ENTRY_CHUNK", 7)
        assert np.array_equal(drop(), fine)
    # floors near the answers (ties and ulps among them), and far under and over them; none under the plain one
    floor = np.maximum(fine + rng.choice([0.0, -1e-12, 1e-12, -0.3, 0.3, -80.0, 80.0], size=len(xy)), -50.0)
    got = drop_profile(build_index(tri), radius, rc, xy, floor)
    above = fine > floor
    assert np.array_equal(got[above], fine[above])
    assert np.array_equal(got[~above], floor[~above])
    with pytest.raises(ToolpathError, match="one per CL point"):
        drop_profile(build_index(tri), radius, rc, xy, floor[:-1])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 80), spread=st.floats(0.2, 4.0),
       pin=st.sampled_from([1e-9, 1e-7, 1e-5]), shape=st.sampled_from(["flat", "ball"]))
def test_a_pins_coarser_buckets_give_the_fine_buckets_answer(seed, count, spread, pin, shape):
    """A pin (a radius far below the triangles: cadcam.relief reads which facets are seen from above with
    one) is queried on buckets of a share of a triangle, not of its radius (issue 35: millions of buckets
    cost a relief's intake 1 s): the CL z is the same to the bit, at the facets' centres and anywhere."""
    import cadcam.dropcutter as dc

    rng = np.random.default_rng(seed)
    tri = rng.uniform(0, 20, (count, 1, 3)) + rng.normal(0, spread, (count, 3, 3))
    xy = np.concatenate([tri.mean(axis=1)[:, :2], rng.uniform(-3, 23, (200, 2))])
    radius = pin * 20.0
    rc = radius if shape == "ball" else 0.0

    def drop() -> tuple[np.ndarray, float]:
        index = build_index(tri)  # fresh: nothing prepared
        return drop_profile(index, radius, rc, xy, -50.0), dc._prepared(index, radius, rc)[0].cell

    coarse, coarse_cell = drop()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dc, "_PIN_RADIUS", 0.0)  # the radius-scaled buckets, as before
        fine, fine_cell = drop()
    assert coarse_cell > fine_cell  # the pin's buckets are coarser here
    assert np.array_equal(coarse, fine)


def test_the_shared_index_is_reused_only_for_the_same_triangles():
    """The waterline's index (and its prepared buckets) serves the raster of the same part, and only it:
    the heights are those of a fresh index, and other triangles get their own."""
    rng = np.random.default_rng(7)
    tris = rng.uniform(0.0, 10.0, (60, 3, 3))
    first = shared_index(tris)
    xy = rng.uniform(0.0, 10.0, (300, 2))
    z = drop_profile(first, 1.5, 1.5, xy, -1.0)
    assert shared_index(tris.copy()) is first and first.prepared
    assert np.array_equal(drop_profile(shared_index(tris), 1.5, 1.5, xy, -1.0), z)
    assert np.array_equal(drop_profile(build_index(tris), 1.5, 1.5, xy, -1.0), z)
    moved = tris.copy()
    moved[0, 0, 2] += 1e-9
    other = shared_index(moved)
    assert other is not first and not other.prepared
    assert shared_index(tris.reshape(60, 3, 3)) is not other


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 80), spread=st.floats(0.05, 4.0),
       shape=st.sampled_from(["flat", "bull", "ball"]), radius=st.floats(0.3, 6.0),
       grid=st.sampled_from([0.0, 0.01, 0.5]), floor=st.sampled_from([-50.0, 10.0]))
def test_the_compiled_contacts_give_numpys_heights_to_the_bit(seed, count, spread, shape, radius, grid, floor):
    """The compiled contacts (cadcam.dropcontacts, issue 35) against the numpy rounds they replaced
    (tests/cadcam/drop_numpy.py): every CL height the same number, on triangle soups whose corners may sit on
    a grid (shared vertices and edges, ties, vertical walls, flat facets), for the three tool shapes."""
    from tests.cadcam.drop_numpy import numpy_drop_profile

    rng = np.random.default_rng(seed)
    tri = rng.uniform(0, 20, (count, 1, 3)) + rng.normal(0, spread, (count, 3, 3))
    if grid:
        tri = np.round(tri / grid) * grid
    xy = np.concatenate([rng.uniform(-3, 23, (300, 2)), tri.reshape(-1, 3)[:, :2], tri.mean(axis=1)[:, :2]])
    rc = {"flat": 0.0, "bull": radius / 3, "ball": radius}[shape]
    index = build_index(tri)
    got = drop_profile(index, radius, rc, xy, floor)
    want = numpy_drop_profile(index, radius, rc, xy, floor)
    assert np.array_equal(got, want)
    assert np.array_equal(np.signbit(got), np.signbit(want))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 80), spread=st.floats(0.05, 4.0),
       shape=st.sampled_from(["flat", "bull", "ball"]), radius=st.floats(0.05, 6.0),
       grid=st.sampled_from([0.0, 0.01, 0.5]))
def test_the_compiled_bucket_entries_are_numpys_to_the_bit(seed, count, spread, shape, radius, grid):
    """The compiled bucket entries (cadcam.dropcontacts.bucket_entries, issue 35) against the numpy pairs they
    replaced (tests/cadcam/drop_numpy.py): every prepared list (vertices, edges, facets) the same pointers, items
    and keys, on triangle soups whose corners may sit on a grid, for the three tool shapes, pins to wide tools."""
    from cadcam import dropcutter as dc
    from tests.cadcam.drop_numpy import numpy_entries

    rng = np.random.default_rng(seed)
    tri = rng.uniform(0, 20, (count, 1, 3)) + rng.normal(0, spread, (count, 3, 3))
    if grid:
        tri = np.round(tri / grid) * grid
    rc = {"flat": 0.0, "bull": radius / 3, "ball": radius}[shape]
    got = dc._prepare(build_index(tri), radius, rc)
    compiled = dc._entries
    dc._entries = numpy_entries
    try:
        want = dc._prepare(build_index(tri), radius, rc)
    finally:
        dc._entries = compiled
    for g, w in zip(got[1:4], want[1:4]):
        assert np.array_equal(g.ptr, w.ptr) and np.array_equal(g.items, w.items)
        assert np.array_equal(g.key, w.key) and np.array_equal(np.signbit(g.key), np.signbit(w.key))
        assert (g.z_hi, g.z_span) == (w.z_hi, w.z_span)
