"""The process record: what every run of the cell did, kept in a SQL database for traceability.

``factory simulate … --db cell.sqlite`` (or ``--db`` any SQLAlchemy URL: ``sqlite:///cell.sqlite``,
``postgresql+psycopg://user:pw@host/plant``) writes one *run* per simulation into the record, as the
simulation goes: the simulation tells a :class:`RunRecorder` every event (a plain callback, see
:data:`robotprog.cellsim.EventSink`) and each event is one transaction. Re-running onto an existing
record appends a new run; nothing written is rewritten except the rows of the run in progress
(an alarm's recovery, a part's outcome, an order's counts). One schema and one code path serve
SQLite and PostgreSQL (SQLAlchemy Core); the schema comes with Alembic migrations
(``factory/migrations``), run when a record is opened, so an old record opens with a new factory.

Tables (named after ISA-95 / B2MML where they fit; times ``*_s`` are simulated seconds [s] from the
run's start, ``seq`` is the number of the event that wrote the row, 1, 2, … per run):

========================  ===================================================================
``run``                   one per ``simulate``: cell, wall-clock start and end, factory version,
                          orders file and its SHA-256, faults seed, makespan, summary (JSON).
``work_order``            one per order: part, material, quantity, priority; outcome, good and
                          rejected counts, reason once it ends.
``operation``             the operations of a work order's part (today one: ``op 1``, the milling
                          program; ``op 2`` once workholding flips the part): program file and
                          SHA-256, planned machining time, ideal cycle time.
``part_unit``             one per blank the cell starts on: serial number (unique across runs and
                          cells: ``R<run id>-<job>``, the run id is the database's), outcome
                          (``good``, ``rejected``, ``scrap``, ``failed``), start and end.
``material_lot``          one per blank taken from the rack: lot id, rack slot, material.
``job_response``          one per stretch of machine work (B2MML JobResponse): ``cut`` (a program
                          run: program SHA-256, machine time, share done, outcome) or ``reset``,
                          each under its operation (op 1 or op 2).
``measurement``           one per inspection: characteristic, nominal, tolerance, actual [mm], pass.
``alarm``                 one per fault: kind, severity (OPC UA bands, :data:`SEVERITY`), the state
                          it hit, time lost, recovery chosen and outcome.
``robot_move``            one per robot action: fetch, missed_grasp, load, flip (turning a part over
                          between op 1 and op 2), unload, unload_reject.
``job_state``             every state transition of every job (B2MML JobState): state, event,
                          message.
========================  ===================================================================

SQLite records are written with WAL and ``synchronous=NORMAL``: every committed event survives
a killed process (``kill -9``) and the file stays consistent; only a power cut may lose the last
events before the operating system wrote them out.
"""

from __future__ import annotations

import datetime as dt
import importlib.util
import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import sqlalchemy as sa
from sqlalchemy import (JSON, Boolean, Column, DateTime, Float, ForeignKey, Integer, MetaData, String, Table, Text,
                        UniqueConstraint)
from sqlalchemy.engine import URL, Connection, Engine, make_url

from factory import __version__
from factory.catalog import sha256_file
from factory.core.errors import RecordError
from factory.core.resources import MIGRATIONS
from robotprog.cellsim import Activity, CellEvent, LogEntry, OrderOutcome, SimulationResult
from robotprog.orders import Order

if TYPE_CHECKING:
    from factory.simulation import PartAssets

log = logging.getLogger(__name__)

#: Severity of each alarm kind on OPC UA's 1-1000 scale (Part 9 bands: 1-200 low, 201-400 medium
#: low, 401-600 medium, 601-800 medium high, 801-1000 high). A fault the cell recovers from by itself
#: is medium low; a stopped program medium high; a part of unknown position high.
SEVERITY = {"inspect_fail": 200, "grasp_missed": 300, "stock_not_found": 300, "machine_alarm": 700,
            "timeout": 800}
#: Severity an alarm is raised to when the cell gives up and the operator must act (OPC UA: high).
SEVERITY_OPERATOR = 900
#: The recovery events of the scheduler, and which of them mean the fault was not overcome.
RECOVERIES = {"retry_fetch": "recovered", "rerun": "recovered", "scrap": "failed", "abandon": "failed"}

