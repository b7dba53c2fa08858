"""Step 1: ingest a drop -- discover, hash, parse, write Parquet.  Plain functions.

The raw files are only read, never followed out of the drop (``O_NOFOLLOW``), never
waited on (``O_NONBLOCK``: a FIFO cannot hang a run).  Files already in the warehouse
(same bytes at the same path) are not parsed again: their stored record stands.

One file never costs another: whatever one file does -- an OS error, a link, a FIFO, a
name that is not UTF-8, bytes that break the format -- is that file's refusal (rule, path
as UTF-8 text, reason), recorded, and the batch goes on.  A file still being written is
held back (not read, not recorded: the next run takes it).  What is not the file's fault
-- the Parquet store cannot be written (disk full, read-only) -- raises StoreError and
stops the run: no verdict is recorded for a file that was not judged.
"""
from __future__ import annotations

import hashlib
import io
import os
import stat
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..provenance import metadata_lines, simulated_line
from ..fileio import StoreError, os_error_text, path_text, sha256_fd, sync_files
from ..warehouse.db import Refusal, RunRecord
from ..warehouse.lineage import validator_version
from ..schemas import dropformat, dropscan, dropspec, tables
from ..schemas.dropspec import SMALL_FILE
from . import progress

_SNIFF_KEYS = ("run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id", "started_at")
_OPEN_FLAGS = os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | \
    getattr(os, "O_CLOEXEC", 0)


@dataclass
class DropIngest:
    drop_name: str
    drop_path: str
    keys: list[tuple[str, str]] = field(default_factory=list)       # (sha256, source_path), all files
    records: list[RunRecord] = field(default_factory=list)          # files not yet in the warehouse
    parsed: dict[str, Any] = field(default_factory=dict)            # source_path -> RunFile
    errors: list[str] = field(default_factory=list)                 # bugs: not judged, not recorded
    held: list[str] = field(default_factory=list)                   # still being written: next run
    known: int = 0
    #: simulated files not taken into the warehouse (no --allow-simulated): path, line
    simulated_held: list[dict[str, Any]] = field(default_factory=list)
    docs: str | None = None
    seconds: float = 0.0                                            # time spent in the step(s)
    #: the same time by step ("ingest": hash + parse + Parquet, "validate": the suites),
    #: and the CPU seconds of the whole ("ingest+validate cpu", the process's, all threads)
    stage_seconds: dict[str, float] = field(default_factory=dict)


def sniff_meta(raw: bytes) -> dict[str, str]:
    """Best-effort metadata of a refused file (so the operator sees which run it was)."""
    out: dict[str, str] = {}
    for _, key, value in metadata_lines(raw):
        if key in _SNIFF_KEYS and key not in out and value:
            out[key] = value[:200]
    return out


def entry_digest(rule: str, detail: str) -> str:
    """The sha256 recorded for an entry refused without its bytes being read (a link, a
    FIFO, an unreadable file): a hash of what was seen, so a re-run finds the same key
    and records nothing new, while a change (another link target) is a new record."""
    return hashlib.sha256(f"accelcal-entry\0{rule}\0{detail}".encode("utf-8", "backslashreplace")
                          ).hexdigest()


def _relative(path: Path, root: Path) -> str:
    try:
        return os.path.relpath(path, root)
    except ValueError:
        return str(path)


def _entries(paths) -> list:
    E = dropscan.Entry
    return [p if isinstance(p, E) else E(os.fspath(p)) for p in paths]


def ingest_drop(drop_dir: str, parquet_root: str, warehouse_root: str,
                known: dict[tuple[str, str], str] | None = None,
                allow_simulated: bool = False) -> DropIngest:
    """Discover, hash, parse and write Parquet for the files of one drop.

    ``known`` maps files already recorded to the validator version of their
    latest verdict; those checked by the current version are skipped.
    """
    entries = dropscan.scan_drop(os.path.realpath(drop_dir))
    progress.stage("ingest", len(entries))
    return ingest_files(drop_dir, entries, parquet_root, warehouse_root, known, allow_simulated)


class _Held(Exception):
    """The file changed while it was looked at: not judged this time."""


