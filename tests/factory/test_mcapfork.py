"""The MCAP log written by a second process (factory.mcapfork): the same file as one process writes, the
same errors at the same calls, and nothing left behind by a run that fails or is killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from factory.core.atomic import part_prefix
from factory.core.errors import McapError, OutputExistsError
from factory.mcapfork import ForkedMcapLog, big_log
from factory.mcaplog import McapLog
from factory.rosmsgs import string_msg, tf_message, transform_stamped
from tests.conftest import ROOT

TOPICS = ("/a", "/b/c", "/tf")


def _log_into(log, calls) -> None:
    for topic, text, t in calls:
        if topic == "/tf":
            m = np.eye(4)
            m[:3, 3] = (len(text), t % 7, 0.5)
            log.write(topic, tf_message([transform_stamped("world", "work", m, t)]), t)
        else:
            log.write(topic, string_msg(text), t)
    log.attach("notes.txt", "text/plain", b"x" * len(calls))


calls_strategy = st.lists(st.tuples(st.sampled_from(TOPICS), st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=300), st.integers(0, 2**40)),
                          max_size=60)


@settings(max_examples=15, deadline=None)
@given(calls=calls_strategy, batch=st.sampled_from([1, 64, 1 << 20]))
def test_the_forked_log_is_byte_for_byte_the_log_written_here(calls, batch, tmp_path_factory):
    """Any calls, in batches of any size, give the file one process gives (and the batches cross the pipe
    several times at a small batch size)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("factory.mcapfork.BATCH_BYTES", batch)
        _same_file(calls, tmp_path_factory.mktemp("fork"))


def _same_file(calls, folder: Path) -> None:
    with McapLog(folder / "here.mcap", stage="test", inputs={"a": "0" * 64}) as here:
        _log_into(here, calls)
    with ForkedMcapLog(folder / "forked.mcap", stage="test", inputs={"a": "0" * 64}) as forked:
        _log_into(forked, calls)
    assert (folder / "forked.mcap").read_bytes() == (folder / "here.mcap").read_bytes()
    assert sorted(p.name for p in folder.iterdir()) == ["forked.mcap", "here.mcap"]


def test_a_call_one_process_refuses_is_refused_at_the_call_and_leaves_nothing(tmp_path):
    out = tmp_path / "x.mcap"
    with pytest.raises(McapError, match="carries std_msgs/msg/String"):
        with ForkedMcapLog(out, stage="test") as log:
            log.write("/a", string_msg("one"), 1)
            log.write("/a", tf_message([]), 2)
    with pytest.raises(McapError, match="must be absolute"):
        with ForkedMcapLog(out, stage="test") as log:
            log.write("a", string_msg("one"), 1)
    with pytest.raises(McapError, match="MCAP time range"):
        with ForkedMcapLog(out, stage="test") as log:
            log.write("/a", string_msg("one"), -1)
    with pytest.raises(McapError, match="written twice"):
        with ForkedMcapLog(out, stage="test") as log:
            log.attach("n", "text/plain", b"1")
            log.attach("n", "text/plain", b"2")
    assert list(tmp_path.iterdir()) == []
    out.write_bytes(b"old")
    with pytest.raises(OutputExistsError):
        ForkedMcapLog(out, stage="test")  # refused before any work, as McapLog refuses
    assert out.read_bytes() == b"old"


def test_a_writer_that_dies_fails_the_log_and_leaves_nothing(tmp_path):
    """Killed once its temporary file exists (it cannot remove it itself), as a loaded machine's scheduling
    may have it; another run's temporary file for the same output is left alone."""
    out = tmp_path / "x.mcap"
    other = tmp_path / f"{part_prefix(out, 1)}abc.part"  # pid 1 is never our writer
    other.write_bytes(b"another run's")
    with pytest.raises(McapError, match="writer"):
        with ForkedMcapLog(out, stage="test") as log:
            log.write("/a", string_msg("one"), 1)
            mine = f"{part_prefix(out, log._proc.pid)}*.part"
            deadline = time.monotonic() + 30.0
            while not list(tmp_path.glob(mine)) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert list(tmp_path.glob(mine)), "the writer never opened its file"
            os.kill(log._proc.pid, signal.SIGKILL)
            log._proc.join()
    assert list(tmp_path.iterdir()) == [other]


def test_a_caller_killed_mid_write_leaves_nothing(tmp_path):
    """The caller killed with no chance to clean up: its writer sees the pipe close before the end and
    removes its temporary file; no `.part` is left for later runs to trip over."""
    script = (f"import sys, time; sys.path.insert(0, {str(ROOT)!r})\n"
              "from factory.mcapfork import ForkedMcapLog\n"
              "from factory.rosmsgs import string_msg\n"
              f"with ForkedMcapLog({str(tmp_path / 'x.mcap')!r}, stage='test') as log:\n"
              "    for i in range(20000):\n"
              "        log.write('/a', string_msg('y' * 500), i)\n"
              "    print(log._proc.pid, flush=True)\n"
              "    time.sleep(60)\n")
    caller = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    writer = int(caller.stdout.readline())
    assert any(p.name.endswith(".part") for p in tmp_path.iterdir())  # the file under way
    caller.send_signal(signal.SIGKILL)
    caller.wait()
    deadline = time.monotonic() + 30
    while _alive(writer) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(writer)
    assert list(tmp_path.iterdir()) == []


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (the killed caller's child, not yet reaped) has exited
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_one_processor_writes_here(monkeypatch, tmp_path):
    monkeypatch.setenv("FACTORY_THREADS", "1")
    assert type(big_log(tmp_path / "x.mcap", stage="test")) is McapLog
    monkeypatch.setenv("FACTORY_THREADS", "2")
    assert type(big_log(tmp_path / "x.mcap", stage="test")) is ForkedMcapLog