metadata = MetaData()


def _run_fk() -> Column:
    return Column("run_id", Integer, ForeignKey("run.id"), nullable=False, index=True)


run_table = Table(
    "run", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("cell", String(200), nullable=False),
    Column("started_at", DateTime(timezone=True), nullable=False),
    Column("ended_at", DateTime(timezone=True)),
    Column("factory_version", String(40), nullable=False),
    Column("orders_file", Text, nullable=False),
    Column("orders_sha256", String(64), nullable=False),
    Column("faults_seed", Integer),
    Column("makespan_s", Float),
    Column("summary", JSON),
)
work_order = Table(
    "work_order", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    Column("order_ref", String(40), nullable=False),
    Column("part", Text, nullable=False),
    Column("part_sha256", String(64)),
    Column("material", String(100), nullable=False),
    Column("quantity", Integer, nullable=False),
    Column("priority", Integer, nullable=False),
    Column("outcome", String(20)),
    Column("good", Integer, nullable=False, default=0),
    Column("rejected", Integer, nullable=False, default=0),
    Column("reason", Text),
    Column("ended_s", Float),
    UniqueConstraint("run_id", "order_ref"),
)
operation = Table(
    "operation", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    Column("work_order_id", Integer, ForeignKey("work_order.id"), nullable=False, index=True),
    Column("sequence", Integer, nullable=False),
    Column("name", String(40), nullable=False),
    Column("program", Text, nullable=False),
    Column("program_sha256", String(64), nullable=False),
    Column("planned_machining_s", Float, nullable=False),
    Column("ideal_cycle_s", Float, nullable=False),
    UniqueConstraint("work_order_id", "sequence"),
)
part_unit = Table(
    "part_unit", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    Column("serial", String(40), nullable=False, unique=True),
    Column("work_order_id", Integer, ForeignKey("work_order.id"), nullable=False, index=True),
    Column("job", Integer, nullable=False),
    Column("started_s", Float, nullable=False),
    Column("ended_s", Float),
    Column("outcome", String(20)),
    Column("seq", Integer, nullable=False),
)


def _unit_fk(nullable: bool = False) -> Column:
    return Column("part_unit_id", Integer, ForeignKey("part_unit.id"), nullable=nullable, index=True)


material_lot = Table(
    "material_lot", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    Column("lot", String(40), nullable=False, unique=True),
    Column("rack_slot", Integer, nullable=False),
    Column("material", String(100), nullable=False),
    _unit_fk(),
    Column("taken_s", Float, nullable=False),
    Column("seq", Integer, nullable=False),
)
job_response = Table(
    "job_response", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    _unit_fk(),
    Column("operation_id", Integer, ForeignKey("operation.id"), nullable=False),
    Column("kind", String(20), nullable=False),
    Column("program_sha256", String(64)),
    Column("start_s", Float, nullable=False),
    Column("end_s", Float, nullable=False),
    Column("machine_time_s", Float, nullable=False),
    Column("fraction", Float, nullable=False),
    Column("outcome", String(40), nullable=False),
    Column("seq", Integer, nullable=False),
)
measurement = Table(
    "measurement", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    _unit_fk(),
    Column("characteristic", String(80), nullable=False),
    Column("unit", String(10), nullable=False),
    Column("nominal", Float, nullable=False),
    Column("tolerance", Float, nullable=False),
    Column("actual", Float, nullable=False),
    Column("passed", Boolean, nullable=False),
    Column("time_s", Float, nullable=False),
    Column("seq", Integer, nullable=False),
)
alarm = Table(
    "alarm", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    _unit_fk(),
    Column("kind", String(40), nullable=False),
    Column("severity", Integer, nullable=False),
    Column("state", String(20), nullable=False),
    Column("message", Text),
    Column("raised_s", Float, nullable=False),
    Column("lost_s", Float, nullable=False),
    Column("recovery", String(40)),
    Column("recovery_message", Text),
    Column("outcome", String(20)),
    Column("cleared_s", Float),
    Column("seq", Integer, nullable=False),
)
robot_move = Table(
    "robot_move", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    _unit_fk(),
    Column("action", String(40), nullable=False),
    Column("rack_slot", Integer),
    Column("start_s", Float, nullable=False),
    Column("end_s", Float, nullable=False),
    Column("fraction", Float, nullable=False),
    Column("outcome", String(40), nullable=False),
    Column("seq", Integer, nullable=False),
)
job_state = Table(
    "job_state", metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    _run_fk(),
    _unit_fk(nullable=True),
    Column("work_order_id", Integer, ForeignKey("work_order.id"), nullable=False),
    Column("time_s", Float, nullable=False),
    Column("state", String(20), nullable=False),
    Column("event", String(40), nullable=False),
    Column("message", Text),
    Column("seq", Integer, nullable=False),
)

