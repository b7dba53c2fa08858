"""The DuckDB warehouse: schema, the write lock, transactional idempotent writes.

Plain Python, no Prefect.  One writer at a time: every write session holds an
exclusive ``fcntl.flock`` on ``<db>.lock`` (re-entrant within a process); readers
(``accelcal sql``) hold it shared, so they wait for a writer and a writer waits for
them, never half-way through a run.  Each drop's run records and each campaign result
with its lineage go in ONE transaction, so a process killed at any moment leaves the
warehouse as it was before that transaction; running again completes the work exactly
once.

A warehouse file is never modified before it has been opened read-only and found to be a
DuckDB database: a truncated or foreign file is refused as it is.  A new warehouse is
created in a temporary file and renamed into place, so a kill never leaves half a one.
Every failure is a WarehouseError with one line naming the file and what to do.

duckdb 2.0: always fetch a result before the next statement.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import shutil
import stat
import tempfile
import threading
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Iterator

import duckdb

from ..fileio import atomic_write, os_error_text, path_text, remove_stale_temps
from .lineage import canonical_json

SCHEMA_VERSION = "2"

Checkpoint = Callable[[str], None] | None


class WarehouseError(RuntimeError):
    """The warehouse cannot be used (one-line message for the CLI)."""


class WarehouseBusy(WarehouseError):
    """Another process holds the warehouse lock."""


_DUCKDB_HINTS = (
    ("no space left", "the disk is full: free space, then run again; what was committed stays"),
    ("read-only file system", "a read-only file system: choose a writable place"),
    ("permission denied", "no permission: make the warehouse folder writable for this user"),
    ("not a valid duckdb database", "restore it from a backup or its -snapshot.duckdb copy"),
    ("serialization", "the file is damaged or from another DuckDB version: restore it from a "
                      "backup or its -snapshot.duckdb copy"),
    ("corrupt", "the file is damaged: restore it from a backup or its -snapshot.duckdb copy"),
    ("checksum", "the file is damaged: restore it from a backup or its -snapshot.duckdb copy"),
)


def _duckdb_size(head: bytes) -> int | None:
    """Bytes a DuckDB file must have, from the newer of its two database headers (at 4096
    and 8192: checksum, iteration, meta block, free list, block count, block size, ...):
    3 header blocks + block count x block size.  None when the header is not understood
    (another storage version): then only DuckDB's own checks apply."""
    import struct
    if len(head) < 3 * 4096:
        return 3 * 4096
    best = None
    for off in (4096, 8192):
        _, iteration, _, _, count, bsize = struct.unpack_from("<QQqqQQ", head, off)
        if not (4096 <= bsize <= 1 << 26 and bsize & (bsize - 1) == 0 and count < 1 << 40):
            return None
        if best is None or iteration > best[0]:
            best = (iteration, 3 * 4096 + count * bsize)
    return best[1]


def duckdb_error_text(e: Exception, what: str, untouched: bool = False) -> str:
    """One line for a DuckDB error: what, DuckDB's first line (cut), what to do."""
    msg = " ".join(str(e).split())[:240]
    low = msg.lower()
    hint = next((h for k, h in _DUCKDB_HINTS if k in low), None)
    if hint is None and untouched:
        hint = "restore it from a backup or its -snapshot.duckdb copy"
    tail = "; it was not modified" if untouched else ""
    return f"{what}: {msg}{tail}" + (f" ({hint})" if hint else "")


# --------------------------------------------------------------------- lock --

_held_lock = threading.RLock()
_held: dict[str, list] = {}      # realpath of lock file -> [fd, depth]


def lock_path_for(db_path: str | Path) -> Path:
    return Path(str(db_path) + ".lock")


def _holder_pid(lock_path: Path) -> str:
    try:
        txt = lock_path.read_text().strip()
        return txt or "unknown"
    except OSError:
        return "unknown"


def lock_holders(lock_path: str | Path) -> list[tuple[int, str]]:
    """(pid, 'WRITE'|'READ') of the processes holding a flock on ``lock_path``, from
    /proc/locks (Linux; empty elsewhere)."""
    try:
        st = os.stat(lock_path)
        with open("/proc/locks") as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    want = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    out = []
    for line in lines:
        parts = line.split()
        if "->" in parts or len(parts) < 6 or parts[1] != "FLOCK":
            continue
        try:
            maj, mnr, ino = parts[5].split(":")
            if (int(maj, 16), int(mnr, 16), int(ino)) == want:
                out.append((int(parts[4]), parts[3]))
        except ValueError:
            continue
    return out


