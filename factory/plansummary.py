"""The shape of a ``PART.plan.json`` plan summary, checked before anything reads its fields.

A catalog is a folder of files anyone can edit; a summary with a missing ``outputs`` or a
list where a mapping belongs must be skipped with a warning, never end in a KeyError.
"""

from __future__ import annotations

from typing import Any

#: Outputs every catalogued plan has, besides the summary itself.
REQUIRED_OUTPUTS = ("program", "setup_sheet", "mcap")


def summary_problem(summary: Any) -> str | None:
    """What makes ``summary`` (a parsed ``PART.plan.json``) unusable as a catalog entry, in a
    few words, or None when every field the catalog and ``simulate`` read has its type:
    ``part`` (str), ``catalog.key`` and ``catalog.mesh_sha256`` (str), ``outputs`` (a mapping
    of names to path strings, with :data:`REQUIRED_OUTPUTS`), ``verify.ok`` (bool, optional)."""
    if not isinstance(summary, dict):
        return "not a JSON object"
    if not isinstance(summary.get("part"), str):
        return "'part' is not a path"
    catalog = summary.get("catalog")
    if not isinstance(catalog, dict):
        return "'catalog' is not an object"
    for field in ("key", "mesh_sha256"):
        if not isinstance(catalog.get(field), str):
            return f"'catalog.{field}' is not a string"
    outputs = summary.get("outputs")
    if not isinstance(outputs, dict):
        return "'outputs' is not an object"
    for name, value in outputs.items():
        if not isinstance(value, str) or not value:
            return f"'outputs.{name}' is not a path"
    missing = [n for n in REQUIRED_OUTPUTS if n not in outputs]
    if missing:
        return f"'outputs' lacks {', '.join(missing)}"
    verify = summary.get("verify", {})
    if not isinstance(verify, dict) or not isinstance(verify.get("ok", True), bool):
        return "'verify.ok' is not true or false"
    return None
