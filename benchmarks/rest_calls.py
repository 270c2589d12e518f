"""CPU of a plan's rest machining calls (the terraces, rest roughing, flats and walls), replayed alone.

    python benchmarks/rest_calls.py record samples/dome_mould.stl CALLS.pkl   # plan it (no robot), keep the calls
    PYTHONPATH=/other/checkout python benchmarks/rest_calls.py replay CALLS.pkl [--profile OUT.prof]

``record`` plans the part in this process (one thread, ``FACTORY_THREADS=1``) and keeps every
:func:`cadcam.roughing.zlevel_roughing` call made with a known stock, with its inputs and a digest of its moves.
``replay`` runs them again with the code on ``PYTHONPATH``, one after another in one process, and prints one JSON
line per call (its CPU and wall [s], whether its points and motion are those recorded) and one of the totals: two
checkouts' figures, run back to back, compare their code on the same inputs, on a loaded machine too (compare CPU).
The stage walls in a plan's summary also hold the shadows another stage made first; here each call makes its own.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import sys
import time
from pathlib import Path

import cloudpickle

ROOT = Path(__file__).resolve().parents[1]
if not os.environ.get("PYTHONPATH"):  # else the checkout it names is the code replayed
    sys.path.insert(0, str(ROOT))


class Recorded:
    """``cut_before(z)`` as the plan answered it, by height [mm] (the real one holds the whole plan)."""

    def __init__(self, seen: dict[float, object]) -> None:
        self.seen = seen

    def __call__(self, z: float) -> object:
        return self.seen[z]


def _digest(op) -> str:
    return hashlib.sha256(op.points.tobytes() + op.motion.tobytes()).hexdigest()[:16]


def record(part: Path, out: Path) -> None:
    os.environ["FACTORY_THREADS"] = "1"
    import cadcam.flatfinish
    import cadcam.plan
    import cadcam.roughing
    from cli.main import main

    real, calls = cadcam.roughing.zlevel_roughing, []

    def kept(*args, **kwargs):
        if kwargs.get("rest") is None:
            return real(*args, **kwargs)
        seen: dict[float, object] = {}
        asked = kwargs.get("cut_before")
        if callable(asked):
            kwargs["cut_before"] = lambda z: seen.setdefault(z, asked(z))
        op = real(*args, **kwargs)
        held = {k: v for k, v in kwargs.items() if k != "progress"}
        if callable(asked):
            held["cut_before"] = Recorded(seen)
        calls.append({"name": op.name, "digest": _digest(op), "call": cloudpickle.dumps((args, held))})
        return op

    cadcam.plan.zlevel_roughing = cadcam.flatfinish.zlevel_roughing = kept
    sys.argv = ["factory", "plan", str(part), "--no-robot", "-o", str(out) + ".plan", "--overwrite", "--quiet"]
    try:
        main()
    except SystemExit as done:
        if done.code:
            raise
    out.write_bytes(pickle.dumps(calls))
    print(json.dumps({"part": part.name, "calls": [c["name"] for c in calls]}))


def replay(calls_file: Path, profile: Path | None) -> None:
    import cProfile

    from cadcam.roughing import zlevel_roughing

    prof = cProfile.Profile() if profile else None
    cpu_all = 0.0
    same_all = True
    for c in pickle.loads(calls_file.read_bytes()):
        args, kwargs = pickle.loads(c["call"])
        cpu, wall = time.process_time(), time.perf_counter()
        if prof:
            prof.enable()
        op = zlevel_roughing(*args, **kwargs)
        if prof:
            prof.disable()
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        same = _digest(op) == c["digest"]
        cpu_all, same_all = cpu_all + cpu, same_all and same
        print(json.dumps({"call": c["name"], "cpu_s": round(cpu, 3), "wall_s": round(wall, 3), "same_moves": same}))
    print(json.dumps({"calls": str(calls_file), "cpu_s": round(cpu_all, 3), "same_moves": same_all,
                      "load": os.getloadavg()[0]}))
    if prof:
        prof.dump_stats(str(profile))


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("part", type=Path)
    rec.add_argument("out", type=Path)
    rep = sub.add_parser("replay")
    rep.add_argument("calls", type=Path)
    rep.add_argument("--profile", type=Path)
    a = ap.parse_args()
    if a.mode == "record":
        record(a.part, a.out)
    else:
        replay(a.calls, a.profile)
