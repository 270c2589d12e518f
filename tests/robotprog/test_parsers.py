"""Every post checked by its consumer: URScript and KRL by the lark grammars, RAPID by rapidchecker,
for the golden programs and for random step lists."""

from __future__ import annotations

import math
from pathlib import Path

import lark
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robotprog.krl import krl_program
from robotprog.rapid import rapid_module
from robotprog.urscript import Branch, Comment, MoveJ, MoveL, ServoJ, SetOutputs, Wait, WaitInput, urscript_program
from tests.robotprog.parsers import parse_krl, parse_urscript, rapid_errors, rapid_shape

GOLDEN = Path(__file__).parent / "golden"
AXIS_SPEED = np.full(6, 3.15)


def test_golden_programs_parse():
    parse_urscript((GOLDEN / "pick_blank.script").read_text())
    parse_krl((GOLDEN / "tending.src").read_text(), (GOLDEN / "tending.dat").read_text())
    assert rapid_errors((GOLDEN / "tending.mod").read_text()) == []


def test_the_checkers_reject_broken_programs():
    script = (GOLDEN / "pick_blank.script").read_text()
    with pytest.raises(lark.exceptions.LarkError):
        parse_urscript(script.replace("movej([", "movej(["[:-1], 1))
    with pytest.raises(lark.exceptions.LarkError):
        parse_urscript(script.replace("\nend", "\n"))
    src, dat = (GOLDEN / "tending.src").read_text(), (GOLDEN / "tending.dat").read_text()
    with pytest.raises(lark.exceptions.LarkError):
        parse_krl(src.replace("PTP XJ1", "PTP"), dat)
    with pytest.raises(ValueError, match="XJ1"):
        parse_krl(src, "\n".join(line for line in dat.splitlines() if "XJ1=" not in line) + "\n")
    mod = (GOLDEN / "tending.mod").read_text()
    assert rapid_errors(mod.replace("tGripper;", "tGripper", 1))
    assert rapid_errors(mod.replace("\\T:=", "\\T=", 1))



@settings(max_examples=10, deadline=None)
@given(st.lists(st.integers(0, 9), min_size=10, max_size=10), st.integers(1, 3))
def test_a_rapid_shape_is_shared_by_other_numbers_and_more_lines_alike(digits, extra):
    """The golden module with every digit replaced (a digit d by digits[d]) and one move repeated has the
    golden's shape (rapid_errors(by_shape=True) gives it the golden's verdict), and rapidchecker itself
    finds nothing in it either."""
    import re

    mod = (GOLDEN / "tending.mod").read_text()
    move = next(line for line in mod.splitlines(keepends=True) if line.strip().startswith("MoveAbsJ"))
    other = re.sub(r"\d", lambda m: str(digits[int(m.group())]), mod.replace(move, move * (1 + extra), 1))
    assert rapid_shape(other) == rapid_shape(mod)
    assert rapid_errors(other) == []


def test_a_rapid_shape_differs_wherever_rapidchecker_could_read_otherwise():
    """What rapidchecker refuses, or could, changes the shape: a token lost or changed, a statement's indent,
    a trailing space, the final newline, an empty line more, a sign that is an operator, a digit starting a
    name, a '#' of the text's own, a continued statement's line repeated."""
    mod = (GOLDEN / "tending.mod").read_text()
    move = next(line for line in mod.splitlines(keepends=True) if line.strip().startswith("MoveAbsJ"))
    broken = [mod.replace("tGripper;", "tGripper", 1), mod.replace("\\T:=", "\\T=", 1),
              mod.replace("  ENDPROC", "ENDPROC"), mod.replace(move, " " + move, 1), mod.replace(move, move[:-1] + " \n", 1),
              mod.rstrip("\n"), mod.replace("\n\n", "\n\n\n", 1), mod.replace(move, move.replace(", ", ", -", 1), 1),
              mod.replace("MoveAbsJ j", "MoveAbsJ 1j", 1), mod.replace("MoveAbsJ j", "MoveAbsJ #", 1),
              mod.replace(move, move.replace(", ", ",\n    ", 1), 1)]
    split = move.replace(", ", ",\n    ", 1)
    broken.append(mod.replace(move, split + split.split("\n", 1)[1], 1))
    assert all(b != mod for b in broken)
    assert len({rapid_shape(b) for b in broken} | {rapid_shape(mod)}) == len(broken) + 1

