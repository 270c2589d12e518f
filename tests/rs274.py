"""LinuxCNC's own G-code interpreter, ``rs274``, run the way every test runs it."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path


def run_rs274(program: Path, tool_table: str, folder: Path, timeout: float = 300.0) -> subprocess.CompletedProcess:
    """``rs274 -t TOOL_TABLE -g PROGRAM`` with the tool table (LinuxCNC ``.tbl`` text) written
    into ``folder``; its canonical machine calls are on stdout.

    rs274 keeps its tool table in ``$HOME/.tool.mmap``: each run gets ``folder`` as its HOME, or
    concurrent runs clobber each other's ("Requested tool 3 not found in the tool table")."""
    tbl = folder / "tool.tbl"
    tbl.write_text(tool_table)
    return subprocess.run(["rs274", "-t", str(tbl), "-g", str(program)], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=timeout, cwd=folder,
                          env={**os.environ, "HOME": str(folder)})
