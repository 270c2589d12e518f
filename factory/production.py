"""Orders through the cell as ``factory simulate`` runs them, as one library call.

:func:`simulate_orders` reads the orders, runs them (:func:`factory.simulation.run_cell`: plans from the
catalog, camera steps, the discrete-event simulation), records the run in a process record if asked, and
writes the outputs asked for: the MCAP log with its Foxglove layout beside it, the Gantt chart. It returns
the run and the summary ``factory simulate --json`` prints::

    from pathlib import Path
    from factory.cellinputs import CellInputs
    from factory.production import SimulateRequest, simulate_orders

    done = simulate_orders(SimulateRequest(Path("samples/orders.yaml"), CellInputs(catalog=Path("build"), faults=7),
                                           mcap=Path("build/cell.mcap"), overwrite=True))
    print(done.summary["summary"]["parts_per_hour"], [o.outcome for o in done.run.result.outcomes])
"""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import Any

from factory.catalog import sha256_file
from factory.core.atomic import check_writable, write_bytes, write_text
from factory.core.progress import Progress, Stopwatch
from factory.core.resources import SAMPLES
from factory.foxglove import layout_json
from factory.live import LiveSink
from factory.pictures import png_bytes
from factory.record import Record
from factory.cellinputs import CellInputs
from factory.simulation import ROBOT_RATE_HZ, CellRun, PartAssets, run_cell, write_cell_log
from robotprog.cell import load_cell
from robotprog.gantt import activity_chart
from robotprog.orders import Order, read_orders

#: Orders ``factory simulate`` runs without an ORDERS argument.
SAMPLE_ORDERS = SAMPLES / "orders.yaml"


@dataclasses.dataclass(frozen=True)
class SimulateRequest:
    """Everything ``factory simulate`` is asked: the orders, the cell's inputs, and the outputs to write.

    Attributes
    ----------
    orders : Path
        Orders file (YAML or CSV: part, quantity, material, priority).
    inputs : CellInputs
        The catalog, cell, camera, tools and faults the orders run with.
    db : str, optional
        Process record to append the run to: a SQLite file or a SQLAlchemy database URL.
    robot_rate_hz : float
        Robot joint states and link transforms per second of simulated time in the log [Hz].
    mcap, png : Path, optional
        The MCAP log (and ``OUT.layout.json`` beside it), the Gantt chart; None: not written.
    overwrite : bool
        Replace outputs that exist.
    """

    orders: Path = SAMPLE_ORDERS
    inputs: CellInputs = CellInputs()
    db: str | None = None
    robot_rate_hz: float = ROBOT_RATE_HZ
    mcap: Path | None = None
    png: Path | None = None
    overwrite: bool = False

    @property
    def layout(self) -> Path | None:
        """The Foxglove layout written beside the MCAP log."""
        return self.mcap.with_suffix(".layout.json") if self.mcap is not None else None

    def checked(self) -> tuple[Order, ...]:
        """The orders, read, once every output is known to be writable: the refusals that come before any work.

        Raises
        ------
        FactoryError
            The orders file is malformed, or an output exists and ``overwrite`` is false.
        """
        orders = read_orders(self.orders)
        for p in (self.mcap, self.layout, self.png):
            if p is not None:
                check_writable(p, self.overwrite)
        return orders


@dataclasses.dataclass(frozen=True)
class SimulatedOrders:
    """What :func:`simulate_orders` ran and wrote.

    Attributes
    ----------
    run : CellRun
        The orders, the cell, every part's assets and the simulation's result.
    summary : dict
        The JSON summary of ``factory simulate --json``: the result's figures, per part where its plan
        came from and its process times [s], wall ``seconds`` per stage, the ``mcap`` written (path,
        layout, bytes, messages per topic) and the ``db`` run, when asked.
    seconds : dict
        Wall time per stage [s].
    """

    run: CellRun
    summary: dict[str, Any]
    seconds: dict[str, float]