_angle = st.floats(-3.1, 3.1, allow_nan=False)
_q = st.tuples(*[_angle] * 6)


def _pose(xyz, rotvec) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    t[:3, 3] = xyz
    return t


_base = st.one_of(
    st.builds(MoveJ, _q, st.floats(0.1, 5.0), st.floats(0.1, 3.0), st.sampled_from([0.0, 0.005, 0.02]),
              st.sampled_from([0.0, 0.1, 0.25])),
    st.builds(lambda xyz, rv, v, r: MoveL.to(_pose(xyz, rv), 0.5, v, r),
              st.tuples(*[st.floats(-1.0, 1.0)] * 3), st.tuples(*[st.floats(-3.0, 3.0)] * 3),
              st.floats(0.01, 1.0), st.sampled_from([0.0, 0.01])),
    st.builds(lambda n, level, s: SetOutputs(((n, level),), s, "gripper"), st.integers(0, 7), st.booleans(),
              st.sampled_from([0.0, 0.4])),
    st.builds(Wait, st.floats(0.01, 10.0)),
    st.builds(WaitInput, st.integers(0, 7), st.booleans(), st.sampled_from(["", "machine: door open"])),
    st.builds(Comment, st.text("abc: ()-,.", max_size=20)),
)
#: and a branch on an input (the verdict: out-tray or reject bin), its ways any of the above
_step = st.one_of(_base, st.builds(lambda n, level, a, b: Branch(n, level, tuple(a), tuple(b), "verdict"),
                                   st.integers(0, 7), st.booleans(), st.lists(_base, max_size=4),
                                   st.lists(_base, max_size=4)))


@settings(max_examples=60, deadline=None)
@given(_q, st.lists(_step, max_size=12))
def test_random_urscript_and_krl_parse(start, steps):
    steps = [MoveJ(start, 1.0, 1.0), *steps]
    parse_urscript(urscript_program(steps, name="prop"))
    src, dat = krl_program(steps, name="prop", axis_speed=AXIS_SPEED)
    parse_krl(src, dat)


# rapidchecker (pyparsing) takes about 1 s per module: fewer examples.
@settings(max_examples=8, deadline=None)
@given(_q, st.lists(_step, max_size=12))
def test_random_rapid_passes_rapidchecker(start, steps):
    assert rapid_errors(rapid_module([MoveJ(start, 1.0, 1.0), *steps], name="prop")) == []


def test_a_branch_is_checked_by_the_consumers():
    """A branch's ways are written inside IF / if blocks the checkers read; an IF without its
    ENDIF is refused (rapidchecker reports it: it exits 0 on errors, so the test reads them)."""
    q = (0.1,) * 6
    steps = [MoveJ(q, 1.0, 1.0), Branch(2, True, (MoveJ((0.2,) * 6, 1.0, 1.0, 0.0, 0.5),), (Wait(1.0),), "verdict")]
    text = rapid_module(steps, name="branch")
    assert "IF DInput(di2) = 1 THEN" in text and rapid_errors(text) == []
    assert rapid_errors(text.replace("    ENDIF\n", "")) != []
    src, dat = krl_program(steps, name="branch", axis_speed=AXIS_SPEED)
    parse_krl(src, dat)
    with pytest.raises(lark.exceptions.LarkError):
        parse_krl(src.replace("  ENDIF\n", ""), dat)
    ur = urscript_program(steps)
    parse_urscript(ur)
    assert "if get_standard_digital_in(2) == True:" in ur
    with pytest.raises(lark.exceptions.LarkError):
        parse_urscript(ur.replace("  else:\n", "  else\n"))


def test_an_empty_comment_leaves_no_trailing_space():
    steps = [MoveJ((0.0,) * 6, 1.0, 1.0), Comment(""), Comment("  "), SetOutputs(((0, True),), 0.0, " ")]
    for text in (urscript_program(steps), rapid_module(steps), *krl_program(steps)):
        assert all(line == line.rstrip() for line in text.splitlines())


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 600), st.floats(0.002, 0.02))
def test_servoj_streams_parse(n, t):
    targets = np.sin(np.linspace(0, math.pi, n))[:, None] * np.arange(6)
    tree = parse_urscript(urscript_program([ServoJ(targets, t)], name="stream"))
    calls = [c for c in tree.find_data("call") if c.children[0] == "servoj"]
    assert len(calls) == math.ceil(n / 250)
