"""The gallery of parts factory was not tuned for (tests/gallery/parts.py), each planned with defaults and judged.

Per part: `factory plan`'s exit and one-line refusal, plan wall time and CPU seconds (user + system: on a
shared machine the wall time grows with the load, the CPU seconds much less), both operations' cycle estimates,
verify's verdict and the stock it left (its regions, place and size), what the plan reported unreached
(place and size), the deepest and widest engagement and the deepest at full width against the axial limit
per tool, and LinuxCNC's `rs274` on every program with the job's tool table (``PART.tbl``); then the
suite's own checks (tests/gallery/judge.py: finished to 0.05 mm, no tool past its flutes, op 1's probe
past no axial limit at full width, the seam within the tolerance), which hold the gallery parts the suite
does not plan (tests/gallery/test_gallery.py keeps a representative subset) to what it holds its own. A part
``expect``-ed to plan that is refused, fails verify or those checks, or whose program rs274 refuses, is a
shortfall; so is one expected refused that plans. The whole gallery's run (no ``--parts``, no ``--mesh``) also
runs the suite's random-block property with the examples the suite leaves to it (tests/gallery/test_gallery.py,
``SEAM_EXAMPLES``; ``--random-blocks`` runs it alone); a property that fails is a shortfall.

    .venv/bin/python benchmarks/gallery.py [--parts a,b] [--mesh FILE ...] [--random-blocks] [--jobs 2] [--json out.json]

``--mesh`` adds mesh files from elsewhere (public CAM test parts), each expected to plan. The public ones
judged so far are OpenCAMLib's test meshes (aewallin/opencamlib @ 95b036fe28ce6d77c97b98e5fbc337904ae49560,
``stl/``: sphere_on_plate.stl, sphere_cutout.stl, wheel_in_box.stl, failedinpycam.stl; LGPL-2.1, fetched,
not kept here). Prints one JSON
line per part as it finishes (so a long run on a loaded machine leaves what it found), then a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

import trimesh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cadcam.stock import OUTSIDE_RELIEF  # noqa: E402
from tests.gallery.judge import check_consumers_accept  # noqa: E402
from tests.gallery.parts import BY_NAME, PARTS, GalleryPart  # noqa: E402
from tests.rs274 import run_rs274  # noqa: E402


def _rs274(program: Path, table: Path, folder: Path) -> str:
    """'ok', or rs274's complaint (it exits 0 on some errors: its output is read too)."""
    done = run_rs274(program, table, folder)
    text = (done.stdout + done.stderr).lower()
    if done.returncode != 0 or "error" in text or "not found" in text:
        lines = [ln for ln in (done.stderr or done.stdout).splitlines() if ln.strip()]
        return (lines[-1] if lines else f"exit {done.returncode}")[:120]
    return "ok"


def _regions(found: list[dict], op: str) -> list[str]:
    """Regions of stock (:class:`cadcam.stock.Unreached` as JSON) as ``op X.. Y.. size a x b, depth d`` [mm]; a
    relief's stock along its boundary says how far in it reaches, its uncut rim (not the part) is left out."""
    return [f"{op} X{u['x']:.1f} Y{u['y']:.1f} {u['size_x']:.1f} x {u['size_y']:.1f} mm, {u['depth']:.1f} deep"
            + (f" within {u['band']:.1f} mm of the boundary" if "band" in u else "")
            for u in found if u.get("why") != OUTSIDE_RELIEF]


def _deepest(engagement: dict[str, dict[str, list]]) -> str:
    """Each tool's deepest engagement [mm] per operation, ``op1 T5 12.6 (3.6/8)``: deepest (a side cut may take
    the flutes), then deepest at full width / its axial limit, which holds only there."""
    return "; ".join(f"{op} " + " ".join(f"{t} {e[0]:g} ({e[2]:g}/{e[3]:g})" if e[3] is not None else f"{t} {e[0]:g}"
                                         for t, e in tools.items())
                     for op, tools in engagement.items())


