"""What a planned gallery part is held to: the suite's representative parts (tests/gallery/test_gallery.py)
and the whole gallery in ``benchmarks/gallery.py`` are judged by the same assertions, so a part moved from
the suite to the benchmark keeps every check it had.
"""

from __future__ import annotations

import json
from pathlib import Path

from cadcam.gcode import parse_gcode
from cadcam.seam import SEAM_TOLERANCE
from cadcam.tools import load_tool_library
from factory.verify import read_sheet
from tests.cadcam.sweep import past_axial_limit, sweep_moves
from tests.rs274 import run_rs274

#: The probe's grid [mm]: a tenth of the 2 mm end mill.
PROBE_CELL = 0.2

#: Parts whose depth op 1 and op 2 split, their walls meeting at a seam (cadcam/seam.py).
SPLIT = ("split_tower",)


def check_consumers_accept(name: str, out: Path, work: Path) -> None:
    """``name``'s plan in ``out`` (``factory plan --no-robot``, both operations) passes its consumers and is
    finished; ``work`` is a scratch folder for rs274. Raises AssertionError with what failed.

    Both operations verify and LinuxCNC's ``rs274`` reads each program with the job's tool table; nothing is
    left above the part but the cell size's rounding on walls; no tool cuts deeper than its flutes; op 1,
    by the independent probe (tests/cadcam/sweep.py), takes no tool past its axial limit at full width;
    the walls of a part in :data:`SPLIT` meet at their seam within the tolerance."""
    doc = json.loads((out / f"{name}.plan.json").read_text())
    library = {t.number: t for t in load_tool_library().tools}
    table = out / f"{name}.tbl"  # the job's tool table, as a LinuxCNC user runs rs274
    reports = [doc["verify"], doc["verify_op2"]]
    for setup, report in zip(doc["setups"], reports, strict=True):
        assert setup["verify_ok"] and report["ok"], (setup["op"], report["faults"])
        done = run_rs274(Path(setup["program"]), table, work, timeout=120)
        assert done.returncode == 0 and "error" not in (done.stdout + done.stderr).lower(), done.stderr[-500:]
        # Finished to tolerance: nothing left above the part but the cell size's rounding on walls.
        assert report["remaining_max"] <= 0.05, (setup["op"], report["remaining_max"])
        assert report["finished"] and report["left"] == [], report["left"]
        for e in report["engagement"]:
            # No tool cuts deeper than its flutes: the shank would rub, the flutes pack.
            assert e["max_depth"] <= library[e["tool"]].flute_length + 1e-6, e
    # Op 1 from its stock box, by the independent probe: no tool past its axial limit at full width
    # (op 2 starts from what op 1 left, which the probe does not model).
    op1 = doc["setups"][0]
    read = read_sheet(Path(op1["setup_sheet"]))
    tools = read.tools
    moves = parse_gcode(Path(op1["program"]).read_text(), source=op1["program"])
    sw = sweep_moves(moves.points, moves.motion, moves.tool, tools, read.setup, PROBE_CELL, full_width=True)
    assert past_axial_limit(sw, moves.tool, tools, PROBE_CELL) == {}
    op2 = doc["setups"][1]
    assert ("seams" in op2) == (name in SPLIT), op2.keys()
    for seam in op2.get("seams", []):
        # where op 1's walls end and op 2's begin: both finished, no step between them
        assert seam["step"] <= SEAM_TOLERANCE and max(seam["above"], seam["below"]) <= SEAM_TOLERANCE, seam