def ingest_files(drop_dir: str, paths: list, parquet_root: str, warehouse_root: str,
                 known: dict[tuple[str, str], str] | None = None,
                 allow_simulated: bool = False) -> DropIngest:
    """:func:`ingest_drop` for some of the drop's entries (Entry objects from
    ``scan_drop``, or paths); the pipeline streams a drop in batches of these, so memory
    does not grow with the drop.

    A file that carries the simulator's mark (accelcal.provenance) is not taken in
    unless ``allow_simulated``: it is listed in ``simulated_held`` and nothing of it is
    written (no Parquet, no record), so a later run with the flag still sees it as new."""
    known = known or {}
    vv = validator_version()
    drop = os.path.realpath(drop_dir)
    out = DropIngest(drop_name=path_text(os.path.basename(drop)), drop_path=path_text(drop))
    DropFormatError = dropspec.DropFormatError

    writes: list[tuple[str, RunRecord, Any]] = []      # (source, its record, Parquet write)
    pending = _Pending()

    def refuse(src: str, sha: str, size: int, rule: str, detail: str, line=None,
               raw: bytes = b"") -> None:
        pending.flush()             # the files before it are recorded first, as read
        meta = sniff_meta(raw) if raw else {}
        out.keys.append((sha, src))
        if known.get((sha, src)) == vv:
            out.known += 1
            return
        out.records.append(RunRecord(
            sha256=sha, source_path=src, drop_name=out.drop_name, drop_path=out.drop_path,
            size_bytes=max(int(size), 0), validator_version=vv, status="refused",
            refusals=[Refusal(rule=rule, detail=detail, line=line, path=src)],
            simulated=bool(raw) and simulated_line(raw) is not None,
            **{k: meta.get(k) for k in _SNIFF_KEYS}))

    with ThreadPoolExecutor(PARQUET_WRITERS, thread_name_prefix="accelcal-parquet") as pool:
        pending.take = lambda items: _take_parsed(items, out, refuse, parquet_root, pool, writes)
        for e in _entries(paths):
            _ingest_entry(e, out, known, vv, parquet_root, warehouse_root, DropFormatError,
                          refuse, allow_simulated, pool, writes, pending)
        pending.flush()
        _finish_writes(out, writes, parquet_root, warehouse_root)
    return out


#: Bytes of small files read and waiting to be parsed together (dropformat.parse_runs):
#: pyarrow's CSV reader costs ~0.2 ms a call, a run file's rows ~0.04 ms.
PENDING_BYTES = 8 << 20


class _Pending:
    """Small files read (hashed, checked unchanged, not known, not held) whose parse is
    put off until PENDING_BYTES of them are waiting, to parse them together.  Whatever
    else is recorded for the batch flushes them first, so records keep the files' order."""

    def __init__(self):
        self.items: list[tuple] = []      # (src, raw, head, base)
        self.nbytes = 0
        self.take = None

    def add(self, item) -> None:
        self.items.append(item)
        self.nbytes += len(item[1])
        if self.nbytes > PENDING_BYTES:
            self.flush()

    def flush(self) -> None:
        items, self.items, self.nbytes = self.items, [], 0
        if items:
            self.take(items)


def _take_parsed(items, out, refuse, parquet_root, pool, writes) -> None:
    """Parse the pending files together and record each as :func:`_ingest_open_file` does
    a file parsed alone.  A bug in the joint parse costs no file: each is parsed alone."""
    try:
        results = dropformat.parse_runs([(raw, src) for src, raw, _, _ in items])
    except Exception:
        results = None
    DropFormatError = dropspec.DropFormatError
    for k, (src, raw, head, base) in enumerate(items):
        try:
            if results is None:
                res = dropformat.parse_runs([(raw, src)])[0]
            else:
                res = results[k]
            if isinstance(res, BaseException):
                if not isinstance(res, DropFormatError):
                    raise res
                refuse(src, base["sha256"], base["size_bytes"], res.rule, res.detail, res.line, head)
                continue
            if res.sha256 != base["sha256"]:
                raise RuntimeError("the parser's sha256 is not that of the bytes read")
            _accept(res, base, out, parquet_root, pool, writes)
        except StoreError:
            raise
        except Exception as err:   # a bug in the parser or here: report, record no verdict
            _forget(out, src)
            out.errors.append(f"{src}: not ingested: {type(err).__name__}: {err}")


