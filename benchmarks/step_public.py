"""Public STEP parts through factory's intake: what each gives and how long it takes.

    python benchmarks/step_public.py DIR [--json] [--plan OUT] [--generated] [--build123d CHECKOUT]

The parts are not in this repository (their licences do not allow it, or they are too large);
fetch them into DIR first, from these commits (paths within each repository):

| file | repository @ commit | licence |
|---|---|---|
| 11752.stp, as1_pe_203.stp, as1-oc-214.stp, face_recognition_sample_part.stp, splinecage.stp | tpaviot/pythonocc-demos @ 8158b217efc313889162e7c4dfefba87078d1270, assets/models/ | none stated in the repository: not redistributed |
| M6-1x12-countersunk-screw.step | gumyr/build123d @ fdd4dc610b3bb121f656b79fce438db322291aa1, docs/ | Apache-2.0 (503 KB: too large to keep) |
| red_cube_blue_cylinder.step | CadQuery/cadquery @ d6729f51bf1ed183f110aacdbc6238e4a5110c96, tests/testdata/ | Apache-2.0: kept in tests/data/step |
| nist_ctc_01..05, nist_ftc_06..11 (``_asme1_r?.stp``, geometry only) | NIST MBE PMI test models, as mirrored in tsun7170/STEPswiftcode @ 1da6b4088bfc834b4fb9b70c1a6e90a7bacf25ac, swiftP21read/TestCases/NIST_CTC_STEP_PMI/ (NIST: pages.nist.gov/CAD-PMI-Testing/models.html) | US Government work: public domain (17 U.S.C. 105) |
| screw.step, linkrods.step | OpenCASCADE's sample data (Debian package occt-misc: /usr/share/opencascade/data/step/) | LGPL-2.1 with the OCCT exception |
| pillow_block.step, ttt-ppp01NN.step (:data:`BUILD123D_EXAMPLES`) | gumyr/build123d @ fdd4dc610b3bb121f656b79fce438db322291aa1: its example scripts run and their part exported (``--build123d CHECKOUT``) | Apache-2.0 (the Too Tall Toby parts are modelled from that site's published practice drawings) |

For each ``*.step``/``*.stp`` in DIR (every solid of a file of several, as ``--body N``): the
file's unit, B-rep faces, the chordal deviation [mm] and the triangles it gave (and whether the
tessellation was coarsened to stay within ``cadcam.step.MAX_TRIANGLES``), the features
recognised, and the wall and process CPU time of :func:`cadcam.mesh.load_part` [s], or the
one-line refusal. ``--generated`` first writes the tests' build123d parts
(``tests/cadcam/stepparts.py``) into DIR; ``--build123d CHECKOUT`` the parts of build123d's examples
(:data:`BUILD123D_EXAMPLES`), from a checkout of it at the commit above.

``--plan OUT`` also runs ``factory plan PART [--body N] --no-robot`` on each part that reads, and
on an STL of its own tessellation, each in a subprocess under OUT: the plan's wall time [s], its
``load`` stage [s], its exit code (or refusal), and the operations (name and tool, op 1 and op 2)
the STEP plan has and the STL plan has not (``step_only``) and the other way (``stl_only``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from collections import Counter
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
            "chordal_deviation_mm": step.chordal_deviation, "coarsened": step.coarsened is not None,
            "triangles": int(len(step.faces)), "closed": step.closed,
            "size_mm": [round(float(v), 1) for v in loaded.mesh.extents],
            "holes": len(features.holes), "elsewhere": len(features.elsewhere), "flats": len(features.flats),
            "corners": len(features.corners), "undercuts": len(features.undercuts), "wall_s": round(time.perf_counter() - wall, 2),
            "cpu_s": round(time.process_time() - cpu, 2)}


def plan(path: Path, body: int | None, out: Path) -> dict:
    """``factory plan`` of ``path`` in a subprocess: wall time [s], CPU time [s] (the subprocess and its
    workers, the figure to compare on a shared machine), exit code, its load stage [s], its operations as
    ``"op N: name (T#)"`` (empty when refused: the refusal's line instead)."""
    cmd = [sys.executable, "-c", "from cli.main import main; main()", "plan", str(path), "-o", str(out), "--no-robot",
           "--overwrite"]
    cmd += ["--body", str(body)] if body else []
    wall, cpu = time.perf_counter(), _children_cpu()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    row = {"plan_wall_s": round(time.perf_counter() - wall, 1), "plan_cpu_s": round(_children_cpu() - cpu, 1),
           "exit": done.returncode}
    summary = next(out.glob("*.plan.json"), None) if out.is_dir() else None
    if summary is None:
        errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
        return {**row, "refused": errors[-1] if errors else done.stderr.strip()[-300:], "operations": []}
    doc = json.loads(summary.read_text())
    return {**row, "load_s": doc["seconds"].get("load"), "verify_ok": doc["verify"].get("ok"),
            "verify_op2_ok": (doc.get("verify_op2") or {}).get("ok"), "operations": operations(doc)}


def _children_cpu() -> float:
    """User and system CPU time [s] of this process's finished subprocesses (and theirs, once waited for)."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def operations(doc: dict) -> list[str]:
    """A plan summary's operations as ``"op N: name (T#)"``: op 1's, then op 2's (its setup entry lists them)."""
    ops = [f"op 1: {o['name']} (T{o['tool']})" for o in doc["operations"]]
    return ops + [f"op {s['op']}: {o['name']} (T{o['tool']})" for s in doc["setups"][1:] for o in s.get("operations", [])]


def plan_both(path: Path, body: int | None, out: Path) -> dict:
    """The part planned from its STEP file and from an STL of its own tessellation, and how their operations differ."""
    name = f"{path.stem}{f'-body{body}' if body else ''}"
    step = plan(path, body, out / name / "step")
    stl = out / name / f"{name}.stl"
    stl.parent.mkdir(parents=True, exist_ok=True)  # a refused STEP plan wrote nothing there
    load_part(path, body=body).mesh.export(stl)
    mesh = plan(stl, None, out / name / "stl")
    a, b = Counter(step.pop("operations")), Counter(mesh.pop("operations"))
    return {"step_plan": step, "stl_plan": mesh, "step_only": sorted((a - b).elements()),
            "stl_only": sorted((b - a).elements()), "same_operations": sum((a & b).values())}


def write_generated(folder: Path) -> None:
    """The tests' build123d parts as STEP files in ``folder`` (their modelling is in tests/cadcam/stepparts.py)."""
    from tests.cadcam import stepparts as sp

    holes = [sp.ModelledHole(-20, -8, 5.0, None), sp.ModelledHole(-20, 8, 6.8, None),
             sp.ModelledHole(0, 8, 4.2, 6.0, "conical"), sp.ModelledHole(0, -8, 3.3, 5.0, "flat"),
             sp.ModelledHole(20, 0, 8.0, None)]
    sinks = [sp.ModelledHole(-12, 0, 6.6, None, counterbore=(11.0, 6.5)), sp.ModelledHole(12, 0, 4.5, None,
                                                                                         countersink=9.0)]
    parts = {"gen_plate_holes": sp.plate((60, 40, 12), holes), "gen_counterbore_countersink": sp.plate((50, 30, 12), sinks),
             "gen_two_solids": sp.two_solids(), "gen_inclined_hole": sp.inclined_hole(),
             "gen_countersunk_head": sp.countersunk_head(), "gen_feature_plate": sp.feature_plate(12, 8)[0]}
    folder.mkdir(parents=True, exist_ok=True)
    for name, shape in parts.items():
        sp.write_step(shape, folder / f"{name}.step")
    sp.write_step(sp.plate((60, 40, 12), holes[:2]), folder / "gen_inch_plate.step", unit="INCH")


#: build123d's example parts that are machined parts (prismatic, inside the vise): STEP name -> (script in a
#: checkout of gumyr/build123d at the commit of the module docstring, the name its part is built under).
BUILD123D_EXAMPLES = {
    "pillow_block": ("examples/pillow_block.py", "pillow_block"),  # 80 x 60 x 10, counterbored holes
    "ttt-ppp0103": ("docs/assets/ttt/ttt-ppp0103.py", "ppp0103"),  # C clamp base, 42 x 104 x 16
    "ttt-ppp0106": ("docs/assets/ttt/ttt-ppp0106.py", "p"),  # bearing jig, 64 x 69 x 36
}


def write_build123d(checkout: Path, folder: Path) -> None:
    """Run each of :data:`BUILD123D_EXAMPLES` from ``checkout`` and write its part as STEP into ``folder``.

    The scripts show their part in the OCP CAD Viewer (``ocp_vscode``); a stand-in that shows nothing
    is imported in its place when the viewer is not installed."""
    import runpy
    import types

    from build123d import export_step

    if "ocp_vscode" not in sys.modules:
        try:
            import ocp_vscode  # noqa: F401
        except ImportError:
            viewer = types.ModuleType("ocp_vscode")
            viewer.show = viewer.show_object = lambda *shapes, **options: None
            sys.modules["ocp_vscode"] = viewer
    folder.mkdir(parents=True, exist_ok=True)
    for name, (script, built) in BUILD123D_EXAMPLES.items():
        done = runpy.run_path(str(checkout / script), run_name="__main__")
        export_step(done[built].part, str(folder / f"{name}.step"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--plan", type=Path, metavar="OUT", help="also plan each part as STEP and as STL under OUT")
    ap.add_argument("--generated", action="store_true", help="first write the tests' build123d parts into DIR")
    ap.add_argument("--build123d", type=Path, metavar="CHECKOUT",
                    help="first write build123d's example parts into DIR, from a checkout of gumyr/build123d")
    args = ap.parse_args()
    if args.generated:
        write_generated(args.folder)
    if args.build123d is not None:
        write_build123d(args.build123d, args.folder)
    rows = []
    for path in sorted(p for p in args.folder.iterdir() if p.suffix.lower() in (".step", ".stp")):
        row = intake(path)
        rows.append(row)
        solids = row.get("refused", "").split(" solids in the file")[0]
        if solids.isdigit():  # an assembly: each solid of a small one as --body picks it, the first of a large one
            rows += [intake(path, k) for k in range(1, (int(solids) if int(solids) <= 4 else 1) + 1)]
    if args.plan is not None:
        planned = []
        for r in rows:
            planned.append({**r, **plan_both(args.folder / r["file"], r["body"], args.plan)} if "refused" not in r
                           else r)
            if not args.json:  # each as it is planned: a part takes minutes
                print(json.dumps(planned[-1]), flush=True)
        rows = planned
        if not args.json:
            print(f"load average {os.getloadavg()[0]:.1f}")
            return
    if args.json:
        print(json.dumps({"load": os.getloadavg(), "parts": rows}, indent=2))
        return
    for r in rows:
        print(json.dumps(r))
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
