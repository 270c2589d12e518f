"""Hostile inputs for every command, and a runner that drives the real ``factory`` command in a
subprocess with its address space capped and a timeout, to prove each ends in one
``error: <file>: <what>`` line, exit 1 (2 for usage), within bounded memory and time, and
writes nothing.

Run alone (``python -m tests.cli.hostile``) it prints one line per case; the tests in
``test_hostile.py`` assert on the same cases.
"""

from __future__ import annotations

import json
import os
import resource
import struct
import subprocess
import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "samples"
FIXTURES = ROOT / "fixtures"

#: Address-space cap of each run [bytes]; the issue's bound is 1 GB of resident memory.
MEMORY_LIMIT = 1536 * 1024 * 1024
#: Processor-time cap of each run [s] (RLIMIT_CPU: on a shared, loaded machine wall time
#: would measure the neighbours).
CPU_LIMIT_S = 30
#: Wall-time cap of each run [s], generous for a loaded machine.
TIMEOUT_S = 180.0


def alias_bomb(levels: int = 9, width: int = 9) -> str:
    """A one-line YAML flow value naming ``width ** levels`` strings through anchors (a
    "billion laughs")."""
    items = ["&l0 [" + ", ".join(["lol"] * width) + "]"]
    for i in range(1, levels):
        items.append(f"&l{i} [" + ", ".join([f"*l{i - 1}"] * width) + "]")
    return "[" + ", ".join(items) + "]"


def png_header_only(width: int, height: int) -> bytes:
    """A valid PNG of ``width`` x ``height`` grey pixels, all zero: a few kB that decode to
    width * height bytes."""
    raw_row = b"\x00" + bytes(width)
    comp = zlib.compressobj(9)
    data = b"".join(comp.compress(raw_row) for _ in range(height)) + comp.flush()

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", data) + chunk(b"IEND", b"")


