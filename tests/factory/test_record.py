"""The process record (`factory simulate --db`): what it holds, checked with the real `sqlite3` client.

A run of the small pocketed block with faults is recorded; its rows are counted against what the
simulation reported, a second run must append without touching the first, serials never repeat, a
run killed with SIGKILL mid-way leaves a consistent file holding exactly the events it committed,
and a database URL's password is never shown.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest
import sqlalchemy as sa
from sqlalchemy.engine import make_url
from typer.testing import CliRunner

from cli.main import app
from factory.core.errors import RecordError
from factory.record import EVENT_TABLES, SEVERITY, SEVERITY_OPERATOR, OperationPlan, Record, masked, metadata, record_url
from tests.cli.expect import assert_one_line_error, simulate_exit

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()
SQLITE3 = shutil.which("sqlite3")
needs_sqlite3 = pytest.mark.skipif(SQLITE3 is None, reason="the sqlite3 client is not installed (.ci/run installs it)")


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def sql(db: Path, query: str) -> list[list[str]]:
    """Rows of ``query`` as the ``sqlite3`` command-line client prints them (|-separated)."""
    out = subprocess.run([SQLITE3, "-batch", str(db), query], check=True, capture_output=True, text=True).stdout
    return [line.split("|") for line in out.splitlines()]


def one(db: Path, query: str) -> str:
    return sql(db, query)[0][0]


def _orders(folder: Path, part: Path) -> Path:
    path = folder / "orders.csv"
    path.write_text(f"part,quantity,material,priority\n{part},4,aluminium,0\n{part},3,aluminium,1\n"
                    "missing.stl,1,aluminium,0\n")
    return path


SIM = ("--faults", "7", "--fault-rate", "0.2")


@pytest.fixture(scope="module")
def recorded(block_catalog, tmp_path_factory):
    """(db, orders, JSON of the run): one run with faults recorded into a fresh SQLite file."""
    folder, part = block_catalog
    out = tmp_path_factory.mktemp("record")
    orders = _orders(out, part)
    db = out / "cell.sqlite"
    r = run("simulate", orders, "--catalog", folder, *SIM, "--db", db, "--json", "--quiet")
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    return db, orders, json.loads(r.stdout)


def test_writing_the_log_and_the_record_leaves_every_figure_as_it_was(recorded, block_catalog, tmp_path):
    """The same orders and faults, simulated bare and with ``--mcap --db``: the log and the record only
    watch the run, so throughput, OEE, every order's outcome and every event are the same."""
    _, orders, logged = recorded
    folder, _ = block_catalog
    bare = run("simulate", orders, "--catalog", folder, *SIM, "--json", "--quiet")
    assert bare.exit_code == simulate_exit(json.loads(bare.stdout)), bare.output
    both = run("simulate", orders, "--catalog", folder, *SIM, "--mcap", tmp_path / "cell.mcap",
               "--db", tmp_path / "cell.sqlite", "--json", "--quiet")
    assert both.exit_code == simulate_exit(json.loads(both.stdout)), both.output
    bare_doc, both_doc = json.loads(bare.stdout), json.loads(both.stdout)
    assert bare_doc["summary"]["faults"] and bare_doc["summary"]["parts_good"] > 0  # a run with something to lose
    for doc in (both_doc, logged):
        for key in ("summary", "orders", "events", "parts"):
            assert doc[key] == bare_doc[key], key
    assert sum(both_doc["mcap"]["messages"].values()) > 0 and "mcap" not in bare_doc and "db" not in bare_doc


