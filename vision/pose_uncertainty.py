"""How far an edge fit's pose (x, y [m], yaw [rad]) may be off, from the fit's own residuals.

:func:`vision.locate._located` reports :data:`vision.locate.COVERAGE_FACTOR` standard deviations of
this covariance (with the edge bias). Three parts, each from what the fit itself shows:

1. The residuals as independent but for their neighbours (:data:`vision.locate.CORRELATED_SAMPLES`):
   the Gauss-Newton covariance scaled by the residuals' variance.
2. The residuals of one mesh edge (a wall's top, a bore's rim) share their error: blur, a shading
   step, a burr lie along a whole edge, not a sample. The cluster-robust ("sandwich") covariance over
   the mesh edges counts each edge's pull on the pose once, so a fit held by a few edges that
   disagree reports it. The larger of 1 and 2 is taken: with many edges that agree, 2 is smaller.
   Only with :data:`MIN_EDGES` edges or more: over fewer, the sandwich is itself too uncertain (a
   blank's 8 or so visible edges on exact renders reported +-1.03 mm for poses 0.01-0.15 mm off).
3. Feet of walls seen nearly edge-on (:meth:`vision.mesh_edges.MeshEdges.unresolved`) that stayed in
   the fit (outside glare) may have taken their tops' edge, a wall's width off: the turn of the pose
   when they leave the fit (linearised, one standard deviation) is added to the yaw's. A stepped wall
   beside a box turned 1.16 deg on them, where 1 and 2 gave +-0.71 and +-0.79 deg. Their shift in
   position is not added: 2 holds it already where it mattered, and on the exact renders of a blank
   (whose feet find their own edges) it reported 0.25 mm for a pose 0.15 mm off.
"""

from __future__ import annotations

import numpy as np

#: Least residual variance counted, for a fit that lies exactly on its edges [px^2].
MIN_VARIANCE_PX2 = 0.05 ** 2
#: Fewest mesh edges in a fit for their pulls to count (:func:`pose_covariance`, 2). Argued from the
#: statistics, not fitted: G edges' pulls estimate a variance of 3 parameters with G - 3 degrees of
#: freedom, so the deviation they give is itself uncertain by about 1 / sqrt(2 (G - 3)) of itself; at
#: 16 edges that is 0.2 (a fifth of the +-), at a blank's 8 edges 0.3 (it reported +-1.03 mm for poses
#: 0.01-0.15 mm off). The gallery bounds it without fixing it: on the tuning seeds 0-4 (40 found poses,
#: 14-263 edges) every threshold from 0 to none covers 40/40; over all 158 cached poses any threshold
#: up to 16 covers 156, 24 loses a stepped wall held out with 19 edges (0.58 mm, +-0.91 by edges,
#: +-0.57 without) and 32 one more (30 edges).
MIN_EDGES = 16
#: Fewest samples that must remain when the unresolved feet leave the fit to take their shift.
MIN_REMAINING = 12


def pose_covariance(jac: np.ndarray, residuals: np.ndarray, edge: np.ndarray, unresolved: np.ndarray,
                    correlated: float) -> np.ndarray:
    """``(3, 3)`` covariance of a fitted pose (x, y [m], yaw [rad]).

    Parameters
    ----------
    jac : (n, 3) float
        The residuals' derivatives by x, y [px/m] and yaw [px/rad] at the fit.
    residuals : (n,) float
        The fit's residuals along the edges' normals [px].
    edge : (n,) int
        The mesh edge each residual's sample lies on (:attr:`vision.mesh_edges.MeshEdges.edge`).
    unresolved : (n,) bool
        Samples that are the foot of a wall beside its top in the picture (kept in the fit).
    correlated : float
        Neighbouring residuals count as this many times fewer independent ones (unitless).
    """
    n = max(len(residuals), 4)
    variance = max(float(np.sum(residuals ** 2)) / max(n - 3, 1), MIN_VARIANCE_PX2)
    try:
        inverse = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.diag([np.inf] * 3)
    independent = inverse * variance * correlated
    groups = np.unique(edge, return_inverse=True)[1].ravel()
    count = int(groups.max()) + 1 if len(groups) else 0
    by_edge = np.zeros((3, 3))
    if count >= MIN_EDGES:
        pull = np.zeros((count, 3))
        np.add.at(pull, groups, jac * residuals[:, None])
        by_edge = inverse @ (pull.T @ pull) @ inverse * count / (count - 1)
    # The larger of the two, in position (its worse direction) and in yaw.
    cov = independent.copy()
    if np.linalg.eigvalsh(by_edge[:2, :2]).max() > np.linalg.eigvalsh(independent[:2, :2]).max():
        cov[:2, :2] = by_edge[:2, :2]
    cov[2, 2] = max(cov[2, 2], by_edge[2, 2])
    cov[2, 2] += feet_shift(jac, residuals, unresolved)[2] ** 2
    return cov


def feet_shift(jac: np.ndarray, residuals: np.ndarray, unresolved: np.ndarray) -> np.ndarray:
    """``(3,)`` the pose's change (x, y [m], yaw [rad]) when the ``unresolved`` samples leave the fit,
    linearised at the fit (the rest's normal equations solved for what they no longer balance); zeros
    when none are in it or too few would remain."""
    keep = ~np.asarray(unresolved, bool)
    if keep.all() or keep.sum() < MIN_REMAINING:
        return np.zeros(3)
    try:
        return np.linalg.solve(jac[keep].T @ jac[keep], jac[~keep].T @ residuals[~keep])
    except np.linalg.LinAlgError:
        return np.zeros(3)
