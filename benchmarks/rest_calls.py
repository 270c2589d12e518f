"""CPU of a plan's rest machining and ball finishing calls (the terraces, rest roughing, flats and walls, the
waterline and the raster), replayed alone.

    python benchmarks/rest_calls.py record samples/dome_mould.stl CALLS.pkl   # plan it (no robot), keep the calls
    PYTHONPATH=/other/checkout python benchmarks/rest_calls.py replay CALLS.pkl [--only NAME] [--rounds N]
                                                                         [--profile OUT.prof]

``record`` plans the part in this process (one thread, ``FACTORY_THREADS=1``) and keeps every
:func:`cadcam.roughing.zlevel_roughing` call made with a known stock, and every
:func:`cadcam.finishing.waterline_finishing` and :func:`cadcam.finishing.raster_finishing` call the plan makes, with
its inputs and a digest of its moves. ``--only`` replays the calls made in the plan's stages whose name holds
NAME (``terraces``, ``rest T6``, ``waterline``, ``raster``). ``--rounds N`` replays each call N times from fresh inputs,
every kept answer (:class:`factory.core.kept.KeptAnswers`) forgotten before each, and counts the least CPU: on a
loaded machine the least of a few is the figure that moves least.
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


#: The functions recorded and replayed, by the name a call is kept under: (module, function).
_KEPT = {"zlevel_roughing": ("cadcam.roughing", "zlevel_roughing"),
         "waterline_finishing": ("cadcam.finishing", "waterline_finishing"),
         "raster_finishing": ("cadcam.finishing", "raster_finishing")}


def _function(name: str):
    import importlib

    module, attr = _KEPT[name]
    return getattr(importlib.import_module(module), attr)


def record(part: Path, out: Path) -> None:
    os.environ["FACTORY_THREADS"] = "1"
    import cadcam.flatfinish
    import cadcam.plan
    from cli.main import main

    calls: list[dict] = []
    timed, stage = cadcam.plan._Planning.timed, [""]

    def staged(self, name, compute):  # the plan's stage each call is made in (the terraces are a rest rough)
        stage.append(name)
        try:
            return timed(self, name, compute)
        finally:
            stage.pop()

    cadcam.plan._Planning.timed = staged
    cadcam.plan.zlevel_roughing = cadcam.flatfinish.zlevel_roughing = _keeper("zlevel_roughing", calls, stage,
                                                                                   rest_only=True)
    cadcam.plan.waterline_finishing = _keeper("waterline_finishing", calls, stage)
    cadcam.plan.raster_finishing = _keeper("raster_finishing", calls, stage)
    sys.argv = ["factory", "plan", str(part), "--no-robot", "-o", str(out) + ".plan", "--overwrite", "--quiet"]
    try:
        main()
    except SystemExit as done:
        if done.code:
            raise
    out.write_bytes(pickle.dumps(calls))
    print(json.dumps({"part": part.name, "calls": [c["stage"] for c in calls]}))


def _keeper(function: str, calls: list[dict], stage: list[str], rest_only: bool = False):
    """``function`` as the plan calls it, keeping each call (with a known stock only, if ``rest_only``) in ``calls``
    with the plan's stage it was made in (``stage[-1]``)."""
    real = _function(function)

    def kept(*args, **kwargs):
        if rest_only and kwargs.get("rest") is None:
            return real(*args, **kwargs)
        seen: dict[float, object] = {}
        asked = kwargs.get("cut_before")
        if callable(asked):
            kwargs["cut_before"] = lambda z: seen.setdefault(z, asked(z))
        op = real(*args, **kwargs)
        held = {k: v for k, v in kwargs.items() if k != "progress"}
        if callable(asked):
            held["cut_before"] = Recorded(seen)
        calls.append({"name": op.name, "stage": stage[-1], "function": function, "digest": _digest(op),
                      "call": cloudpickle.dumps((args, held))})
        return op

    return kept


def replay(calls_file: Path, profile: Path | None, only: str | None = None, rounds: int = 1) -> None:
    import cProfile

    import cadcam.dropcontacts  # noqa: F401  numba and the drop-cutter's kernels: a plan has loaded them by then
    from factory.core.kept import KeptAnswers

    prof = cProfile.Profile(time.process_time) if profile else None  # processor time: the machine is shared
    cpu_all = 0.0
    same_all = True
    for c in pickle.loads(calls_file.read_bytes()):
        if only is not None and only not in c.get("stage", c["name"]):
            continue
        run = _function(c.get("function", "zlevel_roughing"))
        cpus, walls = [], []
        for _ in range(rounds):  # each round from fresh inputs, with nothing kept from the round before
            for table in list(KeptAnswers._all):
                table.forget()
            args, kwargs = pickle.loads(c["call"])
            cpu, wall = time.process_time(), time.perf_counter()
            if prof:
                prof.enable()
            op = run(*args, **kwargs)
            if prof:
                prof.disable()
            cpus.append(time.process_time() - cpu)
            walls.append(time.perf_counter() - wall)
            same = _digest(op) == c["digest"]
            same_all = same_all and same
        cpu_all += min(cpus)
        print(json.dumps({"call": c["name"], "stage": c.get("stage"), "cpu_s": round(min(cpus), 3),
                          "cpu_rounds": [round(t, 3) for t in cpus], "wall_s": round(min(walls), 3),
                          "same_moves": same}))
    print(json.dumps({"calls": str(calls_file), "cpu_s": round(cpu_all, 3), "rounds": rounds, "same_moves": same_all,
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
    rep.add_argument("--only", help="replay only the calls whose plan stage holds this")
    rep.add_argument("--rounds", type=int, default=1, help="replay each call this many times (the least CPU counts)")
    a = ap.parse_args()
    if a.mode == "record":
        record(a.part, a.out)
    else:
        replay(a.calls, a.profile, a.only, a.rounds)
