"""``inspect`` in real light: good parts against defective ones, per light condition (issue 33 item 4).

    python benchmarks/inspect_real_light.py [--poses 2] [--first-seed 0] [--cache /tmp/lit-gallery] [--json]
        [--camera fixtures/camera_5mp.yaml] [--parts bracket,dome_mould]

The pictures are those of ``benchmarks/locate_real_light.py`` (``tests/vision/lit.py``: brushed
and polished aluminium, shadows, glare, a box beside the part, dim exposure, noise, taken by the
sample cell's camera at 0.82 mm per pixel), and the same pictures with the part made defective
(``tests/vision/defects.py``: a missing hole, a missing boss, a 1 mm burr on an edge) at the same
pose, light and noise. Each goes to ``inspect_part`` as ``factory inspect`` calls it, expecting
the good part's mesh.

Outcomes: a good part *passed* or *rejected*; a defective one *caught* (rejected) or *missed*
(passed); *refused* when inspection gave no verdict, with its reason: locate could not place the
part confidently, or too little of its outline or of a feature can be judged (glare). A verdict on
a part located more than 1.5 mm or 1 deg from the truth is counted *misplaced* as well (a judgement
at a wrong pose). A burr the verdict says it cannot resolve (``smallest_burr_mm`` over the lip's
1 mm: the cell camera's 0.82 mm per pixel) is counted apart below the table. One JSON line per picture goes to stderr; the confusion table (per condition and
defect) to stdout, in Markdown.

Inspection's thresholds were set on seeds 0-1; ``--first-seed 2`` and ``--first-seed 4`` draw poses
inspection was not tuned on (held out: seeds 2-3 by one session, 4-5 by the next).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.locate_real_light import FOUND_M, FOUND_RAD, picture, yaw_error  # noqa: E402
from factory.core.errors import VisionError  # noqa: E402
from tests.vision.defects import DEFECTS, defect_parts  # noqa: E402
from tests.vision.lit import CONDITIONS, SAMPLE_PARTS, cell_station, sample_mesh  # noqa: E402
from vision.camera import CameraModel  # noqa: E402
from vision.inspect import InspectOptions, inspect_part  # noqa: E402

KINDS = ("good", *DEFECTS)
#: The burr of tests/vision/defects.py sticks out this far [mm].
BURR_MM = 1.0
OUTCOMES = ("passed", "rejected", "refused")


def judge(station, part: str, condition: str, seed: int, kind: str, cache: Path | None,
          options: InspectOptions = InspectOptions()) -> dict:
    """Inspect one picture: the row of the table (outcome, deviation, why refused)."""
    scene = picture(station, part, condition, seed, cache, None if kind == "good" else kind)
    mesh, footprint, _ = sample_mesh(part)
    row = {"condition": condition, "part": part, "seed": seed, "kind": kind}
    start = time.perf_counter()
    try:
        found = inspect_part(scene.image, station.camera, station.camera_pose, footprint, mesh.vertices,
                             mesh.faces, station.plane_z, options)
    except VisionError as e:
        return {**row, "seconds": time.perf_counter() - start, "outcome": "refused",
                "reason": str(e).split("; ", 1)[-1]}
    ins = min(found, key=lambda r: np.hypot(r.part.x - scene.x, r.part.y - scene.y))
    summary = ins.to_dict()
    placed = (np.hypot(ins.part.x - scene.x, ins.part.y - scene.y) <= FOUND_M
              and yaw_error(ins.part.yaw, scene.yaw, scene.symmetry) <= FOUND_RAD)
    # Too little of the part can be judged (glare): refused, with the reason, not rejected.
    outcome = "refused" if ins.refusal else "passed" if ins.passed else "rejected"
    return {**row, "seconds": time.perf_counter() - start, "outcome": outcome, "reason": ins.refusal,
            "hidden": ins.hidden,
            "misplaced": not placed, "max_deviation_mm": summary["max_deviation_mm"],
            "excess_mm": summary["excess_mm"], "profile_excess_mm": summary["profile_excess_mm"],
            "missing_mm": summary["missing_mm"],
            "outline_seen": summary["outline_seen"], "smallest_burr_mm": summary["smallest_burr_mm"],
            "missing_features": len(summary["missing_features"])}


def run(poses: int, cache: Path | None, conditions: list[str], kinds: list[str], first_seed: int = 0,
        camera: Path | None = None, parts: list[str] | None = None,
        options: InspectOptions = InspectOptions()) -> list[dict]:
    station = cell_station(CameraModel.read(camera) if camera is not None else None)
    rows = []
    for condition in conditions:
        for kind in kinds:
            for part in SAMPLE_PARTS if kind == "good" else defect_parts(kind):
                if parts and part not in parts:
                    continue
                for seed in range(first_seed, first_seed + poses):
                    row = judge(station, part, condition, seed, kind, cache, options)
                    rows.append(row)
                    print(json.dumps(row), file=sys.stderr, flush=True)
    return rows


def table(rows: list[dict], conditions: list[str], kinds: list[str]) -> dict:
    """Print the confusion table; return its counts per (condition, kind) and overall."""
    counts: dict = {}
    heads = [f"{k}: passed / rejected / refused" if k == "good" else f"{k}: caught / missed / refused" for k in kinds]
    print("| condition | " + " | ".join(heads) + " |")
    print("|---|" + "---|" * len(kinds))
    for c in [*conditions, "all"]:
        cells = []
        for k in kinds:
            r = [x for x in rows if (c == "all" or x["condition"] == c) and x["kind"] == k]
            n = {o: sum(x["outcome"] == o for x in r) for o in OUTCOMES}
            counts[f"{c}/{k}"] = n
            # A defective part is caught when rejected, missed when passed.
            first, second = (n["passed"], n["rejected"]) if k == "good" else (n["rejected"], n["passed"])
            cells.append(f"{first} / {second} / {n['refused']}")
        print(f"| {c} | " + " | ".join(cells) + " |")
    # A burr narrower than the picture resolves may pass, and its verdict says so (Inspection.smallest_burr).
    burrs = [x for x in rows if x["kind"] == "burr" and x["outcome"] != "refused"]
    if burrs:
        under = [x for x in burrs if x["smallest_burr_mm"] > BURR_MM]
        print(f"burrs judged: {len(burrs)}; the verdict resolves no burr under {BURR_MM:g} mm in {len(under)} "
              f"({sum(x['outcome'] == 'passed' for x in under)} of them passed); smallest burr resolved: "
              f"{min(x['smallest_burr_mm'] for x in burrs):.2f}-{max(x['smallest_burr_mm'] for x in burrs):.2f} mm")
    misplaced = sum(x.get("misplaced", False) for x in rows)
    print(f"verdicts at a wrong pose: {misplaced}; median seconds per picture: "
          f"{np.median([x['seconds'] for x in rows]):.2f}")
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=2)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--conditions", default=",".join(CONDITIONS))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--camera", type=Path, default=None, help="cell camera file (default fixtures/camera.yaml)")
    ap.add_argument("--parts", default="", help="only these sample parts (comma-separated; default all)")
    ap.add_argument("--from-above", action=argparse.BooleanOptionalAction, default=True,
                    help="judge features seen from straight above by all their edges (InspectOptions.judge_from_above, "
                         "the default; --no-from-above as the simulated cell's flat-shaded pictures are judged)")
    a = ap.parse_args()
    conditions, kinds = a.conditions.split(","), a.kinds.split(",")
    rows = run(a.poses, a.cache, conditions, kinds, a.first_seed, a.camera, [p for p in a.parts.split(",") if p],
               InspectOptions(judge_from_above=a.from_above))
    counts = table(rows, conditions, kinds)
    if a.json:
        print(json.dumps({"counts": counts, "rows": rows}))


if __name__ == "__main__":
    main()
