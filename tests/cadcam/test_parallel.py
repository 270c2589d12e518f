"""Work in forked processes answers as the serial loop does, errors included."""

import os
import time

import pytest

import cadcam.parallel as par
from factory.core.errors import FactoryError, ToolpathError


def square_and_pid(x):
    return x * x, os.getpid()


def fails(x):
    raise ToolpathError(f"no path for {x}")


def test_process_map_keeps_the_order_and_uses_other_processes(monkeypatch):
    monkeypatch.setenv(par.THREADS_ENV, "2")
    done = []
    out = par.process_map(square_and_pid, [(i,) for i in range(6)], weights=[1, 5, 2, 9, 3, 1], min_total=0,
                          done=done.append)
    assert [v for v, _ in out] == [i * i for i in range(6)]
    assert all(pid != os.getpid() for _, pid in out)
    assert sorted(done) == list(range(6))


def test_process_map_runs_small_work_here():
    out = par.process_map(square_and_pid, [(3,), (4,)], weights=[1, 1], min_total=100)
    assert out == [(9, os.getpid()), (16, os.getpid())]


def test_background_result_and_error_are_the_serial_ones(monkeypatch):
    monkeypatch.setenv(par.THREADS_ENV, "2")
    value, pid = par.Background(square_and_pid, 7).result()
    assert value == 49 and pid != os.getpid()
    with pytest.raises(ToolpathError, match="no path for 3"):
        par.Background(fails, 3).result()


def test_background_is_ready_once_the_child_has_answered(monkeypatch):
    monkeypatch.setenv(par.THREADS_ENV, "2")
    b = par.Background(square_and_pid, 5)
    for _ in range(2000):  # the child's answer arrives (at most 20 s on a loaded machine)
        if b.ready():
            break
        time.sleep(0.01)
    assert b.ready()
    assert b.result()[0] == 25
    assert not b.ready()  # taken: no child left to answer
    monkeypatch.setenv(par.THREADS_ENV, "1")
    assert not par.Background(square_and_pid, 5).ready()  # no child: the work is done by result, here


def test_background_cancel_ends_the_child(monkeypatch):
    monkeypatch.setenv(par.THREADS_ENV, "2")
    b = par.Background(square_and_pid, 2)
    proc = b._proc
    b.cancel()
    assert proc is not None and not proc.is_alive()
    assert b.result()[0] == 4  # after a cancel the work is done here


def test_one_thread_runs_everything_here(monkeypatch):
    """FACTORY_THREADS=1 (a workflow job's one thread): no worker process, whatever the work."""
    monkeypatch.setenv(par.THREADS_ENV, "1")
    assert par.processors() == 1
    out = par.process_map(square_and_pid, [(i,) for i in range(4)], weights=[9] * 4, min_total=0)
    assert [pid for _, pid in out] == [os.getpid()] * 4
    background = par.Background(square_and_pid, 5)
    assert background._proc is None and background.result() == (25, os.getpid())


@pytest.mark.parametrize("text", ["0", "-2", "two", "1.5"])
def test_a_bad_thread_count_is_refused_by_name(monkeypatch, text):
    monkeypatch.setenv(par.THREADS_ENV, text)
    with pytest.raises(FactoryError) as e:
        par.processors()
    assert e.value.source == "FACTORY_THREADS" and repr(text) in e.value.message


def test_the_thread_count_is_capped_and_unset_follows_the_affinity(monkeypatch):
    monkeypatch.setenv(par.THREADS_ENV, "64")
    assert par.processors() == par.MAX_WORKERS
    monkeypatch.delenv(par.THREADS_ENV)
    assert par.processors() == min(par.MAX_WORKERS, len(os.sched_getaffinity(0)))


def _stat(path, user, idle, iowait=0):
    """A /proc/stat of the whole machine's counters [ticks] (one processor's line after it, not read)."""
    path.write_text(f"cpu  {user} 0 0 {idle} {iowait} 0 0 0 0 0\ncpu0 {user} 0 0 {idle} {iowait} 0 0 0 0 0\n")


def test_idle_meter_reads_the_span_between_its_looks(monkeypatch, tmp_path):
    stat, clock = tmp_path / "stat", [100.0]
    monkeypatch.setattr(par, "PROC_STAT", str(stat))
    monkeypatch.setattr(par.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(par.os, "cpu_count", lambda: 2)
    _stat(stat, user=1000, idle=5000)
    meter = par.IdleMeter()
    _stat(stat, user=1100, idle=5100)  # one processor busy, the other idle
    clock[0] += 0.1
    assert meter.idle() is None  # too short a span to tell: it goes on
    clock[0] += 0.9
    assert meter.idle() == pytest.approx(1.0)
    _stat(stat, user=1500, idle=5100)  # both busy for 2 s, 0.5 s of it a round of the meter's owner
    clock[0] += 2.0
    assert meter.idle(own=0.5) == pytest.approx(0.25)
    assert meter.idle() is None  # a new span began with that look
    _stat(stat, user=1550, idle=5100, iowait=50)  # waiting on a disk is idle
    clock[0] += 0.5
    assert meter.idle() == pytest.approx(1.0)
    _stat(stat, user=1550, idle=5300, iowait=50)
    clock[0] += 1.0
    assert meter.idle(own=5.0) == 2.0  # never more than the machine has


def test_idle_meter_without_the_kernels_counters_reads_the_load_average(monkeypatch, tmp_path):
    monkeypatch.setattr(par, "PROC_STAT", str(tmp_path / "none"))
    monkeypatch.setattr(par, "idle_processors", lambda: 1.25)
    assert par.IdleMeter().idle() == 1.25


@pytest.mark.skipif(not os.path.exists(par.PROC_STAT), reason="no /proc/stat here")
def test_idle_meter_on_this_machine_is_within_its_processors():
    meter = par.IdleMeter()
    time.sleep(par.MIN_SPAN + 0.05)
    idle = meter.idle()
    assert idle is not None and 0.0 <= idle <= os.cpu_count()
