"""The one mm → m conversion: setup sheet stock box into the vise frame."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.errors import CellError, SetupError
from factory.core.setupsheet import SetupSheet
from robotprog.frames import StockInVise, check_stock_fits, setup_sheet_to_cell


def _sheet(smin, smax, origin="top-front-left", mesh_to_work=None, mesh_scale=1.0) -> dict:
    return {
        "format": "factory.setup/1",
        "units": "mm",
        "work_origin": origin,
        "stock": {"min": list(smin), "max": list(smax), "size": list(np.subtract(smax, smin))},
        "transform_mesh_to_work": (np.eye(4) if mesh_to_work is None else mesh_to_work).tolist(),
        "mesh_scale": mesh_scale,
        "tools": [],
    }


def _apply(t: np.ndarray, p) -> np.ndarray:
    return t[:3, :3] @ np.asarray(p, dtype=float) + t[:3, 3]


def test_top_front_left_stock_sits_centred_on_the_parallels() -> None:
    s = setup_sheet_to_cell(_sheet([0, 0, -40], [100, 60, 0]))
    np.testing.assert_allclose(s.stock_min, [-0.05, -0.03, 0.0])
    np.testing.assert_allclose(s.stock_max, [0.05, 0.03, 0.04])
    np.testing.assert_allclose(s.size, [0.1, 0.06, 0.04])
    # The work origin (top-front-left corner) in the vise frame.
    np.testing.assert_allclose(s.transform_vise_to_work[:3, 3], [-0.05, -0.03, 0.04])
    with pytest.raises(ValueError):
        s.stock_min[0] = 1.0  # read-only


def test_top_centre_origin_gives_the_same_stock_in_the_vise() -> None:
    a = setup_sheet_to_cell(_sheet([0, 0, -40], [100, 60, 0]))
    b = setup_sheet_to_cell(_sheet([-50, -30, -40], [50, 30, 0], origin="top-centre"))
    np.testing.assert_allclose(a.stock_min, b.stock_min)
    np.testing.assert_allclose(b.transform_vise_to_work[:3, 3], [0, 0, 0.04])


@settings(max_examples=50, deadline=None)
@given(
    lo=st.tuples(*[st.floats(-200, 0) for _ in range(3)]),
    size=st.tuples(*[st.floats(1, 300) for _ in range(3)]),
    p=st.tuples(*[st.floats(0, 1) for _ in range(3)]),
)
def test_work_points_map_into_the_stock_box(lo, size, p) -> None:
    """Any point of the stock (work, mm) lands inside the vise-frame stock box at /1000 scale."""
    smin = np.array(lo)
    smax = smin + np.array(size)
    s = setup_sheet_to_cell(_sheet(smin, smax))
    p_work_mm = smin + np.array(p) * (smax - smin)
    p_vise = _apply(s.transform_vise_to_work, p_work_mm / 1000.0)
    assert (p_vise >= s.stock_min - 1e-12).all() and (p_vise <= s.stock_max + 1e-12).all()
    np.testing.assert_allclose(np.linalg.norm(np.diff([s.stock_min, s.stock_max], axis=0)),
                               np.linalg.norm(size) / 1000.0, rtol=1e-12)


def test_mesh_transform_translation_in_metres() -> None:
    t = np.eye(4)
    t[:3, 3] = [2.0, 3.0, -40.0]
    s = setup_sheet_to_cell(_sheet([0, 0, -40], [100, 60, 0], mesh_to_work=t, mesh_scale=25.4))
    np.testing.assert_allclose(s.transform_mesh_to_work[:3, 3], [0.002, 0.003, -0.04])
    assert s.mesh_scale_m == pytest.approx(0.0254)
    # The part's bottom (mesh z = 0) is the stock bottom: z = 0 in the vise.
    vise_to_mesh = s.transform_vise_to_work @ s.transform_mesh_to_work
    assert _apply(vise_to_mesh, [0.0, 0.0, 0.0])[2] == pytest.approx(0.0)


def test_not_a_setup_sheet() -> None:
    with pytest.raises(SetupError, match="not a factory setup sheet"):
        setup_sheet_to_cell({"format": "other"}, source="x.json")


def test_stock_fit_checks() -> None:
    s: StockInVise = setup_sheet_to_cell(_sheet([0, 0, -40], [100, 60, 0]))
    check_stock_fits(s.size, 0.0, 0.16, 0.03, 0.085)
    with pytest.raises(CellError, match="60.0 mm wide does not fit the vise"):
        check_stock_fits(s.size, 0.0, 0.05, 0.03, 0.085)
    with pytest.raises(CellError, match="exceeds the gripper opening"):
        check_stock_fits(s.size, 0.0, 0.16, 0.03, 0.05)
    with pytest.raises(CellError, match="does not stand above"):
        check_stock_fits(s.size, 0.0, 0.16, 0.05, 0.085)


def test_a_typed_sheet_crosses_as_its_json_does() -> None:
    """The pipeline hands the robot a SetupSheet, the robot's tests and ``factory robot`` its JSON: same stock."""
    doc = _sheet([0, 0, -40], [100, 60, 0], mesh_scale=25.4)
    a, b = setup_sheet_to_cell(doc), setup_sheet_to_cell(SetupSheet.from_json(doc))
    for name in ("transform_vise_to_work", "stock_min", "stock_max", "size", "transform_mesh_to_work"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.mesh_scale_m == b.mesh_scale_m