_INSERTS = {t.name: sa.insert(t) for t in metadata.sorted_tables}
#: Tables whose rows events write (each has ``seq``).
EVENT_TABLES = ("part_unit", "material_lot", "job_response", "measurement", "alarm", "robot_move", "job_state")


# --- where the record is -------------------------------------------------------------------


#: PostgreSQL drivers SQLAlchemy speaks, the first installed one serving a plain ``postgresql://``.
POSTGRESQL_DRIVERS = (("psycopg", "postgresql+psycopg"), ("psycopg2", "postgresql+psycopg2"))


def record_url(target: str | Path) -> URL:
    """The database a ``--db`` value names: a SQLAlchemy URL (``dialect[+driver]://…``) or a file
    path, taken as SQLite.

    A PostgreSQL URL as psql, libpq and hosting providers write it (``postgresql://`` or
    ``postgres://``, no driver named) is served by the driver that is installed: psycopg 3, else
    psycopg2 (:data:`POSTGRESQL_DRIVERS`).

    Raises RecordError for a malformed URL, or a PostgreSQL one without a driver installed (the
    message never holds the URL: it may hold a password).
    """
    text = str(target)
    if "://" not in text:
        return URL.create("sqlite", database=text)
    try:
        url = make_url(text)
    except (sa.exc.ArgumentError, ValueError):
        raise RecordError("not a database URL (expected a file, or dialect://user@host/database)",
                          source="--db") from None
    if url.drivername in ("postgresql", "postgres"):
        installed = [name for module, name in POSTGRESQL_DRIVERS if importlib.util.find_spec(module) is not None]
        if not installed:
            raise RecordError("no PostgreSQL driver is installed: pip install 'factory[postgresql]' (psycopg)",
                              source="--db")
        url = url.set(drivername=installed[0])
    return url


def masked(url: URL | str | Path) -> str:
    """The URL as it may be shown: the password, if any, replaced by ``***``."""
    if not isinstance(url, URL):
        try:
            url = record_url(url)
        except RecordError:
            return "<malformed database URL>"
    return url.render_as_string(hide_password=True)


def _scrub(text: str, url: URL) -> str:
    """``text`` with the URL's password (and the whole URL written out) removed."""
    if url.password:
        text = text.replace(url.render_as_string(hide_password=False), masked(url))
        text = text.replace(str(url.password), "***")
    return text


def _error(e: BaseException, url: URL, doing: str) -> RecordError:
    first = _scrub(str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__, url)
    first = re.sub(r"\s*\(Background on this error at: .*\)$", "", first)
    return RecordError(f"{doing}: {first}", source=masked(url))


def _sqlite_pragmas(engine: Engine, immediate: bool) -> None:
    """WAL, NORMAL sync, foreign keys, a writer waits for another's lock; transactions begin
    ``IMMEDIATE`` for writers (SQLAlchemy's documented recipe: pysqlite's own BEGIN is turned off),
    so concurrent runs queue instead of failing to upgrade a read lock."""

    @sa.event.listens_for(engine, "connect")
    def _connect(dbapi_connection, _record):
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA busy_timeout = 30000")
        if immediate:
            cursor.execute("PRAGMA journal_mode = WAL")
        cursor.execute("PRAGMA synchronous = NORMAL")
        cursor.execute("PRAGMA foreign_keys = ON")
        cursor.close()

    @sa.event.listens_for(engine, "begin")
    def _begin(conn):
        conn.exec_driver_sql("BEGIN IMMEDIATE" if immediate else "BEGIN")


