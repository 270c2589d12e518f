"""Upper envelope of part meshes on regular grids: exact at grid points, no gaps on shared edges."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam import heightmap
from cadcam.heightmap import Grid, grid_over, upper_envelope, upper_envelope_at
from factory.core.errors import MeshError, SetupError


def points(grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(grid.xs, grid.ys)  # (ny, nx) each, like the envelope


def test_grid_over_centres_points_inside_the_stock():
    g = grid_over([0, 0, -10], [10, 5.1, 0], 0.5)
    assert (g.nx, g.ny) == (20, 11)
    assert g.shape == (11, 20)
    assert g.xs[0] == pytest.approx(0.25) and g.xs[-1] == pytest.approx(9.75)
    # 5.1 mm is not a whole number of cells: equal margins, each under one cell
    assert g.ys[0] == pytest.approx(5.1 - g.ys[-1])
    assert 0 < g.ys[0] < 0.5
    assert np.allclose(np.diff(g.xs), 0.5) and np.allclose(np.diff(g.ys), 0.5)


@pytest.mark.parametrize("cell", [0.0, -1.0, float("nan")])
def test_grid_over_rejects_bad_cell(cell):
    with pytest.raises(SetupError):
        grid_over([0, 0, 0], [1, 1, 1], cell)


def test_rejects_malformed_triangles():
    g = grid_over([0, 0, 0], [1, 1, 1], 0.5)
    with pytest.raises(MeshError):
        upper_envelope(np.zeros((3, 3)), g)
    with pytest.raises(MeshError):
        upper_envelope(np.full((1, 3, 3), np.nan), g)


def test_box_top_inside_footprint_including_points_on_its_edges():
    # Box footprint [2, 6] x [1, 4]: grid points at multiples of 0.5 lie exactly on its sides.
    box = trimesh.creation.box(bounds=[[2, 1, -3], [6, 4, -1]])
    g = Grid(x0=0.0, y0=0.0, cell=0.5, nx=17, ny=11)
    top = upper_envelope(box.triangles, g)
    X, Y = points(g)
    inside = (X >= 2) & (X <= 6) & (Y >= 1) & (Y <= 4)
    assert np.all(top[inside] == pytest.approx(-1.0, abs=1e-12))
    assert np.all(np.isneginf(top[~inside]))


def test_sphere_envelope_is_the_inscribed_polyhedron():
    R = 10.0
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=R)
    g = grid_over([-11, -11, -11], [11, 11, 11], 0.25)
    top = upper_envelope(sphere.triangles, g)
    X, Y = points(g)
    r2 = X**2 + Y**2
    exact = np.sqrt(np.clip(R * R - r2, 0, None))
    assert np.all(np.isneginf(top[r2 > R * R]))
    # Every vertex is on the sphere, so the facets are inside it: never above ...
    inner = r2 < (0.9 * R) ** 2
    assert np.all(top[inner] <= exact[inner] + 1e-9)
    # ... and below it by at most the sagitta of the largest facet, seen along z.
    tri = sphere.triangles
    a = np.linalg.norm(tri[:, 1] - tri[:, 2], axis=1)
    b = np.linalg.norm(tri[:, 2] - tri[:, 0], axis=1)
    c = np.linalg.norm(tri[:, 0] - tri[:, 1], axis=1)
    circumradius = np.max(a * b * c / (4 * sphere.area_faces))
    sagitta = R - np.sqrt(R * R - circumradius**2)
    cos_min = np.sqrt(1 - 0.81)
    assert np.all(top[inner] >= exact[inner] - sagitta / cos_min)
    assert np.all(np.isfinite(top[inner]))


def test_through_hole_has_no_part():
    plate = trimesh.creation.box(bounds=[[0, 0, -5], [20, 20, 0]])
    hole = trimesh.creation.cylinder(radius=4, height=20, sections=64)
    hole.apply_translation([10, 10, 0])
    part = plate.difference(hole)
    g = grid_over([0, 0, -5], [20, 20, 0], 0.2)
    top = upper_envelope(part.triangles, g)
    X, Y = points(g)
    d = np.hypot(X - 10, Y - 10)
    assert np.all(np.isneginf(top[d < 4 * np.cos(np.pi / 64) - 1e-6]))
    assert np.all(top[d > 4 + 1e-6] == pytest.approx(0.0, abs=1e-12))


def test_vertical_triangles_give_their_top_edge():
    # A lone vertical wall along y = 1 from x = 0 to 2, z from -2 up to a slanted top edge.
    tri = np.array([
        [[0, 1, -2], [2, 1, -2], [2, 1, 1]],
        [[0, 1, -2], [2, 1, 1], [0, 1, 0]],
    ], dtype=float)
    g = Grid(x0=0.0, y0=0.0, cell=0.5, nx=5, ny=5)
    top = upper_envelope(tri, g)
    assert np.allclose(top[2], g.xs * 0.5)  # row y = 1: the top edge from z = 0 to 1
    assert np.all(np.isneginf(np.delete(top, 2, axis=0)))


@st.composite
def heightfield_meshes(draw):
    """A random triangulated heightfield whose vertices sit on (or near) grid points."""
    cell = draw(st.sampled_from([0.1, 0.2, 0.25, 0.5]))
    k = draw(st.integers(1, 3))  # grid points per mesh cell
    mx, my = draw(st.integers(1, 6)), draw(st.integers(1, 6))
    z = np.array(draw(st.lists(st.floats(-5, 5, allow_nan=False, allow_infinity=False),
                               min_size=(mx + 1) * (my + 1), max_size=(mx + 1) * (my + 1)))).reshape(my + 1, mx + 1)
    flip = np.array(draw(st.lists(st.booleans(), min_size=mx * my, max_size=mx * my))).reshape(my, mx)
    with_walls = draw(st.booleans())
    return cell, k, z, flip, with_walls


def triangulate(cell, k, z, flip, with_walls):
    my, mx = flip.shape
    h = k * cell
    V = lambda i, j: (i * h, j * h, z[j, i])  # noqa: E731
    tris = []
    for j in range(my):
        for i in range(mx):
            a, b, c, d = V(i, j), V(i + 1, j), V(i + 1, j + 1), V(i, j + 1)
            tris += [(a, b, d), (b, c, d)] if flip[j, i] else [(a, b, c), (a, c, d)]
    if with_walls:  # skirts down to z = -10 on the boundary: vertical triangles
        ring = [(i, 0) for i in range(mx)] + [(mx, j) for j in range(my)] + \
               [(i, my) for i in range(mx, 0, -1)] + [(0, j) for j in range(my, 0, -1)]
        ring.append(ring[0])
        for (i0, j0), (i1, j1) in zip(ring[:-1], ring[1:]):
            p, q = V(i0, j0), V(i1, j1)
            tris += [(p, q, (q[0], q[1], -10.0)), (p, (q[0], q[1], -10.0), (p[0], p[1], -10.0))]
    return np.array(tris, dtype=float)


def interpolate(cell, k, z, flip, x, y):
    """The triangulation's height at (x, y), by hand."""
    h = k * cell
    my, mx = flip.shape
    i = min(int(np.floor(x / h + 1e-9)), mx - 1)
    j = min(int(np.floor(y / h + 1e-9)), my - 1)
    u, v = x / h - i, y / h - j
    z00, z10, z11, z01 = z[j, i], z[j, i + 1], z[j + 1, i + 1], z[j + 1, i]
    if flip[j, i]:  # diagonal from (1, 0) to (0, 1)
        if u + v <= 1:
            return z00 + u * (z10 - z00) + v * (z01 - z00)
        return z11 + (1 - u) * (z01 - z11) + (1 - v) * (z10 - z11)
    if u >= v:  # diagonal from (0, 0) to (1, 1)
        return z00 + u * (z10 - z00) + v * (z11 - z10)
    return z00 + v * (z01 - z00) + u * (z11 - z01)


