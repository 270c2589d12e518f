"""benchmarks/cycle_time.py's own G-code counter, against hand sums and against cadcam.gcode."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest

from cadcam.gcode import parse_gcode
from cadcam.model import Job
from cadcam.post import PostOptions, post_process
from cadcam.roughing import zlevel_roughing
from cadcam.setup import make_setup
from cadcam.tools import load_tool_library
from tests.conftest import ROOT, pocket_block

_spec = importlib.util.spec_from_file_location("cycle_time", ROOT / "benchmarks" / "cycle_time.py")
cycle_time = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cycle_time)


def test_lines_arcs_and_rapids_by_hand():
    text = "\n".join([
        "G21 G90 G17 G91.1",
        "T1 M6",
        "(op 1: rough [roughing] T1 6 mm flat)",
        "G0 X0 Y0 Z5",
        "G0 Z1",                       # 4 mm rapid
        "G1 Z0 F100",                  # 1 mm at 100
        "G1 X10 F1000",                # 10 mm at 1000
        "G2 X20 Y0 I5 J0",             # half circle r5, clockwise over the top: 5 pi
        "G3 X20 Y0 Z-1 I-5 J0",        # full helix turn r5, 1 mm down
        "G28 G91 Z0.",                 # machine home: not counted
        "G90",
        "T2 M6",
        "(op 2: finish [finishing] T2 10 mm flat)",
        "G0 X20 Y10 Z5",               # from (20, 0, -1): hypot(10, 6)
    ])
    out = cycle_time.count_program(text, rapid_feed=5000.0)
    rough, finish = out["ops"]
    assert (rough["kind"], rough["tool"], finish["tool"]) == ("roughing", 1, 2)
    helix = math.hypot(2 * math.pi * 5, 1.0)
    assert rough["cut_mm"] == pytest.approx(1 + 10 + 5 * math.pi + helix)
    assert rough["minutes"] == pytest.approx(4 / 5000 + 1 / 100 + (10 + 5 * math.pi + helix) / 1000)
    assert finish["rapid_mm"] == pytest.approx(math.hypot(10, 6))
    assert out["tool_changes"] == 2


def test_a_posted_program_counts_as_cadcam_gcode_reads_it():
    lib = load_tool_library()
    setup, part = make_setup(pocket_block())
    tool = lib.tool(1)
    op = zlevel_roughing(part, setup, tool, lib.cutting_data(tool, setup.material))
    text = post_process(Job("p", setup, (op,)), PostOptions()).text
    moves = parse_gcode(text)
    seg = np.linalg.norm(np.diff(moves.points, axis=0), axis=1)
    ok = np.isfinite(seg)
    rapid = moves.motion[1:] == 0
    out = cycle_time.count_program(text)
    # parse_gcode also follows the G28/G53 moves home the counter leaves out: compare feeds only,
    # and rapids up to those.
    assert out["cut_mm"] == pytest.approx(float(seg[ok & ~rapid].sum()), rel=1e-4)
    assert out["rapid_mm"] <= float(seg[ok & rapid].sum()) + 1e-6
