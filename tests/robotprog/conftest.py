"""The default cell and its collision world, built once per test session."""

from __future__ import annotations

import pytest

from factory.core.resources import FIXTURES
from robotprog.cell import load_cell
from robotprog.collision import collision_world


@pytest.fixture(scope="session")
def cell():
    return load_cell(FIXTURES / "cell.yaml")


@pytest.fixture(scope="session")
def world(cell):
    return collision_world(cell)
