"""The README says what the code does: its command list is `factory --help`'s, and the figures it
quotes are the code's own."""

from __future__ import annotations

import re
from pathlib import Path

import yaml
from typer.testing import CliRunner

from cadcam.plan import PlanOptions
from cli.cam import SCALLOP
from cli.main import app, load_command

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
NUMBERS = {"two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9, "ten": 10}


def _command_list() -> list[list[str]]:
    """The words of each line of the README's command list (its ``## Commands`` shell block)."""
    section = README.split("\n## Commands\n", 1)[1]
    block = section.split("```sh\n", 1)[1].split("```", 1)[0]
    return [line.split("#", 1)[0].split() for line in block.splitlines() if line.strip()]


def _help_commands() -> list[str]:
    out = CliRunner().invoke(app, ["--help"], terminal_width=100).output
    return [line.split()[0] for line in out.split("Commands:")[1].splitlines() if line.strip()]


def test_the_command_list_is_factory_help():
    lines = _command_list()
    assert lines and all(words[0] == "factory" for words in lines), lines
    listed = {words[1] for words in lines}
    assert listed == set(_help_commands()), (listed ^ set(_help_commands()))


def test_every_option_in_the_command_list_is_the_commands_own():
    for words in _command_list():
        command = load_command(words[1])
        flags = {f for p in command.params for f in (*p.opts, *p.secondary_opts)}
        for word in words[2:]:
            flag = re.match(r"\[?(--?[a-z][a-z0-9-]*)", word)
            if flag:
                assert flag.group(1) in flags, f"README: factory {words[1]} has no {flag.group(1)}"


def test_the_sample_orders_are_counted_right():
    said = re.search(r"`samples/orders\.yaml` \((\d+) orders, (\d+) parts, of the (\w+) sample parts\)", README)
    assert said, "the README no longer counts the sample orders"
    orders = yaml.safe_load((ROOT / "samples" / "orders.yaml").read_text())["orders"]
    assert int(said.group(1)) == len(orders)
    assert int(said.group(2)) == sum(o["quantity"] for o in orders)
    assert NUMBERS[said.group(3)] == len({o["part"] for o in orders})


def test_the_scallop_is_the_codes_in_the_readme_and_the_help():
    solid, relief = PlanOptions.freeform_scallop, SCALLOP
    assert solid != relief  # two figures, both stated
    readme = " ".join(README.split())
    assert f"the ball's scallop is {solid:g} mm on a solid's freeform faces and {relief:g} mm over a relief" in readme
    out = " ".join(CliRunner().invoke(app, ["plan", "--help"], terminal_width=200).output.split())
    assert f"default: {solid:g} on a solid's freeform faces, {relief:g} over a relief" in out
