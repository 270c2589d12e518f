"""Orders files: YAML and CSV read the same orders; every malformed file stops with the line or field named."""

from pathlib import Path

import pytest
from hypothesis import given, settings, strategies as st

from factory.core.errors import SchedulerError
from robotprog.orders import Order, read_orders


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_yaml_and_csv_give_the_same_orders(tmp_path):
    y = _write(tmp_path, "o.yaml", "orders:\n"
               "  - {part: parts/bracket.stl, quantity: 2, material: aluminium, priority: 1}\n"
               "  - {part: /abs/plate.stl, quantity: 1, material: steel}\n")
    c = _write(tmp_path, "o.csv", "part,quantity,material,priority\n"
               "parts/bracket.stl,2,aluminium,1\n\n/abs/plate.stl,1,steel,\n")
    orders = read_orders(y)
    assert orders == read_orders(c)
    assert orders[0] == Order("o1", tmp_path / "parts/bracket.stl", 2, "aluminium", 1)
    assert orders[1].part == Path("/abs/plate.stl") and orders[1].priority == 0


def test_order_is_frozen(tmp_path):
    order = read_orders(_write(tmp_path, "o.csv", "part,quantity,material\na.stl,1,steel\n"))[0]
    with pytest.raises(AttributeError):
        order.quantity = 3


def test_csv_columns_in_any_order(tmp_path):
    orders = read_orders(_write(tmp_path, "o.csv", "material,part,quantity\nsteel,a.stl,3\n"))
    assert orders[0].material == "steel" and orders[0].quantity == 3


@pytest.mark.parametrize("text, where, what", [
    ("part,quantity,material\na.stl,0,steel\n", ":2", "quantity"),
    ("part,quantity,material\na.stl,1,steel\nb.stl,two,steel\n", ":3", "quantity"),
    ("part,quantity,material\n\na.stl,1,\n", ":3", "material"),
    ("part,quantity,material\na.stl,1\n", ":2", "expected 3 fields"),
    ("part,quantity\na.stl,1\n", ":1", "header"),
    ("part,quantity,material,priority\na.stl,1,steel,-1\n", ":2", "priority"),
    ("part,quantity,material\n", "", "no orders"),
    ("", "", "empty"),
])
def test_bad_csv_names_the_line(tmp_path, text, where, what):
    path = _write(tmp_path, "o.csv", text)
    with pytest.raises(SchedulerError) as err:
        read_orders(path)
    assert str(err.value).startswith(f"{path}{where}") and what in str(err.value)


@pytest.mark.parametrize("text, where, what", [
    ("orders:\n  - {part: a.stl, quantity: 1.5, material: steel}\n", "orders[0]", "quantity"),
    ("orders:\n  - {part: a.stl, quantity: 1, material: steel}\n  - {quantity: 1, material: steel}\n",
     "orders[1]", "part: missing"),
    ("orders:\n  - {part: a.stl, quantity: true, material: steel}\n", "orders[0]", "quantity"),
    ("orders:\n  - {part: a.stl, quantity: 1, material: steel, colour: red}\n", "orders[0]", "colour"),
    ("orders:\n  - {part: 3, quantity: 1, material: steel}\n", "orders[0]", "part"),
    ("orders:\n  - a.stl\n", "orders[0]", "mapping"),
    ("orders: {part: a.stl}\n", "", "list"),
    ("jobs: []\n", "", "orders"),
    ("orders: []\n", "", "no orders"),
    ("orders: [\n", ":", "YAML"),
])
def test_bad_yaml_names_the_entry(tmp_path, text, where, what):
    path = _write(tmp_path, "o.yaml", text)
    with pytest.raises(SchedulerError) as err:
        read_orders(path)
    assert str(err.value).startswith(str(path)) and where in str(err.value) and what in str(err.value)


def test_unknown_extension_and_missing_file(tmp_path):
    with pytest.raises(SchedulerError, match="format"):
        read_orders(_write(tmp_path, "o.txt", "x"))
    with pytest.raises(SchedulerError, match="cannot read"):
        read_orders(tmp_path / "none.csv")


_name = st.text(st.characters(min_codepoint=97, max_codepoint=122), min_size=1, max_size=8)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(_name, st.integers(1, 50), _name, st.integers(0, 9)), min_size=1, max_size=6))
def test_csv_round_trip(tmp_path_factory, rows):
    folder = tmp_path_factory.mktemp("orders")
    text = "part,quantity,material,priority\n" + "".join(f"{p}.stl,{q},{m},{pr}\n" for p, q, m, pr in rows)
    orders = read_orders(_write(folder, "o.csv", text))
    assert [(o.part, o.quantity, o.material, o.priority) for o in orders] == \
        [(folder / f"{p}.stl", q, m, pr) for p, q, m, pr in rows]
    assert len({o.id for o in orders}) == len(orders)


def test_part_paths_resolve_against_the_orders_folder_and_are_logged(tmp_path, caplog):
    import logging

    folder = tmp_path / "jobs"
    folder.mkdir()
    path = _write(folder, "o.yaml", "orders:\n  - {part: ../parts/a.stl, quantity: 1, material: steel}\n"
                  "  - {part: b.stl, quantity: 1, material: steel}\n  - {part: /abs/c.stl, quantity: 1, material: steel}\n")
    with caplog.at_level(logging.INFO, logger="robotprog.orders"):
        orders = read_orders(path)
    assert [o.part for o in orders] == [folder / "../parts/a.stl", folder / "b.stl", Path("/abs/c.stl")]
    assert f"{(tmp_path / 'parts/a.stl')} (outside the orders file's folder)" in caplog.text
    assert f"{folder / 'b.stl'}\n" in caplog.text + "\n" and "b.stl (outside" not in caplog.text


def test_alias_bomb_in_quantity_stops_at_once_with_one_line(tmp_path):
    from tests.cli.hostile import alias_bomb

    path = _write(tmp_path, "o.yaml", f"orders:\n  - part: a.stl\n    material: steel\n    quantity: {alias_bomb()}\n")
    with pytest.raises(SchedulerError, match="alias") as err:
        read_orders(path)
    assert err.value.source == f"{path}:4" and "\n" not in str(err.value)


def test_a_huge_value_is_quoted_short(tmp_path):
    path = _write(tmp_path, "o.yaml", "orders:\n  - {part: a.stl, material: steel, quantity: " + "9" * 100_000 + "x}\n")
    with pytest.raises(SchedulerError, match="quantity") as err:
        read_orders(path)
    assert len(str(err.value)) < len(str(path)) + 150