#: ``factory plan`` that writes its CPU seconds (user + system, its own and its children's) to ``{cpu}`` as it
#: exits: a figure the machine's load inflates much less than the wall time, and right with ``--jobs`` > 1 too.
_PLAN_COUNTING_CPU = (
    "import atexit, pathlib, resource\n"
    "def cpu():\n"
    "    r = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]\n"
    "    pathlib.Path({cpu!r}).write_text(str(sum(u.ru_utime + u.ru_stime for u in r)))\n"
    "atexit.register(cpu)\n"
    "from cli.main import main; main()")


def _external(path: Path) -> GalleryPart:
    """A mesh file from elsewhere as a gallery part a machinist expects to plan."""
    return GalleryPart(path.stem, lambda: trimesh.load(path, force="mesh"), "plans", f"public mesh {path.name}")


def _checks(name: str, folder: Path) -> str:
    """'ok', or the first of the suite's checks (tests/gallery/judge.py) the plan in ``folder/out`` fails."""
    try:
        check_consumers_accept(name, folder / "out", folder)
    except AssertionError as e:
        return f"check failed: {e}"[:200]
    except (KeyError, ValueError) as e:  # a plan of one operation: no op 2 to judge
        return f"check failed: {type(e).__name__} {e}"[:200]
    return "ok"


def judge(part: GalleryPart, work: Path, source: Path | None = None) -> dict[str, object]:
    folder = work / part.name
    folder.mkdir()
    stl = part.write(folder) if source is None else source
    t0 = time.perf_counter()
    cpu = folder / "plan_cpu_s"
    done = subprocess.run([sys.executable, "-c", _PLAN_COUNTING_CPU.format(cpu=str(cpu)), "plan", str(stl),
                           "-o", str(folder / "out"), "--quiet", "--no-robot"],
                          cwd=ROOT, capture_output=True, text=True, env=dict(os.environ, FACTORY_THREADS="1"))
    row: dict[str, object] = {"part": part.name, "expect": part.expect, "exit": done.returncode,
                              "plan_s": round(time.perf_counter() - t0, 1),
                              "plan_cpu_s": round(float(cpu.read_text()), 1) if cpu.exists() else None}
    summary = folder / "out" / f"{part.name}.plan.json"
    if not summary.exists():
        row["error"] = done.stderr.strip().splitlines()[-1][:200] if done.stderr.strip() else ""
        row["shortfall"] = part.expect == "plans"
        return row
    doc = json.loads(summary.read_text())
    ops = doc["setups"]
    row["cycle_min"] = [round(s["estimated_cycle_s"] / 60.0, 2) for s in ops]
    row["verify_ok"] = [s["verify_ok"] for s in ops]
    reports = [doc["verify"]] + ([doc["verify_op2"]] if doc.get("verify_op2") else [])
    # verify's raw figure: the most stock over any grid cell; on a facetted round wall a cell a few microns
    # outside the wall reads the wall's whole height, so what the verdict calls left is in "left"
    row["remaining_max_mm"] = [round(r["remaining_max"], 2) for r in reports]
    row["left"] = [_regions(r.get("left", []), f"op{i + 1}") for i, r in enumerate(reports)]
    row["unreached"] = _regions(doc.get("unreached", []), "op1") + [
        u for i, s in enumerate(ops[1:]) for u in _regions(s.get("unreached", []), f"op{i + 2}")]
    # per tool: deepest, widest, deepest at full width and its axial limit [mm]
    row["engagement"] = {f"op{i + 1}": {f"T{e['tool']}": [round(e["max_depth"], 2), round(e["max_width"], 2),
                                                          round(e.get("max_full_depth", 0.0), 2),
                                                          e.get("axial_limit")]
                                        for e in r.get("engagement", [])} for i, r in enumerate(reports)}
    table = folder / "out" / f"{part.name}.tbl"
    row["rs274"] = [_rs274(Path(s["program"]), table, folder) for s in ops]
    row["checks"] = _checks(part.name, folder)
    row["shortfall"] = (part.expect != "plans" or done.returncode != 0 or not all(row["verify_ok"])
                        or any(r != "ok" for r in row["rs274"]) or row["checks"] != "ok")
    return row


