"""Production orders for the cell: which part, how many, in what material, how urgent.

Two file formats, chosen by extension:

YAML (``.yaml`` / ``.yml``)::

    orders:
      - {part: samples/bracket.stl, quantity: 2, material: aluminium, priority: 1}

CSV (``.csv``), a header row then one order per row::

    part,quantity,material,priority
    samples/bracket.stl,2,aluminium,1

``part`` is a path relative to the folder of the orders file; an absolute path is kept. A path
may leave that folder (``../parts/x.stl``): an orders file is trusted like a command line, and
factory only reads the part (plans go to the catalog). Each part's resolved path is logged
(INFO), with a note when it lies outside the orders file's folder. ``quantity`` is a
whole number >= 1. ``material`` is a non-empty name (the cutting-data key). ``priority`` is
an optional whole number >= 0, default 0; *lower numbers run first*, ties in file order.

Every problem raises :class:`~factory.core.errors.SchedulerError` naming the file and the line
(CSV) or the entry and field (YAML), before anything runs. Whether the part file exists or
can be planned is *not* checked here: that is a per-order failure, so the other orders of
the file still run (see :mod:`robotprog.cellsim`).
"""

from __future__ import annotations

import csv
import logging
from dataclasses import dataclass
from pathlib import Path

from factory.core.errors import SchedulerError, shown
from factory.core.yamlfile import load_yaml

log = logging.getLogger(__name__)

FIELDS = ("part", "quantity", "material", "priority")
REQUIRED = ("part", "quantity", "material")


@dataclass(frozen=True)
class Order:
    """One production order.

    Attributes
    ----------
    id : str
        ``"o1"``, ``"o2"``, … in file order; unique within a file.
    part : Path
        The part mesh, resolved against the orders file's folder.
    quantity : int
        Good parts wanted, >= 1.
    material : str
        Stock material name (cutting-data key).
    priority : int
        >= 0; lower numbers run first.
    """

    id: str
    part: Path
    quantity: int
    material: str
    priority: int = 0


def _whole(value: object, field: str, where: str, minimum: int) -> int:
    if isinstance(value, bool):
        raise SchedulerError(f"{field}: expected a whole number, got {shown(value)}", source=where)
    if isinstance(value, int):
        number = value
    elif isinstance(value, float) and value.is_integer():
        number = int(value)
    elif isinstance(value, str) and value.strip().lstrip("+").isdigit():
        number = int(value.strip())
    else:
        raise SchedulerError(f"{field}: expected a whole number, got {shown(value)}", source=where)
    if number < minimum:
        raise SchedulerError(f"{field}: must be >= {minimum}, got {number}", source=where)
    return number


def _order(entry: dict, index: int, where: str, base: Path) -> Order:
    unknown = sorted(set(map(str, entry)) - set(FIELDS))
    if unknown:
        raise SchedulerError(f"unknown field {shown(unknown[0])} (expected {', '.join(FIELDS)})", source=where)
    for field in REQUIRED:
        value = entry.get(field)
        if value is None or (isinstance(value, str) and not value.strip()):
            raise SchedulerError(f"{field}: missing", source=where)
    part, material = entry["part"], entry["material"]
    if not isinstance(part, str):
        raise SchedulerError(f"part: expected a file path, got {shown(part)}", source=where)
    if not isinstance(material, str):
        raise SchedulerError(f"material: expected a name, got {shown(material)}", source=where)
    priority = entry.get("priority")
    path = Path(part.strip())
    path = path if path.is_absolute() else base / path
    resolved = path.resolve()
    outside = not resolved.is_relative_to(base.resolve())
    log.info("%s: part %s%s", where, resolved, " (outside the orders file's folder)" if outside else "")
    return Order(
        id=f"o{index + 1}",
        part=path,
        quantity=_whole(entry["quantity"], "quantity", where, 1),
        material=material.strip(),
        priority=0 if priority is None or priority == "" else _whole(priority, "priority", where, 0),
    )


def _read_yaml(path: Path, text: str) -> list[Order]:
    doc = load_yaml(text, source=path, error=SchedulerError)
    if not isinstance(doc, dict) or "orders" not in doc:
        raise SchedulerError("expected a mapping with an 'orders' list", source=path)
    extra = sorted(set(map(str, doc)) - {"orders"})
    if extra:
        raise SchedulerError(f"unknown key {shown(extra[0])} (expected 'orders')", source=path)
    entries = doc["orders"]
    if not isinstance(entries, list):
        raise SchedulerError("orders: expected a list", source=path)
    orders = []
    for i, entry in enumerate(entries):
        where = f"{path}: orders[{i}]"
        if not isinstance(entry, dict):
            raise SchedulerError(f"expected a mapping of {', '.join(FIELDS)}, got {shown(entry)}", source=where)
        orders.append(_order(entry, i, where, path.parent))
    return orders


def _read_csv(path: Path, text: str) -> list[Order]:
    rows = list(csv.reader(text.splitlines()))
    numbered = [(n, row) for n, row in enumerate(rows, start=1) if any(cell.strip() for cell in row)]
    if not numbered:
        raise SchedulerError("empty orders file (expected a header part,quantity,material,priority)", source=path)
    line, header = numbered[0]
    header = [h.strip().lower() for h in header]
    missing = [f for f in REQUIRED if f not in header]
    if missing or len(set(header)) != len(header):
        raise SchedulerError(f"header must name {', '.join(FIELDS)} once each (priority optional), got "
                             f"{','.join(header)}", source=f"{path}:{line}")
    orders = []
    for i, (line, row) in enumerate(numbered[1:]):
        where = f"{path}:{line}"
        if len(row) != len(header):
            raise SchedulerError(f"expected {len(header)} fields, got {len(row)}", source=where)
        orders.append(_order(dict(zip(header, (c.strip() for c in row))), i, where, path.parent))
    return orders


def read_orders(path: str | Path) -> tuple[Order, ...]:
    """Read and validate an orders file (YAML or CSV by extension).

    Parameters
    ----------
    path : str or Path
        ``.yaml``, ``.yml`` or ``.csv`` file.

    Returns
    -------
    tuple of Order
        In file order (the scheduler sorts by priority). At least one order.

    Raises
    ------
    SchedulerError
        Unreadable file, unknown extension, malformed YAML/CSV, missing or invalid field
        (the source names the line or entry), or no orders at all.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".yaml", ".yml", ".csv"):
        raise SchedulerError(f"unknown orders format {suffix or '(none)'!r}: expected .yaml, .yml or .csv",
                             source=path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SchedulerError(f"cannot read: {exc}", source=path) from None
    orders = _read_csv(path, text) if suffix == ".csv" else _read_yaml(path, text)
    if not orders:
        raise SchedulerError("no orders", source=path)
    log.debug("%s: %d orders", path, len(orders))
    return tuple(orders)
