"""A run as a rosbag2 folder (``metadata.yaml`` and one MCAP file), which ``ros2 bag info`` and ``ros2 bag play`` take.

:class:`BagLog` takes the same ``write(topic, msg, log_time_ns, latched=...)`` calls as
:class:`factory.mcaplog.McapLog` and writes each message with rosbags' rosbag2 writer (bag format 9,
the MCAP storage plugin): the same CDR bytes, types (:data:`factory.rosmsgs.TYPESTORE`, with their
RIHS01 hashes) and offered QoS (:func:`factory.mcaplog.offered_qos_profiles`: a latched topic is
replayed transient local) as the MCAP log. The folder appears only when the ``with`` block ends
without an exception: it is written beside, under a hidden name, and renamed, so an interrupted run
leaves nothing.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.metadata import parse_qos

from factory.core.errors import McapError, OutputError, OutputExistsError
from factory.mcaplog import offered_qos_profiles
from factory.rosmsgs import TYPESTORE

log = logging.getLogger(__name__)


class BagLog:
    """Writes one rosbag2 folder at ``path``. Use as a context manager.

    Parameters
    ----------
    path : Path
        The bag's folder; its MCAP file inside is ``<folder name>.mcap`` (rosbags' name; ``ros2 bag``
        reads the files ``metadata.yaml`` lists).
    overwrite : bool
        Replace a folder that exists (only once the new one is complete).

    Raises
    ------
    OutputExistsError
        ``path`` exists and ``overwrite`` is false (raised by the constructor, before any work).
    OutputError
        Its folder does not exist.
    McapError
        A topic is reused with another type, or the writer fails.
    """

    def __init__(self, path: str | Path, *, overwrite: bool = False) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        if self.path.exists() and not overwrite:
            raise OutputExistsError("exists; pass --overwrite to replace it", source=self.path)
        if not self.path.parent.is_dir():
            raise OutputError(f"folder {self.path.parent} does not exist", source=self.path)
        self._tmp: Path | None = None
        self._writer: Writer | None = None
        self._connections: dict[str, tuple[Any, str]] = {}  # topic -> (connection, type)

    def __enter__(self) -> "BagLog":
        holder = Path(tempfile.mkdtemp(prefix=f".{self.path.name}.", dir=self.path.parent))
        self._tmp = holder / self.path.name  # the writer names its file after this folder
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        return self

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        """Serialise ``msg`` to CDR and write it on ``topic`` at log time ``log_time_ns`` [ns]."""
        if self._writer is None:
            raise McapError("BagLog is not open; use it in a with block", source=self.path)
        typename = msg.__msgtype__
        known = self._connections.get(topic)
        if known is None:
            conn = self._writer.add_connection(topic, typename, typestore=TYPESTORE,
                                               offered_qos_profiles=parse_qos(offered_qos_profiles(latched)))
            known = self._connections[topic] = (conn, typename)
        elif known[1] != typename:
            raise McapError(f"topic {topic} carries {known[1]}, not {typename}", source=self.path)
        self._writer.write(known[0], int(log_time_ns), bytes(TYPESTORE.serialize_cdr(msg, typename)))

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        writer, tmp = self._writer, self._tmp
        self._writer = self._tmp = None
        if writer is None or tmp is None:
            return
        try:
            try:
                writer.close()
            except WriterError as e:
                if exc_type is None:
                    raise McapError(f"cannot finish the bag: {e}", source=self.path) from None
            if exc_type is None:
                if self.path.exists():  # overwrite: the old folder goes once the new one is whole
                    shutil.rmtree(self.path)
                os.replace(tmp, self.path)
                log.info("wrote %s (%d topics)", self.path, len(self._connections))
        finally:
            shutil.rmtree(tmp.parent, ignore_errors=True)


__all__ = ["BagLog"]
