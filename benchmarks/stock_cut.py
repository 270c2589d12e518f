"""Processor time of the stock model's cut (issue 35): verify of a planned op-1 program, in this process.

    python benchmarks/stock_cut.py OUT/PART.nc [--repeat 3] [--grid 0.2]

``OUT`` is a ``factory plan`` output folder (the program, its setup sheet ``PART.setup.json``; the part is
``samples/PART.stl``). The program is verified as ``factory verify`` verifies it (:func:`factory.verify.run_verify`),
``--repeat`` times; each run's processor time (user + sys of this process) is printed, with a fingerprint of
everything the cut measured (the stock left, what each move removed and met): two checkouts timed in turn on
the same program must print the same fingerprint. Also the processor time of this (the main) thread alone: the
cut makes each batch's pairs in a second thread while the batch before cuts, so on a machine with a processor
idle its wall time is this thread's (``FACTORY_THREADS=1``: all of it here). Prints one JSON line; times in seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cadcam.verify import VerifyOptions  # noqa: E402
from factory.verify import part_triangles, read_sheet, run_verify  # noqa: E402


def _fingerprint(result) -> str:
    """SHA-256 over the simulated stock and every field of the verdict (arrays to the bit)."""
    h = hashlib.sha256()
    sim = result.simulation
    for a in (sim.stock_top, sim.removed_volume):
        h.update(np.ascontiguousarray(a).tobytes())
    for f in dataclasses.fields(result.report):
        value = getattr(result.report, f.name)
        h.update(f.name.encode())
        h.update(np.ascontiguousarray(value).tobytes() if isinstance(value, np.ndarray) else repr(value).encode())
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("program", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--grid", type=float, default=0.2, help="verify's grid [mm]")
    args = ap.parse_args()
    part = args.program.name.split(".")[0]
    read = read_sheet(args.program.with_name(f"{part}.setup.json"))
    triangles = part_triangles(ROOT / "samples" / f"{part}.stl", read.setup, read.sheet.source_sha256,
                               read.sheet.intake, 0.01)
    options = VerifyOptions(cell=args.grid, op2_follows=read.sheet.next is not None)
    text = args.program.read_text()
    cpu, main_cpu, prints = [], [], set()
    for _ in range(args.repeat):
        t, m = time.process_time(), time.thread_time()
        result = run_verify(text, str(args.program), read.setup, read.tools, triangles, options,
                            operations=read.sheet.operations)
        cpu.append(round(time.process_time() - t, 3))
        main_cpu.append(round(time.thread_time() - m, 3))
        prints.add(_fingerprint(result))
    print(json.dumps({"program": str(args.program), "grid_mm": args.grid, "cpu_s": cpu, "min_cpu_s": min(cpu),
                      "main_thread_cpu_s": main_cpu, "min_main_thread_cpu_s": min(main_cpu),
                      "fingerprint": sorted(prints)}))


if __name__ == "__main__":
    main()
