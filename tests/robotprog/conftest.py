"""The default cell and its collision world, built once per test session; tending plans, made once per
test run whichever module and worker asks first (:mod:`tests.shared`)."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import pytest

from factory.core.resources import FIXTURES
from robotprog.cell import load_cell
from robotprog.collision import collision_world
from robotprog.tending import PartBox, TendingPlan, plan_tending
from tests.shared import content, key_of, once


@pytest.fixture(scope="session")
def cell():
    return load_cell(FIXTURES / "cell.yaml")


@pytest.fixture(scope="session")
def world(cell):
    return collision_world(cell)


def _plan(cell_file: str, sheet: dict[str, Any], part_box: PartBox | None = None, setups: int = 1) -> TendingPlan:
    """``plan_tending`` with its default options in the sample cell ``cell_file`` (in fixtures/), in its
    own collision world; planned once in the run for these inputs, a copy of its own for each caller."""
    box = None if part_box is None else (part_box.low.tolist(), part_box.high.tolist())
    key = key_of(content(FIXTURES / cell_file), json.dumps(sheet, sort_keys=True), box, setups)

    def compute() -> TendingPlan:
        c = load_cell(FIXTURES / cell_file)
        return plan_tending(c, sheet, part_box=part_box, world=collision_world(c), setups=setups)

    return once("tending", key, compute)


@pytest.fixture(scope="session")
def tending() -> Callable[..., TendingPlan]:
    """``tending(cell_file, sheet, part_box=None, setups=1)``: the tending plan of ``sheet``'s stock in
    the sample cell ``cell_file``, with the default options. Several modules plan the same stock (the
    samples' in the default cell, the flipped bracket): the plan is deterministic, so it is made once in
    the run and each asks for its own copy, asserting on it as on a plan of its own."""
    return _plan
