"""The house's floors: the ground imports nothing of the project, the domain packages import only the ground.

Read from the source with ``ast`` (nothing is imported), so a new import that runs back up a floor, or closes
a circle between two modules, fails here and names the file and line.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("factory", "cadcam", "robotprog", "vision", "cli")
DOMAIN = ("cadcam", "robotprog", "vision")


def _module(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """Every project module ``path`` imports, with the line, functions' local imports included."""
    tree = ast.parse(path.read_text(), filename=str(path))
    here = _module(path).split(".")
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package that holds this file
                pkg = here[: len(here) - node.level + (1 if path.name == "__init__.py" else 0)]
                base = ".".join([*pkg, base] if base else pkg)
            found.append((base, node.lineno))
            # ``from pkg import mod`` imports the module pkg.mod
            found += [(f"{base}.{a.name}", node.lineno) for a in node.names
                      if (ROOT / Path(*base.split("."), a.name)).with_suffix(".py").exists()]
    return [(m, line) for m, line in found if m.split(".")[0] in PROJECT]


def _sources(*packages: str) -> list[Path]:
    return sorted(p for pkg in packages for p in (ROOT / pkg).rglob("*.py")
                  if "migrations" not in p.parts)


@pytest.mark.parametrize("path", _sources("factory/core"), ids=lambda p: str(p.relative_to(ROOT)))
def test_the_ground_floor_imports_nothing_above_it(path: Path) -> None:
    above = [f"{m} (line {line})" for m, line in _imports(path) if not m.startswith("factory.core")]
    assert not above, f"{path.relative_to(ROOT)} imports {', '.join(above)}"


@pytest.mark.parametrize("path", _sources(*DOMAIN), ids=lambda p: str(p.relative_to(ROOT)))
def test_a_domain_package_imports_only_the_ground_and_itself(path: Path) -> None:
    own = path.relative_to(ROOT).parts[0]
    above = [f"{m} (line {line})" for m, line in _imports(path)
             if not (m.startswith("factory.core") or m.split(".")[0] == own)]
    assert not above, f"{path.relative_to(ROOT)} imports {', '.join(above)}"


def test_the_import_reader_sees_a_back_arrow(tmp_path: Path) -> None:
    """The check above can fail: an import of the pipeline from a domain module is found, with its line."""
    probe = ROOT / "cadcam" / "_layering_probe.py"
    probe.write_text("import numpy\n\ndef f():\n    from factory.plan import plan_part\n")
    try:
        assert _imports(probe) == [("factory.plan", 4)]
    finally:
        probe.unlink()


#: The size a maintainer reads in one sitting: no module over 1,000 lines, no function over 120
#: (decorators and docstring included); the database migrations are generated.
MAX_FILE_LINES, MAX_FUNCTION_LINES = 1000, 120


@pytest.mark.parametrize("path", _sources(*PROJECT), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_module_or_function_is_too_long_to_read(path: Path) -> None:
    text = path.read_text()
    assert len(text.splitlines()) <= MAX_FILE_LINES, f"{path.relative_to(ROOT)}: {len(text.splitlines())} lines"
    long = [f"{node.name} ({node.end_lineno - min([node.lineno, *(d.lineno for d in node.decorator_list)]) + 1} lines)"
            for node in ast.walk(ast.parse(text))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - min([node.lineno, *(d.lineno for d in node.decorator_list)]) + 1 > MAX_FUNCTION_LINES]
    assert not long, f"{path.relative_to(ROOT)}: {', '.join(long)}"


def test_no_two_modules_import_each_other_in_a_circle() -> None:
    """Module-level imports of the project, functions' local ones included, form no circle."""
    edges: dict[str, set[str]] = {}
    modules = {_module(p): p for p in _sources(*PROJECT)}
    for name, path in modules.items():
        edges[name] = {m for m, _ in _imports(path) if m in modules and m != name}
    # Tarjan-free: a depth-first search that meets a module still on its path has found a circle.
    state: dict[str, int] = {}
    path_stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        path_stack.append(m)
        for n in sorted(edges.get(m, ())):
            if state.get(n) == 1:
                return path_stack[path_stack.index(n):] + [n]
            if n not in state and (found := visit(n)):
                return found
        state[m] = 2
        path_stack.pop()
        return None

    for m in sorted(edges):
        if m not in state:
            found = visit(m)
            assert found is None, " -> ".join(found)
