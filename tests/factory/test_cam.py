"""The CAM half of the pipeline: the cell's vise crossing into CAM's millimetres."""

from __future__ import annotations

import pytest

from factory.cam import vise_jaws
from factory.core.resources import FIXTURES
from robotprog.cell import load_cell


def test_vise_crosses_into_millimetres() -> None:
    vise = load_cell(FIXTURES / "cell.yaml", check_robot=False).vise
    jaws = vise_jaws(vise)
    # a 6-inch vise: 1.75 in jaws, 8.8 in opening, parallels leaving the same 5 mm grip
    assert jaws.jaw_height == pytest.approx(44.5) and jaws.parallels_height == pytest.approx(39.5)
    assert jaws.grip_depth == pytest.approx(vise.grip_depth * 1000.0)
    assert (jaws.opening_min, jaws.opening_max) == pytest.approx((0.0, 223.5))
    assert jaws.jaw_width == pytest.approx(152.4) and jaws.jaw_thickness == pytest.approx(20.0)
    assert jaws.soft_jaws.kind == "parallels" and jaws.soft_jaws.depth == pytest.approx(5.0)