def triangle_soup(n: int = 400, size_mm: float = 30.0, seed: int = 1) -> bytes:
    """A binary STL of ``n`` random triangles in a ``size_mm`` cube: no solid at all."""
    rng = np.random.default_rng(seed)
    tris = rng.uniform(0, size_mm, (n, 3, 3)).astype("<f4")
    rec = np.zeros(n, dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tris
    return b"\0" * 80 + struct.pack("<I", n) + rec.tobytes()


def setup_sheet(part: Path, allowance: float = 2.0, top: float = 1.0) -> dict:
    """A setup sheet placing ``part`` in a stock box ``allowance`` bigger around, ``top`` above [mm]."""
    import trimesh

    lo, hi = trimesh.load(part).bounds
    size = (hi - lo) + [2 * allowance, 2 * allowance, top]
    t = np.eye(4)
    t[:3, 3] = [allowance - lo[0], allowance - lo[1], -size[2] - lo[2]]
    return {"format": "factory.setup/1", "units": "mm", "work_origin": "top-front-left",
            "stock": {"min": [0, 0, -float(size[2])], "max": [float(size[0]), float(size[1]), 0],
                      "size": size.tolist()},
            "transform_mesh_to_work": t.tolist(), "mesh_scale": 1.0, "tools": []}


@dataclass(frozen=True)
class Case:
    """One hostile input: ``build(tmp)`` writes its files and returns the command's arguments."""

    name: str
    build: Callable[[Path], list[str]]
    code: int = 1
    #: Text the one error line must contain (besides ``error: ``).
    needle: str = ""


def _write(path: Path, text: str | bytes) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def _cell_with(tmp: Path, old: str, new: str) -> Path:
    text = (FIXTURES / "cell.yaml").read_text()
    assert old in text, old
    return _write(tmp / "cell.yaml", text.replace(old, new, 1))


def _robot_args(tmp: Path, cell: Path) -> list[str]:
    part = SAMPLES / "bracket.stl"
    sheet = _write(tmp / "p.setup.json", json.dumps(setup_sheet(part)))
    return ["robot", str(cell), "--setup", str(sheet), "--part", str(part), "-o", str(tmp / "out" / "r.mcap")]


def _orders(tmp: Path, body: str) -> list[str]:
    return ["simulate", str(_write(tmp / "orders.yaml", body)), "--catalog", str(tmp / "out"),
            "--mcap", str(tmp / "out" / "cell.mcap")]


def _locate_args(tmp: Path, image: Path, camera: Path | None = None, extrinsics: Path | None = None) -> list[str]:
    from tests.vision import TRUE_CAMERA

    camera = camera or _write(tmp / "camera.yaml", TRUE_CAMERA.to_camera_info_yaml())
    t = np.eye(4)
    t[:3, 3] = [0.5, 0.0, 1.0]
    extrinsics = extrinsics or _write(tmp / "handeye.yaml", json.dumps(
        {"format": "factory.handeye/1", "mode": "eye-to-hand", "transform": {"matrix": t.tolist()}, "tray_z": 0.0}))
    return ["locate", str(image), "--camera", str(camera), "--extrinsics", str(extrinsics),
            "--part", str(SAMPLES / "bracket.stl")]


def _verify_args(tmp: Path, program: str, sheet: dict | str | None = None) -> list[str]:
    part = SAMPLES / "bracket.stl"
    sheet = setup_sheet(part) if sheet is None else sheet
    sheet_path = _write(tmp / "p.setup.json", sheet if isinstance(sheet, str) else json.dumps(sheet))
    return ["verify", str(_write(tmp / "p.ngc", program)), "--setup", str(sheet_path), "--part", str(part),
            "-o", str(tmp / "out" / "report.json")]


def _plan_args(tmp: Path, part: Path, *extra: str) -> list[str]:
    return ["plan", str(part), "-o", str(tmp / "out"), "--no-robot", *extra]


BRACKET = str(SAMPLES / "bracket.stl")
STEP_HEADER = ("ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION(('x'),'2;1');\n"
               "FILE_NAME('p.step','2026-01-01T00:00:00',(''),(''),'','','');\n"
               "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));\nENDSEC;\nDATA;\n")

CASES: list[Case] = [
    # YAML: alias bombs, recursion, depth, syntax errors in every YAML input.
    Case("cell name: alias bomb", lambda t: _robot_args(t, _cell_with(t, "name: ur5-mill-tending", "name: " + alias_bomb()))),
    Case("orders quantity: alias bomb", lambda t: _orders(
        t, f"orders:\n  - part: {BRACKET}\n    material: aluminium_6061\n    quantity: {alias_bomb()}\n"),
        ),
    Case("tools.yaml alias bomb", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--tools", str(
        _write(t / "tools.yaml", "machine: " + alias_bomb())))),
    Case("camera yaml alias bomb", lambda t: _locate_args(
        t, _write(t / "img.png", png_header_only(64, 48)), camera=_write(t / "camera.yaml", "K: " + alias_bomb())),
        ),
    Case("handeye yaml alias bomb", lambda t: _locate_args(
        t, _write(t / "img.png", png_header_only(64, 48)), extrinsics=_write(t / "he.yaml", "x: " + alias_bomb())),
        ),
    Case("orders recursive alias", lambda t: _orders(t, "orders: &a [*a]\n")),
    Case("orders nested 5000 deep", lambda t: _orders(t, "orders: " + "[" * 5000 + "]" * 5000 + "\n")),
    Case("cell YAML syntax error", lambda t: _robot_args(t, _write(t / "cell.yaml", "format: x\nrobot: [unclosed\n")),
         needle="cell.yaml:"),
    Case("orders YAML syntax error", lambda t: _orders(t, "orders:\n  - part: [x\n"), needle="orders.yaml:"),
    Case("tools YAML syntax error", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--tools", str(
        _write(t / "tools.yaml", "machine: {max_rpm: 1\n"))), needle="tools.yaml:"),
    Case("orders 10 MB part name", lambda t: _orders(
        t, "orders:\n  - part: x\n    material: aluminium_6061\n    quantity: " + "9" * 10_000_000 + "x\n")),
    # Stock sizes: bounded like meshes, a command-line mistake.
    Case("--stock 2000,2000,31", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--stock", "2000,2000,31"), code=2,
         needle="--stock"),
    Case("--stock 100000,100000,31", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--stock", "100000,100000,31"),
         code=2, needle="--stock"),
    Case("--stock inf", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--stock", "inf,100,30"), code=2, needle="--stock"),
    Case("--stock nan", lambda t: _plan_args(t, SAMPLES / "bracket.stl", "--stock", "nan,100,30"), code=2, needle="--stock"),
    # Images: refused by their header before decoding.
    Case("locate 20000x20000 PNG", lambda t: _locate_args(t, _write(t / "big.png", png_header_only(20000, 20000))),
         needle="big.png"),
    Case("locate truncated PNG", lambda t: _locate_args(t, _write(t / "cut.png", png_header_only(640, 480)[:60])),
         needle="cut.png"),
    Case("locate text as image", lambda t: _locate_args(t, _write(t / "x.png", "not a picture")), needle="x.png"),
    # Meshes.
    Case("triangle soup in a 30 mm cube", lambda t: _plan_args(t, _write(t / "soup.stl", triangle_soup())),
         needle="soup.stl"),
    Case("empty STL", lambda t: _plan_args(t, _write(t / "empty.stl", b"")), needle="empty.stl"),
    # STEP: cut off mid-entity, no geometry, an IGES file under a .step name.
    Case("damaged STEP", lambda t: _plan_args(t, _write(t / "cut.step", STEP_HEADER + "#1 = CARTESIAN_POINT('',(0.,0.,0.));\n"
                                                       "#2 = AXIS2_PLACEMENT_3D('',#1,#3,#4);\n#3 = DIRECTION('',(0.,")),
         needle="cut.step"),
    Case("STEP with no geometry", lambda t: _plan_args(t, _write(t / "none.step", STEP_HEADER + "ENDSEC;\nEND-ISO-10303-21;\n")),
         needle="none.step: STEP file holds no geometry"),
    Case("IGES renamed .step", lambda t: _plan_args(t, _write(t / "part.step", f"{'IGES part':<72}S{1:7d}\n"
                                                                f"{'1H,,1H;':<72}G{1:7d}\n")),
         needle="part.step: an IGES file, not STEP"),
    Case("STL claiming 1e9 triangles", lambda t: _plan_args(
        t, _write(t / "liar.stl", b"\0" * 80 + struct.pack("<I", 10**9) + b"\0" * 100)), needle="liar.stl"),
    # Outputs whose folder is a file: refused before any work.
    Case("plan -o a regular file", lambda t: ["plan", BRACKET, "-o", str(_write(t / "afile", "x")), "--no-robot"],
         code=2, needle="afile"),
    Case("plan -o afile/sub", lambda t: ["plan", BRACKET, "-o", str(_write(t / "afile", "x") / "sub"), "--no-robot"],
         needle="afile"),
    Case("verify -o afile/r.json", lambda t: _verify_args(t, "G0 X0 Y0 Z5\nM2\n")[:-1]
         + [str(_write(t / "afile", "x") / "r.json")], needle="afile"),
    Case("robot -o afile/r.mcap", lambda t: _robot_args(t, FIXTURES / "cell.yaml")[:-1]
         + [str(_write(t / "afile", "x") / "r.mcap")], needle="afile"),
    # G-code and setup sheets.
    Case("verify: unknown word", lambda t: _verify_args(t, "G0 X0 Y0 Z5\nQQQ\n"), needle="p.ngc"),
    Case("verify: binary garbage", lambda t: _verify_args(t, bytes(range(256)).decode("latin-1") * 100),
         needle="p.ngc"),
    Case("verify: 1e300 coordinate", lambda t: _verify_args(t, "G0 X1e300 Y0 Z5\nM2\n"), needle="p.ngc"),
    Case("verify: setup sheet not JSON", lambda t: _verify_args(t, "M2\n", "{not json"), needle="p.setup.json"),
    Case("verify: setup sheet wrong types", lambda t: _verify_args(
        t, "M2\n", json.dumps({**setup_sheet(SAMPLES / "bracket.stl"), "stock": "big"})), needle="p.setup.json"),
]