@needs_sqlite3
def test_rows_match_what_the_simulation_reported(recorded):
    db, _, doc = recorded
    s = doc["summary"]
    assert doc["db"] == {"url": str(db), "run": 1}
    assert one(db, "PRAGMA journal_mode") == "wal"
    assert one(db, "PRAGMA integrity_check") == "ok"
    assert one(db, "SELECT count(*) FROM run") == "1"
    assert sql(db, "SELECT order_ref, outcome, good, rejected FROM work_order ORDER BY order_ref") == \
        [[o["order"], o["outcome"], str(o["good"]), str(o["rejected"])] for o in sorted(doc["orders"],
                                                                                      key=lambda o: o["order"])]
    # one operation per order that can run (the missing part has none)
    assert one(db, "SELECT count(*) FROM operation") == "2"
    # every transition, one row each; every fault one alarm; every good part a good unit
    assert int(one(db, "SELECT count(*) FROM job_state")) == doc["events"]
    assert int(one(db, "SELECT count(*) FROM alarm")) == sum(s["faults"].values()) > 0
    assert sql(db, "SELECT kind, count(*) FROM alarm GROUP BY kind ORDER BY kind") == \
        [[k, str(v)] for k, v in sorted(s["faults"].items())]
    assert int(one(db, "SELECT count(*) FROM part_unit WHERE outcome = 'good'")) == s["parts_good"]
    assert int(one(db, "SELECT count(*) FROM part_unit WHERE outcome IN ('rejected', 'scrap')")) == \
        s["parts_rejected"]
    # each alarm ends as one recovery or one failure, as the scheduler counts them
    assert int(one(db, "SELECT count(*) FROM alarm WHERE outcome = 'recovered'")) == s["recoveries"]
    assert int(one(db, "SELECT count(*) FROM alarm WHERE outcome = 'failed'")) == s["failures"]
    # OPC UA severities; raised to "operator" when the cell gave up
    for kind, severity, recovery, outcome in sql(db, "SELECT kind, severity, recovery, outcome FROM alarm"):
        assert int(severity) == (SEVERITY_OPERATOR if recovery == "abandon" else SEVERITY[kind])
        assert outcome in ("recovered", "failed")
    # machine time: the cut rows add up to the machine's utilisation
    cut = float(one(db, "SELECT sum(machine_time_s) FROM job_response WHERE kind = 'cut'"))
    assert cut / s["makespan_s"] == pytest.approx(s["machine_utilisation"], abs=1e-3)
    assert one(db, "SELECT count(DISTINCT program_sha256) FROM job_response WHERE kind = 'cut'") == "1"
    # one measurement per inspection; pass as the cell decided
    assert int(one(db, "SELECT count(*) FROM measurement")) == \
        int(one(db, "SELECT count(*) FROM job_state WHERE event IN ('inspect_pass', 'inspect_fail')"))
    assert one(db, "SELECT count(*) FROM measurement WHERE passed = 0") == \
        one(db, "SELECT count(*) FROM alarm WHERE kind = 'inspect_fail'")
    assert one(db, "SELECT count(*) FROM measurement WHERE passed = 1 AND actual > tolerance") == "0"
    # a blank taken from each rack slot at most once; every fetched blank came from a lot
    assert int(one(db, "SELECT count(*) FROM material_lot")) == \
        int(one(db, "SELECT count(*) FROM robot_move WHERE action = 'fetch' AND outcome = 'fetched'"))
    assert one(db, "SELECT count(*) - count(DISTINCT rack_slot) FROM material_lot") == "0"
    assert one(db, "SELECT ended_at IS NOT NULL AND makespan_s > 0 FROM run") == "1"


def test_schema_is_what_the_migrations_build(recorded):
    """The Alembic migrations and the schema the code writes with agree (autogenerate finds nothing)."""
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    db, _, _ = recorded
    engine = sa.create_engine(record_url(db))
    with engine.connect() as conn:
        assert compare_metadata(MigrationContext.configure(conn), metadata) == []
        assert conn.exec_driver_sql("SELECT version_num FROM alembic_version").scalar_one() == "0001"
    engine.dispose()


