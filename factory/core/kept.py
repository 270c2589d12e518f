"""The last few answers of a costly pure function, kept by key and shared by a process's threads.

A plan asks several modules for the same part's envelope, shadows or drop-cutter index; passing one object down
through all of them would thread a cache through every signature, so those answers are kept here instead, by
their inputs' content. One mechanism: a bounded, least-recently-used table under a lock, which a forked child
starts afresh (another thread of the parent may have held the lock at the fork, and the child's copy of it
would never be released).
"""

from __future__ import annotations

import collections
import hashlib
import os
import threading
import weakref
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

import numpy as np

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")

__all__ = ["KeptAnswers", "content_key"]


def content_key(array: np.ndarray) -> bytes:
    """A 20-byte digest of ``array``'s values, shape and dtype: equal arrays give equal keys."""
    a = np.ascontiguousarray(array)
    digest = hashlib.blake2b(a.tobytes(), digest_size=20)
    digest.update(repr((a.shape, a.dtype.str)).encode())
    return digest.digest()


class KeptAnswers(Generic[K, V]):
    """At most ``kept`` answers, or as many as fit in ``kept_bytes`` by ``size`` (the oldest go first).

    :meth:`get` makes a missing answer outside the lock, so threads asking for different keys do not wait for
    each other; when two make the same answer at once, the first one kept is the one both get, so every
    caller after the race shares one answer (which matters where the answer gathers state of its own).
    """

    #: Every table, for the at-fork hook (weakly: a table dropped is not kept alive for it).
    _all: weakref.WeakSet[KeptAnswers] = weakref.WeakSet()

    def __init__(self, *, kept: int | None = None, kept_bytes: int | None = None,
                 size: Callable[[V], int] | None = None) -> None:
        if (kept is None) == (kept_bytes is None) or (kept_bytes is not None and size is None):
            raise ValueError("give either kept, or kept_bytes with size")
        self._kept, self._kept_bytes, self._size = kept, kept_bytes, size
        self._answers: collections.OrderedDict[K, V] = collections.OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        KeptAnswers._all.add(self)

    def get(self, key: K, make: Callable[[], V]) -> V:
        """The kept answer for ``key``, else ``make()``'s, kept."""
        with self._lock:
            if key in self._answers:
                self._answers.move_to_end(key)
                return self._answers[key]
        answer = make()
        with self._lock:
            if key in self._answers:  # another thread kept one meanwhile: share it
                self._answers.move_to_end(key)
                return self._answers[key]
            self._answers[key] = answer
            if self._size is not None:
                self._bytes += self._size(answer)
            while self._answers and self._over():
                _, old = self._answers.popitem(last=False)
                if self._size is not None:
                    self._bytes -= self._size(old)
        return answer

    def _over(self) -> bool:
        if self._kept is not None:
            return len(self._answers) > self._kept
        return self._bytes > self._kept_bytes

    def __len__(self) -> int:
        return len(self._answers)

    def forget(self) -> None:
        """Drop every kept answer."""
        with self._lock:
            self._answers.clear()
            self._bytes = 0

    @classmethod
    def _after_fork(cls) -> None:
        """A forked child's tables start empty, each with a lock nobody holds."""
        for table in cls._all:
            table._lock = threading.Lock()
            table._answers.clear()
            table._bytes = 0


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=KeptAnswers._after_fork)
