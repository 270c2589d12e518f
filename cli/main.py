"""The ``factory`` command: one sub-command per stage, each reading and writing files.

The command group is lazy: a sub-command's module, and with it the libraries that command needs
(OpenCV, SQLAlchemy, the Foxglove server, TOPP-RA with matplotlib, ...), is imported only when that
command runs or shows its help. ``factory --help`` reads each command's one-line help from its
module's source text, so it starts in a fraction of the time and imports none of them. Start-up
counts: every job of the Snakemake workflow is one ``factory`` process.
"""

from __future__ import annotations

import ast
import functools
import importlib
import importlib.util
from collections.abc import Iterator, Mapping
from typing import Annotated, Any

import typer
import typer.core
import typer.main

import factory

#: The sub-commands in the order ``factory --help`` lists them: each is the function of its own
#: name in the module ``cli.<name>``.
COMMANDS = ("toolpath", "gcode", "verify", "plan", "calibrate", "robot", "handeye", "locate", "inspect",
            "simulate", "cell", "report")

TYPER_SETTINGS: dict[str, Any] = dict(
    add_completion=False,
    pretty_exceptions_enable=False,
    # Help texts carry units in brackets ("[mm]"); rich markup would swallow them as tags.
    rich_markup_mode=None,
)


@functools.cache
def load_command(name: str) -> typer.core.TyperCommand | typer.core.TyperGroup:
    """The click command ``factory NAME``, its module imported now.

    A module that holds a typer app ``NAME_app`` is a command group (``factory cell warm ...``): its
    callback is the function ``NAME``, whose docstring is the group's one-line help.
    """
    module = importlib.import_module(f"cli.{name}")
    group = getattr(module, f"{name}_app", None)
    if isinstance(group, typer.Typer):
        return typer.main.get_group(group)
    single = typer.Typer(**TYPER_SETTINGS)
    single.command(name)(getattr(module, name))
    return typer.main.get_command(single)


def command_docstring(name: str) -> str:
    """The docstring of ``factory NAME``'s function, read from its module's source without importing it."""
    spec = importlib.util.find_spec(f"cli.{name}")
    if spec is None or spec.origin is None:
        raise LookupError(f"no module cli.{name}")
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read(), spec.origin)
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == name:
            return ast.get_docstring(node) or ""
    raise LookupError(f"cli.{name} has no function {name}")


class _Commands(Mapping[str, typer.core.TyperCommand]):
    """Name → command, each loaded on first access: listing the names imports nothing."""

    def __getitem__(self, name: str) -> typer.core.TyperCommand:
        if name not in COMMANDS:
            raise KeyError(name)
        return load_command(name)

    def __iter__(self) -> Iterator[str]:
        return iter(COMMANDS)

    def __len__(self) -> int:
        return len(COMMANDS)


class LazyGroup(typer.core.TyperGroup):
    """A typer group whose sub-commands are imported when they are run, not when ``factory`` starts."""

    def __init__(self, **attrs: Any):
        super().__init__(**attrs)
        self.commands = _Commands()  # type: ignore[assignment]

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def format_commands(self, ctx: Any, formatter: Any) -> None:
        # What click's own listing shows (the first sentence, cut to the width), from the docstrings.
        stubs = [typer.core.TyperCommand(name, help=command_docstring(name)) for name in COMMANDS]
        limit = formatter.width - 6 - max(len(name) for name in COMMANDS)
        with formatter.section("Commands"):
            formatter.write_dl([(c.name, c.get_short_help_str(limit)) for c in stubs])


app = typer.Typer(
    name="factory",
    help="From a part's CAD mesh to a running robotic machining cell.",
    no_args_is_help=True,
    cls=LazyGroup,
    **TYPER_SETTINGS,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"factory {factory.__version__}")
        raise typer.Exit()


@app.callback()
def _factory(
    version: Annotated[bool, typer.Option("--version", help="Print factory's version and exit.",
                                          callback=_print_version, is_eager=True)] = False,
) -> None:
    # A group needs a callback when its commands are not registered with typer up front.
    pass


def main() -> None:
    app()
