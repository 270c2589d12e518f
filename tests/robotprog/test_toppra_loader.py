"""TOPP-RA loaded without matplotlib: timing a move imports no plotting, toppra's plots still work."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(code: str) -> dict:
    """The JSON object a fresh interpreter prints last after running ``code``."""
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                       env={**os.environ, "MPLBACKEND": "Agg"})
    return json.loads(r.stdout.splitlines()[-1])


def test_timing_a_move_imports_toppra_but_no_matplotlib():
    seen = _run(
        "import json, sys\n"
        "import numpy as np\n"
        "from robotprog.timing import time_path\n"
        "wp = np.array([[0.0, -1.57, 1.57, -1.57, -1.57, 0.0], [1.2, -1.0, 1.9, -2.0, -1.57, 2.5]])\n"
        "traj = time_path(wp, np.full(6, 1.5), np.full(6, 1.5))\n"
        "print(json.dumps({'duration': traj.duration, 'modules': sorted({m.split('.')[0] for m in sys.modules})}))\n")
    assert seen["duration"] > 0
    assert "toppra" in seen["modules"]
    assert "matplotlib" not in seen["modules"]


def test_toppras_plotting_gets_the_real_pyplot_on_first_use():
    seen = _run(
        "import json, sys\n"
        "from robotprog.toppra_loader import load_toppra\n"
        "toppra = load_toppra()\n"
        "import toppra.algorithm.algorithm as algorithm\n"
        "before = 'matplotlib' in sys.modules\n"
        "plot = algorithm.plt.plot\n"  # first use: the real pyplot is imported now
        "import matplotlib.pyplot\n"
        "print(json.dumps({'before': before, 'real': plot is matplotlib.pyplot.plot,\n"
        "                  'module': type(sys.modules['matplotlib.pyplot']).__name__,\n"
        "                  'parent': sys.modules['matplotlib'].pyplot is sys.modules['matplotlib.pyplot']}))\n")
    assert seen == {"before": False, "real": True, "module": "module", "parent": True}


def test_matplotlib_imported_first_is_left_as_it_is():
    seen = _run(
        "import json, sys\n"
        "import matplotlib.pyplot\n"
        "from robotprog.toppra_loader import load_toppra\n"
        "load_toppra()\n"
        "import toppra.algorithm.algorithm as algorithm\n"
        "print(json.dumps({'same': algorithm.plt is matplotlib.pyplot}))\n")
    assert seen == {"same": True}
