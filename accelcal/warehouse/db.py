"""The DuckDB warehouse: the :class:`Warehouse` (its files, connections, schema, the
guarding of the file, run records, plans, quarantine), beside the modules it uses:

- ``lock.py``: the cross-process write lock (``fcntl.flock`` on ``<db>.lock``);
- ``results.py``: the results writer (a batch of campaign results with their lineage);
- ``extras.py``: the extras store (a result's extras as content-addressed files);
- ``columnar.py``: transactions and one-Arrow-insert-per-table writes;
- ``errors.py``: WarehouseError and its kin, one line each.

Plain Python, no Prefect.  One writer at a time: every write session holds an
exclusive ``fcntl.flock`` on ``<db>.lock`` (re-entrant within a process); readers
(``accelcal sql``) hold it shared, so they wait for a writer and a writer waits for
them, never half-way through a run.  Each batch of run records and each group of
campaign results with their lineage go in ONE transaction, written column-wise (one
Arrow insert per table, never row by row), so a process killed at any moment leaves the
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
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, NamedTuple

import duckdb

from ..fileio import atomic_write, current_umask, os_error_text, path_text, remove_stale_temps
from ..schemas.dropspec import Refusal  # the one Refusal (drop format and warehouse)
from .columnar import Checkpoint, _arrow, _attr_columns, _cp, _insert, _nextvals, _registered, \
    _transaction
from .errors import WarehouseBusy, WarehouseError, duckdb_error_text
from .extras import EXTRAS_DIR_KEY, extras_root_of
from .lineage import canonical_json
from .lock import describe_pid, holds_lock, warehouse_lock
from . import priors as _priors
from .results import write_results
from .views import apply_views

#: 3: results.extras (the JSON the certificate's plots and checks read, ~48 KB a result)
#: moved out of the table into content-addressed files; results.extras_sha256 names one.
SCHEMA_VERSION = "4"

#: What other modules take from here (the lock, the extras store and the errors are
#: imported from lock.py, extras.py and errors.py).
__all__ = ["SCHEMA_VERSION", "RunRecord", "Refusal", "Warehouse", "check_schema_version",
           "ensure_views", "roomy", "schema_version", "query_memory_limit",
           "write_memory_limit"]


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


# ---------------------------------------------------------------- records --

class KnownFile(NamedTuple):
    """A recorded file as its latest verdict has it (:meth:`Warehouse.latest_verdicts`):
    the fields of its ``runs`` row a run reads of a file it does not take in again."""
    sha256: str
    source_path: str
    validator_version: str
    status: str
    reason: str | None
    campaign: str | None


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


# ------------------------------------------------------- plans and memory --

#: The runs a campaign is computed from (parameter: the list of campaigns): its current
#: runs, without the simulated ones when the label also has real runs.
_PLAN_RUNS = """
    SELECT c.* FROM current_runs c
    WHERE list_contains(?, c.campaign)
      AND (NOT c.simulated OR NOT EXISTS (
           SELECT 1 FROM current_runs r WHERE r.campaign = c.campaign AND NOT r.simulated))"""


#: DuckDB's memory limit on a write connection (``ACCELCAL_DUCKDB_MEMORY``).  The
#: pipeline holds one write connection for the whole run; with DuckDB's default (80 % of
#: RAM) its buffer pool kept every block of the growing file it had written, so the flow
#: process's memory grew with the warehouse (≈ 0.1 MB per campaign).  The writes and the
#: plan queries need a few MB; blocks beyond the limit are dropped (they are on disk).
WRITE_MEMORY_LIMIT = "64MB"


#: ... raised to this (``ACCELCAL_DUCKDB_QUERY_MEMORY``) for the statements whose working
#: set grows with the warehouse (the plan of which campaigns to compute, the run summary):
#: at 2,000 campaigns the plan query needed more than 64 MB and the run stopped with
#: "Out of Memory Error: could not allocate block".  The limit is set back afterwards,
#: which drops the cached blocks beyond it, so memory between those statements stays flat.
QUERY_MEMORY_LIMIT = "2GB"


def _memory_setting(name: str, default: str) -> str:
    v = os.environ.get(name, default).strip()
    return v if re.fullmatch(r"\d+(\.\d+)?\s*[KMGT]i?B", v, re.I) else default


def write_memory_limit() -> str:
    return _memory_setting("ACCELCAL_DUCKDB_MEMORY", WRITE_MEMORY_LIMIT)


def query_memory_limit() -> str:
    return _memory_setting("ACCELCAL_DUCKDB_QUERY_MEMORY", QUERY_MEMORY_LIMIT)


@contextlib.contextmanager
def roomy(con: duckdb.DuckDBPyConnection) -> Iterator[duckdb.DuckDBPyConnection]:
    """``con`` with DuckDB's memory limit raised to :func:`query_memory_limit` for the
    statements inside, then set back to :func:`write_memory_limit`."""
    con.execute(f"SET memory_limit = '{query_memory_limit()}'").fetchall()
    try:
        yield con
    finally:
        try:
            con.execute(f"SET memory_limit = '{write_memory_limit()}'").fetchall()
        except duckdb.Error:        # cannot free down to it now: keep the larger limit
            pass


# ----------------------------------------------------------------- schema --

def schema_version(con) -> str | None:
    """The schema version the warehouse open on ``con`` says it has (None: no
    schema_info table or no version in it, i.e. an empty warehouse)."""
    have = con.execute("SELECT count(*) FROM information_schema.tables "
                       "WHERE table_name = 'schema_info'").fetchall()[0][0]
    if not have:
        return None
    row = con.execute("SELECT value FROM schema_info WHERE key = 'schema_version'").fetchall()
    return row[0][0] if row else None


def check_schema_version(con, path) -> None:
    """Raise WarehouseError (one line) unless the open warehouse is empty or written with
    this SCHEMA_VERSION.  Every reader and writer calls it before touching tables, so an
    old warehouse gets a sentence, never a traceback about a missing column."""
    have = schema_version(con)
    if have is not None and have != SCHEMA_VERSION:
        older = have < SCHEMA_VERSION
        raise WarehouseError(
            f"warehouse {path} has schema version {have}, this accelcal uses "
            f"{SCHEMA_VERSION}: " + (
                ("upgrade it with `accelcal migrate -w WAREHOUSE` (it keeps a copy of the "
                 "old file), or process its drops again into a new warehouse"
                 if have in ("2", "3") else
                 "process its drops again into a new warehouse (the raw drops are never "
                 "changed; results are recomputed exactly)") if older else
                "it was written by a newer accelcal; upgrade accelcal to read it"))


# -------------------------------------------------------------- warehouse --

class Warehouse:
    """A DuckDB warehouse file plus its Parquet store and Data Docs, side by side.

    ``lab.duckdb`` -> ``lab-parquet/`` (run data), ``lab-datadocs/<drop>/`` (GE docs),
    ``lab-extras/`` (results' extras, :func:`write_extras`), ``lab.duckdb.lock`` (writer
    lock).
    """

    def __init__(self, path: str | Path, lock_timeout: float = 60.0):
        self.path = Path(path).expanduser().resolve()
        self.root = self.path.parent
        self.parquet_root = self.root / f"{self.path.stem}-parquet"
        self.docs_root = self.root / f"{self.path.stem}-datadocs"
        self.extras_root = self.root / f"{self.path.stem}-extras"   # or schema_info's
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
                con.execute(f"SET memory_limit = '{write_memory_limit()}'").fetchall()
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
        if need is not None and size < need and not self._all_blocks_readable(path):
            raise WarehouseError(
                f"warehouse {path} is truncated ({size:,} bytes; its header needs {need:,}); it "
                "was not modified (restore it from a backup or its -snapshot.duckdb copy)")

    @staticmethod
    def _all_blocks_readable(path: Path) -> bool:
        """Whether every row of every table can be read (read-only).  Asked only when the
        file is shorter than its header's block count: DuckDB cuts free blocks off the
        end of the file at a checkpoint (seen at 1,000 campaigns: 172 of 229 blocks on
        disk, 74 free) without lowering that count, so the size alone cannot tell a
        truncated file from a sound one.  A truncated file fails on a missing block."""
        try:
            con = duckdb.connect(str(path), read_only=True)
        except duckdb.IOException as e:
            return "lock" in str(e).lower()     # open in a writer: not ours to judge here
        except duckdb.Error:
            return False
        try:
            for (t,) in con.execute("SELECT table_name FROM information_schema.tables "
                                    "WHERE table_type = 'BASE TABLE'").fetchall():
                con.execute(f'SELECT bit_xor(hash(x)) FROM "{t}" AS x').fetchall()
            return True
        except duckdb.Error:
            return False
        finally:
            con.close()

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
                + remove_stale_temps(self.parquet_root) + remove_stale_temps(self.extras_root))

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
            os.chmod(self.snapshot_path, 0o444 & ~current_umask())
        except OSError as e:
            raise WarehouseError(os_error_text(e, f"cannot publish the snapshot {self.snapshot_path}")) from None
        return self.snapshot_path

    def _apply_schema(self, con) -> None:
        sql = resources.files("accelcal.warehouse").joinpath("schema.sql").read_text()
        check_schema_version(con, self.path)
        with _transaction(con):
            con.execute(sql)
            # operations views (fleet, history, rig comparison): read history tables only
            apply_views(con)
            con.execute("INSERT INTO schema_info VALUES ('schema_version', ?) "
                        "ON CONFLICT DO NOTHING", [SCHEMA_VERSION])
            con.execute("INSERT INTO schema_info VALUES (?, ?) ON CONFLICT DO NOTHING",
                        [EXTRAS_DIR_KEY, self.extras_root.name])
        self.extras_root = extras_root_of(con, self.path)
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

        Columnar: what the warehouse already knows about the batch is read in four
        set queries, the rows are decided in Python in record order (as one record at
        a time would), and each table gets one Arrow insert.
        """
        with self.connect() as con, _transaction(con):
            self._record_runs(con, records, flow_run_id, checkpoint)
        return records

    @staticmethod
    def _record_runs(con, records: list[RunRecord], flow_run_id, checkpoint) -> None:
        if not records:
            return
        keys = _arrow({"sha256": [r.sha256 for r in records],
                       "source_path": [r.source_path for r in records],
                       "run_id": [r.run_id for r in records],
                       "validator_version": [r.validator_version for r in records]})
        with _registered(con, "_rec_keys", keys):
            known = dict(((s, p), rev) for s, p, rev in con.execute(
                "SELECT f.sha256, f.source_path, f.revision FROM run_files f "
                "JOIN (SELECT DISTINCT sha256, source_path FROM _rec_keys) k "
                "USING (sha256, source_path)").fetchall())
            seen_sha = {s for (s,) in con.execute(
                "SELECT DISTINCT sha256 FROM run_files "
                "WHERE sha256 IN (SELECT sha256 FROM _rec_keys)").fetchall()}
            same_rev = {(r, s): m for r, s, m in con.execute(
                "SELECT run_id, sha256, max(revision) FROM run_files "
                "WHERE (run_id, sha256) IN (SELECT (run_id, sha256) FROM _rec_keys "
                "WHERE run_id IS NOT NULL) GROUP BY run_id, sha256").fetchall()}
            top_rev = dict(con.execute(
                "SELECT run_id, max(revision) FROM run_files "
                "WHERE run_id IN (SELECT run_id FROM _rec_keys WHERE run_id IS NOT NULL) "
                "GROUP BY run_id").fetchall())
            have_verdict = set(con.execute(
                "SELECT v.sha256, v.source_path, v.validator_version FROM run_verdicts v "
                "JOIN (SELECT DISTINCT sha256, source_path, validator_version FROM _rec_keys) k "
                "USING (sha256, source_path, validator_version)").fetchall())
        # decide, in record order, exactly what one-at-a-time inserts would have done
        batch_rev: dict[tuple[str, str], int] = {}
        batch_max: dict[str, int] = {}
        new_files: list[RunRecord] = []
        new_verdicts: list[RunRecord] = []
        for rec in records:
            key = (rec.sha256, rec.source_path)
            if key in known:
                rec.revision, rec.new = known[key], False
            else:
                rec.new_content = rec.sha256 not in seen_sha
                if rec.run_id is not None:
                    rk = (rec.run_id, rec.sha256)
                    if rk in batch_rev:
                        rec.revision = batch_rev[rk]
                    elif same_rev.get(rk) is not None:
                        rec.revision = same_rev[rk]
                    else:
                        top = top_rev.get(rec.run_id) or 0
                        rec.revision = max(top, batch_max.get(rec.run_id, 0)) + 1
                    batch_rev[rk] = rec.revision
                    batch_max[rec.run_id] = max(batch_max.get(rec.run_id, 0), rec.revision)
                new_files.append(rec)
                known[key] = rec.revision
                seen_sha.add(rec.sha256)
                rec.new = True
            vkey = (rec.sha256, rec.source_path, rec.validator_version)
            if vkey not in have_verdict:
                have_verdict.add(vkey)
                new_verdicts.append(rec)
                rec.rechecked = not rec.new
        if new_files:
            _insert(con, "run_files", {
                **_attr_columns(new_files, (
                    "sha256", "source_path", "drop_name", "drop_path", "run_id", "revision",
                    "test", "unit_serial", "unit_model", "campaign", "rig_id", "started_at",
                    "size_bytes")),
                "ingested_at": None,
                "flow_run_id": [flow_run_id] * len(new_files),
                "simulated": [bool(r.simulated) for r in new_files]})
        if new_verdicts:
            _insert(con, "run_verdicts", {
                **_attr_columns(new_verdicts, ("sha256", "source_path", "validator_version",
                                               "status", "reason", "n_rows", "parquet_path")),
                "seq": _nextvals(con, "verdict_seq", len(new_verdicts)),
                "checked_at": None,
                "flow_run_id": [flow_run_id] * len(new_verdicts)})
            refused = [(r, j, rf) for r in new_verdicts for j, rf in enumerate(r.refusals)]
            if refused:
                _insert(con, "refusals", {
                    "sha256": [r.sha256 for r, _, _ in refused],
                    "source_path": [r.source_path for r, _, _ in refused],
                    "validator_version": [r.validator_version for r, _, _ in refused],
                    "seq": [j for _, j, _ in refused],
                    "line": [rf.line for _, _, rf in refused],
                    "rule": [rf.rule for _, _, rf in refused],
                    "detail": [rf.detail for _, _, rf in refused]})
        for i in range(len(records)):
            _cp(checkpoint, f"run:{i}")

    def latest_verdicts(self, source_prefix: str) -> dict[tuple[str, str], "KnownFile"]:
        """(sha256, source_path) -> its latest verdict (:class:`KnownFile`), for the files
        below a folder: what the ``runs`` view says of them, with the verdicts and files
        taken below the folder first, so a drop costs its own files, not the warehouse's
        (the view's window over every verdict cost ~40 ms a drop at 2,000 campaigns)."""
        with self.connect() as con:
            rows = con.execute(
                "SELECT v.sha256, v.source_path, v.validator_version, v.status, v.reason, f.campaign "
                "FROM run_verdicts v JOIN run_files f USING (sha256, source_path) "
                "WHERE starts_with(v.source_path, ?) AND starts_with(f.source_path, ?) "
                "QUALIFY row_number() OVER (PARTITION BY v.sha256, v.source_path ORDER BY v.seq DESC) = 1",
                [source_prefix, source_prefix]).fetchall()
        return {(a, b): KnownFile(a, b, *rest) for a, b, *rest in rows}

    def stored_runs(self, keys: list[tuple[str, str]]) -> list[dict[str, Any]]:
        """Run records by (sha256, source_path), as the ``runs`` view has them: the file's
        row with its latest verdict (the status and reason of the newest validator that
        judged it), in path order."""
        if not keys:
            return []
        tbl = _arrow({"sha256": [k[0] for k in keys], "source_path": [k[1] for k in keys]})
        with self.connect() as con, _registered(con, "_run_keys", tbl):
            cur = con.execute(
                """SELECT r.* FROM runs r JOIN _run_keys k USING (sha256, source_path)
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
        with self.connect() as con, roomy(con):
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
        with self.connect() as con, roomy(con):
            return dict(con.execute(
                f"""SELECT campaign, count(DISTINCT run_id) FROM run_revisions
                    WHERE list_contains(?, campaign) AND simulated AND status = 'accepted'
                      AND sha256 NOT IN (SELECT sha256 FROM ({_PLAN_RUNS}))
                    GROUP BY campaign""", [list(campaigns), list(campaigns)]).fetchall())

    def campaign_dates(self, campaigns: list[str]) -> dict[str, tuple[str, Any, bool]]:
        """Campaign -> (unit serial, start of its first current run, every run simulated)."""
        with self.connect() as con, roomy(con):
            return _priors.campaign_dates(con, _PLAN_RUNS, campaigns)

    def unit_priors(self, dates: dict[str, tuple[str, Any, bool]]) -> dict[str, dict[str, dict[str, Any]]]:
        """Campaign -> coefficient -> the unit's last earlier calibration of it
        (:func:`accelcal.warehouse.priors.unit_priors`; ``dates`` from :meth:`campaign_dates`)."""
        with self.connect() as con, roomy(con):
            return _priors.unit_priors(con, dates)

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
        return self.store_results([(result, result_id, inputs)], code_version=code_version,
                                  parameters=parameters, flow_run_id=flow_run_id,
                                  checkpoint=checkpoint)[0]

    def store_results(self, items: list[tuple], *, code_version: str,
                      parameters: dict[str, Any], flow_run_id: str | None,
                      checkpoint: Checkpoint = None,
                      own_parameters: dict[str, dict[str, Any]] | None = None) -> list[str]:
        """Store several (CampaignResult, result_id, inputs) with their lineage in ONE
        transaction: all of them or none.  Each gets the status :meth:`store_result`
        would have given it, stored one after the other in this order.  A result_id in
        ``own_parameters`` is stored with those parameters instead of ``parameters`` (a
        campaign held at its unit's priors: they enter its result_id).

        Columnar: the warehouse's state for the batch is read in three set queries, the
        statuses are decided in Python in order, and every table gets one Arrow insert.
        """
        params_json = canonical_json(parameters)
        with self.connect() as con, _transaction(con):
            return write_results(con, items, code_version, params_json, flow_run_id,
                                 checkpoint, self.extras_root,
                                 {rid: canonical_json(p) for rid, p in (own_parameters or {}).items()})

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


def ensure_views(warehouse: str | Path, lock_timeout: float = 60.0) -> None:
    """Apply the registered views (:mod:`accelcal.warehouse.views`) to a warehouse file
    (write connection, holds the lock)."""
    wh = Warehouse(warehouse, lock_timeout=lock_timeout)
    with wh.connect() as con:
        apply_views(con)
