"""CPU and wall of a plan's chip feeds stage (:func:`cadcam.chipfeed.chip_fed` calls), replayed alone.

    python benchmarks/chip_calls.py record samples/relief.stl CALLS.pkl     # plan it (no robot), keep the calls
    PYTHONPATH=/other/checkout python benchmarks/chip_calls.py replay CALLS.pkl [--rounds 2] [--profile OUT.prof]

``record`` plans the part in this process and keeps every :func:`cadcam.chipfeed.chip_fed` call (the roughing's,
the raster's, the flats and walls'; :func:`cadcam.chipfeed.chip_feeds` goes through it) with its inputs and a
digest of its answer (every operation's feeds, the stock left). ``replay`` runs them again with the code on
``PYTHONPATH``, one after another in one process, and prints one JSON line per call and one of the totals: its
processor time (this process and the worker processes it waited for, user + sys [s]), its wall [s], and whether
the answer is the recorded one to the bit. Two checkouts' figures, run back to back, compare their code on the
same inputs, on a loaded machine too (compare CPU).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import resource
import sys
import time
from pathlib import Path

import cloudpickle

ROOT = Path(__file__).resolve().parents[1]
if not os.environ.get("PYTHONPATH"):  # else the checkout it names is the code replayed
    sys.path.insert(0, str(ROOT))


def _digest(fed) -> str:
    """The answer's bytes: each operation's points, motion and feeds, and the stock left (or its absence)."""
    h = hashlib.sha256()
    for op in fed.operations:
        h.update(op.points.tobytes() + op.motion.tobytes())
        h.update(b"-" if op.feeds is None else op.feeds.tobytes())
    if fed.stock is None:
        h.update(b"no stock")
    else:
        h.update(fed.stock.stock_top.tobytes() + fed.stock.part_top.tobytes())
        h.update(b"-" if fed.stock.stock_under is None else fed.stock.stock_under.tobytes())
    return h.hexdigest()[:16]


def _cpu() -> float:
    """User + sys processor time of this process and of its children waited for [s]."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def record(part: Path, out: Path) -> None:
    import cadcam.chipfeed
    import cadcam.plan
    from cli.main import app

    real, calls = cadcam.chipfeed.chip_fed, []

    def kept(ops, stock, setup, part_triangles, max_feed):
        fed = real(ops, stock, setup, part_triangles, max_feed)
        points = sum(len(op.points) for op in ops)
        calls.append({"ops": [op.name for op in ops], "points": points, "digest": _digest(fed),
                      "call": cloudpickle.dumps((list(ops), stock, setup, part_triangles, max_feed))})
        return fed

    cadcam.plan.chip_fed = cadcam.chipfeed.chip_fed = kept  # chip_feeds calls it through the module
    app(["plan", str(part), "--no-robot", "-o", f"{out}.plan", "--overwrite", "--quiet"], standalone_mode=False)
    out.write_bytes(pickle.dumps(calls))
    print(json.dumps({"part": part.name, "calls": [c["ops"] for c in calls]}))


def replay(calls_file: Path, rounds: int, profile: Path | None) -> None:
    import cProfile

    from cadcam import toolsweep  # noqa: F401  (numba's kernels compiled or loaded before the clock starts)
    from cadcam.chipfeed import chip_fed

    prof = cProfile.Profile() if profile else None
    calls = pickle.loads(calls_file.read_bytes())
    for r in range(rounds):
        cpu_all = wall_all = 0.0
        same_all = True
        for c in calls:
            args = pickle.loads(c["call"])
            cpu, wall = _cpu(), time.perf_counter()
            if prof:
                prof.enable()
            fed = chip_fed(*args)
            if prof:
                prof.disable()
            cpu, wall = _cpu() - cpu, time.perf_counter() - wall
            same = _digest(fed) == c["digest"]
            cpu_all, wall_all, same_all = cpu_all + cpu, wall_all + wall, same_all and same
            print(json.dumps({"round": r, "ops": c["ops"], "points": c["points"], "cpu_s": round(cpu, 3),
                              "wall_s": round(wall, 3), "same": same}))
        print(json.dumps({"calls": str(calls_file), "round": r, "cpu_s": round(cpu_all, 3),
                          "wall_s": round(wall_all, 3), "same": same_all, "load": os.getloadavg()[0]}))
    if prof:
        prof.dump_stats(str(profile))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("record", "replay"))
    ap.add_argument("paths", type=Path, nargs="+", help="record: PART.stl CALLS.pkl; replay: CALLS.pkl")
    ap.add_argument("--rounds", type=int, default=1, help="replay: times over the calls")
    ap.add_argument("--profile", type=Path, help="replay: cProfile's statistics to this file")
    a = ap.parse_args()
    record(*a.paths) if a.mode == "record" else replay(a.paths[0], a.rounds, a.profile)
