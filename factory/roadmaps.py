"""The cell roadmaps kept on disk: built once per cell file, found again by its content.

A roadmap (:mod:`robotprog.roadmap`) is keyed by the SHA-256 of the cell file's content it stands
on (:func:`roadmap_path`) and of the code that builds and proves it (:func:`code_version`), so an
edited cell or a changed proof never reads a stale one. The cache folder is ``$FACTORY_CACHE_DIR`` if set (tests point it at a
temporary folder), else ``$XDG_CACHE_HOME/factory``, else ``~/.cache/factory``; roadmaps live in
its ``roadmaps/`` folder as ``<key>.npz``, written atomically; plans that need the same one at once
build it once (the first builds, the others wait for it and read it).
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

from factory.core.atomic import write_bytes
from factory.core.errors import CellError
from robotprog.cell import Cell
from robotprog.collision import CollisionWorld, cell_static_boxes
from robotprog.roadmap import Roadmap, RoadmapOptions, cell_roadmap

log = logging.getLogger(__name__)

#: The modules whose source decides what a roadmap holds and what it proves.
_CODE = ("robotprog/roadmap.py", "robotprog/sweep.py", "robotprog/collision.py", "robotprog/robots.py")


def cache_dir() -> Path:
    """The folder of factory's cache (``$FACTORY_CACHE_DIR``, ``$XDG_CACHE_HOME/factory``, ``~/.cache/factory``)."""
    own = os.environ.get("FACTORY_CACHE_DIR")
    if own:
        return Path(own)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "factory"


@functools.cache
def code_version() -> str:
    """SHA-256 of the sources that build and prove a roadmap (hex)."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for name in _CODE:
        h.update(name.encode())
        h.update((root / name).read_bytes())
    return h.hexdigest()


def roadmap_path(cell: Cell, options: RoadmapOptions = RoadmapOptions()) -> Path:
    """Where the roadmap of ``cell`` is kept: keyed by what of the cell file's content it stands on
    (the robot, its home and base, the gripper, the static boxes: an edit to the speed scaling or
    the I/O of the same cell reuses it), the options and :func:`code_version`."""
    h = hashlib.sha256()
    h.update(repr((cell.robot, cell.gripper, cell_static_boxes(cell))).encode())
    h.update(repr(options).encode())
    h.update(code_version().encode())
    return cache_dir() / "roadmaps" / f"{h.hexdigest()[:32]}.npz"


@dataclass(frozen=True, eq=False)
class CachedRoadmap:
    """A cell's roadmap and where it came from.

    Attributes
    ----------
    roadmap : Roadmap
    path : Path
        Its file in the cache.
    built : bool
        Whether it was built now (else read from ``path``).
    """

    roadmap: Roadmap
    path: Path
    built: bool


def cached_roadmap(cell: Cell, world: CollisionWorld, *, rebuild: bool = False,
                   options: RoadmapOptions = RoadmapOptions(),
                   progress: Callable[[int, int], None] | None = None) -> CachedRoadmap:
    """The roadmap of ``cell`` (its robot loaded in ``world``): read from the cache, else (or with
    ``rebuild``) built, proven and written there.

    A cached file that cannot be read is built again (logged), not trusted.

    Raises
    ------
    CellError
        The roadmap cannot be built (:func:`robotprog.roadmap.build_roadmap`).
    """
    path = roadmap_path(cell, options)
    found = None if rebuild else _read(path, world, say=False)  # said under the lock, once
    if found is not None:
        return CachedRoadmap(found, path, False)
    path.parent.mkdir(parents=True, exist_ok=True)
    with _one_builder(path):
        # Plans started together (make demo's, a workflow's, the test workers') build a roadmap once: the
        # others wait here for it and read it, instead of spending the same processor minute each.
        found = None if rebuild else _read(path, world)
        if found is not None:
            return CachedRoadmap(found, path, False)
        roadmap = cell_roadmap(cell, world, options, progress)
        write_bytes(path, roadmap.to_bytes(), overwrite=True)
    return CachedRoadmap(roadmap, path, True)


def _read(path: Path, world: CollisionWorld, say: bool = True) -> Roadmap | None:
    """The roadmap kept at ``path``; None when there is none, or it cannot be read (logged if ``say``:
    it is built again)."""
    if not path.exists():
        return None
    try:
        return Roadmap.from_bytes(path.read_bytes(), world.robot.dof, str(path))
    except (CellError, OSError) as e:
        if say:
            log.warning("%s: cached roadmap unreadable (%s); building it again", path, e)
        return None


@contextlib.contextmanager
def _one_builder(path: Path) -> Iterator[None]:
    """Hold ``path``'s build lock (``<key>.lock`` beside it, an advisory ``flock`` the system drops
    with the process, so a killed build leaves no lock held)."""
    with open(path.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
