"""Fixtures shared across the test suite: small real parts made on the fly."""

from __future__ import annotations

import copy
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import manifold3d
import numpy as np
import pytest
import trimesh
from hypothesis import settings

# The suite's property tests draw the same examples on every run (`derandomize`), so a red CI always means
# a change broke something, never an unlucky draw. `make explore` draws fresh examples to hunt for new
# failures; a failure it finds becomes an explicit @example in the test it broke. No deadline: an example's
# time is no property of it, and a loaded machine (CI's, or xdist's two workers) would fail it at random.
settings.register_profile("ci", derandomize=True, print_blob=True, deadline=None)
settings.register_profile("explore", derandomize=False, print_blob=True, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def _without_local_constants() -> None:
    """Hypothesis also draws, now and then, literals it reads from the project's modules imported so far,
    so under xdist a test's "fixed" examples depended on which tests had run before it on its worker (a
    draw the suite had never made failed once, 2026-11-27). Under the fixed profile it reads none; the
    explore profile keeps them. A Hypothesis without this (private) hook draws as it always did."""
    try:
        from hypothesis.internal.conjecture import providers
    except ImportError:  # pragma: no cover - another Hypothesis
        return
    if not (callable(getattr(providers, "_get_local_constants", None)) and hasattr(providers, "_local_constants")):
        return  # pragma: no cover
    none_read = copy.deepcopy(providers._local_constants)  # nothing is read before the first draw
    providers._get_local_constants = lambda: none_read


if os.environ.get("HYPOTHESIS_PROFILE", "ci") == "ci":
    _without_local_constants()

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples"
SHARED = ROOT.parent / "shared"


def manifold_to_trimesh(m: manifold3d.Manifold) -> trimesh.Trimesh:
    mesh = m.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=True)


def pocket_block(size=(30.0, 20.0, 10.0), pocket=(16.0, 12.0, 4.0)) -> trimesh.Trimesh:
    """A block with a rectangular pocket in its top, base at z=0 [mm]."""
    block = manifold3d.Manifold.cube(size)
    cut = manifold3d.Manifold.cube((pocket[0], pocket[1], pocket[2] + 1.0)).translate(
        ((size[0] - pocket[0]) / 2, (size[1] - pocket[1]) / 2, size[2] - pocket[2])
    )
    return manifold_to_trimesh(block - cut)


@pytest.fixture
def small_part(tmp_path: Path) -> Path:
    """A 30×20×10 mm block with a 16×12×4 mm pocket, as binary STL."""
    path = tmp_path / "block.stl"
    pocket_block().export(path)
    return path


def _run_folder(tmp_path_factory, name: str) -> Path:
    """A folder of this test run that all its xdist workers share (each has its own basetemp in the
    run's), or the session's own without xdist."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        folder = tmp_path_factory.getbasetemp().parent / name
        folder.mkdir(exist_ok=True)
        return folder
    return tmp_path_factory.mktemp(name)


@pytest.fixture(scope="session", autouse=True)
def shared_work(tmp_path_factory) -> Path:
    """The run's folder of work shared by modules and workers (:mod:`tests.shared`)."""
    from tests import shared

    shared.FOLDER = _run_folder(tmp_path_factory, "shared_work")
    return shared.FOLDER


#: The options :func:`block_catalog` plans with (fast CAM: the cell, not the finish, is under test).
BLOCK_PLAN = ("--scallop", "0.05", "--no-waterline", "--grid", "0.5", "--quiet")


def copy_block_catalog(dest: Path) -> tuple[Path, Path]:
    """(catalog folder, part): a 30x20x16 mm pocketed block planned with fast options (:data:`BLOCK_PLAN`),
    planned once in the run (:mod:`tests.shared`), its catalog copied into ``dest``. A copy: ``simulate``
    keeps its camera pictures and their measured times in the catalog (factory.cellcameras), so each user
    keeps its own, as when each planned its own; the part, which the plan names, is the run's one."""
    from tests.shared import key_of, once_folder

    def make(root: Path) -> None:
        from typer.testing import CliRunner

        from cli.main import app

        pocket_block(size=(30.0, 20.0, 16.0)).export(root / "block.stl")
        r = CliRunner().invoke(app, ["plan", str(root / "block.stl"), "-o", str(root / "catalog"), *BLOCK_PLAN])
        assert r.exit_code == 0, r.output

    root = once_folder("block_catalog", key_of(BLOCK_PLAN), make)
    shutil.copytree(root / "catalog", dest / "catalog")
    return dest / "catalog", root / "block.stl"


@pytest.fixture(scope="session")
def block_catalog(shared_work, tmp_path_factory) -> tuple[Path, Path]:
    """(catalog folder, part): :func:`copy_block_catalog` once per session (per worker), for tests that
    run the cell (``factory simulate``) and what reads its output."""
    return copy_block_catalog(tmp_path_factory.mktemp("block_catalog"))


@pytest.fixture(scope="session", autouse=True)
def roadmap_cache(tmp_path_factory) -> Iterator[Path]:
    """factory's cache (the cells' roadmaps, :mod:`factory.roadmaps`) in a folder of this session (its
    workers share it), for the commands it runs in-process and in subprocesses alike: never the user's ~/.cache."""
    import os

    # One folder for all the run's workers: a cell's roadmap is built once, a worker that needs it while
    # another builds it waits for that build.
    folder = _run_folder(tmp_path_factory, "factory_cache")
    before = os.environ.get("FACTORY_CACHE_DIR")
    os.environ["FACTORY_CACHE_DIR"] = str(folder)
    yield folder
    if before is None:
        os.environ.pop("FACTORY_CACHE_DIR", None)
    else:
        os.environ["FACTORY_CACHE_DIR"] = before



# How the suite spreads over pytest-xdist's workers (`make test` runs `--dist loadfile`).
# A module's tests stay together on one worker, because many modules plan a part once in a module fixture
# and a second worker would plan it again. A module listed in SPREAD shares no fixture wider than a
# function's, so each of its tests goes to whichever worker is free: the gallery's ten plans no longer
# queue on one worker. SPREAD and LONG modules start first, so the run does not end with one worker alone on
# minutes of work while the other idles. (xdist's own `--dist loadgroup` cannot do this under pytest 9: it
# renames the item's `_nodeid`, which pytest 9 no longer reads, so its groups are silently ignored.)
#: Modules whose tests each plan their own part [paths from the checkout's root].
SPREAD = ("tests/gallery/test_gallery.py",)
#: Modules that take minutes of work on one worker, longest first.
LONG = ("tests/workflow/test_snakemake.py", "tests/robotprog/test_programs.py", "tests/cadcam/test_plan.py",
        "tests/cli/test_simulate.py")


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def pytest_xdist_make_scheduler(config: pytest.Config, log):
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class SpreadScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return nodeid if _module(nodeid) in SPREAD else _module(nodeid)

    # The work units go out in collection order (pytest_collection_modifyitems below), not sorted by their
    # number of tests: that would send the spread tests, one unit each, last.
    config.option.loadscopereorder = False
    return SpreadScheduling(config, log)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    first = {m: n for n, m in enumerate(SPREAD + LONG)}
    # a stable sort: within a module, and among the other modules, the order stays as collected
    items.sort(key=lambda item: first.get(_module(item.nodeid), len(first)))