@needs_sqlite3
def test_a_second_run_appends_and_never_rewrites_the_first(recorded, block_catalog, tmp_path):
    db0, orders, _ = recorded
    folder, _ = block_catalog
    db = tmp_path / "cell.sqlite"
    shutil.copy(db0, db)
    dump = {t.name: sql(db, f"SELECT * FROM {t.name} ORDER BY id") for t in metadata.sorted_tables}
    r = run("simulate", orders, "--catalog", folder, *SIM, "--db", f"sqlite:///{db}", "--json", "--quiet")
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    assert json.loads(r.stdout)["db"]["run"] == 2
    for table, rows in dump.items():
        assert sql(db, f"SELECT * FROM {table} WHERE id <= {len(rows)} ORDER BY id") == rows, table
        if table != "run":
            assert one(db, f"SELECT count(*) FROM {table} WHERE run_id = 2") == str(len(rows)), table
    # same seed, same run: the second run's events are the first's, under new serials
    assert sql(db, "SELECT time_s, state, event, message, seq FROM job_state WHERE run_id = 1 ORDER BY id") == \
        sql(db, "SELECT time_s, state, event, message, seq FROM job_state WHERE run_id = 2 ORDER BY id")
    assert one(db, "SELECT count(*) - count(DISTINCT serial) FROM part_unit") == "0"
    assert one(db, "SELECT count(*) FROM part_unit WHERE serial LIKE 'R000002-%' AND run_id = 2") == \
        one(db, "SELECT count(*) FROM part_unit WHERE run_id = 2")
    assert one(db, "PRAGMA integrity_check") == "ok"


#: Runs `factory simulate` with a recorder that kills its own process (SIGKILL, nothing flushed or
#: closed) right after committing event N.
_DYING = """
import os, signal, sys
import factory.record as record

N = int(sys.argv[1])
told = 0
call = record.RunRecorder.__call__


def dying(self, event):
    global told
    call(self, event)
    told += 1
    if told == N:
        os.kill(os.getpid(), signal.SIGKILL)


record.RunRecorder.__call__ = dying
from cli.main import app
app(sys.argv[2:], prog_name="factory")
"""


