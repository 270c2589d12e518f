"""The toolpath picture shows every operation in its colour over the stock."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.model import CuttingData, Job, Motion, Operation, Setup, Tool
from cadcam.preview import ORIGIN_COLOUR, RAPID_COLOUR, tick_step, tool_colours, toolpath_image, toolpath_legend


def test_every_operation_and_the_rapids_are_drawn():
    setup = Setup(stock_min=[0, 0, -10], stock_max=[60, 30, 0], transform_mesh_to_work=np.eye(4))
    ball = Tool(3, "ball", "ball", 6.0, 3.0, 18.0, 2, 30.0)
    flat = Tool(1, "flat", "flat", 6.0, 0.0, 18.0, 3, 30.0)
    cut = CuttingData(10000, 1000, 300)
    square = [[5, 5, -1], [55, 5, -1], [55, 25, -1], [5, 25, -1], [5, 5, -1]]
    rough = Operation("rough", "roughing", flat, cut, [[5, 5, 5]] + square + [[5, 5, 5]],
                      [0, 2] + [1] * 4 + [0])
    raster = Operation("raster", "raster", ball, cut, [[10, 10, 5], [10, 10, -2], [50, 12, -2], [50, 12, 5]],
                       [0, 2, 1, 0])
    rest = Operation("rest", "roughing", flat, cut, [[20, 5, 5], [20, 5, -1], [20, 25, -1], [20, 25, 5]],
                     [0, 2, 1, 0])
    job = Job("p", setup, (rough, raster, rest))
    img = toolpath_image(job, width=600)
    assert img.shape[1] == 600 and img.dtype == np.uint8
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    per_tool = tool_colours(job)
    assert list(per_tool) == [1, 3] and per_tool[1] != per_tool[3]  # one colour per tool, not per operation
    for c in (*per_tool.values(), RAPID_COLOUR, ORIGIN_COLOUR):
        assert c in colours
    assert toolpath_legend(job) == ["T1 flat: rough, rest", "T3 ball: raster"]


def test_rapids_lie_under_the_cuts_and_the_axes_are_in_round_millimetres():
    setup = Setup(stock_min=[0, 0, -10], stock_max=[60, 30, 0], transform_mesh_to_work=np.eye(4))
    flat = Tool(1, "flat", "flat", 6.0, 0.0, 18.0, 3, 30.0)
    cut = CuttingData(10000, 1000, 300)
    # a rapid along Y = 15 and a cut across it along X = 30: where they cross, the cut shows
    op = Operation("rough", "roughing", flat, cut, [[5, 15, 5], [55, 15, 5], [30, 5, 5], [30, 5, -1], [30, 25, -1]],
                   [0, 0, 0, 2, 1])
    job = Job("p", setup, (op,))
    img = toolpath_image(job, width=600)
    r = int(np.argmax((img == RAPID_COLOUR).all(axis=2).sum(axis=1)))  # the long rapid's row
    c = int(np.argmax((img == tool_colours(job)[1]).all(axis=2).sum(axis=0)))  # the cut's column
    assert (img[r, c - 20:c - 5] == RAPID_COLOUR).all(axis=1).any()
    assert tuple(img[r, c]) == tool_colours(job)[1]
    assert tick_step(68.0) == 10.0 and tick_step(300.0) == 50.0 and tick_step(7.0) == 1.0


def test_the_setup_picture_draws_the_part_in_the_jaws_over_the_floor():
    import trimesh

    from cadcam import preview
    from cadcam.model import ViseJaws

    jaws = ViseJaws(jaw_height=40.0, jaw_width=150.0, jaw_thickness=20.0, parallels_height=35.0, opening_min=0.0,
                    opening_max=160.0)
    lo, hi = np.array([0.0, 0.0, -22.5]), np.array([104.0, 64.0, 0.0])
    setup = Setup(stock_min=lo, stock_max=hi, transform_mesh_to_work=np.eye(4), floor_z=-16.5,
                  jaws=jaws.place(lo, hi))
    part = trimesh.creation.box(bounds=[[2, 2, -16], [102, 62, -1]]).triangles
    img = preview.setup_image(setup, part, "bracket", width=700)
    assert img.shape[1] == 700 and img.dtype == np.uint8
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    for c in (preview._JAW_COLOUR, preview._PARALLELS_COLOUR, preview._PART_COLOUR, preview._FLOOR_COLOUR):
        assert c in colours
    no_vise = preview.setup_image(Setup(stock_min=lo, stock_max=hi, transform_mesh_to_work=np.eye(4)), part, "p")
    assert preview._JAW_COLOUR not in {tuple(c) for c in no_vise.reshape(-1, 3)}


def test_the_faces_by_kind_are_drawn_under_the_toolpaths():
    import manifold3d

    from cadcam.faces import FLAT, SHALLOW, WALL, classify_faces
    from cadcam.preview import FACE_COLOURS
    from cadcam.setup import make_setup
    from tests.conftest import manifold_to_trimesh

    body = manifold3d.Manifold.cube((40.0, 30.0, 10.0)) - manifold3d.Manifold.sphere(8.0, 64).translate(
        (20.0, 15.0, 14.0))
    setup, part = make_setup(manifold_to_trimesh(body))
    faces = classify_faces(part)
    img = toolpath_image(Job("p", setup, ()), width=400, faces=faces)
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    for k in (FLAT, SHALLOW, WALL):
        assert FACE_COLOURS[k] in colours, k
    plain = toolpath_image(Job("p", setup, ()), width=400)
    assert FACE_COLOURS[FLAT] not in {tuple(c) for c in plain.reshape(-1, 3)}


def _scattered_triangles(seed: int, n: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n, 3, 3) small triangles [mm] at random places and tilts inside the box ``lo``..``hi``."""
    rng = np.random.default_rng(seed)
    centres = lo + (hi - lo) * rng.random((n, 1, 3))
    return centres + rng.normal(scale=2.0, size=(n, 3, 3))


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(1, 6))
def test_the_setup_pictures_silhouette_is_every_triangles_own(seed, n):
    """The part's silhouette in the setup picture is the union of each triangle's alone, in both views: each
    triangle is filled where it projects, and nowhere else (the corners are worked out for all at once)."""
    from cadcam import preview

    lo, hi = np.array([0.0, 0.0, -20.0]), np.array([60.0, 40.0, 0.0])
    setup = Setup(stock_min=lo, stock_max=hi, transform_mesh_to_work=np.eye(4), floor_z=-15.0)
    tri = _scattered_triangles(seed, n, lo, hi)

    def silhouette(triangles: np.ndarray) -> np.ndarray:
        img = preview.setup_image(setup, triangles, "p", width=400)
        return (img == preview._PART_COLOUR).all(axis=2)

    alone = np.logical_or.reduce([silhouette(tri[i:i + 1]) for i in range(n)])
    assert alone.any()
    assert np.array_equal(silhouette(tri), alone)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(1, 6))
def test_the_faces_of_a_kind_are_each_faces_own(seed, n):
    """Under the toolpaths, the faces of one kind fill (walls: outline) the union of each face's alone."""
    from cadcam.faces import FLAT, WALL, FaceClasses
    from cadcam.preview import FACE_COLOURS
    import trimesh

    from cadcam.setup import make_setup

    setup, _ = make_setup(trimesh.creation.box(extents=(60.0, 40.0, 20.0)))
    lo, hi = setup.stock_min, setup.stock_max
    tri = _scattered_triangles(seed, n, lo, hi)
    for kind in (FLAT, WALL):
        def drawn(triangles: np.ndarray) -> np.ndarray:
            m = len(triangles)
            faces = FaceClasses(np.full(m, kind, np.int8), np.ones(m), np.zeros(0), np.full(m, -1), triangles)
            img = toolpath_image(Job("p", setup, ()), width=400, faces=faces)
            return (img == FACE_COLOURS[kind]).all(axis=2)

        alone = np.logical_or.reduce([drawn(tri[i:i + 1]) for i in range(n)])
        assert alone.any()
        assert np.array_equal(drawn(tri), alone), kind
