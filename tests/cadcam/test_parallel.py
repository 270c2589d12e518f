"""Work in forked processes answers as the serial loop does, errors included."""

import os

import pytest

import cadcam.parallel as par
from factory.errors import ToolpathError


def square_and_pid(x):
    return x * x, os.getpid()


def fails(x):
    raise ToolpathError(f"no path for {x}")


def test_process_map_keeps_the_order_and_uses_other_processes(monkeypatch):
    monkeypatch.setattr(par, "WORKERS", 2)
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
    monkeypatch.setattr(par, "WORKERS", 2)
    value, pid = par.Background(square_and_pid, 7).result()
    assert value == 49 and pid != os.getpid()
    with pytest.raises(ToolpathError, match="no path for 3"):
        par.Background(fails, 3).result()


def test_background_cancel_ends_the_child(monkeypatch):
    monkeypatch.setattr(par, "WORKERS", 2)
    b = par.Background(square_and_pid, 2)
    proc = b._proc
    b.cancel()
    assert proc is not None and not proc.is_alive()
    assert b.result()[0] == 4  # after a cancel the work is done here
