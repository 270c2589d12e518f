"""Cell regions built from row runs against the plain union of every cell's square."""

import numpy as np
from scipy import ndimage
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from cadcam.gridregion import GrownMaskCache, cell_runs, cells_region, grown_cells_region, near_cells
from cadcam.heightmap import Grid

GRID = Grid(x0=1.25, y0=-3.5, cell=0.5, nx=12, ny=9)
masks = arrays(bool, (GRID.ny, GRID.nx))


def squares(mask: np.ndarray, grid: Grid):
    jj, ii = np.nonzero(mask)
    h = 0.5 * grid.cell
    x, y = grid.x0 + ii * grid.cell, grid.y0 + jj * grid.cell
    return shapely.union_all(shapely.box(x - h, y - h, x + h, y + h))


@settings(max_examples=60, deadline=None)
@given(masks)
def test_cells_region_is_the_union_of_the_cells(mask):
    region = cells_region(mask, GRID)
    if not mask.any():
        assert region.is_empty
        return
    want = squares(mask, GRID)
    assert abs(region.area - mask.sum() * GRID.cell ** 2) < 1e-9
    assert region.symmetric_difference(want).area < 1e-9


@settings(max_examples=40, deadline=None)
@given(masks, st.sampled_from([0.0, 0.3, 1.0, 3.0]))
def test_grown_region_is_the_buffer_of_the_union(mask, radius):
    grown = grown_cells_region(mask, GRID, radius)
    if not mask.any():
        assert grown.is_empty
        return
    want = squares(mask, GRID).buffer(radius, quad_segs=8)
    assert shapely.hausdorff_distance(grown, want) < 1e-6
    assert abs(grown.area - want.area) < 1e-6 * max(1.0, want.area)


def test_runs_are_one_rectangle_per_run_of_a_row():
    mask = np.zeros((GRID.ny, GRID.nx), dtype=bool)
    mask[2, 1:4] = True
    mask[2, 6] = True
    mask[5, :] = True
    runs = cell_runs(mask, GRID)
    assert len(runs) == 3
    assert sorted(round(a, 9) for a in shapely.area(runs)) == [0.25, 0.75, 3.0]


def test_cache_answers_a_repeated_mask_with_the_same_region():
    mask = np.zeros((GRID.ny, GRID.nx), dtype=bool)
    mask[3:6, 2:9] = True
    cache = GrownMaskCache(GRID, 1.0)
    first = cache(mask)
    assert cache(mask.copy()) is first
    other = mask.copy()
    other[0, 0] = True
    assert cache(other) is not first
    assert cache(other).area > first.area


@settings(max_examples=150, deadline=None)
@given(arrays(bool, st.tuples(st.integers(1, 40), st.integers(1, 40))), st.floats(0.0, 15.0),
       st.sampled_from([1.0, 0.2, 0.25, 0.5, 0.7]))
def test_the_points_near_a_mask_are_its_dilation_by_the_disc(mask, reach_cells, cell):
    """near_cells (a distance transform) stands in for a dilation by a disc of offsets: the same points, the disc's
    edge decided the same way (reaches of whole cells and of square roots of sums of squares included)."""
    for reach in (reach_cells * cell, float(np.sqrt(np.round(reach_cells ** 2))) * cell):
        k = int(np.ceil(reach / cell)) + 1
        di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
        dilated = ndimage.binary_dilation(mask, structure=np.hypot(di, dj) * cell <= reach)
        assert np.array_equal(near_cells(mask, reach, cell), dilated)