def run_case(case: Case, tmp: Path, python: str = sys.executable, env: dict | None = None) -> dict:
    """Run ``case`` through ``python -m cli.main`` in a subprocess capped at
    :data:`MEMORY_LIMIT` and :data:`TIMEOUT_S`; what happened, and whether it was clean."""
    tmp.mkdir(parents=True, exist_ok=True)
    args = case.build(tmp)
    before = {p for p in tmp.rglob("*")}

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
        resource.setrlimit(resource.RLIMIT_CPU, (CPU_LIMIT_S, CPU_LIMIT_S + 1))

    t0 = time.perf_counter()
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime
    try:
        proc = subprocess.run([python, "-c", "from cli.main import main; main()", *args], capture_output=True,
                              text=True, timeout=TIMEOUT_S, preexec_fn=limit, cwd=tmp,
                              env={**os.environ, **(env or {}), "COLUMNS": "200"})
        code, out, err = proc.returncode, proc.stdout, proc.stderr
    except subprocess.TimeoutExpired as e:
        code, out, err = None, "", f"timeout after {TIMEOUT_S} s: {(e.stderr or b'')[-200:]!r}"
    seconds = time.perf_counter() - t0
    cpu_s = resource.getrusage(resource.RUSAGE_CHILDREN).ru_utime - cpu0
    if code is not None and code < 0:
        err = f"killed by signal {-code} (memory or processor-time limit)\n" + err
    written = sorted(str(p.relative_to(tmp)) for p in set(tmp.rglob("*")) - before
                     if p.is_file() or not any(p.iterdir()))
    # Every line, stage lines too: a quick failure shows no stage (cli.common.STAGE_LINES_AFTER_S).
    lines = [line for line in err.splitlines() if line.strip()]
    if case.code == 2:
        # A command-line mistake: click's usage message (a few lines) naming the option.
        one_line = "Traceback" not in err and any(line.startswith("Error: ") for line in lines)
        said = err
    else:
        one_line = (len(lines) == 1 and lines[0].startswith("error: ") and not err.startswith("\n")
                    and len(lines[0]) < 1000)
        said = lines[0] if lines else ""
    clean = code == case.code and one_line and case.needle in said and out == "" and not written
    return {"name": case.name, "code": code, "clean": clean, "seconds": round(seconds, 1), "cpu_s": round(cpu_s, 1),
            "stderr": err[-300:], "written": written}


if __name__ == "__main__":
    import tempfile

    sys.path.insert(0, str(ROOT))
    only = sys.argv[1:]
    results = []
    with tempfile.TemporaryDirectory() as d:
        for i, case in enumerate(CASES):
            if only and not any(o in case.name for o in only):
                continue
            r = run_case(case, Path(d) / f"c{i}")
            results.append(r)
            first = r["stderr"].strip().splitlines()[:1] or [""]
            print(f"{'clean' if r['clean'] else 'BAD  '} {r['code']!s:>4} {r['seconds']:5.1f}s {case.name}: "
                  f"{first[0][:150]} {'WROTE ' + ','.join(r['written'][:3]) if r['written'] else ''}", flush=True)
    print(f"{sum(r['clean'] for r in results)} of {len(results)} clean")
