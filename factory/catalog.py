"""The part catalog: ``factory plan`` outputs found again by a content hash.

A catalog is a folder of ``factory plan`` outputs (``make demo`` writes one to ``build/``). Each
plan's ``PART.plan.json`` carries a ``catalog`` record::

    "catalog": {"format": "factory.catalog/1", "key": "<sha256>", "mesh_sha256": ..., "material": ...,
                "cell_sha256": ..., "tools_sha256": ...}

The key hashes what the cell makes and where: the mesh file's bytes, the material, the cell file
and the tool library. ``factory simulate`` takes any plan in the catalog with the part's key
(whatever CAM options it was planned with: those are the planner's choice, recorded in the
plan) and plans the part with the default options only when there is none, so unchanged parts
are never planned twice.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from factory.plansummary import summary_problem

log = logging.getLogger(__name__)

CATALOG_FORMAT = "factory.catalog/1"


def sha256_file(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def catalog_record(mesh_sha256: str, material: str, cell_sha256: str | None, tools_sha256: str) -> dict[str, str]:
    """The ``catalog`` record of a plan, with its key (hex SHA-256 of the other fields).

    ``cell_sha256`` is None for a plan without a robot: such plans carry no key the cell
    simulation looks for."""
    fields = {"mesh_sha256": mesh_sha256, "material": material, "cell_sha256": cell_sha256 or "",
              "tools_sha256": tools_sha256}
    key = hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()
    return {"format": CATALOG_FORMAT, "key": key, **fields}


@dataclass(frozen=True)
class CatalogEntry:
    """One planned part in a catalog.

    Attributes
    ----------
    summary_path : Path
        Its ``PART.plan.json``.
    summary : dict
        That file's content.
    """

    summary_path: Path
    summary: dict[str, Any]

    @property
    def key(self) -> str:
        return self.summary["catalog"]["key"]

    def output(self, name: str) -> Path:
        """Path of one output (``program``, ``setup_sheet``, ``mcap``, …), relative paths taken from
        the plan file's folder when the recorded path does not exist (a moved catalog)."""
        recorded = Path(self.summary["outputs"][name])
        return recorded if recorded.exists() else self.summary_path.parent / recorded.name


def find_entry(catalog: Path, key: str) -> CatalogEntry | None:
    """The newest plan in ``catalog`` (searched recursively) with ``key`` whose outputs all exist."""
    found: list[tuple[float, CatalogEntry]] = []
    if not catalog.is_dir():
        return None
    for path in catalog.rglob("*.plan.json"):
        try:
            summary = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            log.warning("%s: not a readable plan summary, ignored", path)
            continue
        problem = summary_problem(summary)
        if problem is not None:
            log.warning("%s: not a usable plan summary (%s), ignored", path, problem)
            continue
        if summary["catalog"]["key"] != key:
            continue
        entry = CatalogEntry(path, summary)
        missing = [n for n in summary.get("outputs", {}) if n != "summary" and not entry.output(n).is_file()]
        if missing:
            log.warning("%s: outputs %s are missing, plan ignored", path, ", ".join(missing))
            continue
        found.append((path.stat().st_mtime, entry))
    return max(found, key=lambda f: f[0])[1] if found else None