@settings(max_examples=60, deadline=None)
@given(heightfield_meshes())
def test_heightfield_mesh_envelope_is_exact_and_gap_free(mesh):
    cell, k, z, flip, with_walls = mesh
    my, mx = flip.shape
    g = Grid(x0=0.0, y0=0.0, cell=cell, nx=mx * k + 1, ny=my * k + 1)
    top = upper_envelope(triangulate(*mesh), g)
    assert np.all(np.isfinite(top)), "a grid point on a shared edge or vertex was missed"
    expected = np.array([[interpolate(cell, k, z, flip, x, y) for x in g.xs] for y in g.ys])
    assert np.allclose(top, expected, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(heightfield_meshes(), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.data())
def test_the_envelope_at_some_points_is_the_whole_envelope_there(mesh, dx, dy, data):
    """Verify looks beside a few cells only (upper_envelope_at): it must read exactly what the whole envelope
    holds there, on a grid shifted off the mesh's own points, walls and points off the part included."""
    cell, k, z, flip, with_walls = mesh
    my, mx = flip.shape
    g = Grid(x0=dx - cell, y0=dy - cell, cell=cell, nx=mx * k + 4, ny=my * k + 4)
    tri = triangulate(*mesh)
    cells = np.array(data.draw(st.lists(st.integers(0, g.size - 1), min_size=1, max_size=40)))
    whole = upper_envelope(tri, g).reshape(-1)
    for tile in (1, 2, 8):
        assert np.array_equal(upper_envelope_at(tri, g, cells, tile=tile), whole[cells])


def _every_node(tri: np.ndarray, g: Grid) -> np.ndarray:
    """The envelope by brute force: every triangle's weights at every grid point, the same arithmetic as the
    rasteriser's exact test (the slack of EDGE_TOLERANCE outside each edge, the clamp to its z range)."""
    from cadcam.heightmap import EDGE_TOLERANCE as tol

    X, Y = np.meshgrid(g.x0 + np.arange(g.nx) * g.cell, g.y0 + np.arange(g.ny) * g.cell)
    top = np.full(g.shape, -np.inf)
    for t in tri:
        xy = t[:, :2]
        a2 = (xy[1, 0] - xy[0, 0]) * (xy[2, 1] - xy[0, 1]) - (xy[1, 1] - xy[0, 1]) * (xy[2, 0] - xy[0, 0])
        edge = np.linalg.norm(xy[[1, 2, 0]] - xy, axis=1)
        box = ((X >= xy[:, 0].min() - tol) & (X <= xy[:, 0].max() + tol)
               & (Y >= xy[:, 1].min() - tol) & (Y <= xy[:, 1].max() + tol))
        inside, zq = box.copy(), np.zeros(g.shape)
        for k in range(3):
            p1, p2 = xy[(k + 1) % 3], xy[(k + 2) % 3]
            gx, gy = -(p2[1] - p1[1]) / a2, (p2[0] - p1[0]) / a2
            lam = -(gx * p1[0] + gy * p1[1]) + gx * X + gy * Y
            inside &= lam >= -(tol * edge[(k + 1) % 3] / abs(a2))
            zq += lam * t[k, 2]
        zq = np.clip(zq, t[:, 2].min(), t[:, 2].max())
        top = np.where(inside, np.maximum(top, zq), top)
    return top


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-3.0, 3.0, allow_nan=False)] * 9), min_size=1, max_size=6),
       st.sampled_from([0.1, 0.25, 0.5]), st.floats(-0.5, 0.5), st.floats(-0.5, 0.5))
