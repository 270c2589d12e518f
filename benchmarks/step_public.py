"""Public STEP parts through factory's intake: what each gives and how long it takes.

    python benchmarks/step_public.py DIR [--json]

The parts are not in this repository (their licences do not allow it, or they are too large);
fetch them into DIR first, from these commits (paths within each repository):

| file | repository @ commit | licence |
|---|---|---|
| 11752.stp, as1_pe_203.stp, as1-oc-214.stp, face_recognition_sample_part.stp, splinecage.stp | tpaviot/pythonocc-demos @ 8158b217efc313889162e7c4dfefba87078d1270, assets/models/ | none stated in the repository: not redistributed |
| M6-1x12-countersunk-screw.step | gumyr/build123d @ fdd4dc610b3bb121f656b79fce438db322291aa1, docs/ | Apache-2.0 (503 KB: too large to keep) |
| red_cube_blue_cylinder.step | CadQuery/cadquery @ d6729f51bf1ed183f110aacdbc6238e4a5110c96, tests/testdata/ | Apache-2.0: kept in tests/data/step |

For each ``*.step``/``*.stp`` in DIR (every solid of a file of several, as ``--body N``): the
file's unit, B-rep faces, triangles at the default chordal deviation, the features recognised,
and the wall and process CPU time of :func:`cadcam.mesh.load_part` [s], or the one-line refusal.
Planning them is ``factory plan PART [--body N]``; a note of what that gave is in the branch's report.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from cadcam.mesh import load_part  # noqa: E402
from factory.core.errors import FactoryError  # noqa: E402


def intake(path: Path, body: int | None = None) -> dict:
    """One part's intake figures (or its refusal)."""
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        loaded = load_part(path, body=body)
    except FactoryError as e:
        return {"file": path.name, "body": body, "refused": e.message,
                "wall_s": round(time.perf_counter() - wall, 2)}
    step, features = loaded.step, loaded.step.features
    return {"file": path.name, "body": body, "unit": step.unit, "brep_faces": step.brep_faces,
            "triangles": int(len(step.faces)), "closed": step.closed,
            "size_mm": [round(float(v), 1) for v in loaded.mesh.extents],
            "holes": len(features.holes), "elsewhere": len(features.elsewhere), "flats": len(features.flats),
            "corners": len(features.corners), "wall_s": round(time.perf_counter() - wall, 2),
            "cpu_s": round(time.process_time() - cpu, 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    for path in sorted(p for p in args.folder.iterdir() if p.suffix.lower() in (".step", ".stp")):
        row = intake(path)
        rows.append(row)
        solids = row.get("refused", "").split(" solids in the file")[0]
        if solids.isdigit() and int(solids) <= 4:  # a small assembly: each solid as --body picks it
            rows += [intake(path, k) for k in range(1, int(solids) + 1)]
    if args.json:
        print(json.dumps({"load": os.getloadavg(), "parts": rows}, indent=2))
        return
    for r in rows:
        print(json.dumps(r))
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