def upgrade(conn: Connection) -> None:
    """Bring the record's schema to this factory's version (Alembic ``upgrade head``), inside the
    caller's transaction; concurrent openers are serialised (SQLite: ``BEGIN IMMEDIATE``;
    PostgreSQL: an advisory lock)."""
    from alembic import command
    from alembic.config import Config

    if conn.dialect.name == "postgresql":
        conn.exec_driver_sql("SELECT pg_advisory_xact_lock(7195022)")  # 'factory record' schema lock
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = conn
    command.upgrade(cfg, "head")


class Record:
    """An open process record.

    Parameters
    ----------
    target : str or Path
        A file (SQLite) or a SQLAlchemy database URL.
    write : bool
        Open for writing runs (creates the file and brings the schema up to date); else read only
        (the report), and the record must exist.

    Raises
    ------
    RecordError
        The database cannot be reached or opened, or holds something else; the message shows the
        URL with its password masked.
    """

    def __init__(self, target: str | Path, *, write: bool = True):
        self.url = record_url(target)
        #: How the record is named in messages: the file as given, or the URL with its password masked.
        self.shown = str(target) if "://" not in str(target) else masked(self.url)
        sqlite = self.url.get_backend_name() == "sqlite"
        if sqlite and self.url.database and self.url.database != ":memory:":
            path = Path(self.url.database)
            if not write and not path.is_file():
                raise RecordError("no such record", source=self.shown)
            if write and not path.parent.is_dir():
                raise RecordError(f"folder {path.parent} does not exist", source=self.shown)
        try:
            self.engine = sa.create_engine(self.url, **({"connect_args": {"timeout": 30.0}} if sqlite else {}))
        except (sa.exc.SQLAlchemyError, ImportError) as e:
            raise _error(e, self.url, "cannot open the database") from None
        if sqlite:
            _sqlite_pragmas(self.engine, immediate=write)
        try:
            if write:
                with self.engine.begin() as conn:
                    upgrade(conn)
            else:
                with self.engine.connect() as conn:
                    if not sa.inspect(conn).has_table("run"):
                        raise RecordError("not a process record (no run table)", source=self.shown)
        except (sa.exc.SQLAlchemyError, ImportError) as e:  # ImportError: the URL's driver is not installed
            self.engine.dispose()
            raise _error(e, self.url, "cannot open the record") from None

    def __enter__(self) -> "Record":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.engine.dispose()

    def recorder(self, *, cell: str, orders: Sequence[Order], orders_file: str, orders_sha256: str,
                 faults_seed: int | None) -> "RunRecorder":
        """A recorder for one run; nothing is written until :meth:`RunRecorder.begin`."""
        return RunRecorder(self, cell, tuple(orders), orders_file, orders_sha256, faults_seed)

    def counts(self, run_id: int | None = None) -> dict[str, int]:
        """Rows per table (of one run, or of the whole record)."""
        out = {}
        with self.engine.connect() as conn:
            for table in metadata.sorted_tables:
                q = sa.select(sa.func.count()).select_from(table)
                if run_id is not None:
                    q = q.where((table.c.id if table is run_table else table.c.run_id) == run_id)
                out[table.name] = int(conn.execute(q).scalar_one())
        return out


# --- writing a run ----------------------------------------------------------------------------


