"""Geometry helpers the tests share (independent of the code under test)."""

from __future__ import annotations

import numpy as np


def point_polyline_distance(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance from each point ``p`` (k, 3) to the polyline ``poly`` (m, 3) [mm]."""
    if len(poly) == 1:
        return np.linalg.norm(p - poly[0], axis=1)
    a = poly[:-1]
    d = poly[1:] - a
    dd = np.einsum("ij,ij->i", d, d)
    dd = np.where(dd == 0, 1.0, dd)
    out = np.empty(len(p))
    for s in range(0, len(p), 256):
        q = p[s:s + 256, None, :] - a[None]
        t = np.clip(np.einsum("kij,ij->ki", q, d) / dd, 0, 1)
        r = q - t[..., None] * d
        out[s:s + 256] = np.sqrt(np.einsum("kij,kij->ki", r, r).min(axis=1))
    return out
