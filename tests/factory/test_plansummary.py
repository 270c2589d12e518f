"""A catalog's plan summaries are checked for shape before anything reads them."""

from __future__ import annotations

import copy
import json
import logging

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from factory.catalog import find_entry
from factory.plansummary import summary_problem

KEY = "k" * 64


def summary(folder) -> dict:
    outputs = {n: str(folder / f"p.{n}") for n in ("program", "setup_sheet", "mcap")}
    for p in outputs.values():
        (folder / p).write_text("x")
    return {"part": "p.stl", "catalog": {"key": KEY, "mesh_sha256": "m" * 64}, "outputs": outputs,
            "verify": {"ok": True}}


def test_a_whole_summary_is_found(tmp_path):
    doc = summary(tmp_path)
    assert summary_problem(doc) is None
    (tmp_path / "p.plan.json").write_text(json.dumps(doc))
    assert find_entry(tmp_path, KEY).output("program") == tmp_path / "p.program"


JUNK = st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=5), st.lists(st.integers(), max_size=2),
                 st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))
PATHS = [("part",), ("catalog",), ("catalog", "key"), ("catalog", "mesh_sha256"), ("outputs",),
         ("outputs", "program"), ("outputs", "mcap"), ("verify",), ("verify", "ok")]


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(PATHS), delete=st.booleans(), junk=JUNK)
def test_a_damaged_summary_is_ignored_with_a_warning_never_a_traceback(tmp_path, caplog, where, delete, junk):
    doc = copy.deepcopy(summary(tmp_path))
    parent = doc
    for k in where[:-1]:
        parent = parent[k]
    if delete:
        parent.pop(where[-1])
    else:
        parent[where[-1]] = junk
    (tmp_path / "p.plan.json").write_text(json.dumps(doc))
    problem = summary_problem(doc)
    with caplog.at_level(logging.WARNING):
        entry = find_entry(tmp_path, KEY)
    if problem is None:  # the junk fit its type (verify deleted, another key, a path that does not exist)
        assert entry is None or entry.summary == doc
    else:
        assert entry is None and problem in caplog.text


def test_not_an_object(tmp_path):
    assert summary_problem([1, 2]) == "not a JSON object"
    assert summary_problem({"part": "p", "catalog": {"key": "k", "mesh_sha256": "m"}, "outputs": {}}) \
        == "'outputs' lacks program, setup_sheet, mcap"
