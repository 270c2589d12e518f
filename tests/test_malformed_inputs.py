"""Property tests: every reader of a user's file, fed a damaged version of a good file, either
reads it or raises the stage's FactoryError naming the file in one line; never another
exception, never unbounded work.

Damage is what happens to real files: a value replaced by one of the wrong type or size, a
key dropped, bytes cut off or flipped.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from cadcam.gcode import parse_gcode
from cadcam.mesh import load_part
from cadcam.sheet import read_setup_sheet
from cadcam.tools import load_tool_library
from factory.core.errors import FactoryError
from robotprog.cell import load_cell, read_cell
from robotprog.orders import read_orders
from tests.cli.hostile import alias_bomb, setup_sheet
from vision.camera import CameraModel

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
SAMPLES = ROOT / "samples"
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])

#: Values of the wrong type or size, including ones whose repr or expansion is huge.
JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20), st.just("x" * 2000), st.lists(st.integers(), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=3), st.just([[1.0] * 3] * 3),
)


def paths_of(doc, prefix=()):
    """Every key path of a parsed YAML/JSON document, leaves and inner nodes."""
    if isinstance(doc, dict):
        items = doc.items()
    elif isinstance(doc, list):
        items = enumerate(doc)
    else:
        return []
    out = []
    for k, v in items:
        out.append(prefix + (k,))
        out.extend(paths_of(v, prefix + (k,)))
    return out


def damage(doc, path, junk, drop: bool):
    doc = copy.deepcopy(doc)
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    if drop and isinstance(parent, dict):
        del parent[path[-1]]
    else:
        parent[path[-1]] = junk
    return doc


def assert_one_line(e: FactoryError, source: str) -> None:
    text = str(e)
    assert text.startswith(source) and "\n" not in text and len(text) < len(source) + 400, text


CELL = yaml.safe_load((FIXTURES / "cell.yaml").read_text())
TOOLS = yaml.safe_load((FIXTURES / "tools.yaml").read_text())
CAMERA = yaml.safe_load((FIXTURES / "camera.yaml").read_text())
SHEET = setup_sheet(SAMPLES / "bracket.stl")


@FAST
@given(path=st.sampled_from(paths_of(CELL)), junk=JUNK, drop=st.booleans())
@example(path=("vise",), junk={"\n": 0}, drop=False)  # a key holding a newline, named in the error
def test_damaged_cell(path, junk, drop):
    try:
        read_cell(damage(CELL, path, junk, drop), "cell.yaml")
    except FactoryError as e:
        assert_one_line(e, "cell.yaml")


@FAST
@given(path=st.sampled_from(paths_of(TOOLS)), junk=JUNK, drop=st.booleans())
@example(path=("machine",), junk={"\n": 0}, drop=False)  # found by hypothesis: the key broke the line
def test_damaged_tool_library(tmp_path, path, junk, drop):
    p = tmp_path / "tools.yaml"
    p.write_text(yaml.safe_dump(damage(TOOLS, path, junk, drop)))
    try:
        load_tool_library(p)
    except FactoryError as e:
        assert_one_line(e, str(p))


@FAST
@given(path=st.sampled_from(paths_of(CAMERA)), junk=JUNK, drop=st.booleans())
@example(path=("distortion_coefficients", "rows"), junk=True, drop=False)  # `make explore` found it: True == 1
def test_damaged_camera(path, junk, drop):
    try:
        CameraModel.from_camera_info_yaml(yaml.safe_dump(damage(CAMERA, path, junk, drop)), source="cam.yaml")
    except FactoryError as e:
        assert_one_line(e, "cam.yaml")


@FAST
@given(path=st.sampled_from(paths_of(SHEET)), junk=JUNK, drop=st.booleans())
def test_damaged_setup_sheet(path, junk, drop):
    try:
        read_setup_sheet(json.loads(json.dumps(damage(SHEET, path, junk, drop), default=str)), "p.setup.json")
    except FactoryError as e:
        assert_one_line(e, "p.setup.json")


ORDER = {"part": "a.stl", "quantity": 2, "material": "steel", "priority": 1}


@FAST
@given(field=st.sampled_from(sorted(ORDER)), junk=JUNK, drop=st.booleans(), fmt=st.sampled_from(["yaml", "csv"]))
def test_damaged_orders(tmp_path, field, junk, drop, fmt):
    order = damage(ORDER, (field,), junk, drop)
    p = tmp_path / f"o.{fmt}"
    if fmt == "yaml":
        p.write_text(yaml.safe_dump({"orders": [order]}))
    else:
        p.write_text(",".join(order) + "\n" + ",".join(str(v).replace(",", ";").replace("\n", " ")
                                                       for v in order.values()) + "\n")
    try:
        read_orders(p)
    except FactoryError as e:
        assert_one_line(e, str(p))


READERS = {"cell": lambda p: load_cell(p, check_robot=False), "orders": read_orders, "tools": load_tool_library,
           "camera": CameraModel.read}


@FAST
@given(text=st.text(max_size=300), where=st.sampled_from(["cell", "orders", "tools", "camera"]))
def test_any_text_as_a_yaml_file(tmp_path, text, where):
    p = tmp_path / ("o.yaml" if where == "orders" else f"{where}.yaml")
    p.write_text(text)
    try:
        READERS[where](p)
    except FactoryError as e:
        assert_one_line(e, str(p))


@pytest.mark.parametrize("where", ["cell", "orders", "tools", "camera"])
def test_alias_bomb_anywhere_is_refused_at_once(tmp_path, where):
    p = tmp_path / ("o.yaml" if where == "orders" else f"{where}.yaml")
    p.write_text("orders: " + alias_bomb() + "\n" if where == "orders" else "name: " + alias_bomb() + "\n")
    with pytest.raises(FactoryError, match="alias") as e:
        READERS[where](p)
    assert_one_line(e.value, str(p))


GCODE_WORDS = st.sampled_from(["G0", "G1", "G2", "G3", "G17", "G20", "G21", "G43", "G54", "G90", "G91", "M3", "M5",
                               "M6", "M2", "T1", "T99", "S1000", "F300", "F-1", "X1e300", "Y-5", "Z", "I0", "J0",
                               "R5", "H1", "P1", "(", ")", "%", "/", "N10", "Q", "G38.2", "X0.5", "Y1e-300"])


@FAST
@given(lines=st.lists(st.lists(GCODE_WORDS, max_size=6).map(" ".join), max_size=40))
def test_any_gcode_program(lines):
    try:
        moves = parse_gcode("\n".join(lines), source="p.ngc")
    except FactoryError as e:
        assert_one_line(e, "p.ngc")
    else:
        assert moves.source == "p.ngc" and len(moves.points) <= 1 + 40 * 6 * 4096


@FAST
@given(data=st.binary(max_size=400), ext=st.sampled_from([".stl", ".obj", ".ply", ".3mf", ".step"]))
def test_any_bytes_as_a_mesh(tmp_path, data, ext):
    p = tmp_path / f"part{ext}"
    p.write_bytes(data)
    try:
        load_part(p)
    except FactoryError as e:
        assert_one_line(e, str(p))


@FAST
@given(n=st.integers(1, 60), scale=st.sampled_from([1e-3, 1.0, 30.0, 1e4]), seed=st.integers(0, 10**6))
def test_random_triangles_as_an_stl(tmp_path, n, scale, seed):
    rng = np.random.default_rng(seed)
    tris = (rng.uniform(0, scale, (n, 3, 3))).astype("<f4")
    rec = np.zeros(n, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tris
    p = tmp_path / "soup.stl"
    p.write_bytes(b"\0" * 80 + np.uint32(n).tobytes() + rec.tobytes())
    with pytest.raises(FactoryError) as e:  # random triangles never make a solid
        load_part(p)
    assert_one_line(e.value, str(p))
