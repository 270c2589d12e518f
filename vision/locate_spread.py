"""How far a pose fitted to a picture's edges may be off, from the residuals of its fit.

:func:`vision.locate.locate_parts` fits x, y and yaw (and a bloom) so the mesh's edges lie on the
picture's; :func:`pose_spread` gives the standard deviations of that pose the residuals allow, and how
much the mesh's edges disagree among themselves (a wrong pose's edges pull apart).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Neighbouring edge samples see the same blur and texture: the fit's residuals count as this
#: many times fewer independent ones when the uncertainty is estimated (unitless).
CORRELATED_SAMPLES = 4.0


@dataclass(frozen=True)
class PoseSpread:
    """Standard deviations of a fitted pose: ``xy`` [m] (larger axis) and ``yaw`` [rad], the larger of
    the plain and the clustered estimate; ``disagreement``: clustered over plain (unitless)."""

    xy: float
    yaw: float
    disagreement: float


def pose_spread(jac: np.ndarray, residuals: np.ndarray, clusters: np.ndarray) -> PoseSpread:
    """How far a fitted pose may be off from the noise of its residuals.

    ``jac`` (k, m) is the residuals' Jacobian [px per m, px per rad, ...] at the pose, whose first three
    parameters are x, y [m] and yaw [rad] (the others, a bloom, are fitted with them); ``residuals``
    (k,) [px]; ``clusters`` (k,) int the mesh edge each residual's sample lies on.

    Plain: the residuals' variance through the Jacobian, the samples counted
    :data:`CORRELATED_SAMPLES` times fewer. Clustered (the sandwich estimate): each mesh edge's
    residuals as one cluster, so an edge whose samples all sit to one side (fitted onto a shadow's
    edge, a wall's foot instead of its top) counts as one voice pulling the pose, as much as it
    pulls. The bloom is fitted with the pose and its share of the spread stays in.
    """
    j, r = np.asarray(jac), np.asarray(residuals)
    n = max(len(r), 4)
    variance = max(float(np.sum(r ** 2)) / max(n - 3, 1), 0.05 ** 2)
    inverse = np.linalg.pinv(j.T @ j)
    plain = inverse[:3, :3] * variance * CORRELATED_SAMPLES
    ids, cluster = np.unique(clusters, return_inverse=True)
    pulls = np.zeros((len(ids), j.shape[1]))
    np.add.at(pulls, cluster, j * r[:, None])
    groups = len(ids)
    clustered = (inverse @ (pulls.T @ pulls) @ inverse)[:3, :3] * groups / max(groups - 1, 1)
    xy = [float(np.sqrt(max(np.linalg.eigvalsh(c[:2, :2]).max(), 0.0))) for c in (plain, clustered)]
    yaw = [float(np.sqrt(max(c[2, 2], 0.0))) for c in (plain, clustered)]
    ratio = max(xy[1] / max(xy[0], 1e-12), yaw[1] / max(yaw[0], 1e-12))
    return PoseSpread(xy=max(xy), yaw=max(yaw), disagreement=ratio)
