"""Outputs that appear whole or not at all.

Every file a stage writes goes to a temporary file in the destination's folder and is
renamed over the destination only when writing succeeded, so a failed run never leaves
a partial file and never destroys what the user had.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from factory.core.errors import OutputError, OutputExistsError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(path: Path, overwrite: bool) -> None:
    """Check, before any work, that ``path`` can be written.

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is false.
    OutputError
        ``path`` is a folder, or the nearest of its folders that exists is not a folder
        (``-o afile/p.nc``).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError("is a folder, expected a file name", source=path)
    if path.exists() and not overwrite:
        raise OutputExistsError("exists; pass --overwrite to replace it", source=path)
    folder = path.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError(f"not a folder, so {path.name} cannot be written in it", source=folder)


def part_prefix(path: Path, pid: int | None = None) -> str:
    """The start of the temporary file's name that :func:`atomic_output` writes ``path`` through from process
    ``pid`` (default this one): the process's id is in it, so that a process that watches another write (a
    forked log's writer, :mod:`factory.mcapfork`) can remove what it leaves if it is killed, which it cannot
    do itself, and nothing another run is writing."""
    return f".{path.name}.{os.getpid() if pid is None else pid}."


@contextlib.contextmanager
def atomic_output(path: str | Path, *, overwrite: bool = False, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file that replaces ``path`` when the block exits cleanly.

    Parameters
    ----------
    path : str or Path
        Final destination. Its parent folder is created if missing.
    overwrite : bool
        Replace an existing file; otherwise :class:`OutputExistsError` is raised before
        anything is written.
    mode : str
        ``"wb"`` or ``"w"`` (text, UTF-8, ``\\n`` line endings).
    """
    path = Path(path)
    check_writable(path, overwrite)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=part_prefix(path), suffix=".part", dir=path.parent)
    # mkstemp makes the file private (0600); an output should get the mode any new file would.
    os.chmod(tmp, 0o666 & ~_umask())
    try:
        if "b" in mode:
            f = os.fdopen(fd, mode)
        else:
            f = os.fdopen(fd, mode, encoding="utf-8", newline="\n")
        with f:
            yield f
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_bytes(path: str | Path, data: bytes, *, overwrite: bool = False) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path, overwrite=overwrite) as f:
        f.write(data)


def write_text(path: str | Path, text: str, *, overwrite: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    with atomic_output(path, overwrite=overwrite, mode="w") as f:
        f.write(text)
