"""Wall and CPU time of `factory plan` with op 1's verify begun ahead (factory.verify.VerifyAhead) and without.

    python benchmarks/verify_ahead.py [--parts relief,dome_mould] [--no-robot] [--force] [--json]

Plans each sample twice in this process, with rounds of verify ahead and with them switched off (the plain
pipeline), and prints the wall time [s], the CPU time of this process and of its children [s] (forked rounds,
arc fits, the robot's planning, verify's second process) and the stage times of the tail: ``verify ahead``
(the wait for the round under way), ``post`` and ``verify`` (the wait for verify's process, or verify here).
Wall time counts the other processes on the machine: run it quiet, or compare CPU. ``verify_thread_cpu_s`` is the
CPU of the thread that runs verify (what a quiet machine waits for), ``resumed_moves`` the program's moves verify
found cut ahead. ``--force`` begins a round at every offer, as the gate does where a processor is idle
(:class:`cadcam.parallel.IdleMeter`), and verify waits for each (``OVERTAKE_BELOW`` 0: it never cuts a slow
round's operations itself): on a loaded machine, what the rounds take off verify. With ``--json`` the
last line is one JSON object. The outputs are the same either way (tests/factory/test_plan.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import factory.plan  # noqa: E402
import factory.verify  # noqa: E402
from factory.plan import PlanRequest, plan_part  # noqa: E402


def _cpu() -> tuple[float, float]:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


def _run(part: Path, robot: bool, ahead: bool, force: bool = False) -> dict:
    request = PlanRequest.defaults(part, "aluminium")
    if not robot:
        request = dataclasses.replace(request, robot=False)
    real = factory.verify.VerifyAhead.__init__

    def switched_off(self, *args, **kwargs):
        real(self, *args, **kwargs)
        self.enabled = False

    verify_cpu, resumed = [0.0], [None]
    real_verify, real_state = factory.plan.run_verify, factory.verify.VerifyAhead.state

    def timed_verify(*args, **kwargs):
        t = time.thread_time()
        try:
            return real_verify(*args, **kwargs)
        finally:
            verify_cpu[0] += time.thread_time() - t

    def state(self, operations):
        out = real_state(self, operations)
        resumed[0] = None if out is None else out.moves
        return out

    (own0, kids0), t0 = _cpu(), time.perf_counter()
    with mock.patch.object(factory.verify.VerifyAhead, "__init__", real if ahead else switched_off), \
            mock.patch.object(factory.plan, "run_verify", timed_verify), \
            mock.patch.object(factory.verify.VerifyAhead, "state", state), \
            mock.patch.object(factory.verify.IdleMeter, "idle",
                              (lambda self, own=0.0: float(os.cpu_count() or 1)) if force
                              else factory.verify.IdleMeter.idle), \
            mock.patch.object(factory.verify, "OVERTAKE_BELOW", 0.0 if force else factory.verify.OVERTAKE_BELOW):
        plan = plan_part(request)
    (own1, kids1), wall = _cpu(), time.perf_counter() - t0
    stages = {k: round(plan.seconds.get(k, 0.0), 2) for k in ("verify ahead", "post", "verify", "rapid check")}
    return {"part": part.stem, "ahead": ahead, "forced": force, "wall_s": round(wall, 2), "cpu_s": round(own1 - own0, 2),
            "children_cpu_s": round(kids1 - kids0, 2), "verify_thread_cpu_s": round(verify_cpu[0], 2),
            "resumed_moves": resumed[0], "stages_s": stages, "ok": plan.ok, "load": round(os.getloadavg()[0], 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default="relief,dome_mould")
    ap.add_argument("--no-robot", action="store_true")
    ap.add_argument("--force", action="store_true", help="a round at every offer, as on an idle processor")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    for name in args.parts.split(","):
        for ahead in (False, True):
            row = _run(ROOT / "samples" / f"{name}.stl", not args.no_robot, ahead, args.force)
            rows.append(row)
            print(f"{row['part']:12} ahead={str(ahead):5} wall {row['wall_s']:7.2f} s  cpu {row['cpu_s']:7.2f} s  "
                  f"children {row['children_cpu_s']:7.2f} s  verify's thread {row['verify_thread_cpu_s']:6.2f} s  "
                  f"resumed at move {row['resumed_moves']}  {row['stages_s']}", flush=True)
    if args.json:
        print(json.dumps({"machine": platform.node(), "rows": rows}))


if __name__ == "__main__":
    main()