def test_the_rasteriser_takes_every_point_inside_each_triangle_however_thin(corners, cell, dx, dy):
    """Each row is rasterised only over the span a triangle may cover (long thin triangles across the grid cover
    a few per cent of their box): no point the exact test takes may be lost, slivers and steep ones included."""
    tri = np.array(corners, dtype=float).reshape(-1, 3, 3)
    xy = tri[:, :, :2]
    a2 = ((xy[:, 1, 0] - xy[:, 0, 0]) * (xy[:, 2, 1] - xy[:, 0, 1])
          - (xy[:, 1, 1] - xy[:, 0, 1]) * (xy[:, 2, 0] - xy[:, 0, 0]))
    longest = np.linalg.norm(xy[:, [1, 2, 0]] - xy, axis=2).max(1)
    tri = tri[np.abs(a2) > 1e-7 * np.maximum(longest, 1e-7)]  # the vertical ones take another path
    if not len(tri):
        return
    g = Grid(x0=-3.2 + dx, y0=-3.2 + dy, cell=cell, nx=int(6.4 / cell) + 2, ny=int(6.4 / cell) + 2)
    expected = _every_node(tri, g)
    for span_points in (-1.0, float("inf")):  # every triangle by its rows' spans; every one by its box
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(heightmap, "_SPAN_POINTS", span_points)
            assert np.array_equal(heightmap._rasterised(tri, g), expected)
