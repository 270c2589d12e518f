"""factory.core.kept: the last few answers of a costly pure function, by key."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from factory.core.kept import KeptAnswers, content_key


@given(st.lists(st.integers(0, 6), max_size=40), st.integers(1, 4))
def test_the_last_few_keys_asked_are_the_ones_kept(keys, kept):
    table: KeptAnswers[int, int] = KeptAnswers(kept=kept)
    made: list[int] = []
    recent: list[int] = []  # the reference: most recently asked last
    for key in keys:
        before = len(made)
        assert table.get(key, lambda k=key: made.append(k) or k * 10) == key * 10
        assert len(made) == before + (key not in recent)  # made exactly when not kept
        if key in recent:
            recent.remove(key)
        recent = (recent + [key])[-kept:]
    assert len(table) == len(recent)
    for key in recent:  # kept: asked again, nothing is made
        n = len(made)
        table.get(key, lambda: pytest.fail("made again"))
        assert len(made) == n


@given(st.lists(st.integers(1, 50), min_size=1, max_size=30), st.integers(20, 100))
def test_a_byte_budget_keeps_the_newest_that_fit(sizes, budget):
    table: KeptAnswers[int, np.ndarray] = KeptAnswers(kept_bytes=budget, size=lambda a: a.nbytes)
    for i, n in enumerate(sizes):
        table.get(i, lambda n=n: np.zeros(n, np.uint8))
    total, expect = 0, 0
    for n in reversed(sizes):  # the newest that fit within the budget together
        if total + n > budget:
            break
        total += n
        expect += 1
    assert len(table) == expect
    assert table._bytes == total


def test_threads_racing_for_one_key_share_the_first_answer_kept():
    table: KeptAnswers[str, object] = KeptAnswers(kept=2)
    start = threading.Barrier(4)
    got = []

    def ask():
        start.wait()
        got.append(table.get("part", object))

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len({id(a) for a in got}) == 1
    assert table.get("part", object) is got[0]


def test_a_forked_child_starts_empty_even_with_the_lock_held():
    table: KeptAnswers[str, int] = KeptAnswers(kept=1)
    table.get("a", lambda: 1)
    with table._lock:  # another thread holds it at the fork
        pid = os.fork()
        if pid == 0:  # the child: must neither hang nor see the parent's answer
            os._exit(0 if table.get("a", lambda: 2) == 2 else 1)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert table.get("a", lambda: 3) == 1


def test_content_keys_tell_values_shapes_and_types_apart():
    a = np.arange(6, dtype=np.float64)
    assert content_key(a) == content_key(a.copy())
    assert content_key(a) != content_key(a.reshape(2, 3))
    assert content_key(a) != content_key(a.astype(np.float32))
    assert content_key(a) != content_key(a + 1e-12)


def test_either_a_count_or_a_byte_budget():
    with pytest.raises(ValueError):
        KeptAnswers()
    with pytest.raises(ValueError):
        KeptAnswers(kept=1, kept_bytes=10, size=len)
    with pytest.raises(ValueError):
        KeptAnswers(kept_bytes=10)
