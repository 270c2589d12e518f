"""One root exception for the whole toolchain, a subclass per stage.

Every exception carries the data a user needs to understand it. ``source`` names the
file (or field, or pose) the problem is in; the CLI prints ``error: <source>: <message>``
and exits non-zero. Library code raises these for bad input; it never asserts on
user input and never returns ``None`` to mean failure.
"""

from __future__ import annotations

import reprlib
from pathlib import Path

#: Longest user value an error message quotes [characters].
SHOWN_CHARS = 60

_repr = reprlib.Repr()
_repr.maxlevel, _repr.maxstring, _repr.maxother = 2, SHOWN_CHARS, SHOWN_CHARS


def clipped(text: str, limit: int = 2 * SHOWN_CHARS) -> str:
    """The first line of a message from elsewhere (a library's exception), at most ``limit`` characters."""
    lines = str(text).strip().splitlines()
    first = lines[0] if lines else ""
    return first if len(first) <= limit else first[:limit - 3] + "..."


def shown(value: object) -> str:
    """A user's value quoted in an error message: its repr, bounded in depth, items and
    length, so a huge or deeply shared value (a YAML alias bomb) is never expanded."""
    text = _repr.repr(value)
    return text if len(text) <= SHOWN_CHARS else text[:SHOWN_CHARS - 3] + "..."


def field_name(key: object) -> str:
    """A mapping key as a step of a field's path (``machine.max_rpm``): bare when it reads as a name,
    else quoted like :func:`shown`, so a key holding a newline or spaces never breaks the one-line error."""
    text = str(key)
    return text if text.replace("-", "_").isidentifier() else shown(key)


class FactoryError(Exception):
    """Root of every error factory raises on purpose.

    Parameters
    ----------
    message : str
        What is wrong, one line, no trailing full stop needed.
    source : str or Path, optional
        The file, field or object the problem is in.
    """

    def __init__(self, message: str, *, source: str | Path | None = None, **data: object):
        super().__init__(message)
        self.message = message
        self.source = None if source is None else str(source)
        self.data = data

    def with_source(self, source: str | Path) -> "FactoryError":
        """Name the file the problem came from, when the raiser did not know it."""
        if self.source is None:
            self.source = str(source)
        return self

    def __str__(self) -> str:
        return f"{self.source}: {self.message}" if self.source else self.message


class MeshError(FactoryError):
    """A part mesh cannot be read, is empty, open, non-finite or implausibly sized."""


class SetupError(FactoryError):
    """Stock, work origin or units do not fit the part."""


class ToolError(FactoryError):
    """The tool library is malformed or has no tool fit for an operation."""


class ToolpathError(FactoryError):
    """A toolpath cannot be computed, or a toolpath file cannot be read."""


class GcodeError(FactoryError):
    """G-code cannot be parsed or posted. ``line`` is the 1-based line number when known."""


class VerifyError(FactoryError):
    """The material-removal simulation cannot run on its inputs."""


class McapError(FactoryError):
    """An MCAP file cannot be written or read back."""


class OutputError(FactoryError):
    """An output cannot be written where it was asked for (its folder is a file, ...)."""


class OutputExistsError(OutputError):
    """An output file exists and overwriting was not asked for."""


class VisionError(FactoryError):
    """An image, board description or camera model file cannot be used."""


class CalibrationError(VisionError):
    """Camera calibration cannot run on its views: no board found, too few views, bad board spec."""


class CellError(FactoryError):
    """The robot cell description (robot, gripper, rack, vise, enclosure) is malformed."""


class PlanningError(FactoryError):
    """A robot motion cannot be planned: unreachable pose, joint limits, timing failure."""


class SchedulerError(FactoryError):
    """An orders file is malformed, or the cell scheduler was driven with an event its state does not accept."""


class RecordError(FactoryError):
    """The process record (database) cannot be opened, read or written. ``source`` is the database
    URL with its password masked."""


class LiveError(FactoryError):
    """The live view's server cannot start (port in use, address not available)."""
