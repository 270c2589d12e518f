"""The spread of a fitted pose (vision/locate_spread.py) and which model edge keeps a picture edge two
found (vision/locate_search.claimed_twice): synthetic residuals and edges, no pictures."""

from __future__ import annotations

import numpy as np
import pytest

from vision.locate_search import claimed_twice
from vision.locate_spread import pose_spread


#: Samples per mesh edge.
N = 50


def _square_fit(rng: np.random.Generator, per_edge_offset: float, noise: float = 0.3):
    """A 100 px square outline, 12 mesh edges of 50 samples (a pixel apart, as on a part): the Jacobian of each sample's residual
    along its outward normal [px] by x, y [px] and yaw [rad] (and a bloom column that is not fitted),
    residuals of pixel noise plus a common offset per mesh edge, and each sample's mesh edge."""
    rows, residuals, clusters = [], [], []
    for k in range(12):
        side = k % 4
        normal = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]][side])
        along = np.array([-normal[1], normal[0]])
        start = -50.0 + 100.0 * (k // 4) / 3
        t = start + np.arange(N) * (100.0 / 3) / N
        points = 50.0 * normal[None, :] + t[:, None] * along[None, :]
        lever = points[:, 0] * normal[1] - points[:, 1] * normal[0]
        rows.append(np.column_stack([np.tile(normal, (N, 1)), -lever, np.zeros(N)]))
        residuals.append(rng.normal(0.0, noise, N) + rng.choice([-1.0, 1.0]) * per_edge_offset)
        clusters.append(np.full(N, k))
    return np.vstack(rows), np.concatenate(residuals), np.concatenate(clusters)


@pytest.mark.parametrize("seed", range(5))
def test_edges_that_agree_leave_the_plain_spread(seed):
    """Pixel noise alone: the clustered spread is no larger than the plain one (which counts the
    samples four times fewer), so the edges agree and the spread is the plain one."""
    jac, residuals, clusters = _square_fit(np.random.default_rng(seed), 0.0)
    spread = pose_spread(jac, residuals, clusters)
    assert spread.disagreement < 1.5
    plain = np.sqrt(np.linalg.inv(jac[:, :3].T @ jac[:, :3])[0, 0] * np.var(residuals) * 4)
    assert spread.xy == pytest.approx(plain, rel=0.2)


@pytest.mark.parametrize("seed", range(5))
def test_edges_that_each_sit_to_one_side_disagree(seed):
    """Each mesh edge 1 px to one side (fitted onto another edge): far more spread than the noise of
    600 samples gives, and the spread reported is the clustered one."""
    jac, residuals, clusters = _square_fit(np.random.default_rng(seed), 1.0)
    spread = pose_spread(jac, residuals, clusters)
    assert spread.disagreement > 3.0
    calm = pose_spread(*_square_fit(np.random.default_rng(seed), 0.0))
    assert spread.xy > 2 * calm.xy and spread.yaw > 2 * calm.yaw


def test_a_picture_edge_two_parallel_model_edges_found_stays_with_the_nearer():
    """A wall's top (mesh edge 0, v = 10 px) and its foot (mesh edge 1, v = 11.5 px) both find the one
    picture edge at v = 10: the foot's samples give it up. Samples of one mesh edge never do, nor
    model edges that found picture edges apart."""
    u = np.arange(10.0)
    uv = np.r_[np.column_stack([u, np.full(10, 10.0)]), np.column_stack([u, np.full(10, 11.5)])]
    normal = np.tile([0.0, 1.0], (20, 1))
    edge = np.r_[np.zeros(10, int), np.ones(10, int)]
    off = np.r_[np.full(10, 0.05), np.full(10, -1.45)]
    twice = claimed_twice(edge, uv, normal, off)
    assert not twice[:10].any() and twice[10:].all()
    assert not claimed_twice(np.zeros(20, int), uv, normal, off).any()
    apart = np.r_[np.full(10, 0.05), np.full(10, 0.4)]  # the foot found its own edge, at v = 11.9
    assert not claimed_twice(edge, uv, normal, apart).any()
    missing = np.r_[np.full(10, 0.05), np.full(10, np.nan)]
    assert not claimed_twice(edge, uv, normal, missing).any()
