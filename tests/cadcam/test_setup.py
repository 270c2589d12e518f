"""Setup: the stock holds the part with the asked-for margins, the origin is where it is named."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from cadcam.mesh import load_part
from cadcam.model import FixtureBox, Setup, ViseJaws
from cadcam.setup import BREAKTHROUGH_MM, MIN_HOLDING_LEFT_MM, StockMargins, default_holding, make_setup, orient_setup
from factory.core.errors import CellError, SetupError

SAMPLES = Path(__file__).resolve().parents[2] / "samples"
EPS = 1e-9
#: The default cell's vise [mm]: jaws 40 mm over the bed, parallels 35: 5 mm grip.
JAWS = ViseJaws(jaw_height=40.0, jaw_width=150.0, jaw_thickness=20.0, parallels_height=35.0, opening_min=0.0,
                opening_max=160.0)


def box(extents, at) -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=extents)
    b.apply_translation(np.asarray(at, float) + np.asarray(extents, float) / 2)
    return b


def test_default_stock_is_part_plus_margins_with_origin_top_front_left():
    part = box((80, 50, 15), at=(-40, 7, 3))  # arbitrary placement in the file
    setup, work = make_setup(part)
    # Without a vise the holding allowance is 3 mm left under the part plus the 0.5 mm breakthrough.
    np.testing.assert_allclose(setup.stock_min, [0, 0, -19.5])
    np.testing.assert_allclose(setup.stock_max, [84, 54, 0])
    # Part sits 3.5 mm above the stock bottom, 2 mm in from the sides, 1 mm below the top.
    np.testing.assert_allclose(work.bounds, [[2, 2, -16], [82, 52, -1]])
    assert setup.floor_z == pytest.approx(-16.5) and setup.jaws is None
    assert setup.safe_z == pytest.approx(5.0)
    assert setup.origin == "top-front-left" and setup.material == "aluminium"
    # The input mesh is untouched; the transform maps it onto the returned mesh.
    np.testing.assert_allclose(part.bounds, [[-40, 7, 3], [40, 57, 18]])
    np.testing.assert_allclose(trimesh.transform_points(part.vertices, setup.transform_mesh_to_work), work.vertices)
    assert np.allclose(setup.transform_mesh_to_work[:3, :3], np.eye(3))


def test_top_centre_origin():
    part = box((60, 40, 10), at=(100, 100, 100))
    setup, work = make_setup(part, origin="top-centre", margins=StockMargins(sides=5, top=0.5, bottom=3.5),
                             safe_height=10)
    np.testing.assert_allclose(setup.stock_min, [-35, -25, -14])
    np.testing.assert_allclose(setup.stock_max, [35, 25, 0])
    np.testing.assert_allclose(work.bounds, [[-30, -20, -10.5], [30, 20, -0.5]])
    assert setup.safe_z == pytest.approx(10)


def test_explicit_stock_centres_the_part_holding_above_the_bottom():
    part = box((80, 50, 15), at=(0, 0, 0))
    setup, work = make_setup(part, stock_size=(100, 60, 25), margins=StockMargins(bottom=4))
    np.testing.assert_allclose(setup.stock_size, [100, 60, 25])
    np.testing.assert_allclose(work.bounds, [[10, 5, -21], [90, 55, -6]])
    assert setup.floor_z == pytest.approx(-21.5)


def test_explicit_stock_exactly_the_part_size_plus_holding_fits():
    part = box((80, 50, 15), at=(1, 2, 3))
    setup, work = make_setup(part, stock_size=(80, 50, 18.5))
    np.testing.assert_allclose(work.bounds, [[0, 0, -15], [80, 50, 0]], atol=1e-9)


def test_default_stock_with_a_vise_stands_above_the_jaws():
    part = box((80, 50, 15), at=(0, 0, 0))
    setup, work = make_setup(part, jaws=JAWS)
    # 5 mm grip + 0.5 mm breakthrough + 1 mm clearance under the part
    assert default_holding(JAWS) == pytest.approx(6.5)
    assert work.bounds[0][2] - setup.stock_min[2] == pytest.approx(6.5)
    assert setup.floor_z == pytest.approx(work.bounds[0][2] - BREAKTHROUGH_MM)
    names = [b.name for b in setup.jaws]
    assert names == ["front jaw", "back jaw", "parallels"]
    front, back, par = setup.jaws
    # the jaws touch the stock's Y faces and reach 5 mm up it; the parallels fill the gap below
    assert front.hi[1] == pytest.approx(setup.stock_min[1]) and back.lo[1] == pytest.approx(setup.stock_max[1])
    assert front.hi[2] == pytest.approx(setup.stock_min[2] + 5) and par.hi[2] == pytest.approx(setup.stock_min[2])
    assert setup.floor_z - front.hi[2] >= 1.0 - EPS
    again = Setup.from_dict(setup.to_dict())
    assert again.floor_z == setup.floor_z and [b.to_dict() for b in again.jaws] == [b.to_dict() for b in setup.jaws]


def test_old_setup_dicts_read_with_floor_at_stock_bottom_and_no_jaws():
    d = make_setup(box((10, 10, 10), (0, 0, 0)))[0].to_dict()
    del d["floor_z"], d["jaws"]
    old = Setup.from_dict(d)
    assert old.floor_z == old.stock_min[2] and old.jaws is None


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"margins": StockMargins(bottom=3.4)}, r"holding allowance 3.4 mm leaves 2.9 mm under the part"),
        ({"margins": StockMargins(bottom=6), "jaws": JAWS},
         r"holding allowance 6 mm is below the jaws' grip depth 5 mm .* give --holding 6.5 or more"),
        ({"stock_size": (100, 170, 30), "jaws": JAWS}, r"stock 170.0 mm wide \(Y\) does not fit the vise opening 0..160 mm"),
        ({"stock_size": (100, 60, 20), "jaws": JAWS}, r"part 15.000 mm tall with 6.5 mm holding allowance under it "
                                                        r"needs stock 21.500 mm tall, stock is 20.000 mm"),
    ],
)
def test_stock_the_vise_cannot_hold_is_one_line_with_figures(kwargs, words):
    with pytest.raises(SetupError, match=words) as info:
        make_setup(box((80, 50, 15), (0, 0, 0)), source="p.stl", **kwargs)
    assert "\n" not in str(info.value) and "p.stl" in str(info.value)


@pytest.mark.parametrize("stock, axis", [((79, 60, 20), "X"), ((100, 49.9, 20), "Y"), ((100, 60, 14), "Z")])
def test_stock_too_small_names_axis_and_sizes(stock, axis):
    part = box((80, 50, 15), at=(0, 0, 0))
    with pytest.raises(SetupError) as info:
        make_setup(part, stock_size=stock, source="bracket.stl")
    msg = str(info.value)
    assert f"in {axis}" in msg and "bracket.stl" in msg
    part_size = {"X": 80, "Y": 50, "Z": 15}[axis]
    stock_size = stock["XYZ".index(axis)]
    assert f"{part_size:.3f}" in msg and f"{stock_size:.3f}" in msg


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"margins": StockMargins(sides=-1)}, "sides"),
        ({"margins": StockMargins(top=-0.1)}, "top"),
        ({"stock_size": (100, 0, 20)}, "stock size"),
        ({"stock_size": (100, 60)}, "stock size"),
        ({"stock_size": (math.inf, 60, 20)}, "stock size"),
        ({"stock_size": (100, 60, 2001)}, "stock Z of 2001 mm is longer than 2000 mm"),
        ({"stock_size": (1500, 800, 30)}, "stock top 1500 x 800 mm is larger than"),
        ({"safe_height": 0}, "safe height"),
        ({"origin": "bottom-left"}, "origin"),
    ],
)
def test_bad_setup_arguments(kwargs, words):
    with pytest.raises(SetupError, match=words):
        make_setup(box((10, 10, 10), (0, 0, 0)), **kwargs)


def test_sample_part_setup_round_trips_through_dict():
    part = load_part(SAMPLES / "bracket.stl")
    setup, work = make_setup(part.mesh, mesh_scale=part.scale, material="steel")
    again = Setup.from_dict(setup.to_dict())
    np.testing.assert_array_equal(again.transform_mesh_to_work, setup.transform_mesh_to_work)
    assert again.material == "steel" and again.mesh_scale == 1.0
    assert work.is_watertight and work.volume == pytest.approx(part.mesh.volume)


@settings(max_examples=60, deadline=None)
@given(
    extents=st.tuples(*[st.floats(1, 500) for _ in range(3)]),
    at=st.tuples(*[st.floats(-1000, 1000) for _ in range(3)]),
    sides=st.floats(0, 20),
    top=st.floats(0, 10),
    holding=st.floats(3.5, 30),
    origin=st.sampled_from(["top-front-left", "top-centre"]),
)
def test_part_always_inside_stock_with_top_at_zero(extents, at, sides, top, holding, origin):
    part = box(extents, at)
    setup, work = make_setup(part, margins=StockMargins(sides=sides, top=top, bottom=holding), origin=origin)
    lo, hi = work.bounds
    tol = 1e-9 * (1 + np.abs(at).max() + max(extents))
    assert setup.stock_max[2] == 0
    assert np.all(lo >= setup.stock_min - tol) and np.all(hi <= setup.stock_max + tol)
    # The margins are exactly what was asked for, and the part sits on the stock bottom.
    np.testing.assert_allclose(lo[:2] - setup.stock_min[:2], [sides, sides], atol=1e-6)
    np.testing.assert_allclose(setup.stock_max[:2] - hi[:2], [sides, sides], atol=1e-6)
    assert setup.stock_max[2] - hi[2] == pytest.approx(top, abs=1e-6)
    assert lo[2] - setup.stock_min[2] == pytest.approx(holding, abs=1e-6)
    # op 1 never feeds below the part bottom by more than the breakthrough, and leaves >= 3 mm
    assert lo[2] - setup.floor_z == pytest.approx(BREAKTHROUGH_MM, abs=1e-6)
    assert setup.floor_z - setup.stock_min[2] >= MIN_HOLDING_LEFT_MM - 1e-6
    if origin == "top-front-left":
        np.testing.assert_allclose(setup.stock_min[:2], 0)
    else:
        np.testing.assert_allclose(setup.stock_min[:2] + setup.stock_max[:2], 0, atol=1e-9)
    assert setup.safe_z > setup.stock_max[2]


def test_a_part_too_long_for_the_jaws_is_turned_about_z_and_the_transform_says_so():
    """50 x 180 mm: stock 184 mm across the jaws (over their 160 mm) as given, 54 mm turned."""
    part = box((50, 180, 16), at=(5, -20, 2))
    with pytest.raises(SetupError, match=r"stock 184.0 mm wide \(Y\) does not fit the vise opening 0..160 mm"):
        make_setup(part, jaws=JAWS)
    setup, work = orient_setup(part, jaws=JAWS, source="long.stl")
    np.testing.assert_allclose(setup.stock_size, [184, 54, 16 + 1 + default_holding(JAWS)])
    np.testing.assert_allclose(work.bounds[:, :2], [[2, 2], [182, 52]])
    # The setup's transform carries the mesh file to exactly the placed part (verify, sheet and robot read it).
    moved = part.copy()
    moved.apply_transform(setup.transform_mesh_to_work)
    np.testing.assert_allclose(moved.vertices, work.vertices, atol=1e-9)
    np.testing.assert_allclose(setup.transform_mesh_to_work[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    # The jaws clamp the turned stock across its 54 mm.
    front, back = setup.jaws[0], setup.jaws[1]
    assert front.hi[1] == pytest.approx(0) and back.lo[1] == pytest.approx(54)
    # An explicit stock turns with the part.
    given, _ = orient_setup(part, jaws=JAWS, stock_size=(60, 190, 30))
    np.testing.assert_allclose(given.stock_size, [190, 60, 30])


def test_a_part_that_fits_as_given_is_placed_exactly_as_before():
    for name, kwargs in itertools.product(("bracket", "plate_bosses", "stepped_wall", "dome_mould"),
                                          ({}, {"jaws": JAWS}, {"jaws": JAWS, "origin": "top-centre"})):
        part = load_part(SAMPLES / f"{name}.stl")
        before, work_before = make_setup(part.mesh, mesh_scale=part.scale, **kwargs)
        after, work_after = orient_setup(part.mesh, mesh_scale=part.scale, fits=lambda s, part: None, **kwargs)
        assert after.to_dict() == before.to_dict()
        assert np.array_equal(work_after.vertices, work_before.vertices)


def test_the_gripper_can_ask_for_the_turn_too():
    """100 x 150 mm fits the vise as given (154 mm) but not a gripper opening 120 mm: turned, 104 mm."""
    def gripper(setup: Setup, part: object) -> None:
        if setup.stock_size[1] > 120:
            raise CellError(f"stock {setup.stock_size[1]:.1f} mm wide exceeds the gripper opening 120.0 mm",
                            source="gripper.opening.max")

    setup, _ = orient_setup(box((100, 150, 10), (0, 0, 0)), jaws=JAWS, fits=gripper)
    np.testing.assert_allclose(setup.stock_size[:2], [154, 104])


def test_what_fits_no_orientation_is_refused_in_one_line_with_both_figures():
    with pytest.raises(SetupError) as info:
        orient_setup(box((170, 200, 10), (0, 0, 0)), jaws=JAWS, source="plate.stl")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("plate.stl: fits the cell in no orientation: ")
    assert "as given, stock 204.0 mm wide (Y) does not fit the vise opening 0..160 mm" in msg
    assert "turned 90 degrees about Z, stock 174.0 mm wide (Y) does not fit the vise opening 0..160 mm" in msg
    # What turning cannot change is said once, as it is.
    with pytest.raises(SetupError) as info:
        orient_setup(box((80, 50, 15), (0, 0, 0)), margins=StockMargins(bottom=3.4), source="p.stl")
    assert str(info.value).startswith("p.stl: holding allowance 3.4 mm leaves 2.9 mm")


def test_the_margin_across_the_jaws_may_differ_from_the_sides():
    part = box((80, 50, 15), (0, 0, 0))
    setup, work = make_setup(part, margins=StockMargins(sides=2, across=0.0, bottom=7))
    assert setup.stock_size == pytest.approx([84.0, 50.0, 15 + 1 + 7])
    # the part still centred across the jaws: flush with the stock's Y faces
    lo, hi = np.asarray(work.bounds)
    assert lo[1] == pytest.approx(setup.stock_min[1]) and hi[1] == pytest.approx(setup.stock_max[1])
    with pytest.raises(SetupError, match="stock margin across must be >= 0 mm"):
        make_setup(part, margins=StockMargins(across=-0.5, bottom=7))
