"""Search time of the transfers the straight joint segment cannot make: ours against OMPL's.

    python benchmarks/transfer_search.py [--stock bracket,stepped_wall] [--repeat 3]

For each sample stock, the default cell's tending plan is made once without a roadmap; each of its
transfers that is not straight (start, goal, what is held, the plan's obstacles) is then searched by

* ``rrt``: the hand-written RRT-Connect and random shortcut (:meth:`MotionPlanner._search`),
* ``ompl-rrtconnect``: OMPL's RRT-Connect and path simplifier (``pip install ompl``) driven by our
  coal checks: the state check :meth:`CollisionWorld.in_collision`, the motion check
  :meth:`MotionPlanner.edge_free` (the same joint resolution),
* ``roadmap``: the cell's roadmap (:func:`robotprog.roadmap.cell_roadmap`, default options, built
  once and timed apart), lazy search, greedy shortcut, pulled taut,

and every found path is then proven with the continuous proof (``SweptMotion.polyline_contact``),
the proof every posted transfer passes. Prints per searcher the CPU seconds [s] of search, of the
proof, the paths proven, and the sum of their time-optimal durations [s]; the last line is JSON.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from factory.core.resources import FIXTURES  # noqa: E402
from robotprog.cell import load_cell  # noqa: E402
from robotprog.collision import collision_world  # noqa: E402
from robotprog.planner import MotionPlanner  # noqa: E402
from robotprog.roadmap import cell_roadmap  # noqa: E402
from robotprog.tending import plan_tending  # noqa: E402
from robotprog.timing import time_path  # noqa: E402
from tests.robotprog.test_tending import SAMPLE_STOCK, sheet  # noqa: E402


def ompl_search(p: MotionPlanner, q_a: np.ndarray, q_b: np.ndarray, held, budget_s: float = 10.0):
    """OMPL RRT-Connect + simplifier with our state and motion checks, or None."""
    from ompl import base as ob, geometric as og

    dof = len(q_a)
    space = ob.RealVectorStateSpace(dof)
    bounds = ob.RealVectorBounds(dof)
    for i in range(dof):
        bounds.setLow(i, float(p.lo[i]))
        bounds.setHigh(i, float(p.hi[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)

    def q_of(s):
        return np.array([s[i] for i in range(dof)])

    ss.setStateValidityChecker(lambda s: not p.world.in_collision(q_of(s), held))
    si = ss.getSpaceInformation()

    class Motion(ob.MotionValidator):
        def checkMotion(self, a, b, *rest):
            return p.edge_free(q_of(a), q_of(b), held)

    motion = Motion(si)
    si.setMotionValidator(motion)
    planner = og.RRTConnect(si)
    planner.setRange(p.options.rrt_step)
    ss.setPlanner(planner)
    start, goal = space.allocState(), space.allocState()
    for i in range(dof):
        start[i], goal[i] = float(q_a[i]), float(q_b[i])
    ss.setStartAndGoalStates(start, goal)
    if not ss.solve(budget_s) or not ss.haveExactSolutionPath():
        return None
    ss.simplifySolution(budget_s)
    path = ss.getSolutionPath()
    return np.array([q_of(path.getState(i)) for i in range(path.getStateCount())])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stock", default="bracket,stepped_wall")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    cell = load_cell(FIXTURES / "cell.yaml")
    world = collision_world(cell)
    c0 = time.process_time()
    roadmap = cell_roadmap(cell, world)
    build_s = time.process_time() - c0
    problems = []
    for stock in args.stock.split(","):
        plan = plan_tending(cell, sheet(*SAMPLE_STOCK[stock]), world=world)
        own = collision_world(cell, world.robot, obstacles=plan.obstacles)
        for m in plan.moves + plan.reject:
            if m.kind == "joint" and len(m.waypoints) > 2:
                problems.append((stock, m.name, own, m.waypoints[0], m.waypoints[-1], m.held))
    searchers = {
        "rrt": lambda p, a, b, h: p._search(a, b, h, "bench"),
        "ompl-rrtconnect": lambda p, a, b, h: ompl_search(p, a, b, h),
        "roadmap": lambda p, a, b, h: p.transfer(a, b, h, "bench").waypoints,
    }
    if importlib.util.find_spec("ompl") is None:  # not a dependency of factory (benchmarks/README: why)
        print("ompl is not installed (pip install ompl): its row is left out", file=sys.stderr)
        del searchers["ompl-rrtconnect"]
    rows = {}
    for name, search in searchers.items():
        search_s = proof_s = 0.0
        proven = tried = 0
        duration = 0.0
        for rep in range(args.repeat):
            for stock, move, own, a, b, held in problems:
                p = MotionPlanner(cell, own, roadmap=roadmap if name == "roadmap" else None)
                p.rng = np.random.default_rng(rep)
                c0 = time.process_time()
                path = search(p, a, b, held)
                c1 = time.process_time()
                ok = path is not None and p.sweep.polyline_contact(path, held) is None
                proof_s += time.process_time() - c1
                search_s += c1 - c0
                tried += 1
                if ok:
                    proven += 1
                    duration += time_path(path, p.vmax, p.amax).duration
        rows[name] = {"search_cpu_s": round(search_s / args.repeat, 3), "proof_cpu_s": round(proof_s / args.repeat, 3),
                      "proven": proven, "tried": tried, "motion_s": round(duration / args.repeat, 3)}
        print(f"{name:16} search {rows[name]['search_cpu_s']:7.3f} s  proof {rows[name]['proof_cpu_s']:7.3f} s  "
              f"proven {proven}/{tried}  motion {rows[name]['motion_s']:.3f} s", flush=True)
    print(json.dumps({"transfers": len(problems), "roadmap_build_cpu_s": round(build_s, 2),
                      "load": os.getloadavg()[0], "searchers": rows}))


if __name__ == "__main__":
    main()
