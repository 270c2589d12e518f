"""The programs' consumers in tests: lark grammars for URScript and KRL (tests/robotprog/grammars),
rapidchecker for RAPID."""

from __future__ import annotations

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


def rapid_errors(text: str) -> list[str]:
    """rapidchecker's findings for a RAPID module (it prints them and exits 0, so tests read them here).

    rapidchecker takes 20-40 s on a tending program, and its findings depend on the text alone (it resets
    its indent count and pyparsing its packrat cache at every parse): a text already checked in the test run
    (the bracket's ABB program, in two tests of test_programs) is read from the run's record
    (:func:`tests.shared.once`, keyed by the text's digest), not checked again."""
    import hashlib

    from rapidchecker.cli import check_file

    from tests import shared

    def check() -> list[str]:
        return [str(e) for e in check_file(text)]

    if shared.FOLDER is None:  # outside a pytest session
        return check()
    return shared.once("rapidchecker", hashlib.sha256(text.encode()).hexdigest()[:20], check)
