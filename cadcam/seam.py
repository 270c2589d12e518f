"""Where op 1's and op 2's walls meet after a depth split, and how well they match (issue 34).

A part deeper than the tools reach from one side is machined from the top down to op 1's floor and, turned
over, from below (:mod:`cadcam.op2`). The walls the two operations leave meet there: :func:`seams` measures
the step between them from both jobs' toolpaths, and :func:`seam_faults` makes a step over
:data:`SEAM_TOLERANCE` a fault of op 2's verdict.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from cadcam.model import Job, Motion
from cadcam.setup import BREAKTHROUGH_MM
from cadcam.verify import Fault

#: Largest step between op 1's and op 2's walls where they meet [mm]: the stock verify lets a finished
#: part keep (:attr:`cadcam.verify.VerifyOptions.left_above`).
SEAM_TOLERANCE = 0.1


@dataclass(frozen=True)
class Seam:
    """Where op 1's and op 2's walls meet, and how well they match.

    Attributes
    ----------
    z : float
        Height of the seam in op-1 work coordinates [mm]: op 1's floor, or the highest op 2 reaches.
    above, below : float
        Most stock left on the part's walls after both operations [mm], in a slice ``probe`` above and
        below ``z`` (negative: the tool cut into the part).
    x, y : float
        Where on the wall the side with more left has it most [mm] (op-1 work coordinates).
    """

    z: float
    above: float
    below: float
    x: float = math.nan
    y: float = math.nan

    @property
    def step(self) -> float:
        """The step between the walls the two operations leave [mm]."""
        return abs(self.above - self.below)

    def to_dict(self) -> dict[str, float]:
        return {"z": round(self.z, 3), "above": round(self.above, 4), "below": round(self.below, 4),
                "step": round(self.step, 4), **{k: None if math.isnan(v) else round(v, 2)
                                                for k, v in (("x", self.x), ("y", self.y))}}

    def fault(self) -> Fault | None:
        """The seam as a verify fault of op 2 when its step is over :data:`SEAM_TOLERANCE` (or no tool came
        near a wall there), else None: a part whose walls do not meet is not finished, and no warning makes
        it so."""
        if self.step <= SEAM_TOLERANCE:
            return None
        step = "no tool finished one side" if math.isnan(self.step) else f"a {self.step:.3f} mm step"
        known = not math.isnan(self.x)
        return Fault("seam", 0, (), float(np.nan_to_num(self.step, nan=math.inf)), SEAM_TOLERANCE,
                     (self.x, self.y, self.z) if known else None,
                     f"the walls of op 1 and op 2 meet at Z{self.z:.2f}"
                     + (f" near X{self.x:.1f} Y{self.y:.1f}" if known else "")
                     + f" with {step} ({self.above:.3f} mm left above, {self.below:.3f} below), over the "
                     f"{SEAM_TOLERANCE:g} mm tolerance")


def seams(part_work: trimesh.Trimesh, job1: Job, job2: Job, probe: float = 0.3, spacing: float = 0.05
          ) -> tuple[Seam, ...]:
    """The seams between op 1 and op 2 on the part's walls, measured from both jobs' toolpaths.

    A check independent of the stock models: at a height ``h`` the part's section is sampled along its
    outline every ``spacing`` [mm]; the flutes of every feed move of both operations that span ``h`` (op 2's
    turned back into op-1 work coordinates) sweep discs, sampled every ``spacing`` along each move; the
    stock left on the wall at an outline point is its distance to the nearest disc's rim. The seams are at
    op 1's floor and at the highest op 2 reaches (unless that lies past the walls' overlap: a pocket's bottom,
    :func:`cadcam.op2._deepest_left`), where they lie within the part's height; ``above`` and
    ``below`` the most left ``probe`` [mm] either side (outline points no tool came near, a narrow slot,
    are left out: farther than a tool radius plus ``probe``).

    Returns
    -------
    tuple of Seam
        Lowest first; empty when op 1 reached the part's bottom and op 2 only faced.
    """
    from scipy.spatial import cKDTree

    # op 1 -> op 2 work coordinates, as op 2 recorded it (:func:`cadcam.op2.flip_transform`): its own inverse
    flip = np.asarray(job2.parameters["flip"]["transform_op1_to_op2"], dtype=np.float64)
    lo, hi = float(part_work.bounds[0][2]), float(part_work.bounds[1][2])
    floor1, top2 = float(job1.setup.floor_z), float(flip[2, 3] - job2.setup.floor_z)
    # Op 2 reaching past the walls' overlap went there for a pocket op 1 never saw
    # (:func:`cadcam.op2._deepest_left`): its walls end on that pocket's bottom, no wall of op 1's meets them there.
    heights = {floor1, top2} if top2 <= floor1 + BREAKTHROUGH_MM + 1e-6 else {floor1}
    out = []
    for z in sorted(h for h in heights if lo + probe < h < hi - probe):
        left, where = [], []
        for h in (z + probe, z - probe):
            outline = _outline(part_work, h, spacing)
            centres, radii = [], []
            for job, turned in ((job1, False), (job2, True)):
                c, r = _discs_at(job, float(flip[2, 3] - h) if turned else h, spacing)
                if turned and len(c):
                    c = (flip[:2, :2] @ c.T).T + flip[:2, 3]
                centres.append(c)
                radii.append(r)
            c, r = np.concatenate(centres), np.concatenate(radii)
            if not len(outline) or not len(c):
                left.append(float("nan"))
                where.append(outline[0] if len(outline) else (math.nan, math.nan))
                continue
            gaps = []
            for radius in np.unique(r):
                d, _ = cKDTree(c[r == radius]).query(outline)
                gaps.append(d - radius)
            gap = np.min(gaps, axis=0)
            near = gap <= float(r.max()) + probe
            worst = int(np.argmax(np.where(near, gap, -np.inf)))
            left.append(float(gap[worst]) if near.any() else float("nan"))
            where.append(outline[worst])
        side = 1 if np.isnan(left[1]) or left[1] > left[0] else 0  # the side with more left
        out.append(Seam(z, left[0], left[1], float(where[side][0]), float(where[side][1])))
    return tuple(out)


def seam_faults(job2: Job) -> tuple[Fault, ...]:
    """Op 2's faults for the seams where its walls meet op 1's with a step over :data:`SEAM_TOLERANCE`
    (its ``parameters["seams"]``, :func:`plan_op2`): verify's own simulation cannot tell op 1's walls from
    op 2's, the seams are measured from both jobs' toolpaths."""
    found = (Seam(s["z"], s["above"], s["below"], *(math.nan if s.get(k) is None else s[k] for k in ("x", "y")))
             for s in job2.parameters.get("seams", ()))
    return tuple(f for f in (s.fault() for s in found) if f is not None)


def _outline(part: trimesh.Trimesh, h: float, spacing: float) -> np.ndarray:
    """(n, 2) points every ``spacing`` [mm] along the part's section at height ``h`` [mm]."""
    segments = trimesh.intersections.mesh_plane(part, [0.0, 0.0, 1.0], [0.0, 0.0, h])
    if not len(segments):
        return np.zeros((0, 2))
    a, b = segments[:, 0, :2], segments[:, 1, :2]
    n = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(int), 1)
    t = np.concatenate([np.arange(k) / k for k in n])
    k = np.repeat(np.arange(len(a)), n)
    return a[k] + (b[k] - a[k]) * t[:, None]


