"""`factory plan` and `factory simulate` with a relief: an open heightfield sheet, planned from above."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.common import STAGE_LINE
from cli.main import app
from factory.mcaplog import read_metadata
from tests.cadcam.reliefs import heightfield_sheet, stl_bytes, wavy
from tests.cli.expect import assert_one_line_error
from tests.cli.hostile import triangle_soup

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def relief(tmp_path_factory):
    root = tmp_path_factory.mktemp("relief")
    part = root / "sign.stl"
    part.write_bytes(stl_bytes(heightfield_sheet(*wavy())))
    return part


def test_plan_says_what_it_found_and_writes_the_relief_into_the_sheet(relief, tmp_path):
    r = run("plan", relief, "-o", tmp_path, "--scallop", "0.03", "--boundary", "on",
            "--floor", "3", "--no-robot")
    assert r.exit_code == 0, r.output
    assert "sign.stl: open surface, machined from above as a relief: 80 boundary edges, 1 shell, " \
           "footprint 48.0 \u00d7 32.0 mm" in " ".join(r.output.split())
    summary = json.loads((tmp_path / "sign.plan.json").read_text())
    sheet = json.loads((tmp_path / "sign.setup.json").read_text())
    assert summary["relief"] == sheet["relief"]
    assert sheet["relief"]["boundary"]["mode"] == "on" and sheet["relief"]["floor"] == 3.0
    assert summary["verify"]["max_gouge"] <= 0.01
    # Issue 30: the uncut rim round the relief's surface is named as such, not as stock no tool
    # reaches, and is not stock left on the part: the verdict counts only what is on the surface.
    left = summary["verify"]["left"]
    rim = [u for u in left if u["why"] == "outside the relief's surface"]
    assert len(rim) == 1 and rim[0]["size_x"] > 48.0 and rim[0]["size_y"] > 32.0, left
    on_surface = [u for u in left if u not in rim]
    assert all(u["size_x"] < 48.0 and u["size_y"] < 32.0 for u in on_surface), left
    verdict = next(line for line in r.output.splitlines() if "verify" in line and not STAGE_LINE.match(line))
    assert (f"stock left in {len(on_surface)} region" in verdict if on_surface else "verify OK" in verdict), verdict
    # `factory verify` on its own judges the program against the same surface on its base.
    v = run("verify", tmp_path / "sign.nc", "--setup", tmp_path / "sign.setup.json", "--part", relief,
            "-o", tmp_path / "v.json")
    assert v.exit_code == 0, v.output
    alone = json.loads((tmp_path / "v.json").read_text())
    assert alone["max_gouge"] == pytest.approx(summary["verify"]["max_gouge"], abs=1e-3)
    # Issue 30: the toolpath picture's background is paper, not the base plane the relief is cut
    # against (it spans far past the stock, and once painted the whole picture the flat faces' blue).
    from PIL import Image

    from cadcam.faces import FLAT
    from cadcam.preview import FACE_COLOURS

    picture = np.asarray(Image.open(tmp_path / "sign.toolpath.png").convert("RGB"))
    assert tuple(picture[2, 2]) == (255, 255, 255) and tuple(picture[-2, -2]) == (255, 255, 255)
    assert (picture == FACE_COLOURS[FLAT]).all(axis=2).mean() < 0.05


def test_toolpath_takes_the_same_floor_and_boundary_as_plan(relief, tmp_path):
    out = tmp_path / "sign.toolpath.mcap"
    r = run("toolpath", relief, "-o", out, "--scallop", "0.05", "--floor", "2.5", "--boundary", "outside", "--quiet")
    assert r.exit_code == 0, r.output
    relief_params = json.loads(read_metadata(out)["param:relief"])
    assert relief_params["floor"] == 2.5 and relief_params["boundary"]["mode"] == "outside"


def test_an_unknown_boundary_mode_is_a_usage_error(relief, tmp_path):
    r = run("plan", relief, "-o", tmp_path, "--boundary", "around", "--no-robot")
    assert r.exit_code == 2 and "--boundary" in r.output


def test_a_triangle_soup_is_one_line_nonzero_and_writes_nothing(tmp_path):
    soup = tmp_path / "soup.stl"
    soup.write_bytes(triangle_soup())
    out = tmp_path / "out"
    r = run("plan", soup, "-o", out, "--no-robot")
    assert_one_line_error(r, str(soup), "disjoint triangles")
    assert not out.exists() or not any(out.iterdir())


def test_simulate_runs_an_order_for_a_relief(relief, tmp_path):
    orders = tmp_path / "orders.csv"
    orders.write_text(f"part,quantity,material,priority\n{relief},1,aluminium,0\n")
    r = run("simulate", orders, "--catalog", tmp_path / "catalog", "--mcap", tmp_path / "cell.mcap", "--json",
            "--quiet")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    (order,) = doc["orders"]
    assert order["outcome"] == "done" and order["good"] == 1, json.dumps(order)
    assert np.isfinite(doc["summary"]["makespan_s"])
