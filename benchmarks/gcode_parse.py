"""Processor time of the G-code parser (issue 35: a third of verify's main thread on the relief), per program.

    python benchmarks/gcode_parse.py OUT/PART.nc [OUT/OTHER.nc ...] [--repeat 3]
    PYTHONPATH=/other/checkout python benchmarks/gcode_parse.py ...     # that checkout's parser

Each program is parsed as verify parses it (:func:`cadcam.gcode.parse_gcode`), ``--repeat`` times; the least
processor time (user + sys of this process) is printed with the moves and a fingerprint of every array parsed
(points, motion, tool, feed, line): two checkouts timed in turn on the same programs must print the same
fingerprints. Prints one JSON line; times in seconds.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parents[1]))  # after PYTHONPATH: another checkout's parser wins

import cadcam.gcode  # noqa: E402
from cadcam.gcode import parse_gcode  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("programs", type=Path, nargs="+")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = []
    for path in args.programs:
        text = path.read_text(encoding="utf-8")
        times = []
        for _ in range(args.repeat):
            began = time.process_time()
            moves = parse_gcode(text, source=str(path))
            times.append(time.process_time() - began)
        h = hashlib.sha256()
        for a in (moves.points, moves.motion, moves.tool, moves.feed, moves.line):
            h.update(a.dtype.str.encode() + a.tobytes())
        rows.append({"program": path.name, "lines": text.count("\n"), "moves": len(moves.points) - 1,
                     "cpu_s": round(min(times), 3), "fingerprint": h.hexdigest()[:16]})
    print(json.dumps({"parser": cadcam.gcode.__file__, "load": round(os.getloadavg()[0], 1), "programs": rows}))


if __name__ == "__main__":
    main()