#: Parquet files of a batch written at once, beside the parsing of the next files (pyarrow
#: encodes and compresses without the GIL).  Each is renamed into place when written
#: (fileio.atomic_write); the batch's files are then made durable by one flush
#: (fileio.sync_files) before the batch's verdicts are returned, so nothing the warehouse
#: records refers to a file that a power loss could take back.  (An fsync per file cost
#: ~3.5 ms a file here.)  Two threads: building a run's Arrow table holds the GIL, and with
#: 8 writers the threads queued for it cost more CPU and more wall time than 2
#: (intake_batch on 550 simulated files, 2 cores, two runs: 2.7 and 3.0 ms of CPU a file
#: with 2 writers, 3.1 and 3.3 with 8; wall 2.0 and 2.3 against 2.5 and 2.6 ms).
PARQUET_WRITERS = 2


def _finish_writes(out: DropIngest, writes: list, parquet_root: str, warehouse_root: str) -> None:
    """Wait for the batch's Parquet writes; fill in each record's path.  The store that
    cannot be written stops the run (StoreError, as the first failure); a bug in one file's
    write costs that file only (reported, not recorded)."""
    store_error = None
    written: list = []
    for src, rec, fut in writes:
        try:
            pq = fut.result()
        except OSError as err:      # name the folder, not our temporary file in it
            if store_error is None:
                where = os.path.dirname(err.filename) if isinstance(err.filename, str) else parquet_root
                store_error = StoreError(os_error_text(OSError(err.errno, err.strerror, where),
                                                       "cannot write the Parquet store"))
            continue
        except Exception as err:
            _forget(out, src)
            out.errors.append(f"{src}: not ingested: {type(err).__name__}: {err}")
            continue
        rec.parquet_path = _relative(Path(pq), Path(warehouse_root))
        written.append(pq)
    if store_error is None:
        try:                    # durable before any verdict refers to them: one flush
            sync_files(written)
        except OSError as err:
            store_error = StoreError(os_error_text(OSError(err.errno, err.strerror, parquet_root),
                                                   "cannot write the Parquet store"))
    if store_error is not None:
        raise store_error from None


def _forget(out: DropIngest, src: str) -> None:
    out.keys = [k for k in out.keys if k[1] != src]
    out.records = [r for r in out.records if r.source_path != src]
    out.parsed.pop(src, None)


def _ingest_entry(e, out, known, vv, parquet_root, warehouse_root, DropFormatError, refuse,
                  allow_simulated, pool, writes, pending: "_Pending") -> None:
    src = path_text(e.path)
    name = os.path.basename(src)
    try:
        if e.refusal is not None:
            refuse(src, entry_digest(*e.refusal), e.size, *e.refusal)
            return
        try:
            fd = os.open(e.path, _OPEN_FLAGS)
        except OSError as err:
            rule, detail = _open_refusal(err)
            refuse(src, entry_digest(rule, detail), e.size, rule, detail)
            return
        try:
            _ingest_open_file(fd, e, src, out, known, vv, parquet_root, warehouse_root,
                              DropFormatError, refuse, allow_simulated, pool, writes, pending)
        finally:
            os.close(fd)
    except _Held as h:
        pending.flush()
        out.held.append(f"{src}: {h}")
    except StoreError:
        raise
    except Exception as err:   # a bug in the parser or here: report, record no verdict
        pending.flush()
        _forget(out, src)
        out.errors.append(f"{src}: not ingested: {type(err).__name__}: {err}")
    progress.advance("ingest", note=name)


def _open_refusal(err: OSError) -> tuple[str, str]:
    import errno
    if err.errno == errno.ELOOP:
        return "link", "a symbolic link (it appeared after the drop was listed): not followed"
    return "unreadable", f"cannot open: {err.strerror or err}"


