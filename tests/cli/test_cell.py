"""`factory cell warm` through typer's CliRunner: the roadmap built once, cached, found again."""

from __future__ import annotations

import json
import os
from pathlib import Path

from typer.testing import CliRunner

from cli.main import app
from factory.core.resources import FIXTURES
from factory.roadmaps import roadmap_path
from robotprog.cell import load_cell
from robotprog.roadmap import Roadmap

runner = CliRunner()


def test_warm_builds_the_roadmap_once_into_the_cache():
    cell_path = FIXTURES / "cell.yaml"
    first = runner.invoke(app, ["cell", "warm", str(cell_path), "--json", "--quiet"])
    assert first.exit_code == 0, first.output
    got = json.loads(first.stdout)
    where = Path(got["roadmap"])
    # the tests' cache (tests/conftest.py), never the user's
    assert where == roadmap_path(load_cell(cell_path))
    assert where.is_relative_to(os.environ["FACTORY_CACHE_DIR"])
    roadmap = Roadmap.from_bytes(where.read_bytes(), 6, str(where))
    assert (got["nodes"], got["edges"]) == (len(roadmap.nodes), len(roadmap.edges))
    assert got["edges"] > got["nodes"]
    mtime = where.stat().st_mtime_ns
    again = runner.invoke(app, ["cell", "warm", str(cell_path), "--json", "--quiet"])
    assert again.exit_code == 0, again.output
    assert json.loads(again.stdout)["built"] is False
    assert where.stat().st_mtime_ns == mtime


def test_warm_refuses_a_malformed_cell_in_one_line(tmp_path):
    bad = tmp_path / "cell.yaml"
    bad.write_text("format: factory.cell/1\nrobot: [1, 2\n")
    r = runner.invoke(app, ["cell", "warm", str(bad)])
    assert r.exit_code == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "cell.yaml" in lines[0]
    assert not (Path(os.environ["FACTORY_CACHE_DIR"]) / "roadmaps" / "cell.npz").exists()


def test_cell_alone_shows_its_sub_commands():
    r = runner.invoke(app, ["cell"])
    assert r.exit_code == 2
    assert "warm" in r.output