@dataclass(frozen=True)
class OperationPlan:
    """What the record keeps of one part's plan.

    Attributes
    ----------
    program : str
        The G-code file.
    program_sha256 : str
    machining_s : float
        Planned program time [s].
    ideal_cycle_s : float
        The OEE ideal cycle of the cell on this part [s] (locate, fetch, load, machining, the
        faster way out of the vise: :attr:`robotprog.cellsim.PartProcess.ideal_cycle_s`).
    inspections : mapping event → dict
        The inspection result (``tolerance_mm``, ``max_deviation_mm``, …) the out-tray camera gives
        for a good part (``inspect_pass``) and a damaged one (``inspect_fail``).
    part_sha256 : str
    op2 : (program, program SHA-256, planned machining [s]) or None
        The op-2 program of a part machined in two setups.
    """

    program: str
    program_sha256: str
    machining_s: float
    ideal_cycle_s: float
    inspections: Mapping[str, Mapping[str, Any]]
    part_sha256: str
    op2: tuple[str, str, float] | None = None

    @classmethod
    def of(cls, assets: "PartAssets") -> "OperationPlan":
        program = assets.entry.output("program")
        detections = {event: (assets.shots[shot].detections or [{}])[0]
                      for event, shot in (("inspect_pass", "inspect"), ("inspect_fail", "reject"))}
        op2 = None
        if assets.process.op2_machining_s is not None:
            program2 = assets.entry.output("program_op2")
            op2 = (str(program2), sha256_file(program2), assets.process.op2_machining_s)
        return cls(str(program), sha256_file(program), assets.process.machining_s, assets.process.ideal_cycle_s,
                   detections, assets.entry.summary["catalog"]["mesh_sha256"], op2)


