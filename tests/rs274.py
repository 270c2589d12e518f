"""LinuxCNC's own G-code interpreter, ``rs274``, run the way every test runs it: on a program and the
job's tool table (``PART.tbl``), as a LinuxCNC user runs ``rs274 -t PART.tbl -g PART.nc``."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path
from typing import Iterable

from cadcam.model import Tool
from cadcam.post import linuxcnc_tool_table


def write_tool_table(program: Path, tools: Iterable[Tool]) -> Path:
    """``DIR/PART.nc`` → ``DIR/PART.tbl``: the table ``factory gcode`` writes beside the program, for a
    job posted in a test (by :func:`cadcam.post.post_process`, which writes no files)."""
    table = program.with_suffix(".tbl")
    table.write_text(linuxcnc_tool_table(tools))
    return table


def run_rs274(program: Path, tool_table: Path, folder: Path, timeout: float = 300.0) -> subprocess.CompletedProcess:
    """``rs274 -t TOOL_TABLE -g PROGRAM``; its canonical machine calls are on stdout.

    A tool the program asks for that the table lacks fails the run (``Requested tool 6 not found in
    the tool table``, exit 1). A table line rs274 cannot read it skips with only a message (and cuts a
    long name with one): either fails the test here, as it would hide a tool behind an unrelated error.

    rs274 keeps its tool table in ``$HOME/.tool.mmap``: each run gets ``folder`` as its HOME, or
    concurrent runs clobber each other's ("Requested tool 3 not found in the tool table")."""
    if not tool_table.is_file():  # rs274 runs on with an empty table, and fails at the first tool
        raise FileNotFoundError(f"no tool table {tool_table}")
    done = subprocess.run(["rs274", "-t", str(tool_table), "-g", str(program)], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=timeout, cwd=folder,
                          env={**os.environ, "HOME": str(folder)})
    said = done.stdout + done.stderr
    assert "Unrecognized line skipped" not in said and "truncated" not in said, (tool_table.read_text(), said[:2000])
    return done