@needs_sqlite3
@pytest.mark.parametrize("n", [1, 45])
def test_kill_9_mid_run_leaves_a_consistent_record_with_every_committed_event(recorded, block_catalog, tmp_path, n):
    db_full, orders, doc = recorded
    folder, _ = block_catalog
    db = tmp_path / "killed.sqlite"
    proc = subprocess.run([sys.executable, "-c", _DYING, str(n), "simulate", str(orders), "--catalog", str(folder),
                           *SIM, "--db", str(db), "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert n < doc["events"]  # killed mid-run
    assert one(db, "PRAGMA integrity_check") == "ok"
    assert sql(db, "PRAGMA foreign_key_check") == []
    assert one(db, "SELECT ended_at IS NULL FROM run") == "1"  # the run never finished
    # exactly the first n events are there: every row the complete run wrote by event n, and no other
    for table in EVENT_TABLES:
        columns = [c.name for c in metadata.tables[table].c if not c.name.endswith("id") and c.name != "ended_s"
                   and c.name not in ("outcome", "recovery", "recovery_message", "cleared_s", "severity")]
        q = f"SELECT {', '.join(columns)} FROM {table} WHERE seq <= {n} ORDER BY seq, id"
        assert sql(db, q) == sql(db_full, q), table
        assert one(db, f"SELECT count(*) FROM {table} WHERE seq > {n}") == "0"
    assert int(one(db, "SELECT max(seq) FROM job_state")) <= n
    # and Python reads it as a record
    with Record(db, write=False) as record:
        counts = record.counts()
    assert counts["run"] == 1 and counts["job_state"] == int(one(db, "SELECT count(*) FROM job_state"))
    # the report reads it, the run marked incomplete and timed to its last recorded event
    r = run("report", db, "--json")
    assert r.exit_code == 0, r.output
    killed = json.loads(r.stdout)["runs"][0]
    last = [float(v) for (v,) in sql(db, "SELECT max(time_s) FROM job_state UNION ALL SELECT max(end_s) FROM "
                                         "robot_move UNION ALL SELECT max(end_s) FROM job_response") if v]
    assert killed["complete"] is False
    assert killed["planned_s"] == pytest.approx(max(last, default=0.0), abs=1e-3)
    # the stdlib driver agrees, and the killed record takes the next run
    with sqlite3.connect(db) as conn:
        assert conn.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    r = run("simulate", orders, "--catalog", folder, *SIM, "--db", db, "--json", "--quiet")
    assert r.exit_code == simulate_exit(json.loads(r.stdout)), r.output
    assert json.loads(r.stdout)["db"]["run"] == 2


def test_a_password_is_never_shown(block_catalog, tmp_path, monkeypatch):
    folder, part = block_catalog
    url = "postgresql+psycopg://cell:hunter2@127.0.0.1:1/plant"
    assert masked(url) == "postgresql+psycopg://cell:***@127.0.0.1:1/plant"
    # unreachable (or no driver): one line, the URL masked, nothing planned or written
    orders = _orders(tmp_path, part)
    r = run("simulate", orders, "--catalog", tmp_path / "catalog", "--db", url, "--mcap", tmp_path / "x.mcap")
    assert_one_line_error(r, "postgresql+psycopg://cell:***@127.0.0.1:1/plant")
    assert "hunter2" not in r.output and not (tmp_path / "catalog").exists()
    with pytest.raises(RecordError) as e:
        Record("postgresql://cell:hunter2@127.0.0.1:1/plant")
    assert "hunter2" not in str(e.value)
    r = run("simulate", orders, "--catalog", tmp_path / "catalog", "--db", "postgresql://cell:hunter2@[::1/x")
    assert "hunter2" not in r.output and r.exit_code != 0

    # a reachable record behind a password URL (SQLite standing in for the server): the MCAP
    # metadata, the JSON and the text output show it masked
    import factory.production

    class Remote(Record):
        def __init__(self, target, write=True):
            super().__init__(tmp_path / "remote.sqlite", write=write)
            self.url = record_url(target)
            self.shown = masked(self.url)

    monkeypatch.setattr(factory.production, "Record", Remote)
    mcap = tmp_path / "cell.mcap"
    r = run("simulate", orders, "--catalog", folder, "--db", url, "--mcap", mcap, "--json")
    assert r.exit_code == 3, r.output  # written, with the missing part's order failed
    assert "hunter2" not in r.output and b"hunter2" not in mcap.read_bytes()
    assert json.loads(r.stdout)["db"]["url"] == masked(url)
    from mcap.reader import make_reader
    with mcap.open("rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["factory"]["param:db"] == masked(url) and meta["factory"]["param:db_run"] == "1"
    r = run("simulate", orders, "--catalog", folder, "--db", url)
    assert r.exit_code == 3 and "hunter2" not in r.output and masked(url) in r.output


def test_a_record_that_is_not_one_is_refused(tmp_path):
    other = tmp_path / "other.sqlite"
    with sqlite3.connect(other) as conn:
        conn.execute("CREATE TABLE t (x)")
    with pytest.raises(RecordError, match="not a process record"):
        Record(other, write=False)
    with pytest.raises(RecordError, match="no such record"):
        Record(tmp_path / "missing.sqlite", write=False)
    with pytest.raises(RecordError, match="does not exist"):
        Record(tmp_path / "no" / "folder.sqlite")
    with pytest.raises(RecordError, match="not a database URL"):
        record_url("postgresql://[::1")


# --- one record for many cells: a real PostgreSQL server ------------------------------------


def _postgres_bin() -> Path | None:
    """Folder of Debian's PostgreSQL server programs (initdb, pg_ctl), newest first; else from PATH."""
    for folder in sorted(Path("/usr/lib/postgresql").glob("*/bin"), key=lambda p: int(p.parent.name), reverse=True):
        if (folder / "initdb").exists():
            return folder
    found = shutil.which("initdb")
    return Path(found).parent if found else None


@pytest.fixture(scope="module")
def postgres():
    """URL of a fresh PostgreSQL server on 127.0.0.1 (a throw-away cluster, password auth), stopped after."""
    import pwd
    import socket
    import tempfile

    pytest.importorskip("psycopg")
    folder = _postgres_bin()
    if folder is None:
        pytest.skip("PostgreSQL's server programs are not installed (.ci/run installs them)")
    as_user: list[str] = []
    root = Path(tempfile.mkdtemp(prefix="factory-pg-"))
    if os.geteuid() == 0:  # the server refuses to run as root: run it as Debian's postgres user
        user = pwd.getpwnam("postgres")
        os.chown(root, user.pw_uid, user.pw_gid)
        as_user = ["runuser", "-u", "postgres", "--"]
    root.chmod(0o755)
    (root / "pw").write_text("s3cret-pw\n")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    data = root / "data"
    subprocess.run(as_user + [str(folder / "initdb"), "-D", str(data), "-U", "factory", f"--pwfile={root / 'pw'}",
                              "--auth=scram-sha-256", "-E", "UTF8"], check=True, capture_output=True)
    subprocess.run(as_user + [str(folder / "pg_ctl"), "-D", str(data), "-w", "-l", str(root / "log"), "-o",
                              f"-c listen_addresses=127.0.0.1 -p {port} -k {root}", "start"],
                   check=True, capture_output=True)
    try:
        admin = sa.create_engine(f"postgresql+psycopg://factory:s3cret-pw@127.0.0.1:{port}/postgres",
                                 isolation_level="AUTOCOMMIT")
        with admin.connect() as conn:
            conn.exec_driver_sql("CREATE DATABASE plant")
        admin.dispose()
        yield f"postgresql+psycopg://factory:s3cret-pw@127.0.0.1:{port}/plant"
    finally:
        subprocess.run(as_user + [str(folder / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"],
                       capture_output=True)
        shutil.rmtree(root, ignore_errors=True)


_FACTORY = "import sys; from cli.main import app; app(sys.argv[1:], prog_name='factory')"


def test_four_cells_write_one_postgresql_record_at_once(postgres, recorded, block_catalog):
    """Four `simulate` runs into one fresh PostgreSQL database at the same time (the first opens
    also race to create the schema): every event of each is there, serials never collide, and
    `factory report` reads it."""
    _, orders, _ = recorded
    folder, _ = block_catalog
    cells = [subprocess.Popen([sys.executable, "-c", _FACTORY, "simulate", str(orders), "--catalog", str(folder),
                               "--faults", str(seed), "--fault-rate", "0.2", "--db", postgres, "--json", "--quiet"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for seed in (1, 2, 3, 4)]
    outputs = [cell.communicate(timeout=900) for cell in cells]
    for cell, (out, err) in zip(cells, outputs):
        assert cell.returncode == simulate_exit(json.loads(out)), err
        assert "s3cret-pw" not in out + err
    docs = [json.loads(out) for out, _ in outputs]
    assert sorted(d["db"]["run"] for d in docs) == [1, 2, 3, 4]
    assert all(d["db"]["url"] == masked(postgres) for d in docs)
    engine = sa.create_engine(postgres)
    with engine.connect() as conn:
        for d in docs:
            run_id = d["db"]["run"]
            events = conn.exec_driver_sql(f"SELECT count(*) FROM job_state WHERE run_id = {run_id}").scalar_one()
            assert events == d["events"]
            good = conn.exec_driver_sql(f"SELECT count(*) FROM part_unit WHERE run_id = {run_id} "
                                        "AND outcome = 'good'").scalar_one()
            assert good == d["summary"]["parts_good"]
            alarms = conn.exec_driver_sql(f"SELECT count(*) FROM alarm WHERE run_id = {run_id}").scalar_one()
            assert alarms == sum(d["summary"]["faults"].values())
        total, distinct = conn.exec_driver_sql("SELECT count(*), count(DISTINCT serial) FROM part_unit").one()
        assert total == distinct > 0
        assert conn.exec_driver_sql("SELECT count(*) FROM run WHERE ended_at IS NOT NULL").scalar_one() == 4
    engine.dispose()
    r = run("report", postgres, "--json")
    assert r.exit_code == 0, r.output
    report = json.loads(r.stdout)
    assert "s3cret-pw" not in r.output and report["record"] == masked(postgres)
    assert report["throughput"]["parts_good"] == sum(d["summary"]["parts_good"] for d in docs)
    assert len(report["parts"]) == total


def test_a_plain_libpq_url_is_served_by_the_installed_driver(postgres, recorded, block_catalog, monkeypatch):
    """`--db postgresql://user@host:port/db` as psql writes it, the password from PGPASSWORD as libpq
    reads it: psycopg 3 (the driver installed) records the run, and `factory report` reads it back."""
    _, orders, _ = recorded
    folder, _ = block_catalog
    server = make_url(postgres)
    admin = sa.create_engine(server.set(database="postgres"), isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.exec_driver_sql("CREATE DATABASE cells")
    admin.dispose()
    plain = f"postgresql://{server.username}@{server.host}:{server.port}/cells"
    assert record_url(plain).drivername == "postgresql+psycopg"
    assert record_url(plain.replace("postgresql://", "postgres://")).drivername == "postgresql+psycopg"
    monkeypatch.setenv("PGPASSWORD", server.password)
    r = run("simulate", orders, "--catalog", folder, *SIM, "--db", plain, "--json", "--quiet")
    doc = json.loads(r.stdout)
    assert r.exit_code == simulate_exit(doc), r.output
    assert doc["db"] == {"url": f"postgresql+psycopg://{server.username}@{server.host}:{server.port}/cells", "run": 1}
    r = run("report", plain, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["throughput"]["parts_good"] == doc["summary"]["parts_good"]
    assert server.password not in r.output
    # a wrong password: refused in one line, neither password shown
    monkeypatch.setenv("PGPASSWORD", "wrong-pw")
    r = run("report", plain.replace("factory@", "factory:other-pw@"), "--json")
    assert_one_line_error(r, "postgresql+psycopg://factory:***@", "password authentication failed")
    assert "other-pw" not in r.output and "wrong-pw" not in r.output


def test_a_plain_postgresql_url_without_a_driver_names_the_package(monkeypatch):
    import factory.record

    monkeypatch.setattr(factory.record, "POSTGRESQL_DRIVERS", (("no_such_driver_module", "postgresql+none"),))
    with pytest.raises(RecordError, match=r"no PostgreSQL driver is installed: pip install 'factory\[postgresql\]'"):
        record_url("postgresql://cell:hunter2@db.example.com/cells")


_NEXT_REVISION = '''
from alembic import op
import sqlalchemy as sa

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("run") as batch:
        batch.add_column(sa.Column("shift", sa.String(20), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("run") as batch:
        batch.drop_column("shift")
'''


@needs_sqlite3
def test_an_old_record_opens_with_a_newer_schema_and_keeps_its_history(recorded, tmp_path, monkeypatch):
    """A factory whose migrations go one revision further opens a record written at revision 0001:
    the record is migrated in place (SQLite alters by copying tables) and every row is kept."""
    import factory.record

    db0, _, _ = recorded
    db = tmp_path / "old.sqlite"
    shutil.copy(db0, db)
    before = {t.name: sql(db, f"SELECT * FROM {t.name} ORDER BY id") for t in metadata.sorted_tables}
    newer = tmp_path / "migrations"
    shutil.copytree(factory.record.MIGRATIONS, newer)
    (newer / "versions" / "0002_shift.py").write_text(_NEXT_REVISION)
    monkeypatch.setattr(factory.record, "MIGRATIONS", newer)
    Record(db).close()
    assert one(db, "SELECT version_num FROM alembic_version") == "0002"
    assert "shift" in [row[1] for row in sql(db, "PRAGMA table_info(run)")]
    for table, rows in before.items():
        got = sql(db, f"SELECT * FROM {table} ORDER BY id")
        assert [r[:len(rows[0])] for r in got] == rows if rows else got == rows, table
    assert one(db, "PRAGMA integrity_check") == "ok" and sql(db, "PRAGMA foreign_key_check") == []
    Record(db).close()  # opening again changes nothing
    assert one(db, "SELECT version_num FROM alembic_version") == "0002"


_CELL = """
import json, os, sys, time
from pathlib import Path
from factory.record import OperationPlan, Record
from robotprog.cellsim import FaultModel, PartProcess, simulate
from robotprog.orders import Order

db, seed, ready, cells = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])
proc = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=0.2, inspect_s=0.2,
                   reject_s=14.0, regrasp_s=3.0)
orders = [Order(f"o{i + 1}", Path("a.stl"), 2, "aluminium", 0) for i in range(60)]
plan = OperationPlan("a.nc", "0" * 64, 300.0, proc.cycle_s, {}, "0" * 64)
with Record(db) as record:
    recorder = record.recorder(cell=f"cell{seed}", orders=orders, orders_file="-", orders_sha256="0" * 64,
                               faults_seed=seed)
    sink = recorder.begin({(Path("a.stl"), "aluminium"): plan})
    # Every cell has its run open before any simulates, however the machine schedules the processes:
    # the runs overlap, and their events interleave in the file.
    (ready / str(seed)).touch()
    deadline = time.monotonic() + 300
    while len(list(ready.iterdir())) < cells and time.monotonic() < deadline:
        time.sleep(0.01)
    result = simulate(orders, {Path("a.stl"): proc}, FaultModel(0.1, 0.1, 0.1, 0.1, seed), sink=sink)
    recorder.finish(result)
print(json.dumps({"run": recorder.run_id, "events": len(result.log), "good": result.summary["parts_good"]}))
"""


@needs_sqlite3
def test_cells_write_one_sqlite_record_at_once(tmp_path):
    """Three cells into one fresh SQLite file at the same time (the schema too): writers queue on
    the lock, nothing is lost, serials never collide."""
    db = tmp_path / "plant.sqlite"
    ready = tmp_path / "ready"
    ready.mkdir()
    cells = [subprocess.Popen([sys.executable, "-c", _CELL, str(db), str(seed), str(ready), "3"], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for seed in (1, 2, 3)]
    outputs = [cell.communicate(timeout=600) for cell in cells]
    assert all(cell.returncode == 0 for cell in cells), [err for _, err in outputs]
    docs = [json.loads(out) for out, _ in outputs]
    assert sorted(d["run"] for d in docs) == [1, 2, 3]
    for d in docs:
        assert int(one(db, f"SELECT count(*) FROM job_state WHERE run_id = {d['run']}")) == d["events"]
        assert int(one(db, f"SELECT count(*) FROM part_unit WHERE run_id = {d['run']} AND outcome = 'good'")) == \
            d["good"]
    assert one(db, "SELECT count(*) - count(DISTINCT serial) FROM part_unit") == "0"
    # the runs really overlapped: each started before another ended (the cells wait for each other)
    spans = sql(db, "SELECT started_at, ended_at FROM run ORDER BY started_at")
    assert any(later[0] < earlier[1] for earlier, later in zip(spans, spans[1:]))
    assert one(db, "PRAGMA integrity_check") == "ok"


def test_two_setups_record_op1_flip_op2_under_their_operations(tmp_path):
    from robotprog.cellsim import PartProcess, simulate
    from robotprog.orders import Order

    proc = PartProcess(fetch_s=12.0, load_s=15.0, machining_s=300.0, unload_s=14.0, locate_s=0.2, inspect_s=0.2,
                       reject_s=14.0, regrasp_s=3.0, flip_s=25.0, op2_machining_s=120.0)
    orders = [Order("o1", Path("a.stl"), 3, "aluminium", 0)]
    plan = OperationPlan("a.nc", "1" * 64, 300.0, proc.cycle_s, {}, "0" * 64, ("a.op2.nc", "2" * 64, 120.0))
    db = tmp_path / "two.sqlite"
    with Record(db) as record:
        recorder = record.recorder(cell="c", orders=orders, orders_file="-", orders_sha256="0" * 64, faults_seed=None)
        result = simulate(orders, {Path("a.stl"): proc}, sink=recorder.begin({(Path("a.stl"), "aluminium"): plan}))
        recorder.finish(result)
    ops = sql(db, "SELECT sequence, name, program, planned_machining_s FROM operation ORDER BY sequence")
    assert [tuple(r) for r in ops] == [("1", "op 1", "a.nc", "300.0"), ("2", "op 2", "a.op2.nc", "120.0")]
    cuts = sql(db, "SELECT o.name, j.program_sha256, j.machine_time_s FROM job_response j "
                   "JOIN operation o ON o.id = j.operation_id ORDER BY j.start_s")
    assert [(r[0], r[1][0], float(r[2])) for r in cuts] == [("op 1", "1", 300.0), ("op 2", "2", 120.0)] * 3
    flips = sql(db, "SELECT start_s, end_s FROM robot_move WHERE action = 'flip' ORDER BY start_s")
    assert len(flips) == 3 and all(float(e) - float(s) == pytest.approx(25.0) for s, e in flips)
