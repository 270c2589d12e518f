"""The programs' consumers in tests: lark grammars for URScript and KRL (tests/robotprog/grammars),
rapidchecker for RAPID."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

from lark import Lark, Tree

GRAMMARS = Path(__file__).parent / "grammars"


@cache
def _parser(name: str) -> Lark:
    return Lark((GRAMMARS / f"{name}.lark").read_text(), parser="lalr", lexer="contextual")


def parse_urscript(text: str) -> Tree:
    """Parse tree of a URScript program; raises lark's error on text outside the grammar."""
    return _parser("urscript").parse(text)


def parse_krl(src: str, dat: str) -> tuple[Tree, Tree]:
    """Parse trees of a KRL ``.src`` and its ``.dat``; every PTP / LIN target must be declared in the ``.dat``."""
    s, d = _parser("krl_src").parse(src), _parser("krl_dat").parse(dat)
    used = {str(t.children[0]) for t in s.iter_subtrees() if t.data in ("ptp", "lin")}
    declared = {str(t.children[1]) for t in d.iter_subtrees() if t.data == "decl"}
    if used - declared:
        raise ValueError(f"KRL points moved to but not declared in the .dat: {sorted(used - declared)}")
    return s, d


#: A number as rapidchecker reads it (pyparsing's ``number``: any digits, a fraction, an exponent), standing
#: alone: not inside a name (``j12``), not part of ``1.2.3``; a minus sign only where it can be no operator
#: (after ``[``, ``,`` or ``(``), where ``-5`` and ``5`` are both one literal.
_NUMBER = re.compile(r"(?:(?<=[\[,(])-|(?<![\w.\-]))\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.])")
#: The digits of a name (``j12``, ``vLine455_9``, ``abb_irb1200``).
_NAME_DIGITS = re.compile(r"(?<=[A-Za-z_])\d+")


#: A line after which a statement begins: a block opened (``IF ... THEN``, ``ELSE``, ``WHILE ... DO``, ``PROC``)
#: or closed (``ENDIF``, ``ENDPROC``) alone on its line.
_OPENS = re.compile(r"(\bTHEN|^\s*ELSE|\bDO|^\s*(PROC|FUNC|TRAP|MODULE)\b.*|^\s*END[A-Z]+)$")


def _ends_a_statement(line: str) -> bool:
    """Whether a line that begins a statement ends one: its last ``;`` outside any string (the double quotes
    pair up, no single ones: rapidchecker's strings hold no quote) and no comment (``!``)."""
    return line.endswith(";") and "!" not in line and "'" not in line and line.count('"') % 2 == 0


def rapid_shape(text: str) -> str:
    """A RAPID module's text with what rapidchecker's verdict cannot depend on taken out: every number is
    ``#``, every run of digits in a name is ``#``, and a run of lines of one shape, each whole statements or
    declarations, is one line. A text with ``#`` of its own is its own shape.

    rapidchecker's grammar reads a number as a number whatever its digits (its parse action converts it;
    ``1e400`` is ``inf``, no error), and a name as a name whatever its digits; declarations and statements sit
    in its ``ZeroOrMore`` sections, so where one whole line of them parses, two do. A line is merged only when
    it is whole: it begins a statement (the code line before it ends one or opens a block) and ends one
    (:func:`_ends_a_statement`). Its indentation check reads the column where a
    line's first statement starts, after the leading spaces, kept as they are (a statement later in the line
    is past that column whatever the numbers before it); its whitespace checks read empty lines (never merged),
    trailing spaces (kept) and the final newline (kept: the text is split at ``\\n`` only). So two modules of
    one shape get the same verdict."""
    if "#" in text:
        return "text\n" + text
    out: list[str] = []
    begins = True  # the next line begins a statement
    for line in text.split("\n"):
        shape = _NAME_DIGITS.sub("#", _NUMBER.sub("#", line))
        whole = begins and _ends_a_statement(shape)
        if not (whole and out and shape == out[-1]):
            out.append(shape)
        code = line.strip()
        if code and not code.startswith("!"):
            begins = (begins and _ends_a_statement(code)) or bool(_OPENS.search(line))
    return "shape\n" + "\n".join(out)


def rapid_errors(text: str, *, by_shape: bool = False) -> list[str]:
    """rapidchecker's findings for a RAPID module (it prints them and exits 0, so tests read them here).

    rapidchecker takes 7-15 s on a tending program, and its findings depend on the text alone (it resets
    its indent count and pyparsing its packrat cache at every parse): a text already checked in the test run
    (the bracket's ABB program, in two tests of test_programs) is read from the run's record
    (:func:`tests.shared.once`, keyed by the text's digest), not checked again. With ``by_shape``, a text of
    the :func:`rapid_shape` of one rapidchecker found nothing in gets that verdict (the ABB cell's programs
    for other stock differ from the bracket's in their numbers and in how many targets they declare and
    move to); findings are always this text's own."""
    import hashlib

    from rapidchecker.cli import check_file

    from tests import shared

    def digest(s: str) -> str:
        return hashlib.sha256(s.encode()).hexdigest()[:20]

    def check() -> list[str]:
        return [str(e) for e in check_file(text)]

    if shared.FOLDER is None:  # outside a pytest session
        return check()
    if by_shape and not shared.once("rapidchecker-shape", digest(rapid_shape(text)), lambda: rapid_errors(text)):
        return []
    return shared.once("rapidchecker", digest(text), check)
