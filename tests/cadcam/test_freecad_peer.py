"""benchmarks/freecad_peer.py's adapter from a G-code program to our timer, and its plunge count.

No FreeCAD here: the programs are written by hand in the shape FreeCAD 0.20's LinuxCNC post
writes them (preamble, ``M6 T2`` then ``G43 H2``, every G1 with its F).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys

import numpy as np
import pytest

from cadcam.finishing import stepover_for
from cadcam.gcode import parse_gcode
from cadcam.model import Job, Motion, Operation
from cadcam.plan import PlanOptions
from cadcam.post import PostOptions, post_process
from cadcam.roughing import zlevel_roughing
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from tests.conftest import ROOT, pocket_block

_spec = importlib.util.spec_from_file_location("freecad_peer", ROOT / "benchmarks" / "freecad_peer.py")
freecad_peer = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = freecad_peer  # its dataclasses look their module up while it loads
_spec.loader.exec_module(freecad_peer)

FREECAD_STYLE = """\
(Exported by FreeCAD)
(Post Processor: PathScripts.post.linuxcnc_post)
(begin preamble)
G17 G54 G40 G49 G80 G90
G21
(begin operation: TC2)
(machine units: mm/min)
(TC2)
M5
M6 T2
G43 H2
M3 S9549
(finish operation: TC2)
(begin operation: AdaptiveOutside)
G0 Z5.000
G0 X10.000 Y0.000 Z5.000
G1 X10.000 Y0.000 Z-10.000 F687.500
(Adaptive - depth: -10.000000)
G1 X50.000 Y0.000 F2291.800
G1 X50.000 Y30.000 F2291.800
G0 Z5.000
G0 X10.000 Y30.000 Z5.000
G1 X10.000 Y30.000 Z-10.000 F687.500
(finish operation: AdaptiveOutside)
M05
M2
"""


def test_freecad_style_program_by_hand():
    opt = PostOptions()
    # The tool change, then: its traverse to X10 Y0 is the change's; 15 mm down at the plunge
    # feed, 40 + 30 mm at the cutting feed, 15 mm up and 40 mm across at the rapid rate, 15 mm down.
    expected = (opt.tool_change_time / 60.0 + 30.0 / 687.5 + 70.0 / 2291.8 + 55.0 / opt.rapid_rate)
    assert freecad_peer.program_minutes(FREECAD_STYLE) == pytest.approx(expected, rel=1e-9)
    slow = PostOptions(rapid_rate=1000.0)
    assert freecad_peer.program_minutes(FREECAD_STYLE, slow) == pytest.approx(
        expected - 55.0 / opt.rapid_rate + 55.0 / 1000.0, rel=1e-9)


def test_timer_is_the_plans_estimate():
    lib = load_tool_library()
    setup, part = make_setup(pocket_block())
    tool = lib.tool(1)
    op = zlevel_roughing(part, setup, tool, lib.cutting_data(tool, setup.material))
    program = post_process(Job("p", setup, (op,)), PostOptions())
    # Equal up to what the text rounds and the chords arcs are read back as.
    assert freecad_peer.program_minutes(program.text) == pytest.approx(program.total_time / 60.0, rel=2e-3)


def test_plunges_count_only_vertical_feeds_into_stock():
    lib = load_tool_library()
    mill = lib.tool(2)
    drill = next(t for t in lib.tools if t.shape == "drill")
    moves = parse_gcode(FREECAD_STYLE)
    feed_down = [i for i in range(1, len(moves.points))
                 if moves.motion[i] != Motion.RAPID and moves.points[i, 2] < moves.points[i - 1, 2]]
    assert len(feed_down) == 2
    engagement = np.zeros(len(moves.points))
    assert freecad_peer.plunges(moves, engagement, {2: mill}) == 0  # both plunges in air
    engagement[feed_down[1]] = 3.0
    assert freecad_peer.plunges(moves, engagement, {2: mill}) == 1
    engagement[:] = 3.0  # the sideways cuts and the rapids are no plunges however deep
    assert freecad_peer.plunges(moves, engagement, {2: mill}) == 2
    # The same program run with a drill as T2: a drill only ever goes in straight down.
    assert freecad_peer.plunges(moves, engagement, {2: dataclasses.replace(drill, number=2)}) == 0


def test_the_peer_takes_our_op_1s_tools_for_each_of_its_operations():
    """FreeCAD's Adaptive gets our first roughing tool, its face pass and profiles our first flats-and-walls
    finishing tool (else the roughing one), its 3D surface our ball at our freeform raster's stepover."""
    lib = load_tool_library()
    setup, _ = make_setup(pocket_block())

    def op(kind: str, number: int) -> Operation:
        tool = lib.tool(number)
        return Operation(f"{kind} T{number}", kind, tool, lib.cutting_data(tool, setup.material),
                         np.zeros((2, 3)), np.zeros(2, np.int8))

    peer = freecad_peer.peer_tools(Job("p", setup, (op("helix", 1), op("roughing", 14), op("roughing", 2),
                                                   op("finishing", 2), op("finishing", 1), op("waterline", 3))))
    assert (peer.rough.tool.number, peer.finish.tool.number, peer.ball.tool.number) == (14, 2, 3)
    assert peer.ball_stepover == pytest.approx(stepover_for(lib.tool(3), PlanOptions().freeform_scallop))
    assert 0.3 < peer.ball_stepover < 0.6  # a 6 mm ball at 0.01 mm scallop
    bare = freecad_peer.peer_tools(Job("p", setup, (op("roughing", 2),)))
    assert bare.finish is bare.rough and bare.ball is None and bare.ball_stepover == 0.0


