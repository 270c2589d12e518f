"""The lazy ``factory`` command group: the listing imports nothing, each command loads when it runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import COMMANDS, app, command_docstring, load_command
from cli.options import command_flags
from factory.core.errors import FactoryError

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()

# Libraries only some commands need: OpenCV (vision), SQLAlchemy (the record), the Foxglove
# server (live view), TOPP-RA with matplotlib (robot timing).
HEAVY = ("cv2", "sqlalchemy", "foxglove", "toppra", "matplotlib", "trimesh", "pinocchio")


def _modules_after(code: str) -> set[str]:
    """Top-level names of the modules a fresh interpreter holds after running ``code``."""
    probe = (f"import sys\n{code}\n"
             "import json; print(json.dumps(sorted({m.split('.')[0] for m in sys.modules} | "
             "{m for m in sys.modules if m.startswith('cli.')})))")
    r = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    return set(json.loads(r.stdout.splitlines()[-1]))


def test_help_lists_every_command_without_importing_any():
    loaded = _modules_after("from cli.main import app\ntry:\n    app(['--help'])\nexcept SystemExit:\n    pass")
    assert not loaded & set(HEAVY), loaded & set(HEAVY)
    assert not {f"cli.{name}" for name in COMMANDS} & loaded
    out = runner.invoke(app, ["--help"]).output
    listed = [line.split()[0] for line in out.split("Commands:")[1].splitlines() if line.strip()]
    assert listed == list(COMMANDS)


def test_help_of_plan_does_not_load_opencv_sqlalchemy_or_the_robot_timing():
    loaded = _modules_after("from cli.main import app\ntry:\n    app(['plan', '--help'])\nexcept SystemExit:\n"
                            "    pass")
    assert "cli.plan" in loaded
    assert not loaded & {"cv2", "sqlalchemy", "foxglove", "toppra", "matplotlib"}


@pytest.mark.parametrize("name", COMMANDS)
def test_listed_help_is_the_commands_own(name):
    cmd = load_command(name)
    assert cmd.name == name
    assert cmd.help is not None and cmd.help.strip() == command_docstring(name).strip()
    out = runner.invoke(app, ["--help"], terminal_width=100).output
    row = next(line for line in out.splitlines() if line.split()[:1] == [name])
    assert row.split(None, 1)[1] == cmd.get_short_help_str(100 - 6 - max(map(len, COMMANDS)))


def test_every_command_module_is_listed():
    # A module cli/X.py with a function X decorated as a command is a sub-command; none forgotten.
    for path in sorted((ROOT / "cli").glob("*.py")):
        if path.stem == "main":  # the entry point itself
            continue
        try:
            command_docstring(path.stem)
        except LookupError:
            continue
        assert path.stem in COMMANDS, f"cli/{path.name} defines {path.stem}() but COMMANDS lacks it"


def test_unknown_command_is_a_usage_error_with_a_suggestion():
    r = runner.invoke(app, ["plann"])
    assert r.exit_code == 2
    assert "No such command 'plann'" in r.output and "'plan'" in r.output


def test_a_command_runs_through_the_lazy_group(tmp_path):
    r = runner.invoke(app, ["report", str(tmp_path / "none.sqlite")])
    assert r.exit_code == 1 and "error:" in r.output
    assert load_command("report") is load_command("report")  # loaded once


def test_command_flags_read_the_lazily_loaded_command():
    assert command_flags("plan", {"rough-tool": 2, "waterline": False, "grid": 0.5}) == \
        ["--rough-tool", "2", "--no-waterline", "--grid", "0.5"]
    with pytest.raises(FactoryError, match="no option --nonsense"):
        command_flags("plan", {"nonsense": 1})
    with pytest.raises(FactoryError, match="no command 'plann'"):
        command_flags("plann", {})
    with pytest.raises(FactoryError, match="--grid takes a value"):
        command_flags("plan", {"grid": True})
    with pytest.raises(FactoryError, match="--waterline is a switch"):
        command_flags("plan", {"waterline": 0})
    with pytest.raises(FactoryError, match="--quiet has no --no-quiet"):
        command_flags("plan", {"quiet": False})


def test_unchecked_flags_are_the_checked_ones_and_load_no_command():
    # A workflow job on a cluster node builds its flags unchecked: they must be the driver's.
    options = {"rough_tool": 2, "waterline": False, "robot": True, "grid": 0.5, "lang": "rapid"}
    probe = ("import json, sys\nfrom cli.options import command_flags\n"
             f"print(json.dumps([command_flags('plan', {options!r}, check=False), sorted(sys.modules)]))")
    r = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    unchecked, loaded = json.loads(r.stdout.splitlines()[-1])
    assert "cli.plan" not in loaded
    assert not {m.split(".")[0] for m in loaded} & set(HEAVY)
    assert unchecked == command_flags("plan", options)


def test_command_flags_of_no_options_load_no_command():
    # A workflow driver with no plan options (the shipped config) never pays for `plan`'s imports.
    loaded = _modules_after("from cli.options import command_flags\n"
                            "assert command_flags('plan', {}) == []")
    assert "cli.plan" not in loaded
    assert not loaded & set(HEAVY), loaded & set(HEAVY)


def test_a_quiet_plan_job_loads_no_progress_bars():
    # Every workflow job runs `factory plan --quiet`: rich's progress module is for a terminal only.
    probe = ("import sys, json\nimport cli.plan\n"
             "print(json.dumps(sorted(m for m in sys.modules if m.startswith('rich.'))))")
    r = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True)
    assert "rich.progress" not in json.loads(r.stdout.splitlines()[-1])


def test_gcode_loads_no_robot_libraries():
    # `factory gcode` posts a toolpath: the robot's libraries (Pinocchio, coal, TOPP-RA) are not its.
    loaded = _modules_after("from cli.main import load_command\nload_command('gcode')")
    assert "cli.gcode" in loaded
    assert not loaded & {"pinocchio", "coal", "toppra", "matplotlib"}, loaded & {"pinocchio", "coal", "toppra"}


def test_version_is_the_packages_and_loads_no_command():
    import factory

    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and r.output == f"factory {factory.__version__}\n"
    loaded = _modules_after("from cli.main import app\ntry:\n    app(['--version'])\nexcept SystemExit:\n    pass")
    assert not {f"cli.{name}" for name in COMMANDS} & loaded
    assert not loaded & set(HEAVY), loaded & set(HEAVY)
