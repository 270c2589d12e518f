"""The Gantt chart of a simulation shows each resource busy for the share of time it was busy."""

from pathlib import Path

import numpy as np
import pytest

from robotprog.cellsim import FaultModel, PartProcess, simulate
from robotprog.gantt import COLOURS, OP_COLOURS, ROWS, activity_chart
from robotprog.orders import Order

PROC = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                   reject_s=5.0, regrasp_s=3.0)


@pytest.mark.parametrize("faults", [FaultModel(), FaultModel(0.2, 0.2, 0.2, 0.2, seed=3)])
def test_machine_row_is_cut_for_the_machine_utilisation(faults):
    result = simulate([Order(f"o{i}", Path("a.stl"), 2, "steel", 0) for i in range(4)], {Path("a.stl"): PROC},
                      faults)
    img = activity_chart(result, width=1400)
    assert img.shape[1] == 1400 and img.shape[2] == 3 and img.dtype == np.uint8
    # the middle line of the machine row: share of the plot width drawn in the cut colour
    row = [r[0] for r in ROWS].index("machine")
    y = 46 + row * (34 + 10) + 17
    line = img[y, 110:1400 - 20]
    cut = np.all(line == COLOURS["cut"], axis=1).mean()
    assert cut == pytest.approx(result.summary["machine_utilisation"], abs=0.01)
    # a fault run frames its faults in red somewhere
    red = np.all(img == (220, 0, 0), axis=2).any()
    assert red == (sum(result.summary["faults"].values()) > 0 and any(
        a.outcome in ("grasp_missed", "stock_not_found", "machine_alarm", "inspect_fail", "timeout")
        for a in result.activities))


def test_two_setups_show_op1_flip_op2():
    two = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=2.0, inspect_s=2.5,
                      reject_s=5.0, regrasp_s=3.0, flip_s=60.0, op2_machining_s=200.0)
    result = simulate([Order(f"o{i}", Path("a.stl"), 2, "steel", 0) for i in range(3)], {Path("a.stl"): two})
    img = activity_chart(result, width=1400)
    names = [r[0] for r in ROWS]
    span = result.summary["makespan_s"]

    def share(row, colour):
        y = 46 + names.index(row) * (34 + 10) + 17
        return np.all(img[y, 110:1400 - 20] == colour, axis=1).mean()

    def busy(action, op=None):
        return sum(a.end - a.start for a in result.activities if a.action == action and a.op == op) / span

    assert share("machine", OP_COLOURS[1]) == pytest.approx(busy("cut", 1), abs=0.01)
    assert share("machine", OP_COLOURS[2]) == pytest.approx(busy("cut", 2), abs=0.01)
    assert share("robot", COLOURS["flip"]) == pytest.approx(busy("flip"), abs=0.01)
    assert busy("flip") > 0
