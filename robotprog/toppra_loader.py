"""TOPP-RA, imported once and without matplotlib.

toppra imports ``matplotlib.pyplot`` at the top of its modules only to draw its own plots on
request. Importing pyplot (and matplotlib under it) costs 0.37 s of processor time, which every
``factory plan`` job paid when it first timed a robot move, and no factory code draws with it.
While toppra is imported, ``matplotlib`` and ``matplotlib.pyplot`` are stand-ins that import the
real modules on first use, so toppra's plotting still works if anyone calls it; afterwards the
stand-ins leave ``sys.modules``, so any other ``import matplotlib`` gets the real package.
"""

from __future__ import annotations

import functools
import importlib
import sys
import threading
from types import ModuleType
from typing import Any

#: The modules toppra imports for plotting only, parent first.
_PLOTTING = ("matplotlib", "matplotlib.pyplot")

_lock = threading.Lock()


class _ImportedOnFirstUse(ModuleType):
    """Stands in for the module of its name: the first attribute asked of it imports the real one."""

    def __getattr__(self, name: str) -> Any:
        if sys.modules.get(self.__name__) is self:  # still in place: make way for the real module
            del sys.modules[self.__name__]
        return getattr(importlib.import_module(self.__name__), name)


@functools.cache
def load_toppra() -> ModuleType:
    """The ``toppra`` package with ``toppra.algorithm`` and ``toppra.constraint`` imported."""
    with _lock:
        stand_ins = {name: _ImportedOnFirstUse(name) for name in _PLOTTING if name not in sys.modules}
        if len(stand_ins) == len(_PLOTTING):
            # `import matplotlib.pyplot as plt` takes pyplot as an attribute of the parent.
            stand_ins["matplotlib"].pyplot = stand_ins["matplotlib.pyplot"]  # type: ignore[attr-defined]
        sys.modules.update(stand_ins)
        try:
            import toppra
            import toppra.algorithm
            import toppra.constraint
        finally:
            for name, stand_in in stand_ins.items():
                if sys.modules.get(name) is stand_in:
                    del sys.modules[name]
    return toppra
