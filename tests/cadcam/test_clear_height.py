"""cadcam.stock.clear_height: the compiled pairs (cadcam.clearheight) give the heights the per-offset numpy loop gave,
to the bit (issue 35)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.heightmap import Grid
from cadcam.model import Tool
from cadcam.stock import Simulation, clear_height


def _one_offset_at_a_time(sim: Simulation, tool: Tool, xy: np.ndarray, within: float | None = None) -> np.ndarray:
    """The construction clear_height had before: one grid offset per step over every axis."""
    g = sim.grid
    slack = g.cell * math.sqrt(2.0)
    reach = (tool.radius if within is None else min(within, tool.radius)) + slack
    k = int(math.ceil(reach / g.cell))
    di, dj = np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1))
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    i0 = np.rint((xy[:, 0] - g.x0) / g.cell).astype(np.int64)
    j0 = np.rint((xy[:, 1] - g.y0) / g.cell).astype(np.int64)
    out = np.full(len(xy), -np.inf)
    for a, b in zip(di.ravel(), dj.ravel()):
        i, j = i0 + a, j0 + b
        inside = (i >= 0) & (i < g.nx) & (j >= 0) & (j < g.ny)
        if not inside.any():
            continue
        ii, jj = i[inside], j[inside]
        r = np.hypot(g.x0 + ii * g.cell - xy[inside, 0], g.y0 + jj * g.cell - xy[inside, 1])
        h = tool.profile_height(np.clip(r - slack, 0.0, tool.radius))
        need = np.where(r <= reach, sim.stock_top[jj, ii] - h, -np.inf)
        out[inside] = np.maximum(out[inside], need)
    return out


TOOLS = {
    "flat": lambda d: Tool(1, "flat", "flat", d, 0.0, 20.0, 2, 40.0),
    "ball": lambda d: Tool(2, "ball", "ball", d, d / 2, 20.0, 2, 40.0),
    "bull": lambda d: Tool(3, "bull", "bull", d, d / 4, 20.0, 2, 40.0),
    "drill": lambda d: Tool(4, "drill", "drill", d, 0.0, 20.0, 2, 40.0, point_angle=118.0),
}


@settings(max_examples=60, deadline=None)
@given(shape=st.sampled_from(sorted(TOOLS)), diameter=st.floats(0.5, 12.0), cell=st.sampled_from([0.2, 0.35, 0.5, 1.0]),
       nx=st.integers(1, 40), ny=st.integers(1, 40), seed=st.integers(0, 2**31 - 1), n=st.integers(0, 60),
       within=st.one_of(st.none(), st.floats(0.0, 8.0)))
def test_compiled_pairs_give_the_loops_heights_to_the_bit(shape, diameter, cell, nx, ny, seed, n, within):
    rng = np.random.default_rng(seed)
    grid = Grid(x0=float(rng.uniform(-5, 5)), y0=float(rng.uniform(-5, 5)), cell=cell, nx=nx, ny=ny)
    top = rng.uniform(-10.0, 10.0, (ny, nx))
    top[rng.random((ny, nx)) < 0.1] = -np.inf  # columns cut through (op 2's stock)
    sim = Simulation(grid=grid, stock_top=top, part_top=np.full((ny, nx), -np.inf), stock_bottom=-10.0)
    # axes over the grid, off its sides (some far beyond the reach) and on grid points exactly
    span = np.array([nx * cell, ny * cell])
    xy = np.array([grid.x0, grid.y0]) + rng.uniform(-0.5, 1.5, (n, 2)) * span
    xy[: n // 4] = np.array([grid.x0, grid.y0]) + rng.integers(0, max(nx, ny), (n // 4, 2)) * cell
    tool = TOOLS[shape](diameter)
    got = clear_height(sim, tool, xy, within)
    want = _one_offset_at_a_time(sim, tool, xy, within)
    assert got.shape == want.shape == (n,)
    assert np.array_equal(got, want)  # to the bit, -inf where no stock is under the tool


def test_a_broken_pairing_is_caught():
    """The comparison can fail: the stock read one grid point off is not the loop's answer."""
    grid = Grid(x0=0.0, y0=0.0, cell=0.5, nx=20, ny=20)
    top = np.zeros((20, 20))
    top[10, 10] = 5.0
    sim = Simulation(grid=grid, stock_top=top, part_top=np.full((20, 20), -np.inf), stock_bottom=-10.0)
    tool = TOOLS["ball"](2.0)
    xy = np.array([[5.0, 5.0], [6.3, 5.0]])
    want = _one_offset_at_a_time(sim, tool, xy)
    assert np.array_equal(clear_height(sim, tool, xy), want)
    shifted = Simulation(grid=grid, stock_top=np.roll(top, 1, axis=1), part_top=sim.part_top, stock_bottom=-10.0)
    assert not np.array_equal(clear_height(shifted, tool, xy), want)
