"""Hostile inputs through the real ``factory`` command, in a subprocess capped at 1.5 GB of
address space and 30 s of processor time: each ends in one ``error:`` line (exit 1), the only line on
stderr (no stage line of ``factory plan`` in a pipe: a quick failure shows none), or a usage error
(exit 2), and writes nothing.

Each run pays the command's start-up (about 2 s of processor time), so this runs one case of
each kind; ``python -m tests.cli.hostile`` runs them all (the issue's list and more).
"""

from __future__ import annotations

import pytest

from tests.cli.hostile import CASES, run_case

#: One case per kind of hostile input; the others differ only in the file they hit.
REPRESENTATIVE = [
    "orders quantity: alias bomb",
    "--stock 2000,2000,31",
    "locate 20000x20000 PNG",
    "triangle soup in a 30 mm cube",
    "damaged STEP",
    "robot -o afile/r.mcap",
    "verify: unknown word",
]


def test_representatives_exist():
    assert set(REPRESENTATIVE) <= {c.name for c in CASES}


@pytest.mark.parametrize("case", [c for c in CASES if c.name in REPRESENTATIVE], ids=lambda c: c.name)
def test_hostile_input_ends_in_one_line_within_bounds(case, tmp_path):
    r = run_case(case, tmp_path)
    assert r["clean"], r
