"""The roadmaps' disk cache: keyed by the cell's content, in the folder the environment names."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factory.core.resources import FIXTURES
from factory.roadmaps import cache_dir, cached_roadmap, roadmap_path
from robotprog.cell import Box, Pose, load_cell
from robotprog.collision import collision_world
from robotprog.roadmap import RoadmapOptions

TINY = RoadmapOptions(nodes=8, neighbours=3)


@pytest.fixture(scope="module")
def cell():
    return load_cell(FIXTURES / "cell.yaml")


@pytest.fixture(scope="module")
def world(cell):
    return collision_world(cell)


def test_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("FACTORY_CACHE_DIR", str(tmp_path / "own"))
    assert cache_dir() == tmp_path / "own"
    monkeypatch.delenv("FACTORY_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "factory"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "factory"


def test_built_once_then_read_and_rebuilt_when_unreadable(monkeypatch, tmp_path, cell, world):
    monkeypatch.setenv("FACTORY_CACHE_DIR", str(tmp_path))
    first = cached_roadmap(cell, world, options=TINY)
    assert first.built and first.path.is_relative_to(tmp_path) and first.path.exists()
    second = cached_roadmap(cell, world, options=TINY)
    assert not second.built
    np.testing.assert_array_equal(second.roadmap.nodes, first.roadmap.nodes)
    np.testing.assert_array_equal(second.roadmap.edges, first.roadmap.edges)
    first.path.write_bytes(b"half a file")
    third = cached_roadmap(cell, world, options=TINY)
    assert third.built
    np.testing.assert_array_equal(third.roadmap.edges, first.roadmap.edges)


def test_a_plan_that_finds_the_roadmap_being_built_waits_and_reads_it(monkeypatch, tmp_path, cell, world):
    """Two plans at once (make demo's, the test workers') build a cell's roadmap once: the second waits
    on the build lock and reads what the first wrote."""
    import threading

    import factory.roadmaps as roadmaps

    monkeypatch.setenv("FACTORY_CACHE_DIR", str(tmp_path / "elsewhere"))
    made = cached_roadmap(cell, world, options=TINY).roadmap  # the first plan's build, made ahead
    monkeypatch.setenv("FACTORY_CACHE_DIR", str(tmp_path))
    path = roadmap_path(cell, TINY)
    path.parent.mkdir(parents=True)
    builds, looked = [], threading.Event()
    monkeypatch.setattr(roadmaps, "cell_roadmap", lambda *a, **k: builds.append(1) or made)
    real_read = roadmaps._read

    def read(*args, **kwargs):
        found = real_read(*args, **kwargs)
        looked.set()  # the second plan found nothing: next it takes the lock
        return found

    monkeypatch.setattr(roadmaps, "_read", read)
    got = []
    with roadmaps._one_builder(path):  # the first plan, building
        second = threading.Thread(target=lambda: got.append(cached_roadmap(cell, world, options=TINY)))
        second.start()
        assert looked.wait(60)
        path.write_bytes(made.to_bytes())  # the first plan's build lands
    second.join(60)
    assert builds == [] and len(got) == 1 and not got[0].built
    np.testing.assert_array_equal(got[0].roadmap.edges, made.edges)


def test_key_changes_with_the_static_cell_not_with_its_speed(cell):
    key = roadmap_path(cell, TINY)
    slower = dataclasses.replace(cell, motion=dataclasses.replace(cell.motion, speed_scaling=0.5))
    assert roadmap_path(slower, TINY) == key
    bin_ = Box("reject_bin", (0.2, 0.2, 0.2), Pose((0.9, 0.9, 0.1), (0.0, 0.0, 0.0)))
    moved = dataclasses.replace(cell, reject_bin=bin_ if cell.reject_bin is None else dataclasses.replace(
        cell.reject_bin, pose=Pose((0.9, 0.9, 0.1), (0.0, 0.0, 0.0))))
    assert roadmap_path(moved, TINY) != key
    assert roadmap_path(cell, RoadmapOptions(nodes=9, neighbours=3)) != key
