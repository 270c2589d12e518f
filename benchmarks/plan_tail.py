"""CPU of the drawing at the tail of `factory plan`: the pictures and the log's views of the job.

    python benchmarks/plan_tail.py samples/relief.stl [--keep planned.pkl] [--repeat 3] [--json]
    PYTHONPATH=OTHER python benchmarks/plan_tail.py --planned planned.pkl --json     # another checkout, same job

Plans the part's op 1 once (or reads a pickled :class:`factory.cam.PlannedPart` with ``--planned``; ``--keep``
writes one), then times, least of ``--repeat`` [s of this process's CPU]: the toolpath picture, the setup picture,
their PNG encoding, and the job's log (:func:`factory.cam.log_job`: the toolpath, part and stock views and the
job's attachment). What a plan draws beside verify (issue 35), replayed alone: it compares checkouts on a loaded
machine. The digests (sha256 of the pictures and of every logged payload) show the same outputs. The last line
printed is one JSON object.
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

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if not os.environ.get("PYTHONPATH"):  # else the checkout PYTHONPATH names is the one measured
    sys.path.insert(0, str(ROOT))

import cadcam  # noqa: E402
from cadcam.preview import setup_image  # noqa: E402
from factory.cam import CamRequest, compute_job, log_job  # noqa: E402
from factory.mcaplog import LogBuffer  # noqa: E402
from factory.pictures import png_bytes  # noqa: E402


def _least(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t)
    return round(best, 4), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("part", nargs="?", type=Path, help="a part to plan (else --planned)")
    ap.add_argument("--planned", type=Path, help="a pickled PlannedPart to draw")
    ap.add_argument("--keep", type=Path, help="write the planned part here (pickle)")
    ap.add_argument("--material", default="aluminium")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true", help="only the JSON line")
    args = ap.parse_args()
    if args.planned is not None:
        planned = pickle.loads(args.planned.read_bytes())
    elif args.part is not None:
        planned = compute_job(CamRequest.defaults(args.part, args.material))
    else:
        ap.error("give a part or --planned")
    if args.keep is not None:
        args.keep.write_bytes(pickle.dumps(planned))
    job = planned.job
    toolpath_s, toolpath = _least(planned.toolpath_picture, args.repeat)
    setup_s, setup = _least(lambda: setup_image(job.setup, np.asarray(planned.part_work.triangles), job.part_name),
                            args.repeat)
    png_s, pngs = _least(lambda: (png_bytes(toolpath), png_bytes(setup)), args.repeat)

    def logged() -> LogBuffer:
        buffer = LogBuffer()
        log_job(buffer, planned, None)
        return buffer

    log_s, buffer = _least(logged, args.repeat)
    payloads = hashlib.sha256()
    for call in buffer._calls:  # (topic, typename, bytes, time, latched) or an attachment (name, type, bytes, time)
        payloads.update(repr((call[0], call[1], call[3])).encode() + bytes(call[2]))
    out = {"part": job.part_name, "points": int(sum(len(op.points) for op in job.operations)),
           "triangles": int(len(planned.part_work.faces)), "toolpath_picture_cpu_s": toolpath_s,
           "setup_picture_cpu_s": setup_s, "png_cpu_s": png_s, "log_job_cpu_s": log_s,
           "pictures_sha256": hashlib.sha256(pngs[0] + pngs[1]).hexdigest()[:16],
           "log_sha256": payloads.hexdigest()[:16], "root": str(Path(cadcam.__file__).parent.parent)}
    if not args.json:
        for k, v in out.items():
            print(f"{k}: {v}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
