"""The toolpath picture shows every operation in its colour over the stock."""

from __future__ import annotations

import numpy as np

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