def _discs_at(job: Job, h: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Centres (n, 2) [mm] and radii (n,) [mm] of the discs the flutes of ``job``'s feed moves sweep at
    height ``h`` [mm], sampled every ``spacing`` along each move (a bull or ball end narrower near its tip)."""
    centres, radii = [], []
    for op in job.operations:
        tool, p = op.tool, np.asarray(op.points, dtype=np.float64)
        if tool.is_drill or len(p) < 2:
            continue
        feed = np.asarray(op.motion[1:]) != int(Motion.RAPID)
        a, b = p[:-1][feed], p[1:][feed]
        if not len(a):
            continue
        n = np.maximum(np.ceil(np.linalg.norm(b[:, :2] - a[:, :2], axis=1) / spacing).astype(int), 1)
        t = np.concatenate([np.arange(k + 1) / k for k in n])
        k = np.repeat(np.arange(len(a)), n + 1)
        q = a[k] + (b[k] - a[k]) * t[:, None]
        up = h - q[:, 2]  # the slice's height above the tip
        span = (up >= 0) & (up <= tool.flute_length)
        rc = tool.corner_radius
        # a torus corner narrows the disc near the tip: r - rc + sqrt(rc^2 - (rc - up)^2)
        below = np.clip(rc - up[span], 0.0, rc)
        radius = tool.radius - rc + np.sqrt(np.maximum(rc * rc - below * below, 0.0))
        centres.append(q[span, :2])
        radii.append(np.floor(radius * 100.0) / 100.0)  # a hundredth smaller: fewer radii, never less left
    if not centres:
        return np.zeros((0, 2)), np.zeros(0)
    return np.concatenate(centres), np.concatenate(radii)