#: The property the suite runs with fewer examples (tests/gallery/test_gallery.py), here with all of them.
PROPERTY = "tests/gallery/test_gallery.py::test_a_random_machinable_block_that_fits_the_vise_plans_and_passes_verify"


def random_blocks() -> dict[str, object]:
    """The suite's random-block property with its every example (``GALLERY_FULL=1``), by pytest: its exit, its
    wall time and CPU seconds (its children's: pytest runs in one), and the last lines it printed if it failed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", PROPERTY], cwd=ROOT,
                          capture_output=True, text=True, env=dict(os.environ, GALLERY_FULL="1"))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    row: dict[str, object] = {
        "part": "random_blocks_property", "expect": "plans", "exit": done.returncode,
        "plan_s": round(time.perf_counter() - t0, 1),
        "plan_cpu_s": round(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, 1),
        "shortfall": done.returncode != 0}
    if done.returncode != 0:
        row["error"] = " | ".join(done.stdout.strip().splitlines()[-3:])[:300]
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", help="comma-separated part names (default: the whole gallery)")
    ap.add_argument("--mesh", type=Path, nargs="*", default=[], help="mesh files from elsewhere, expected to plan")
    ap.add_argument("--random-blocks", action="store_true",
                    help="run the suite's random-block property with all its examples (the whole gallery's run does)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", type=Path, help="write the rows here too")
    args = ap.parse_args()
    whole = not (args.parts or args.mesh or args.random_blocks)
    parts: list[tuple[GalleryPart, Path | None]] = [(BY_NAME[n], None) for n in args.parts.split(",")] \
        if args.parts else [(p, None) for p in PARTS] if whole else []
    parts += [(_external(m), m.resolve()) for m in args.mesh]
    with tempfile.TemporaryDirectory(prefix="gallery-") as tmp, ThreadPoolExecutor(args.jobs) as pool:
        todo = {pool.submit(judge, p, Path(tmp), src): p.name for p, src in parts}
        done = {}
        for f in as_completed(todo):
            done[todo[f]] = f.result()
            print(json.dumps(done[todo[f]]), flush=True)
        rows = [done[p.name] for p, _ in parts]
    if args.random_blocks or whole:
        rows.append(random_blocks())
        print(json.dumps(rows[-1]), flush=True)
    print()
    print("| part | expect | exit | plan s | plan CPU s | cycle op1/op2 min | verify | stock left (verify) | unreached (plan) "
          "| deepest engagement mm (at full width / axial limit) | rs274 | note |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        note = r.get("error", "") or ("; ".join(x for x in [*r.get("rs274", []), r.get("checks", "ok")] if x != "ok"))
        left = [u for op in r.get("left", []) for u in op]
        print(f"| {r['part']} | {r['expect']} | {r['exit']} | {r['plan_s']} | {r['plan_cpu_s']} | {r.get('cycle_min', '')} | "
              f"{r.get('verify_ok', '')} | {'; '.join(left) or ('none' if 'left' in r else '')} | "
              f"{'; '.join(r.get('unreached', [])) or ('none' if 'left' in r else '')} | "
              f"{_deepest(r.get('engagement', {}))} | "
              f"{'' if 'rs274' not in r else 'ok' if all(x == 'ok' for x in r['rs274']) else 'FAIL'} | {note} |")
    short = [r["part"] for r in rows if r["shortfall"]]
    print(f"\n{len(rows) - len(short)} of {len(rows)} parts as a machinist expects; short: {', '.join(short) or 'none'}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
