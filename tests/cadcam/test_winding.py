"""The intake's fast face winding (:func:`cadcam.mesh.fix_winding`) and edge grouping
(:func:`cadcam.relief._edge_groups`) give exactly what the slower constructions they replace gave."""

from __future__ import annotations

import numpy as np
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.mesh import fix_winding
from cadcam.relief import _edge_groups
from tests.cadcam.reliefs import heightfield_sheet, overlapping_sheets


def _mobius(n: int = 12) -> trimesh.Trimesh:
    """A one-sided strip: no consistent winding exists, the walk decides."""
    t = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    rows = []
    for s in (-1.0, 1.0):
        r = 10.0 + s * np.cos(t / 2.0)
        rows.append(np.column_stack([r * np.cos(t), r * np.sin(t), s * np.sin(t / 2.0)]))
    v = np.vstack(rows)  # 0..n-1 one side, n..2n-1 the other
    f = []
    for i in range(n):
        j = (i + 1) % n
        a, b = i, n + i
        c, d = (j, n + j) if j else (n + j, j)  # the half twist joins the sides crossed over
        f += [[a, c, b], [b, c, d]]
    return trimesh.Trimesh(v, np.array(f), process=False)


def _pieces(rng: np.random.Generator, count: int) -> trimesh.Trimesh:
    parts = []
    for k in range(count):
        kind = rng.integers(4)
        if kind == 0:
            nx, ny = rng.integers(3, 9, size=2)
            x = np.sort(rng.uniform(0, 20, nx)) + 25.0 * k
            y = np.sort(rng.uniform(0, 20, ny))
            z = rng.uniform(1, 5, (ny, nx))
            parts.append(heightfield_sheet(np.unique(x), np.unique(y), z[:len(np.unique(y)), :len(np.unique(x))],
                                           sides_to=0.0 if rng.integers(2) else None))
        elif kind == 1:
            parts.append(trimesh.creation.icosphere(subdivisions=int(rng.integers(1, 3))).apply_translation([0, 0, 9 * k]))
        elif kind == 2:
            parts.append(_mobius(int(rng.integers(6, 14))))
        else:
            parts.append(overlapping_sheets())
    return trimesh.util.concatenate(parts)


def _scrambled(mesh: trimesh.Trimesh, rng: np.random.Generator, flip_share: float) -> trimesh.Trimesh:
    """The mesh with its faces in a random order, some reversed and some rotated ([a,b,c] -> [b,c,a])."""
    faces = np.asarray(mesh.faces)[rng.permutation(len(mesh.faces))]
    flip = rng.random(len(faces)) < flip_share
    faces[flip] = faces[flip][:, ::-1]
    roll = rng.random(len(faces)) < 0.3
    faces[roll] = np.roll(faces[roll], 1, axis=1)
    return trimesh.Trimesh(np.asarray(mesh.vertices), faces, process=False)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 4), flip_share=st.sampled_from([0.0, 0.05, 0.5]))
def test_fix_winding_is_trimesh_fix_winding(seed, count, flip_share):
    rng = np.random.default_rng(seed)
    mesh = _scrambled(_pieces(rng, count), rng, flip_share)
    ours, theirs = mesh.copy(), mesh.copy()
    fix_winding(ours)
    trimesh.repair.fix_winding(theirs)
    assert np.array_equal(np.asarray(ours.faces), np.asarray(theirs.faces))
    assert np.array_equal(np.asarray(ours.vertices), np.asarray(theirs.vertices))


def test_fix_winding_turns_a_reversed_half_back():
    """The comparison above can fail: the fix really changes faces, and keeps each piece's start face."""
    sheet = heightfield_sheet(np.linspace(0, 10, 6), np.linspace(0, 8, 5), np.ones((5, 6)))
    faces = np.asarray(sheet.faces).copy()
    faces[1::2] = faces[1::2][:, ::-1]
    mesh = trimesh.Trimesh(sheet.vertices, faces, process=False)
    assert not mesh.is_winding_consistent
    fix_winding(mesh)
    assert mesh.is_winding_consistent
    assert not np.array_equal(np.asarray(mesh.faces), faces)
    theirs = trimesh.Trimesh(sheet.vertices, faces, process=False)
    trimesh.repair.fix_winding(theirs)
    assert np.array_equal(np.asarray(mesh.faces), np.asarray(theirs.faces))
    # the other consistent winding (every face reversed) is not what trimesh keeps
    assert not np.array_equal(np.asarray(mesh.faces)[:, ::-1], np.asarray(theirs.faces))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 400), k=st.integers(1, 300))
def test_edge_groups_are_unique_rows(seed, n, k):
    faces = np.random.default_rng(seed).integers(0, k, (n, 3))
    edge_of, counts = _edge_groups(faces)
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    if len(e):
        _, inverse, expected = np.unique(e, axis=0, return_inverse=True, return_counts=True)
        assert np.array_equal(edge_of, inverse.reshape(-1)) and np.array_equal(counts, expected)
    else:
        assert len(edge_of) == 0 and len(counts) == 0
