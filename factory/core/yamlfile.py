"""YAML from users' files, read within bounds.

A few hundred bytes of YAML can name a billion values through anchors and aliases
(the "billion laughs" document). ``yaml.safe_load`` builds it cheaply as shared
objects, but anything that walks or prints the result expands every alias. Every user
YAML file is read through :func:`load_yaml`, which counts the document's values as if
its aliases were expanded and refuses it past :data:`MAX_VALUES`, before anything is
built. Ordinary anchors and merge keys (``<<: *defaults``) stay allowed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from factory.core.errors import FactoryError

#: Most values a user YAML document may hold with its aliases expanded. A cell, tool
#: library or camera file holds hundreds; an orders file a few per order.
MAX_VALUES = 1_000_000


def load_yaml(text: str, *, source: str | Path, error: type[FactoryError],
              max_values: int = MAX_VALUES) -> Any:
    """Parse one YAML document from a user's file.

    Parameters
    ----------
    text : str
        The file's text.
    source : str or Path
        The file, named in errors (with ``:LINE`` when the parser knows the line).
    error : type of FactoryError
        The stage's exception class to raise.
    max_values : int
        Most scalars, sequences and mappings the document may hold with aliases expanded.

    Raises
    ------
    FactoryError (of class ``error``)
        Not valid YAML (one line, ``source:LINE``), more than one document, nesting too
        deep for the parser, a recursive alias, or more than ``max_values`` values.
    """
    loader = None
    try:
        loader = yaml.SafeLoader(text)  # checks the characters: may raise already
        node = loader.get_single_node()
        if node is None:
            return None
        _check_size(node, max_values, source, error)
        return loader.construct_document(node)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark is not None else str(source)
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise error(f"not valid YAML: {problem}", source=where) from None
    except RecursionError:
        raise error("not valid YAML: nested too deeply", source=source) from None
    finally:
        if loader is not None:
            loader.dispose()


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_size(root: yaml.Node, limit: int, source: str | Path, error: type[FactoryError]) -> None:
    """Count values with aliases expanded (each distinct node is visited once: aliases
    share their node, so its count is reused), without recursion."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        key = id(node)
        if children_done:
            on_path.discard(key)
            total = 1 + sum(size[id(c)] for c in _children(node))
            if total > limit:
                line = node.start_mark.line + 1 if node.start_mark is not None else None
                where = f"{source}:{line}" if line else str(source)
                raise error(f"document expands to more than {limit:,} values through its aliases "
                            "(a YAML alias bomb?)", source=where)
            size[key] = total
            continue
        if key in size:
            continue
        if key in on_path:
            line = node.start_mark.line + 1 if node.start_mark is not None else None
            raise error("recursive alias: a value contains itself",
                        source=f"{source}:{line}" if line else source)
        on_path.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in size)