class RunRecorder:
    """Writes one run into the record, one transaction per event (an :data:`EventSink`).

    Call :meth:`begin` once the parts are planned (writes the run, its work orders and operations),
    then call the recorder with every event, then :meth:`finish`.
    """

    def __init__(self, record: Record, cell: str, orders: tuple[Order, ...], orders_file: str,
                 orders_sha256: str, faults_seed: int | None):
        self.record = record
        self.cell = cell
        self.orders = orders
        self.orders_file = orders_file
        self.orders_sha256 = orders_sha256
        self.faults_seed = faults_seed
        self.conn: Connection | None = None
        self.run_id: int | None = None
        self.seq = 0
        self.now = 0.0
        self.work_orders: dict[str, int] = {}
        self.operations: dict[str, int] = {}
        self.operations_op2: dict[str, int] = {}  # order -> its op-2 operation row (two setups)
        self.plans: dict[str, OperationPlan] = {}
        self.units: dict[int, int] = {}
        self.job_order: dict[int, str] = {}
        self.state_of: dict[int, str] = {}
        self.attempt_start: dict[int, float] = {}
        self.open_alarm: dict[int, int] = {}
        self.recovery_message: dict[int, str] = {}
        self.marks: dict[int, set[str]] = {}
        #: (alarm id, order, time) of a failed inspection whose part was just sorted to the reject bin
        self.rejecting: tuple[int, str, float] | None = None

    def _transaction(self):
        if self.conn is None:
            raise RecordError("the run has not begun", source=self.record.shown)
        return self.conn.begin()

    def _write(self, fn, *args) -> None:
        try:
            with self._transaction():
                fn(*args)
        except sa.exc.SQLAlchemyError as e:
            raise _error(e, self.record.url, f"cannot record run {self.run_id}") from None

    def _insert(self, table: Table, **values: Any) -> int:
        # values as parameters of one statement per table, not baked into it: SQLAlchemy compiles it once
        return int(self.conn.execute(_INSERTS[table.name], values).inserted_primary_key[0])

    def begin(self, parts: Mapping[tuple[Path, str], "PartAssets | OperationPlan | str"]) -> "RunRecorder":
        """Write the run, its work orders and their operations (one transaction); returns the
        recorder, the sink to give the simulation. ``parts``: (part, material) → its assets (or
        directly its :class:`OperationPlan`), or why it cannot be made."""
        try:
            self.conn = self.record.engine.connect()
        except sa.exc.SQLAlchemyError as e:
            raise _error(e, self.record.url, "cannot open the record") from None
        plans = {k: v if isinstance(v, OperationPlan) else OperationPlan.of(v) for k, v in parts.items()
                 if not isinstance(v, str)}

        def write():
            self.run_id = self._insert(
                run_table, cell=self.cell, started_at=dt.datetime.now(dt.timezone.utc),
                factory_version=__version__, orders_file=self.orders_file, orders_sha256=self.orders_sha256,
                faults_seed=self.faults_seed)
            for o in self.orders:
                plan = plans.get((o.part, o.material))
                wo = self._insert(work_order, run_id=self.run_id, order_ref=o.id, part=str(o.part),
                                  part_sha256=plan.part_sha256 if plan else None, material=o.material,
                                  quantity=o.quantity, priority=o.priority, good=0, rejected=0)
                self.work_orders[o.id] = wo
                if plan is not None:
                    self.plans[o.id] = plan
                    self.operations[o.id] = self._insert(
                        operation, run_id=self.run_id, work_order_id=wo, sequence=1, name="op 1",
                        program=plan.program, program_sha256=plan.program_sha256,
                        planned_machining_s=plan.machining_s, ideal_cycle_s=plan.ideal_cycle_s)
                    if plan.op2 is not None:
                        self.operations_op2[o.id] = self._insert(
                            operation, run_id=self.run_id, work_order_id=wo, sequence=2, name="op 2",
                            program=plan.op2[0], program_sha256=plan.op2[1], planned_machining_s=plan.op2[2],
                            ideal_cycle_s=plan.ideal_cycle_s)

        self._write(write)
        log.info("record %s: run %s", self.record.shown, self.run_id)
        return self

    def __call__(self, event: CellEvent) -> None:
        """Record one event of the simulation (one transaction)."""
        self.seq += 1
        handler = {LogEntry: self._transition, Activity: self._activity, OrderOutcome: self._outcome}.get(type(event))
        if handler is None:
            raise RecordError(f"unknown event {type(event).__name__}", source=self.record.shown)

        def write():
            if self.rejecting is not None:
                self._resolve_reject(event)
            handler(event)

        self._write(write)

    def serial(self, job: int) -> str:
        """The serial number of a job's part unit: unique across runs, since the run id is the database's."""
        return f"R{self.run_id:06d}-{job:05d}"

    def _transition(self, e: LogEntry) -> None:
        self.now = max(self.now, e.time)
        unit = self.units.get(e.job)
        if e.job and unit is None:
            unit = self.units[e.job] = self._insert(
                part_unit, run_id=self.run_id, serial=self.serial(e.job), work_order_id=self.work_orders[e.order],
                job=e.job, started_s=e.time, seq=self.seq)
            self.marks[e.job] = set()
            self.job_order[e.job] = e.order
        self._insert(job_state, run_id=self.run_id, part_unit_id=unit, work_order_id=self.work_orders[e.order],
                     time_s=e.time, state=e.state, event=e.event, message=e.message or None, seq=self.seq)
        if e.state == "FAULT":
            start = self.attempt_start.get(e.job, e.time)
            self.open_alarm[e.job] = self._insert(
                alarm, run_id=self.run_id, part_unit_id=unit, kind=e.event, severity=SEVERITY.get(e.event, 500),
                state=self.state_of.get(e.job, "-"), message=e.message or None, raised_s=e.time,
                lost_s=max(e.time - start, 0.0), seq=self.seq)
        elif e.event == "inspect_fail":
            self.marks[e.job].add("rejected")
            self.open_alarm[e.job] = self._insert(
                alarm, run_id=self.run_id, part_unit_id=unit, kind=e.event, severity=SEVERITY[e.event],
                state="INSPECT", message=e.message or None, raised_s=e.time, lost_s=0.0, seq=self.seq)
        elif e.event == "recover":
            self.recovery_message[e.job] = e.message
        elif e.event in RECOVERIES and e.job in self.open_alarm:
            values = dict(recovery=e.event, recovery_message=self.recovery_message.pop(e.job, None) or None,
                          outcome=RECOVERIES[e.event], cleared_s=e.time)
            if e.event == "abandon":
                values["severity"] = SEVERITY_OPERATOR
            if e.event == "scrap":
                self.marks[e.job].add("scrap")
            self.conn.execute(sa.update(alarm).where(alarm.c.id == self.open_alarm.pop(e.job)).values(**values))
        if e.event == "sorted" and e.job in self.open_alarm:
            # a rejected part is sorted: the order re-makes it, or ends (told next, see _resolve_reject)
            self.rejecting = (self.open_alarm.pop(e.job), e.order, e.time)
        if e.event in ("sorted", "abandon") and unit is not None:
            marks = self.marks[e.job]
            outcome = "failed" if e.event == "abandon" else \
                "scrap" if "scrap" in marks else "rejected" if "rejected" in marks else "good"
            self.conn.execute(sa.update(part_unit).where(part_unit.c.id == unit)
                              .values(ended_s=e.time, outcome=outcome))
        if e.job:
            self.state_of[e.job] = e.state
            self.attempt_start.pop(e.job, None)

    def _resolve_reject(self, event: CellEvent) -> None:
        """A failed inspection is recovered when the order re-makes the part (nothing said), failed
        when the rejected part ends the order or comes after its end (the order's outcome is told
        right after the sort), as the scheduler counts recoveries and failures."""
        alarm_id, order, time = self.rejecting
        self.rejecting = None
        failed = isinstance(event, OrderOutcome) and event.order == order
        self.conn.execute(sa.update(alarm).where(alarm.c.id == alarm_id).values(
            recovery="reject" if failed else "remake", outcome="failed" if failed else "recovered", cleared_s=time))

    def _activity(self, a: Activity) -> None:
        unit = self.units[a.job]
        if a.action != "reset":  # a reset is the cost of the last alarm, not part of the next attempt
            self.attempt_start.setdefault(a.job, a.start)
        order = self.job_order[a.job]
        if a.resource == "robot":
            self._insert(robot_move, run_id=self.run_id, part_unit_id=unit, action=a.action, rack_slot=a.slot,
                         start_s=a.start, end_s=a.end, fraction=a.fraction, outcome=a.outcome, seq=self.seq)
            if a.action == "fetch" and a.outcome == "fetched":
                material = next(o.material for o in self.orders if o.id == order)
                self._insert(material_lot, run_id=self.run_id, lot=f"R{self.run_id:06d}-S{a.slot:04d}",
                             rack_slot=a.slot, material=material, part_unit_id=unit, taken_s=a.end, seq=self.seq)
            if a.action == "unload_reject" and a.outcome == "inspect_fail":
                self._measurement(a, order, unit)  # the verdict that sent the part to the bin
        elif a.resource == "machine":
            plan = self.plans[order]
            op2 = a.op == 2 and plan.op2 is not None
            self._insert(job_response, run_id=self.run_id, part_unit_id=unit,
                         operation_id=self.operations_op2[order] if op2 else self.operations[order], kind=a.action,
                         program_sha256=(plan.op2[1] if op2 else plan.program_sha256) if a.action == "cut" else None,
                         start_s=a.start, end_s=a.end, machine_time_s=a.end - a.start, fraction=a.fraction,
                         outcome=a.outcome, seq=self.seq)
        elif a.action == "inspect" and a.outcome in ("inspect_pass", "inspect_fail"):
            self._measurement(a, order, unit)

    def _measurement(self, a: Activity, order: str, unit: int) -> None:
        """One inspection's measurement, passed or failed as ``a.outcome`` says."""
        found = self.plans[order].inspections.get(a.outcome, {})
        self._insert(measurement, run_id=self.run_id, part_unit_id=unit,
                     characteristic="silhouette max deviation", unit="mm", nominal=0.0,
                     tolerance=float(found.get("tolerance_mm", 0.0)),
                     actual=float(found.get("max_deviation_mm", 0.0)), passed=a.outcome == "inspect_pass",
                     time_s=a.end, seq=self.seq)

    def _outcome(self, o: OrderOutcome) -> None:
        self.conn.execute(sa.update(work_order).where(work_order.c.id == self.work_orders[o.order]).values(
            outcome=o.outcome, good=o.good, rejected=o.rejected, reason=o.reason, ended_s=self.now))

    def finish(self, result: SimulationResult) -> None:
        """Close the run: its end, makespan and summary (one transaction)."""

        def write():
            if self.rejecting is not None:  # the last event was a sort that ended nothing
                self._resolve_reject(None)
            self.conn.execute(sa.update(run_table).where(run_table.c.id == self.run_id).values(
                ended_at=dt.datetime.now(dt.timezone.utc), makespan_s=float(result.summary["makespan_s"]),
                summary=_plain(result.summary)))

        self._write(write)
        self.close()

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def _plain(value: Any) -> Any:
    """JSON-ready copy (mapping proxies become dicts)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value