def test_a_group_freecad_made_no_path_for_takes_no_time():
    assert freecad_peer.group_minutes("(begin operation: Face0)\nG0 Z5.000\n") == 0.0
    assert freecad_peer.group_minutes(FREECAD_STYLE) == freecad_peer.program_minutes(FREECAD_STYLE)


def test_the_bound_sweeps_the_freeform_faces_once_with_the_finishing_ball():
    """The bound's ball (``benchmarks.adaptive``): nothing on a prismatic block; on a half sphere standing on a
    block, the sphere's surface (2 pi r^2, less what its top tessellates as flat) swept once at the stepover the
    plan's freeform scallop leaves with the 6 mm ball, at that ball's library feed."""
    import manifold3d

    from benchmarks.adaptive import _ball_minutes
    from tests.conftest import manifold_to_trimesh

    library = load_tool_library()
    block = manifold3d.Manifold.cube((60.0, 50.0, 10.0))
    setup, part = make_setup(manifold_to_trimesh(block))
    assert _ball_minutes(library, setup, part) == 0.0
    r = 15.0
    dome = block + manifold3d.Manifold.sphere(r, 128).translate((30.0, 25.0, 10.0))
    setup, part = make_setup(manifold_to_trimesh(dome))
    ball = library.tool(3)
    step = stepover_for(ball, PlanOptions().freeform_scallop)
    expected = 2 * np.pi * r * r / (step * library.cutting_data(ball, setup.material).feed)
    assert _ball_minutes(library, setup, part) == pytest.approx(expected, rel=0.03)


def test_the_bounds_flats_are_both_operations_faces_up_in_op_1_and_the_bottom_in_op_2():
    """The bound (``benchmarks.adaptive``) is of both operations: on a stepped block the flats faced are its two
    upward levels (op 1) and its bottom, which op 2 faces when it takes off the holding allowance; the walls
    and a through hole's bore are not flats."""
    import manifold3d

    from benchmarks.adaptive import _flat_area
    from tests.conftest import manifold_to_trimesh

    step = manifold3d.Manifold.cube((60.0, 50.0, 10.0)) + manifold3d.Manifold.cube((30.0, 50.0, 5.0)).translate(
        (0.0, 0.0, 10.0))
    hole = manifold3d.Manifold.cylinder(30.0, 5.0, 5.0, 64).translate((45.0, 25.0, -5.0))
    _, part = make_setup(manifold_to_trimesh(step - hole))
    disc = float(manifold_to_trimesh(hole).area_faces[np.abs(manifold_to_trimesh(hole).face_normals[:, 2]) > 0.5]
                 .sum()) / 2  # one end of the 64-gon hole
    assert _flat_area(part) == pytest.approx(2 * 60.0 * 50.0 - 2 * disc, rel=1e-6)