def describe_pid(pid: int) -> str:
    """'pid N (command line)' for a message."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read().replace(b"\0", b" ").decode("utf-8", "replace").strip()
    except OSError:
        cmd = ""
    cmd = re.sub(r"^\S*python[0-9.]*\s+(-m\s+)?", "", " ".join(cmd.split()))
    return f"pid {pid}" + (f" ({cmd[:60]})" if cmd else "")


def _busy_text(db_path, lp: Path, timeout: float) -> str:
    holders = lock_holders(lp)
    if holders:
        who = ", ".join(describe_pid(p) + (", reading" if m == "READ" else "") for p, m in holders[:3])
    else:
        who = f"pid {_holder_pid(lp)}"
    return f"warehouse {db_path} is in use by {who} (waited {timeout:g} s; see {lp})"


@contextlib.contextmanager
def warehouse_lock(db_path: str | Path, timeout: float = 60.0,
                   poll: float = 0.1, shared: bool = False) -> Iterator[None]:
    """Exclusive OS lock on ``<db>.lock`` (``shared=True``: a reader's shared lock);
    waits up to ``timeout`` seconds.

    Re-entrant within one process.  Raises :class:`WarehouseBusy` naming the
    holder's pid when the wait times out.  A reader in a folder where the lock file
    cannot be created goes on without it (no writer can work there either).
    """
    lp = lock_path_for(db_path)
    key = os.path.realpath(lp)
    with _held_lock:
        if key in _held:
            _held[key][1] += 1
            reentered = True
        else:
            reentered = False
    if reentered:
        try:
            yield
        finally:
            with _held_lock:
                _held[key][1] -= 1
        return

    try:
        if not shared:
            lp.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lp, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as e:
        fd = None
        if shared:
            try:
                fd = os.open(lp, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                pass
        if fd is None and not shared:
            raise WarehouseError(os_error_text(e, f"cannot use warehouse {db_path}: cannot "
                                                  "create its lock file")) from None
    if fd is None:                     # a reader, no lock file and none can be made
        yield
        return
    deadline = time.monotonic() + max(0.0, timeout)
    try:
        while True:
            try:
                fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
                break
            except OSError as e:
                if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                if time.monotonic() >= deadline:
                    raise WarehouseBusy(_busy_text(db_path, lp, timeout)) from None
                time.sleep(poll)
    except BaseException:
        os.close(fd)
        raise
    if not shared:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    with _held_lock:
        _held[key] = [fd, 1]
    try:
        yield
    finally:
        with _held_lock:
            del _held[key]
        try:
            if not shared:
                os.ftruncate(fd, 0)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def holds_lock(db_path: str | Path) -> bool:
    with _held_lock:
        return os.path.realpath(lock_path_for(db_path)) in _held


# ---------------------------------------------------------------- records --

@dataclass
class Refusal:
    """A broken rule (mirrors schemas' Refusal; line may be None)."""
    rule: str
    detail: str = ""
    line: int | None = None
    path: str = ""

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line is not None else f"{self.path}"
        return f"{where}: {self.rule}: {self.detail}" if self.detail else f"{where}: {self.rule}"


@dataclass
class RunRecord:
    """What the warehouse keeps about one ingested file."""
    sha256: str
    source_path: str
    drop_name: str
    drop_path: str
    size_bytes: int
    status: str                           # 'accepted' | 'refused'
    run_id: str | None = None
    test: str | None = None
    unit_serial: str | None = None
    unit_model: str | None = None
    campaign: str | None = None
    rig_id: str | None = None
    started_at: str | None = None
    n_rows: int | None = None
    parquet_path: str | None = None       # relative to the warehouse folder
    refusals: list[Refusal] = field(default_factory=list)
    validator_version: str = ""           # parser + suites version that gave the verdict
    simulated: bool = False               # carries the simulator's mark (accelcal.provenance)
    revision: int | None = None           # filled by the warehouse
    new: bool = False                     # filled by the warehouse: file row added
    rechecked: bool = False               # filled by the warehouse: new verdict on a known file
    new_content: bool = False             # filled by the warehouse: bytes never seen before

    @property
    def reason(self) -> str | None:
        if self.status == "accepted":
            return None
        return "; ".join(str(r) for r in self.refusals) or "refused"


def _transaction(con) -> contextlib.AbstractContextManager:
    @contextlib.contextmanager
    def tx():
        con.execute("BEGIN TRANSACTION")
        try:
            yield con
        except BaseException:
            try:
                con.execute("ROLLBACK")
            except Exception:
                pass
            raise
        con.execute("COMMIT")
    return tx()


def _cp(checkpoint: Checkpoint, step: str) -> None:
    if checkpoint is not None:
        checkpoint(step)


#: The runs a campaign is computed from (parameter: the list of campaigns): its current
#: runs, without the simulated ones when the label also has real runs.
_PLAN_RUNS = """
    SELECT c.* FROM current_runs c
    WHERE list_contains(?, c.campaign)
      AND (NOT c.simulated OR NOT EXISTS (
           SELECT 1 FROM current_runs r WHERE r.campaign = c.campaign AND NOT r.simulated))"""


# ----------------------------------------------------------------- schema --

def check_schema_version(con, path) -> None:
    """Raise WarehouseError (one line) unless the open warehouse is empty or written with
    this SCHEMA_VERSION.  Every reader and writer calls it before touching tables, so an
    old warehouse gets a sentence, never a traceback about a missing column."""
    have = con.execute("SELECT count(*) FROM information_schema.tables "
                       "WHERE table_name = 'schema_info'").fetchall()[0][0]
    if not have:
        return
    row = con.execute("SELECT value FROM schema_info WHERE key = 'schema_version'").fetchall()
    if row and row[0][0] != SCHEMA_VERSION:
        older = row[0][0] < SCHEMA_VERSION
        raise WarehouseError(
            f"warehouse {path} has schema version {row[0][0]}, this accelcal uses "
            f"{SCHEMA_VERSION}: " + (
                "process its drops again into a new warehouse (the raw drops are never "
                "changed; results are recomputed exactly)" if older else
                "it was written by a newer accelcal; upgrade accelcal to read it"))


# -------------------------------------------------------------- warehouse --

class Warehouse:
    """A DuckDB warehouse file plus its Parquet store and Data Docs, side by side.

    ``lab.duckdb`` -> ``lab-parquet/`` (run data), ``lab-datadocs/<drop>/`` (GE docs),
    ``lab.duckdb.lock`` (writer lock).
    """

    def __init__(self, path: str | Path, lock_timeout: float = 60.0):
        self.path = Path(path).expanduser().resolve()
        self.root = self.path.parent
        self.parquet_root = self.root / f"{self.path.stem}-parquet"
        self.docs_root = self.root / f"{self.path.stem}-datadocs"
        self.snapshot_path = self.root / f"{self.path.stem}-snapshot.duckdb"
        self.lock_timeout = lock_timeout
        self._schema_ok = False
        self._checked = False            # opened read-only once and found sound
        self._session: duckdb.DuckDBPyConnection | None = None

    def __repr__(self) -> str:
        return f"Warehouse({str(self.path)!r})"

    # -- connections -------------------------------------------------------

    def lock(self, timeout: float | None = None):
        return warehouse_lock(self.path, self.lock_timeout if timeout is None else timeout)

    @contextlib.contextmanager
    def session(self) -> Iterator[duckdb.DuckDBPyConnection]:
        """Hold ONE write connection (and the lock) for a stretch of work.

        Inside it every write ``connect()`` of this object reuses that connection
        instead of opening the file again (18 ms per open on a 20 MB warehouse,
        growing with the file).  Each method still commits its own transaction,
        so what a crash leaves is unchanged.  Readers in other processes wait
        while a session is open: keep sessions to a bounded stretch (the pipeline
        closes and reopens one every few seconds of work).  Re-entrant.
        """
        if self._session is not None:
            yield self._session
            return
        with self.connect() as con:
            self._session = con
            try:
                yield con
            finally:
                self._session = None

    @contextlib.contextmanager
    def connect(self, read_only: bool = False) -> Iterator[duckdb.DuckDBPyConnection]:
        """A connection; write connections hold the lock and see the schema applied."""
        if not read_only and self._session is not None:
            try:
                yield self._session
            except duckdb.Error as e:
                raise WarehouseError(duckdb_error_text(e, f"cannot write warehouse {self.path}")) from None
            return
        if read_only:
            if not self.path.exists():
                raise WarehouseError(f"warehouse {self.path} does not exist")
            con = self._open(read_only=True)
            try:
                check_schema_version(con, self.path)
                yield con
            finally:
                con.close()
            return
        with self.lock():
            if not self.root.is_dir():
                raise WarehouseError(f"the warehouse folder {self.root} does not exist")
            con = self._open(read_only=False)
            try:
                if not self._schema_ok:
                    self._apply_schema(con)
                yield con
            except duckdb.Error as e:
                raise WarehouseError(duckdb_error_text(e, f"cannot write warehouse {self.path}")) from None
            finally:
                with contextlib.suppress(duckdb.Error):
                    con.close()

    def _open(self, read_only: bool, path: Path | None = None) -> duckdb.DuckDBPyConnection:
        """Open the DuckDB file; while another process has it open (DuckDB's own file
        lock, e.g. a reader outside accelcal), retry until ``lock_timeout``.  Before the
        first write open, a new warehouse is created whole (temporary file + rename) and an
        existing one is opened read-only and checked, so a file that is not a sound DuckDB
        database is refused untouched."""
        path = path or self.path
        if not read_only and path == self.path and not self._checked:
            if self.path.exists():
                self.check_readable()
            else:
                self._create()
            self._checked = True
        deadline = time.monotonic() + max(0.0, self.lock_timeout)
        while True:
            try:
                return duckdb.connect(str(path), read_only=read_only)
            except duckdb.IOException as e:
                msg = str(e).splitlines()[0]
                if "lock" not in msg.lower():
                    raise WarehouseError(duckdb_error_text(e, f"cannot open warehouse {path}")) from None
                if time.monotonic() >= deadline:
                    m = re.search(r"PID (\d+)", msg)
                    who = describe_pid(int(m.group(1))) if m else "another process"
                    raise WarehouseBusy(
                        f"warehouse {path} is open in {who}, which blocks "
                        f"{'reading' if read_only else 'writing'} (waited {self.lock_timeout:g} s): "
                        f"close it; programs outside accelcal should read {self.snapshot_path.name} "
                        "or use `accelcal sql`") from None
                time.sleep(0.1)
            except duckdb.Error as e:
                raise WarehouseError(duckdb_error_text(e, f"cannot open warehouse {path}")) from None

    # -- guarding the file -------------------------------------------------------

    def check_place(self, create: bool = False, drops: list[str] = ()) -> None:
        """Before a run writes anything: the warehouse's folder exists (or ``create``), is
        writable, lies in no drop; an existing file is a DuckDB database.  Raises
        WarehouseError with one line naming the path and what to do."""
        p, root = self.path, self.root
        if p.is_dir():
            raise WarehouseError(f"warehouse {p} is a folder: give the path of a .duckdb file")
        if p.exists():
            self.check_duckdb_file()
        for d in drops:
            d = os.path.realpath(d)
            if str(p).startswith(d.rstrip(os.sep) + os.sep):
                raise WarehouseError(
                    f"warehouse {p} is inside the drop {path_text(d)}: a run never writes into a "
                    "drop (what arrives is never modified); put the warehouse elsewhere")
        if not root.is_dir():
            if root.exists():
                raise WarehouseError(f"the warehouse folder {root} is not a folder")
            if not create:
                raise WarehouseError(f"the warehouse folder {root} does not exist: create it, "
                                     "or give --create")
            try:
                root.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise WarehouseError(os_error_text(e, "cannot create the warehouse folder")) from None
        try:
            fd, probe = tempfile.mkstemp(prefix=f".{p.name}.probe.", suffix=".tmp", dir=root)
            os.close(fd)
            os.unlink(probe)
        except OSError as e:
            raise WarehouseError(os_error_text(
                e, f"cannot write in the warehouse folder {root} (a run writes {p.name}, its "
                   ".wal and .lock, and the Parquet store there)")) from None

    def check_duckdb_file(self, path: Path | None = None) -> None:
        """The file is a DuckDB database (magic bytes) of the size its header says; read
        only.  DuckDB itself opens a truncated file and only fails when it reaches a
        missing block -- after a write open may already have changed the file."""
        path = path or self.path
        try:
            with open(path, "rb") as f:
                head = f.read(3 * 4096)
                size = os.fstat(f.fileno()).st_size
        except OSError as e:
            raise WarehouseError(os_error_text(e, "cannot read the warehouse")) from None
        if len(head) < 12 or head[8:12] != b"DUCK":
            what = "an empty file" if not head else f"a file that starts {head[:12]!r}"
            raise WarehouseError(f"{path} is not a DuckDB warehouse ({what}); it was not "
                                 "touched: give the path of a .duckdb file, or a new name")
        need = _duckdb_size(head)
        if need is not None and size < need:
            raise WarehouseError(
                f"warehouse {path} is truncated ({size:,} bytes; its header needs {need:,}); it "
                "was not modified (restore it from a backup or its -snapshot.duckdb copy)")

    def check_readable(self) -> None:
        """Open the existing file read-only and read its catalog; refuse it untouched
        when DuckDB cannot (truncated, corrupt, another program's file)."""
        self.check_duckdb_file()
        try:
            con = duckdb.connect(str(self.path), read_only=True)
        except duckdb.IOException as e:
            if "lock" in str(e).lower():       # a reader outside accelcal has it open
                return                         # (the write open waits for it)
            raise WarehouseError(duckdb_error_text(
                e, f"cannot open warehouse {self.path}", untouched=True)) from None
        except duckdb.Error as e:
            raise WarehouseError(duckdb_error_text(
                e, f"cannot open warehouse {self.path}", untouched=True)) from None
        try:
            con.execute("SELECT count(*) FROM duckdb_tables()").fetchall()
        except duckdb.Error as e:
            raise WarehouseError(duckdb_error_text(
                e, f"cannot read warehouse {self.path}", untouched=True)) from None
        finally:
            con.close()

    def _create(self) -> None:
        """A new, empty warehouse file: made as a temporary file, renamed into place."""
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.root)
        os.close(fd)
        os.unlink(tmp)                          # DuckDB creates it itself
        try:
            con = duckdb.connect(tmp)
            try:
                con.execute("CREATE TABLE IF NOT EXISTS schema_info "
                            "(key VARCHAR PRIMARY KEY, value VARCHAR NOT NULL)")
                con.execute("CHECKPOINT")
            finally:
                con.close()
            os.replace(tmp, self.path)
        except duckdb.Error as e:
            raise WarehouseError(duckdb_error_text(e, f"cannot create warehouse {self.path}")) from None
        except OSError as e:
            raise WarehouseError(os_error_text(e, f"cannot create warehouse {self.path}")) from None
        finally:
            for f in (tmp, tmp + ".wal"):
                with contextlib.suppress(OSError):
                    os.unlink(f)

    def remove_stale_temps(self) -> list[str]:
        """Temporary files of writers that were killed (Parquet, snapshot, creation);
        only while holding the lock."""
        if not holds_lock(self.path):
            raise RuntimeError("remove_stale_temps needs the warehouse lock")
        return (remove_stale_temps(self.root, recursive=False)
                + remove_stale_temps(self.parquet_root))

    def publish_snapshot(self) -> Path:
        """Copy the warehouse to ``<stem>-snapshot.duckdb`` (checkpointed first, written
        as a temporary file and renamed, mode 0444): a read-only copy that dashboards and
        programs outside accelcal can open at any time without DuckDB's file lock getting
        in the way of a run.  Needs the lock."""
        with self.lock(), self.connect() as con:
            con.execute("CHECKPOINT")
        try:
            def copy(fh):
                with open(self.path, "rb") as src:
                    shutil.copyfileobj(src, fh, 1 << 20)
            atomic_write(self.snapshot_path, copy, "wb", fsync=True)
            os.chmod(self.snapshot_path, 0o444)
        except OSError as e:
            raise WarehouseError(os_error_text(e, f"cannot publish the snapshot {self.snapshot_path}")) from None
        return self.snapshot_path

    def _apply_schema(self, con) -> None:
        sql = resources.files("accelcal.warehouse").joinpath("schema.sql").read_text()
        check_schema_version(con, self.path)
        with _transaction(con):
            con.execute(sql)
            # operations views (fleet, history, rig comparison): read history tables only
            views = resources.files("accelcal.warehouse").joinpath("views.sql")
            if views.is_file():
                con.execute(views.read_text())
            con.execute("INSERT INTO schema_info VALUES ('schema_version', ?) "
                        "ON CONFLICT DO NOTHING", [SCHEMA_VERSION])
        self._schema_ok = True

    def init(self) -> None:
        with self.connect():
            pass

    # -- runs ----------------------------------------------------------------

    def record_runs(self, records: list[RunRecord], flow_run_id: str | None = None,
                    checkpoint: Checkpoint = None) -> list[RunRecord]:
        """Record the files of one drop in ONE transaction; idempotent.

        ``run_files`` key (sha256, source_path): a file already recorded adds no
        file row.  Its revision is 1 + the highest of its run_id, unless these
        exact bytes already have one.  A verdict (status, reason) is added per
        (file, validator_version) once.  Fills ``revision`` and ``new`` (file row
        added) of each record.
        """
        with self.connect() as con, _transaction(con):
            batch_rev: dict[tuple[str, str], int] = {}
            batch_max: dict[str, int] = {}
            for i, rec in enumerate(records):
                exists = con.execute(
                    "SELECT revision FROM run_files WHERE sha256 = ? AND source_path = ?",
                    [rec.sha256, rec.source_path]).fetchall()
                if exists:
                    rec.revision, rec.new = exists[0][0], False
                else:
                    rec.new_content = not con.execute(
                        "SELECT count(*) FROM run_files WHERE sha256 = ?",
                        [rec.sha256]).fetchall()[0][0]
                    if rec.run_id is not None:
                        key = (rec.run_id, rec.sha256)
                        if key in batch_rev:
                            rec.revision = batch_rev[key]
                        else:
                            same = con.execute(
                                "SELECT max(revision) FROM run_files WHERE run_id = ? AND sha256 = ?",
                                [rec.run_id, rec.sha256]).fetchall()[0][0]
                            if same is not None:
                                rec.revision = same
                            else:
                                top = con.execute(
                                    "SELECT coalesce(max(revision), 0) FROM run_files WHERE run_id = ?",
                                    [rec.run_id]).fetchall()[0][0]
                                rec.revision = max(top, batch_max.get(rec.run_id, 0)) + 1
                            batch_rev[key] = rec.revision
                        batch_max[rec.run_id] = max(batch_max.get(rec.run_id, 0), rec.revision)
                    con.execute(
                        """INSERT INTO run_files (sha256, source_path, drop_name, drop_path, run_id,
                               revision, test, unit_serial, unit_model, campaign, rig_id, started_at,
                               size_bytes, ingested_at, flow_run_id, simulated)
                           VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, now(), ?, ?)""",
                        [rec.sha256, rec.source_path, rec.drop_name, rec.drop_path, rec.run_id,
                         rec.revision, rec.test, rec.unit_serial, rec.unit_model, rec.campaign,
                         rec.rig_id, rec.started_at, rec.size_bytes, flow_run_id,
                         bool(rec.simulated)]).fetchall()
                    rec.new = True
                have = con.execute(
                    "SELECT count(*) FROM run_verdicts WHERE sha256 = ? AND source_path = ? "
                    "AND validator_version = ?",
                    [rec.sha256, rec.source_path, rec.validator_version]).fetchall()[0][0]
                if not have:
                    con.execute(
                        """INSERT INTO run_verdicts VALUES
                           (?, ?, ?, nextval('verdict_seq'), ?, ?, ?, ?, now(), ?)""",
                        [rec.sha256, rec.source_path, rec.validator_version, rec.status,
                         rec.reason, rec.n_rows, rec.parquet_path, flow_run_id]).fetchall()
                    for j, rf in enumerate(rec.refusals):
                        con.execute("INSERT INTO refusals VALUES (?, ?, ?, ?, ?, ?, ?)",
                                    [rec.sha256, rec.source_path, rec.validator_version, j,
                                     rf.line, rf.rule, rf.detail]).fetchall()
                    rec.rechecked = not rec.new
                _cp(checkpoint, f"run:{i}")
        return records

    def latest_verdicts(self, source_prefix: str) -> dict[tuple[str, str], str]:
        """(sha256, source_path) -> validator_version of its latest verdict, below a folder."""
        with self.connect() as con:
            rows = con.execute(
                "SELECT sha256, source_path, validator_version FROM runs "
                "WHERE starts_with(source_path, ?)", [source_prefix]).fetchall()
        return {(a, b): c for a, b, c in rows}

    def stored_runs(self, keys: list[tuple[str, str]]) -> list[dict[str, Any]]:
        """Run records by (sha256, source_path), as stored (status/reason of first sight)."""
        if not keys:
            return []
        with self.connect() as con:
            con.execute("CREATE TEMP TABLE IF NOT EXISTS _keys (sha256 VARCHAR, source_path VARCHAR)")
            con.execute("DELETE FROM _keys")
            con.executemany("INSERT INTO _keys VALUES (?, ?)", [list(k) for k in keys])
            cur = con.execute(
                """SELECT r.* FROM runs r JOIN _keys k USING (sha256, source_path)
                   ORDER BY r.source_path""")
            cols = [d[0] for d in cur.description]
            return [dict(zip(cols, row)) for row in cur.fetchall()]

    def campaign_inputs(self, campaign: str) -> list[dict[str, Any]]:
        """The runs a campaign is computed from: newest accepted revision per run_id."""
        return self.campaign_plans([campaign])[campaign][0]

    def campaign_plans(self, campaigns: list[str]) -> dict[str, tuple[list[dict[str, Any]], str | None]]:
        """For many campaigns at once: (the runs each is computed from -- newest accepted
        revision per run_id, ordered by run_id -- and its current result_id or None).

        Simulated runs never join real ones: a campaign label that has real runs is
        computed from its real runs only (:meth:`simulated_left_out` counts the others)."""
        out: dict[str, tuple[list[dict[str, Any]], str | None]] = {c: ([], None) for c in campaigns}
        if not campaigns:
            return out
        with self.connect() as con:
            cur = con.execute(
                f"""SELECT campaign, run_id, revision, sha256, test, rig_id, source_path,
                          parquet_path, simulated
                   FROM ({_PLAN_RUNS}) ORDER BY campaign, run_id""", [list(campaigns)])
            cols = [d[0] for d in cur.description][1:]
            for row in cur.fetchall():
                out[row[0]][0].append(dict(zip(cols, row[1:])))
            for camp, rid in con.execute(
                    """SELECT campaign, arg_max(result_id, seq) FROM result_activations
                       WHERE list_contains(?, campaign) GROUP BY campaign""",
                    [list(campaigns)]).fetchall():
                out[camp] = (out[camp][0], rid)
        return out

    def simulated_left_out(self, campaigns: list[str]) -> dict[str, int]:
        """Simulated runs under the label (or run id) of a campaign's real runs: not used."""
        if not campaigns:
            return {}
        with self.connect() as con:
            return dict(con.execute(
                f"""SELECT campaign, count(DISTINCT run_id) FROM run_revisions
                    WHERE list_contains(?, campaign) AND simulated AND status = 'accepted'
                      AND sha256 NOT IN (SELECT sha256 FROM ({_PLAN_RUNS}))
                    GROUP BY campaign""", [list(campaigns), list(campaigns)]).fetchall())

    # -- results -------------------------------------------------------------

    def store_result(self, result, *, result_id: str, inputs: list[dict[str, Any]],
                     code_version: str, parameters: dict[str, Any],
                     flow_run_id: str | None, checkpoint: Checkpoint = None) -> str:
        """Store one CampaignResult with its lineage in ONE transaction.

        Returns 'unchanged' (already current: nothing written), 'new' (result
        inserted and made current), 'reactivated' (an earlier identical result made
        current again) or 'simulated-not-current' (a result computed from simulated
        runs, stored but not made current because its unit has a complete real
        result; nothing is written when it is already stored).
        """
        params_json = canonical_json(parameters)
        campaign = result.campaign
        simulated = any(bool(i.get("simulated")) for i in inputs)
        with self.connect() as con, _transaction(con):
            cur = con.execute(
                "SELECT result_id FROM result_activations WHERE campaign = ? "
                "ORDER BY seq DESC LIMIT 1", [campaign]).fetchall()
            if cur and cur[0][0] == result_id:
                return "unchanged"
            exists = con.execute("SELECT count(*) FROM results WHERE result_id = ?",
                                 [result_id]).fetchall()[0][0]
            if not exists:
                self._insert_result(con, result, result_id, inputs, code_version,
                                    params_json, flow_run_id, checkpoint, simulated)
            if simulated and con.execute(
                    "SELECT count(*) FROM real_units WHERE unit_serial = ?",
                    [result.unit_serial]).fetchall()[0][0]:
                return "simulated-not-current"
            _cp(checkpoint, "activate")
            con.execute(
                "INSERT INTO result_activations VALUES (nextval('activation_seq'), ?, ?, now(), ?)",
                [campaign, result_id, flow_run_id]).fetchall()
            _cp(checkpoint, "commit")
        return "reactivated" if exists else "new"

    @staticmethod
    def _insert_result(con, result, result_id, inputs, code_version, params_json,
                       flow_run_id, checkpoint, simulated=False) -> None:
        camp = result.campaign
        completeness = getattr(result, "completeness", "complete") or "complete"
        con.execute(
            """INSERT INTO results (result_id, campaign, unit_serial, unit_model, tests, rig_ids,
                   computed_at, flow_run_id, code_version, parameters, science_parameters,
                   input_sha256, extras, simulated, completeness, completeness_reasons)
               VALUES (?, ?, ?, ?, ?, ?, now(), ?, ?, ?, ?, ?, ?, ?, ?, ?)""",
            [result_id, camp, result.unit_serial, result.unit_model,
             canonical_json(list(result.tests)), canonical_json(list(result.rig_ids)),
             flow_run_id, code_version, params_json, canonical_json(result.parameters),
             canonical_json(sorted(i["sha256"] for i in inputs)),
             canonical_json(result.extras), bool(simulated), completeness,
             canonical_json(list(getattr(result, "completeness_reasons", []) or []))]).fetchall()
        _cp(checkpoint, "results")
        con.executemany(
            "INSERT INTO lineage VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            [[result_id, i["sha256"], i.get("run_id"), i.get("revision"), i.get("source_path"),
              i.get("parquet_path"), flow_run_id, code_version, params_json]
             for i in sorted(inputs, key=lambda i: i["sha256"])])
        _cp(checkpoint, "lineage")
        rows = [[result_id, k, result.unit_serial, camp, c.name, _f(c.value),
                 _f(c.std_uncertainty), c.unit, c.method, c.rig_id, _f(c.dof), c.note,
                 bool(getattr(c, "adopted", False)), _f(getattr(c, "coverage_factor", 2.0)) or 2.0]
                for k, c in enumerate(result.coefficients)]
        if rows:
            con.executemany("INSERT INTO coefficient_history VALUES "
                            "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
        _cp(checkpoint, "coefficients")
        rows = [[result_id, k, camp, r.rig_id, r.polarity, r.method, r.model_order,
                 _f(r.g_max), _f(r.radius_m), _f(r.std_uncertainty_m), r.note]
                for k, r in enumerate(result.radii)]
        if rows:
            con.executemany("INSERT INTO radius_history VALUES "
                            "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
        _cp(checkpoint, "radii")
        rows = [[result_id, k, camp, a.rig_id, a.fit, a.model_order, _f(a.g_max),
                 _f(a.f_statistic), _f(a.p_value), a.dof_lack_of_fit, a.dof_pure_error,
                 _f(a.trend_p), _f(a.sweep_p), _f(a.runs_p), bool(a.adequate), bool(a.chosen),
                 a.note]
                for k, a in enumerate(result.adequacy)]
        if rows:
            con.executemany("INSERT INTO adequacy_history VALUES "
                            "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
        rows = [[result_id, k, camp, b.coefficient, b.quantity, _f(b.value),
                 _f(b.std_uncertainty), _f(b.sensitivity), _f(b.contribution), b.type,
                 b.distribution, getattr(b, "method", "")]
                for k, b in enumerate(result.budget)]
        if rows:
            con.executemany("INSERT INTO budget_history VALUES "
                            "(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
        rows = [[result_id, k, camp, canonical_json(a)] for k, a in enumerate(result.alignment)]
        if rows:
            con.executemany("INSERT INTO alignment_history VALUES (?, ?, ?, ?)", rows)
        rows = [[result_id, k, camp, str(f)] for k, f in enumerate(result.flags)]
        if rows:
            con.executemany("INSERT INTO flag_history VALUES (?, ?, ?, ?)", rows)
        _cp(checkpoint, "details")

    # -- quarantine ------------------------------------------------------------

    def campaign_action(self, campaign: str, action: str, why: str,
                        by: str | None = None) -> dict[str, Any]:
        """Append 'exclude' or 'include' for a campaign to the audit trail (campaign_actions).

        Refuses (WarehouseError, one line) an unknown campaign, an empty reason, and an
        action that would change nothing (excluding an excluded campaign).  Nothing is
        ever updated or deleted: the latest action is the campaign's state.
        """
        if action not in ("exclude", "include"):
            raise WarehouseError(f"unknown action {action!r}: exclude or include")
        if not (why or "").strip():
            raise WarehouseError("give a reason (--why): the audit trail needs one")
        with self.connect() as con, _transaction(con):
            known = con.execute(
                "SELECT (SELECT count(*) FROM results WHERE campaign = ?) + "
                "(SELECT count(*) FROM run_files WHERE campaign = ?)",
                [campaign, campaign]).fetchall()[0][0]
            if not known:
                raise WarehouseError(f"no campaign {campaign!r} in warehouse {self.path}")
            last = con.execute(
                "SELECT action, why, acted_at, acted_by FROM campaign_actions WHERE campaign = ? "
                "ORDER BY seq DESC LIMIT 1", [campaign]).fetchall()
            state = last[0][0] if last else "include"
            if state == action:
                since = (f" since {last[0][2]:%Y-%m-%d %H:%M} by {last[0][3] or '?'}: {last[0][1]}"
                         if last else "")
                raise WarehouseError(f"campaign {campaign!r} is already "
                                     f"{'excluded' if action == 'exclude' else 'included'}{since}; "
                                     "nothing recorded")
            row = con.execute(
                "INSERT INTO campaign_actions VALUES (nextval('campaign_action_seq'), ?, ?, ?, "
                "now(), ?) RETURNING seq, acted_at", [campaign, action, why.strip(), by]).fetchall()
        return {"seq": row[0][0], "acted_at": row[0][1], "campaign": campaign, "action": action,
                "why": why.strip(), "by": by}

    # -- reading ---------------------------------------------------------------

    def query(self, sql: str, params: list | None = None) -> list[dict[str, Any]]:
        """Read-only helper (opens read-only; fails if a writer is active)."""
        con = self._open(read_only=True)
        try:
            check_schema_version(con, self.path)
            cur = con.execute(sql, params or [])
            cols = [d[0] for d in cur.description]
            return [dict(zip(cols, r)) for r in cur.fetchall()]
        finally:
            con.close()

    def counts(self) -> dict[str, int]:
        """Row counts of every base table (for idempotency checks)."""
        tables = ["run_files", "run_verdicts", "refusals", "results", "result_activations", "lineage",
                  "coefficient_history", "radius_history", "adequacy_history",
                  "budget_history", "alignment_history", "flag_history", "campaign_actions"]
        with self.connect() as con:
            return {t: con.execute(f"SELECT count(*) FROM {t}").fetchall()[0][0] for t in tables}


def _f(x) -> float | None:
    if x is None:
        return None
    try:
        return float(x)
    except (TypeError, ValueError):
        return None
