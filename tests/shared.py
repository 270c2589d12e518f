"""Work several test modules need with the same inputs (a sample's tending plan, a planned catalog), done
once per test run and shared through files by pytest-xdist's workers.

``make test`` runs ``--dist loadfile``: each module on one worker, so a module- or session-scoped fixture
still runs once per module or once per worker. Here the first test that needs a result computes it under
a file lock and writes it whole into the run's folder (a value: a temporary name, then an atomic rename; a
folder: a marker beside it once it is complete); every other test, on either worker, waits for the lock if
it is held and reads it. The folder belongs to the run (pytest's base temp, beside the
cells' roadmaps, :func:`tests.conftest.roadmap_cache`), so nothing outlives the run and the code a result
was computed with is always the code under test: a key names only the inputs that change the result.

Each caller gets its own copy (:func:`once` unpickles afresh; a folder from :func:`once_folder` is read,
never written): a test that changes what it got changes nothing another test sees.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import pickle
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

#: The run's folder of shared results; set by :func:`tests.conftest.shared_work` for the session.
FOLDER: Path | None = None


def key_of(*inputs: Any) -> str:
    """A short digest of ``inputs`` by their ``repr`` (paths by their content, see :func:`content`)."""
    return hashlib.sha256(repr(inputs).encode()).hexdigest()[:20]


def content(path: Path) -> str:
    """A file's content digest, for keys: the same name with other content is another input."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _folder() -> Path:
    if FOLDER is None:
        raise RuntimeError("tests.shared is used outside a pytest session (tests/conftest.py sets its folder)")
    return FOLDER


@contextlib.contextmanager
def _only_one(path: Path) -> Iterator[None]:
    """Hold ``path``'s lock (an advisory ``flock`` the system drops with the process: a worker killed
    while computing leaves no lock held)."""
    with open(path.with_name(path.name + ".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def once(name: str, key: str, compute: Callable[[], T]) -> T:
    """``compute()``, computed once in the run for ``(name, key)``; every call returns its own copy."""
    path = _folder() / f"{name}-{key}.pickle"
    if not path.exists():
        with _only_one(path):
            if not path.exists():
                tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
                tmp.write_bytes(pickle.dumps(compute(), protocol=pickle.HIGHEST_PROTOCOL))
                os.replace(tmp, path)
    return pickle.loads(path.read_bytes())


def once_folder(name: str, key: str, make: Callable[[Path], None]) -> Path:
    """A folder ``make(folder)`` filled, made once in the run for ``(name, key)``; callers only read it.

    It is made in place, not renamed into place: files in it may name each other by absolute path (a
    catalog's plans name their part). A marker beside it says it is whole; a folder without one (its
    maker failed or was killed) is made again by the next caller."""
    path = _folder() / f"{name}-{key}"
    done = path.with_name(path.name + ".done")
    if not done.exists():
        with _only_one(path):
            if not done.exists():
                shutil.rmtree(path, ignore_errors=True)
                path.mkdir()
                make(path)
                done.touch()
    return path