def _ingest_open_file(fd, e, src, out, known, vv, parquet_root, warehouse_root,
                      DropFormatError, refuse, allow_simulated: bool, pool, writes,
                      pending: "_Pending") -> None:
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        detail = "not a regular file (it changed after the drop was listed)"
        refuse(src, entry_digest("not-a-file", detail), 0, "not-a-file", detail)
        return
    if e.size >= 0 and (st.st_size, st.st_mtime_ns) != (e.size, e.mtime_ns):
        raise _Held("changed since the drop was listed (still being written?): not read "
                    "this time")
    try:
        if st.st_size <= SMALL_FILE:
            raw = _read_all(fd, st.st_size)
            sha, size, head = hashlib.sha256(raw).hexdigest(), len(raw), raw
        else:
            raw = None
            sha, size = sha256_fd(fd)
            head = os.pread(fd, 65536, 0)
    except OSError as err:
        detail = f"cannot read: {err.strerror or err}"
        refuse(src, entry_digest("unreadable", detail), st.st_size, "unreadable", detail)
        return
    _check_unchanged(fd, st, size)
    if known.get((sha, src)) == vv:
        pending.flush()
        out.keys.append((sha, src))
        out.known += 1
        return
    sim_line = simulated_line(head)
    if sim_line is not None and not allow_simulated:
        pending.flush()
        out.simulated_held.append({"path": src, "line": sim_line})
        return
    base = dict(sha256=sha, source_path=src, drop_name=out.drop_name, drop_path=out.drop_path,
                size_bytes=size, validator_version=vv, simulated=sim_line is not None)
    if raw is not None:
        # the bytes are what was hashed, and the file did not change while read: its
        # parse can wait for the next files' (parsed together, _take_parsed)
        pending.add((src, raw, head, base))
        return
    # a big file's rows go to its Parquet file as they are parsed: the run is
    # never in memory whole; the file is put in place only once the bytes parsed are the
    # bytes hashed and the file did not change, else removed
    stream = tables.RunParquetStream(parquet_root, sha, size)
    try:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            with io.FileIO(fd, "rb", closefd=False) as fh:
                run = dropformat.parse_run(fh, src, stream)
        except DropFormatError as err:
            refuse(src, sha, size, err.rule, err.detail, err.line, head)
            return
        except StoreError:
            raise
        except OSError as err:
            detail = f"cannot read: {err.strerror or err}"
            refuse(src, sha, size, "unreadable", detail, None, head)
            return
        if run.sha256 != sha:
            raise _Held("changed while being read: not read this time")
        _check_unchanged(fd, st, size)
        written = stream.commit()
    finally:
        stream.abort()              # nothing once committed
    _accept(run, base, out, parquet_root, pool, writes, written)


def _accept(run, base: dict, out: DropIngest, parquet_root, pool, writes,
            written: Path | None = None) -> None:
    """Record an accepted run and start its Parquet write (``written``: the run's Parquet
    file, already written as it was parsed)."""
    src, sha = base["source_path"], base["sha256"]
    m = run.meta
    rec = RunRecord(
        **base, status="accepted", run_id=str(m["run_id"]), test=str(m["test"]),
        unit_serial=str(m["unit_serial"]), unit_model=str(m.get("unit_model", "")),
        campaign=str(m["campaign"]), rig_id=str(m.get("rig_id", "")),
        started_at=str(run.meta_raw.get("started_at", m.get("started_at", ""))),
        n_rows=run.n_rows)
    # the Parquet file is written beside the next files' reading; its path is filled in
    # when it is in place, before the batch returns (_finish_writes)
    if written is None:
        fut = pool.submit(tables.write_run_parquet, run, parquet_root)
    else:
        fut = Future()
        fut.set_result(written)
    writes.append((src, rec, fut))
    out.keys.append((sha, src))
    out.records.append(rec)
    out.parsed[src] = run


def _read_all(fd: int, size: int) -> bytes:
    chunks, n = [], 0
    while True:
        b = os.read(fd, max(size - n, 0) + 1)
        if not b:
            break
        chunks.append(b)
        n += len(b)
        if n > SMALL_FILE + 1:
            break
    return b"".join(chunks)


def _check_unchanged(fd: int, st: os.stat_result, size: int) -> None:
    now = os.fstat(fd)
    if size != st.st_size or (now.st_size, now.st_mtime_ns) != (st.st_size, st.st_mtime_ns):
        raise _Held("changed while being read (still being written?): not read this time")
