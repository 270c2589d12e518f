"""The installed wheel works anywhere: built from the project, installed into a clean venv outside
the checkout (as ``pipx install`` does), it carries its data and plans a sample.

The venv is clean of the project: the wheel is its only copy of factory. For speed, the
third-party packages are this test environment's own, seen through a folder of links to every
entry of its site-packages except the project's (a checkout's editable install or an installed
copy would otherwise stand in for the wheel).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

from factory import __version__ as checkout_version

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "bracket.stl"


def _clean_env() -> dict[str, str]:
    """This environment without anything that would put the checkout on the import path."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")}


def _source_tree(dest: Path) -> Path:
    """A copy of what the wheel is built from (pyproject's packages, fixtures/, ros/), links kept:
    the build's ``build/`` and ``*.egg-info`` land there, not in the checkout."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    packages = [p.rstrip("*") for p in config["tool"]["setuptools"]["packages"]["find"]["include"]]
    dest.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, dest / name)
    for name in (*packages, "fixtures", "ros", "samples"):
        shutil.copytree(ROOT / name, dest / name, symlinks=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return dest


def _third_party_paths(farm: Path, project: set[str]) -> list[Path]:
    """This environment's import folders beyond the standard library, each as a folder of links
    to its entries minus the project's packages, metadata and ``.pth`` hooks."""
    probe = "import json, sys; print(json.dumps(sys.path))"
    paths = json.loads(subprocess.run([sys.executable, "-c", probe], cwd=farm, env=_clean_env(), check=True,
                                      capture_output=True, text=True).stdout)
    stdlib = Path(sysconfig.get_path("stdlib")).resolve()
    out = []
    for i, entry in enumerate(paths):
        folder = Path(entry).resolve() if entry else None
        if folder is None or not folder.is_dir() or folder.is_relative_to(stdlib):
            continue
        # the checkout itself must not be importable (its venv may well live inside it, as `make test` puts it)
        assert folder != ROOT.resolve(), f"{folder}: the checkout is on this environment's path"
        mirror = farm / str(i)
        mirror.mkdir()
        for item in folder.iterdir():
            name = item.name
            if (name.split(".")[0].split("-")[0] in project or name.startswith("__editable__")
                    or name.endswith((".pth", ".egg-link"))):
                continue
            (mirror / name).symlink_to(item)
        out.append(mirror)
    return out


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """A venv outside the checkout with the project's wheel installed (and nothing else of it)."""
    base = tmp_path_factory.mktemp("install")
    assert not base.is_relative_to(ROOT)
    src = _source_tree(base / "src")
    dist = base / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--disable-pip-version-check", "-q",
                    "-w", str(dist), str(src)], check=True, env=_clean_env(), capture_output=True)
    (wheel,) = dist.glob("factory-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
    project = {n.split("/")[0] for n in names if "/" in n and not n.split("/")[0].endswith(".dist-info")}
    assert project == {"cadcam", "cli", "factory", "robotprog", "vision"}
    venv = base / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, env=_clean_env())
    python = venv / "bin" / "python"
    site = Path(subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                               check=True, capture_output=True, text=True, env=_clean_env()).stdout.strip())
    farm = base / "deps"
    farm.mkdir()
    (site / "third_party.pth").write_text("".join(f"{p}\n" for p in _third_party_paths(farm, project)))
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index",
                    "--disable-pip-version-check", "-q", str(wheel)], check=True, env=_clean_env(), capture_output=True)
    return venv


def test_the_wheel_carries_its_data(installed):
    probe = """
import json
import cadcam, cli, factory, robotprog, vision
from factory.core import resources
from factory.rosmsgs import TYPESTORE
from factory.production import SAMPLE_ORDERS
from factory.record import Record
from robotprog.orders import read_orders
Record(__import__("sys").argv[1]).close()  # the schema from the wheel's migrations
print(json.dumps({
    "modules": [m.__file__ for m in (cadcam, cli, factory, robotprog, vision)],
    "folders": [str(p) for p in (resources.FIXTURES, resources.ROS_INTERFACES, resources.FOXGLOVE_INTERFACES,
                                 resources.MIGRATIONS)],
    "fixtures": sorted(p.name for p in resources.FIXTURES.glob("*.yaml")),
    "sample_orders": [str(o.part) for o in read_orders(SAMPLE_ORDERS)],
    "types": sorted(t for t in TYPESTORE.fielddefs if t.startswith(("factory_msgs/", "foxglove_msgs/"))),
}))
"""
    record = installed.parent / "record.sqlite"
    r = subprocess.run([installed / "bin" / "python", "-c", probe, str(record)], cwd=installed.parent,
                       env=_clean_env(), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    found = json.loads(r.stdout)
    # `factory simulate` with no orders file runs the sample orders: their parts ship too
    assert found["sample_orders"]
    for path in found["modules"] + found["folders"] + found["sample_orders"]:
        assert Path(path).is_file() or Path(path).is_dir(), path
        assert Path(path).is_relative_to(installed), path  # the project comes from the wheel alone
    assert found["fixtures"] == sorted(p.name for p in (ROOT / "fixtures").glob("*.yaml"))
    shipped = {f"factory_msgs/msg/{p.stem}" for p in (ROOT / "ros" / "factory_msgs" / "msg").glob("*.msg")}
    assert shipped and shipped <= set(found["types"])
    assert "foxglove_msgs/msg/SceneUpdate" in found["types"]
    assert record.stat().st_size > 0


def test_the_installed_command_plans_a_sample_outside_the_checkout(installed):
    work = installed.parent / "work"
    work.mkdir()
    factory = installed / "bin" / "factory"
    version = subprocess.run([factory, "--version"], cwd=work, env=_clean_env(), capture_output=True, text=True)
    # one version: the package's, the wheel's metadata (pyproject reads it) and the command's
    dist_info = next(installed.glob("lib/python*/site-packages/factory-*.dist-info")).name
    assert dist_info == f"factory-{checkout_version}.dist-info"
    assert version.returncode == 0 and version.stdout == f"factory {checkout_version}\n", version.stderr
    r = subprocess.run([factory, "plan", str(SAMPLE), "-o", "out", "--quiet"], cwd=work, env=_clean_env(),
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    summary = json.loads((work / "out" / "bracket.plan.json").read_text())
    assert summary["robot"]["cell"] and summary["verify"]["ok"] is not None
    for output in summary["outputs"].values():
        assert (work / output).stat().st_size > 0, output