def simulate_orders(request: SimulateRequest, *, orders: tuple[Order, ...] | None = None,
                    live: LiveSink | None = None, progress: Progress | None = None) -> SimulatedOrders:
    """Run ``request``'s orders through the cell and write what it asks for.

    ``orders``: as :meth:`SimulateRequest.checked` read them (None: read now, the outputs checked).
    ``live``: a bound live view the run is streamed to as it is logged. An order whose part is missing
    or cannot be planned fails on its own; the others run.

    Raises
    ------
    FactoryError
        Malformed orders, cell or camera file, an output that exists without ``overwrite``, a process
        record that cannot be opened or written.
    """
    cell = request.inputs
    cell.fault_model()  # a fault rate without a seed: refused before any file is read
    if orders is None:
        orders = request.checked()
    watch = Stopwatch(progress)
    record = Record(request.db) if request.db is not None else None  # unreachable: fails before any planning
    recorder = None
    if record is not None:
        recorder = record.recorder(cell=load_cell(cell.cell).name, orders=orders, orders_file=str(request.orders),
                                   orders_sha256=sha256_file(request.orders), faults_seed=cell.faults)
    try:
        run = run_cell(orders, cell, progress=progress, events=recorder.begin if recorder else None)
        if recorder is not None:
            recorder.finish(run.result)
    finally:
        if recorder is not None:
            recorder.close()
            record.close()  # type: ignore[union-attr]
    watch.seconds.update(run.seconds)
    counts = _write_log(request, run, record.shown if record is not None else None,
                        recorder.run_id if recorder is not None else None, live, watch)
    if request.png is not None:
        write_bytes(request.png, png_bytes(activity_chart(run.result)), overwrite=request.overwrite)
    doc = run.result.to_dict()
    doc["parts"] = [
        {"part": str(k[0]), "material": k[1],
         **({"planned_now": v.planned_now, "plan": str(v.entry.summary_path),
             "process_s": {f: None if getattr(v.process, f) is None else round(getattr(v.process, f), 3)
                           for f in v.process.__dataclass_fields__}}
            if isinstance(v, PartAssets) else {"error": v})}
        for k, v in run.assets.items()]
    if run.picks:
        doc["rack_picks"] = [p.to_dict() for p in run.picks]
    doc["seconds"] = watch.rounded()
    if request.mcap is not None:
        doc["mcap"] = {"path": str(request.mcap), "layout": str(request.layout), "bytes": request.mcap.stat().st_size,
                       "messages": counts}
    if record is not None:
        doc["db"] = {"url": record.shown, "run": recorder.run_id}  # type: ignore[union-attr]
    return SimulatedOrders(run, doc, dict(watch.seconds))


def _write_log(request: SimulateRequest, run: CellRun, db: str | None, db_run: int | None, live: LiveSink | None,
               watch: Stopwatch) -> dict[str, int]:
    """The MCAP log and its layout, and the live view's stream: messages written per topic ({}: neither)."""
    if request.mcap is None and live is None:
        return {}
    with watch("write"), (live or contextlib.nullcontext()):
        cell = request.inputs
        inputs = {str(request.orders): sha256_file(request.orders), str(cell.cell): sha256_file(cell.cell)}
        inputs.update({str(a.part): a.entry.summary["catalog"]["mesh_sha256"] for a in run.ready.values()})
        counts = write_cell_log(request.mcap, run.result, run.ready, run.orders, run.cell, run.world, run.stations,
                                overwrite=request.overwrite, inputs=inputs,
                                parameters={"faults_seed": cell.faults, "catalog": str(cell.catalog),
                                            **({"blank_offsets_seed": cell.blank_offsets}
                                               if cell.blank_offsets is not None else {}),
                                            **({"rack_light": cell.rack_light} if cell.rack_light is not None else {}),
                                            "robot_rate_hz": request.robot_rate_hz,
                                            **({"db": db, "db_run": db_run} if db is not None else {})},
                                live=live, robot_rate_hz=request.robot_rate_hz, picks=run.picks)
        if request.layout is not None:
            write_text(request.layout, layout_json(), overwrite=request.overwrite)
    return counts
