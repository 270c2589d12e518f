"""The cell as a long-running service: work orders in on ``/order``, the simulated cell out (``factory cell --ros2``).

:class:`CellService` keeps one ROS 2 participant (:class:`factory.ros2.Ros2Graph`) for as long as it runs.
It subscribes ``/order`` with two types, as the scheduler node:

* ``factory_msgs/WorkOrder`` (``ros/factory_msgs/msg/WorkOrder.msg``): id, part, material, quantity, priority;
* ``std_msgs/String``: a part's name in the catalog, one part, the catalog plan's material.

A part is a catalog name (``PART`` of a ``PART.plan.json`` in the catalog, whose ``part`` and material the
plan records) or the path of a mesh on this machine. Each order is answered on ``/order_status``
(``factory_msgs/OrderStatus``, its id: the sender's, or ``r1``, ``r2``, ... when it gave none): ``queued``
when taken, ``refused`` with the reason when malformed (the cell carries on), then ``running`` with the
good and rejected parts so far, and its outcome, ``done``, ``rejected`` or ``failed``.

When the cell is free it runs every order waiting as one run (:func:`factory.simulation.run_cell`: planned
from the catalog, the discrete-event simulation) and streams that run to the graph and the session's logs
(:func:`factory.simulation.write_cell_log`) at ``speed`` times real time. The session has one clock: each
run's log times and every stamp in its messages (each ``builtin_interfaces/Time``) are moved on to start
where the previous run ended, so ``/tf`` and the log never go back in time.

Stopping (:attr:`CellService.stop`, set by the command on SIGINT or SIGTERM): no new run starts; the run
under way is written to its end without pacing, so the log and the process record hold whole runs only;
orders still waiting are answered ``failed``; then the caller closes the sinks.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from factory.cellmsgs import OrderLine
from factory.core.errors import FactoryError, SchedulerError
from factory.live import Pacer
from factory.rosmsgs import TYPESTORE, ros_time
from factory.cellinputs import CellInputs
from factory.record import Record
from factory.simulation import ROBOT_RATE_HZ, run_cell, write_cell_log
from robotprog.cell import load_cell
from robotprog.orders import Order

if TYPE_CHECKING:  # DDS loads with the graph the caller makes
    from factory.ros2 import Received, Ros2Graph

log = logging.getLogger(__name__)

#: Where orders come in, and where their status goes out.
ORDER_TOPIC, STATUS_TOPIC = "/order", "/order_status"
#: The types ``/order`` takes: a full work order, or a catalog part's name.
WORK_ORDER, PART_NAME = "factory_msgs/msg/WorkOrder", "std_msgs/msg/String"
#: Mesh files a part given by path may be (the others are catalog names).
_MESH_SUFFIXES = (".stl", ".obj", ".3mf", ".ply", ".step", ".stp")
#: Orders are looked for at least this often [s] while the cell streams a run or waits.
POLL_S = 0.05

_OrderStatus = TYPESTORE.types["factory_msgs/msg/OrderStatus"]


@dataclasses.dataclass(frozen=True)
class CatalogPart:
    """A part the catalog has a plan of: its mesh and the material it was planned in."""

    mesh: Path
    material: str


def catalog_part(catalog: Path, name: str) -> CatalogPart:
    """The part called ``name`` in ``catalog``: the ``part`` and material of its ``NAME.plan.json``
    (the newest, when the catalog holds several in one material).

    Raises
    ------
    SchedulerError
        No plan of that name, or plans of it in several materials (a work order must name one).
    """
    found: dict[str, tuple[float, CatalogPart]] = {}
    for path in catalog.rglob(f"{name}.plan.json") if catalog.is_dir() else ():
        try:
            summary = json.loads(path.read_text(encoding="utf-8"))
            part = CatalogPart(Path(summary["part"]), str(summary["catalog"]["material"]))
        except (OSError, ValueError, KeyError, TypeError):
            continue  # not a plan the cell could use; find_entry says why when it is looked up
        mtime = path.stat().st_mtime
        if part.material not in found or found[part.material][0] < mtime:
            found[part.material] = (mtime, part)
    if not found:
        raise SchedulerError(f"no part {name!r} in the catalog {catalog}")
    if len(found) > 1:
        raise SchedulerError(f"part {name!r} is planned in {', '.join(sorted(found))}: send a WorkOrder "
                             "naming the material")
    return next(iter(found.values()))[1]


def work_order(received: Received, catalog: Path, order_id: str) -> Order:
    """The :class:`Order` a message on ``/order`` asks for, with id ``order_id``.

    Raises
    ------
    SchedulerError
        The message did not decode, names no part, a catalog name the catalog lacks, or a mesh path
        that is not a file.
    """
    if received.msg is None:
        raise SchedulerError(received.error, source=received.topic)
    if received.typename == PART_NAME:
        text, material, quantity, priority = received.msg.data, "", 1, 0
    else:
        m = received.msg
        text, material, quantity, priority = m.part, m.material.strip(), max(int(m.quantity), 1), int(m.priority)
    text = text.strip()
    if not text:
        raise SchedulerError("no part named", source=received.topic)
    if text.lower().endswith(_MESH_SUFFIXES) or "/" in text:
        mesh = Path(text)
        if not mesh.is_file():
            raise SchedulerError(f"part file not found: {text}", source=received.topic)
        if not material:
            raise SchedulerError(f"{text}: a part given by its file needs a material", source=received.topic)
        return Order(order_id, mesh, quantity, material, priority)
    part = catalog_part(catalog, text)
    return Order(order_id, part.mesh, quantity, material or part.material, priority)


def shifted(msg: Any, offset_ns: int) -> Any:
    """``msg`` with every ``builtin_interfaces/Time`` in it moved on by ``offset_ns`` [ns]: a copy where
    anything changes (messages are cached and logged again), ``msg`` itself when the offset is 0."""
    if offset_ns == 0:
        return msg
    return _shifted(msg, offset_ns)


def _shifted(value: Any, offset_ns: int) -> Any:
    kind = getattr(value, "__msgtype__", None)
    if kind == "builtin_interfaces/msg/Time":
        return ros_time(value.sec * 1_000_000_000 + value.nanosec + offset_ns)
    if kind is not None:
        changed = {}
        for name in value.__dataclass_fields__:
            old = getattr(value, name)
            new = _shifted(old, offset_ns)
            if new is not old:
                changed[name] = new
        return dataclasses.replace(value, **changed) if changed else value
    if isinstance(value, list) and value and hasattr(value[0], "__msgtype__"):
        return [_shifted(v, offset_ns) for v in value]
    return value  # numbers, strings, arrays: no time in them


@dataclasses.dataclass(frozen=True)
class CellOptions:
    """How the service runs each batch of orders, as ``factory simulate`` runs an orders file.

    Attributes
    ----------
    inputs : CellInputs
        The catalog (parts not in it are planned into it), cell, camera, tools and the faults injected
        in every run (as ``factory simulate --faults``).
    robot_rate_hz : float
        Robot joint states and link transforms per second of simulated time [Hz].
    speed : float
        Runs are streamed at this many times real time (``inf``: at once).
    """

    inputs: CellInputs = CellInputs()
    robot_rate_hz: float = ROBOT_RATE_HZ
    speed: float = 60.0


class CellService:
    """The cell taking orders from ``graph`` until :attr:`stop` is set; see the module's docstring.

    Parameters
    ----------
    options : CellOptions
    graph : Ros2Graph
        The ROS 2 participant (made with ``speed=inf``: the service paces each run itself).
    out : LiveSink
        Where runs and statuses are written: the graph, and the session's logs beside it (a
        :class:`factory.live.Fanout`).
    record : Record, optional
        Process record each run is appended to, as ``factory simulate --db`` does.
    """

    def __init__(self, options: CellOptions, graph: Ros2Graph, out: Any, record: Record | None = None) -> None:
        self.options = options
        self.stop = threading.Event()
        self._graph, self._out, self._record = graph, out, record
        self._cell_name = load_cell(options.inputs.cell).name  # a malformed cell file is refused before any order
        options.inputs.fault_model()  # a fault rate without a seed is refused before any order
        self._waiting: list[Order] = []
        self._sent: dict[str, OrderLine] = {}  # last status sent per order id
        self._numbered = 0
        self._now_ns = 0  # the session's clock: the last log time written [ns]
        self._offset_ns = 0  # added to the log times of the run under way [ns]
        self._last_poll = 0.0
        self.runs = 0
        graph.subscribe(ORDER_TOPIC, WORK_ORDER)
        graph.subscribe(ORDER_TOPIC, PART_NAME)
        graph.advertise(STATUS_TOPIC, _OrderStatus.__msgtype__)  # matched before the first order's answer

    # --- orders in, statuses out -------------------------------------------------------------

    def _status(self, line: OrderLine) -> None:
        if self._sent.get(line.id) == line:
            return
        self._sent[line.id] = line
        msg = _OrderStatus(id=line.id, part=line.part, material=line.material, quantity=int(line.quantity),
                           good=int(line.good), rejected=int(line.rejected), state=line.state, reason=line.reason)
        self._out.write(STATUS_TOPIC, msg, self._now_ns)

    def _order_id(self, received: Received) -> str:
        given = received.msg.id.strip() if received.typename == WORK_ORDER and received.msg is not None else ""
        if given:
            return given
        self._numbered += 1
        while f"r{self._numbered}" in self._sent:
            self._numbered += 1
        return f"r{self._numbered}"

    def take_orders(self) -> int:
        """Take what came on ``/order``: each queued (status ``queued``) or refused with the reason."""
        self._last_poll = time.monotonic()
        taken = 0
        for received in self._graph.take():
            order_id = self._order_id(received)
            try:
                if order_id in self._sent:
                    raise SchedulerError(f"order id {order_id!r} was used before in this session",
                                         source=received.topic)
                order = work_order(received, self.options.inputs.catalog, order_id)
            except FactoryError as e:
                part = received.msg.data if received.typename == PART_NAME and received.msg is not None else \
                    getattr(received.msg, "part", "")
                log.warning("order %s refused: %s", order_id, e)
                self._sent.pop(order_id, None)
                self._status(OrderLine(order_id, part, getattr(received.msg, "material", ""), 0, 0, 0, "refused",
                                       str(e)))
                continue
            log.info("order %s: %d x %s in %s", order.id, order.quantity, order.part, order.material)
            self._waiting.append(order)
            self._status(OrderLine(order.id, order.part.name, order.material, order.quantity, 0, 0, "queued"))
            taken += 1
        return taken

    # --- runs --------------------------------------------------------------------------------

    def serve(self) -> None:
        """Take orders and run them until :attr:`stop` is set; orders left waiting then are answered failed."""
        while not self.stop.is_set():
            self.take_orders()
            if self._waiting:
                batch, self._waiting = tuple(self._waiting), []
                self._run(batch)
            else:
                self.stop.wait(POLL_S)
        self.take_orders()
        for order in self._waiting:
            self._status(dataclasses.replace(self._sent[order.id], state="failed",
                                             reason="the cell stopped before it ran the order"))
        self._waiting = []

    def _run(self, orders: tuple[Order, ...]) -> None:
        options = self.options
        o = options.inputs
        recorder = None
        if self._record is not None:
            digest = hashlib.sha256(repr(orders).encode()).hexdigest()
            recorder = self._record.recorder(cell=self._cell_name, orders=orders, orders_file=ORDER_TOPIC,
                                             orders_sha256=digest, faults_seed=o.faults)
        try:
            try:
                run = run_cell(orders, o, events=recorder.begin if recorder else None)
                if recorder is not None:
                    recorder.finish(run.result)
            finally:
                if recorder is not None:
                    recorder.close()
            self._offset_ns = self._now_ns + (1_000_000_000 if self.runs else 0)  # a second between runs
            session = _RunSink(self, Pacer(options.speed, cancel=self.stop))
            write_cell_log(None, run.result, run.ready, orders, run.cell, run.world, run.stations, overwrite=False,
                           inputs={}, parameters={}, live=session, robot_rate_hz=options.robot_rate_hz)
        except FactoryError as e:  # this run's orders fail; the cell carries on
            log.error("run of %s failed: %s", ", ".join(x.id for x in orders), e)
            for order in orders:
                self._status(dataclasses.replace(self._sent[order.id], state="failed", reason=str(e)))
            return
        self.runs += 1
        for out in run.result.outcomes:  # the outcomes the order queue may not have reached
            self._status(dataclasses.replace(self._sent[out.order], good=out.good, rejected=out.rejected,
                                             state=out.outcome, reason=out.reason))


class _RunSink:
    """One run's stream into the session: paced, moved onto the session's clock, order changes
    answered on ``/order_status``, and ``/order`` read while it plays."""

    def __init__(self, service: CellService, pacer: Pacer) -> None:
        self.service, self.pacer = service, pacer

    def write(self, topic: str, msg: Any, log_time_ns: int, *, latched: bool = False) -> None:
        s = self.service
        if log_time_ns > 0:
            self.pacer.wait(log_time_ns)
        t = s._offset_ns + log_time_ns
        s._now_ns = max(s._now_ns, t)
        s._out.write(topic, shifted(msg, s._offset_ns), t, latched=latched)
        if topic == "/cell/orders":
            for line in msg.orders:
                s._status(OrderLine(line.id, line.part, line.material, line.quantity, line.good, line.rejected,
                                    line.state, line.reason))
        if time.monotonic() - s._last_poll > POLL_S:
            s.take_orders()

    def __enter__(self) -> "_RunSink":
        return self

    def __exit__(self, *exc: object) -> None:
        pass  # the session's sinks outlive the run


__all__ = ["ORDER_TOPIC", "PART_NAME", "STATUS_TOPIC", "WORK_ORDER", "CatalogPart", "CellOptions", "CellService",
           "catalog_part", "shifted", "work_order"]
