"""Arrow/Parquet schemas of parsed runs and their Parquet files (docs/design.md, schemas;
drop-format.md "A run file" for the columns, "A drop" for re-exports and revisions).

One Parquet file per (run_id, sha256), content addressed, hive-style partitions::

    root/test=<test>/unit_serial=<serial>/<run_id>__<sha256[:16]>.parquet

A re-export with the same bytes maps to the same file (not rewritten); a revision
(same run_id, other bytes) gets its own file, so nothing is silently merged.
Writes are atomic (temporary file in the same folder + ``os.replace``).

The file keeps the run's metadata twice: as key-value file metadata
(``accelcal.run``: JSON of meta_raw, typed meta, meta_lines, sha256, source path,
size, header line) and as constant columns ``run_id`` and ``sha256``.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from urllib.parse import quote

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..fileio import AtomicFile, StoreError, atomic_write, os_error_text
from .dropformat import RunFile
from .dropspec import COLUMNS, INT_COLUMNS

#: Key of the JSON run metadata in the Parquet key-value metadata.
META_KEY = b"accelcal.run"
#: Version of what this module writes.
LAYOUT_VERSION = 1


def run_schema(test: str) -> pa.Schema:
    """Arrow schema of a run of ``test``: its columns (float64; step/position int64),
    ``line`` (int64), and the constant columns ``run_id``, ``sha256`` (string)."""
    fields = [pa.field(c, pa.int64() if c in INT_COLUMNS else pa.float64(), nullable=True)
              for c in COLUMNS[test]]
    fields += [pa.field("line", pa.int64(), nullable=False),
               pa.field("run_id", pa.string(), nullable=False),
               pa.field("sha256", pa.string(), nullable=False)]
    return pa.schema(fields)


#: Arrow schema per test kind.
SCHEMAS: dict[str, pa.Schema] = {t: run_schema(t) for t in COLUMNS}


#: Longest path component made from a value (bytes; file systems allow 255).
PART_MAX = 96


def _part(value: str) -> str:
    """A path component that is safe (percent-encoding) and short: a value whose encoding
    is longer than PART_MAX keeps its first characters and gets a hash of the whole value
    (``~<sha256[:16]>``), so a 300-byte run_id or serial cannot make a name the file
    system refuses.  Values of up to PART_MAX encoded bytes map as before."""
    q = quote(str(value), safe="-_+@")
    q = q.replace(".", "%2E") if q.strip(".") == "" or q.startswith(".") else q
    if len(q) > PART_MAX:
        head = q[:PART_MAX - 17]
        head = head[:head.rfind("%")] if "%" in head[-2:] else head
        q = f"{head}~{hashlib.sha256(str(value).encode('utf-8', 'surrogatepass')).hexdigest()[:16]}"
    return q or "%00"


def parquet_path(run: RunFile, root: Path) -> Path:
    """Where :func:`write_run_parquet` puts ``run`` under ``root`` (content addressed)."""
    return (Path(root) / f"test={_part(run.test)}" / f"unit_serial={_part(run.meta['unit_serial'])}"
            / f"{_part(run.run_id)}__{run.sha256[:16]}.parquet")


def _schema_with_metadata(run: RunFile) -> pa.Schema:
    info = {
        "layout_version": LAYOUT_VERSION, "source_path": run.path, "sha256": run.sha256,
        "size_bytes": run.size_bytes, "header_line": run.header_line, "meta_raw": run.meta_raw,
        "meta": run.meta, "meta_lines": run.meta_lines,
    }
    md = {META_KEY: json.dumps(info, sort_keys=False).encode("utf-8"),
          b"accelcal.run_id": run.run_id.encode("utf-8"),
          b"accelcal.sha256": run.sha256.encode("ascii")}
    return SCHEMAS[run.test].with_metadata(md)


#: Bytes of the constant columns (run_id, sha256) built per row group: a run of millions
#: of rows is written a row group at a time, so they never exist for the whole run.
_CONST_BYTES = 8 << 20


def _row_group_rows(run: RunFile) -> int:
    per_row = len(run.run_id.encode("utf-8")) + len(run.sha256) + 8
    return int(min(1 << 20, max(1024, _CONST_BYTES // per_row)))


def _batches(run: RunFile, schema: pa.Schema):
    cols = run.arrays
    n = run.n_rows
    step = _row_group_rows(run)
    for a in range(0, max(n, 1), step):
        b = min(a + step, n)
        yield _record_batch(run, schema, {c: v[a:b] for c, v in cols.items()}, b - a)


def _record_batch(run: RunFile, schema: pa.Schema, cols: dict, m: int) -> pa.RecordBatch:
    """``m`` rows of the run's columns ``cols`` as a batch of ``schema``."""
    arrays = []
    for f in schema:
        if f.name in ("run_id", "sha256"):      # a constant: repeated in Arrow, no Python list
            arrays.append(pa.repeat(pa.scalar(getattr(run, f.name), pa.string()), m))
        else:
            arrays.append(pa.array(cols[f.name], type=f.type))
    return pa.RecordBatch.from_arrays(arrays, schema=schema)


def run_table(run: RunFile) -> pa.Table:
    """The run as an Arrow table of :func:`run_schema` with the metadata attached."""
    schema = _schema_with_metadata(run)
    return pa.Table.from_batches(list(_batches(run, schema)), schema=schema)


def write_run_parquet(run: RunFile, root: Path) -> Path:
    """Write ``run`` under ``root`` (see module doc) and return the file's path.

    Idempotent: when the content-addressed file already exists, whole, it is left alone.
    Atomic: written to a temporary file in the target folder, then ``os.replace``-d, so a
    killed writer leaves no partial ``*.parquet`` (its ``.*.tmp`` is removed by the next
    run, accelcal.fileio.remove_stale_temps).  A long run is written a row group at a time.
    Not flushed to disk: the caller makes a batch of them durable at once
    (accelcal.fileio.sync_files) before anything refers to them.  A file cut short by a
    power loss before that flush is not whole (no Parquet footer) and is written again.
    """
    target = parquet_path(run, root)
    if _whole(target):
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    schema = _schema_with_metadata(run)

    def write(fh):
        if run.n_rows <= _row_group_rows(run):
            pq.write_table(pa.Table.from_batches(list(_batches(run, schema)), schema=schema), fh,
                           compression="zstd")
            return
        with pq.ParquetWriter(fh, schema, compression="zstd") as w:
            for batch in _batches(run, schema):
                w.write_batch(batch)
    atomic_write(target, write, "wb")
    return target


def _whole(path: Path) -> bool:
    """The file exists and ends with a readable Parquet footer."""
    try:
        pq.read_metadata(path)
    except FileNotFoundError:
        return False
    except Exception:
        return False
    return True


class RunParquetStream:
    """A run's Parquet file written as its raw file is parsed: the parser hands
    each chunk of rows over (:meth:`write`, one row group each) and keeps none, so a run
    file of any length is parsed in the memory of a chunk.  The file is the one
    :func:`write_run_parquet` writes -- same place, schema, metadata and values, in row
    groups of a chunk -- and as atomic: a temporary file renamed into place by
    :meth:`commit`, removed by :meth:`abort` (a refusal, a file that changed).  The
    run's sha256 and size are those of the ingest's hashing pass, read before the parse
    (the parser's own are compared with them before the commit).

    Parameters
    ----------
    root : path
        The Parquet store.
    sha256 : str
        sha256 of the raw file [hex].
    size_bytes : int
        Its size [byte].
    """

    def __init__(self, root, sha256: str, size_bytes: int):
        self.root, self.sha256, self.size_bytes = Path(root), sha256, int(size_bytes)
        self.head: RunFile | None = None
        self.target: Path | None = None
        self._file: AtomicFile | None = None
        self._writer = None

    def open(self, head: RunFile) -> None:
        """Start the file of ``head`` (the run's metadata, no rows).  A whole file already
        at its place (the same bytes ingested before) is left alone: nothing is written."""
        self.head, self.target = head, parquet_path(head, self.root)
        if _whole(self.target):
            return
        try:
            self.target.parent.mkdir(parents=True, exist_ok=True)
            self._file = AtomicFile(self.target)
            self._schema = _schema_with_metadata(head)
            self._writer = pq.ParquetWriter(self._file.fh, self._schema, compression="zstd")
        except OSError as err:
            self.abort()
            raise self._store_error(err) from None

    def write(self, cols: dict[str, np.ndarray], m: int) -> None:
        """Append ``m`` rows: the test's columns and ``line``, as the parser typed them."""
        if self._writer is None:
            return
        try:
            self._writer.write_batch(_record_batch(self.head, self._schema, cols, m))
        except OSError as err:
            self.abort()
            raise self._store_error(err) from None

    def commit(self) -> Path:
        """Close the file and put it in its place; its path."""
        if self._writer is not None:
            try:
                self._writer.close()
                self._writer = None
                self._file.commit()
            except OSError as err:
                self.abort()
                raise self._store_error(err) from None
        return self.target

    def columns(self, names, n_rows: int) -> "ParquetColumns":
        """The run's columns ``names`` in its file, read when asked for (after :meth:`commit`,
        or from the file already in place)."""
        return ParquetColumns(self.target, names, n_rows)

    def abort(self) -> None:
        """Remove the temporary file (nothing is left of an unfinished run)."""
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:
                pass
            self._writer = None
        if self._file is not None:
            self._file.abort()

    def _store_error(self, err: OSError) -> StoreError:
        where = self.target.parent if self.target is not None else self.root
        return StoreError(os_error_text(OSError(err.errno, err.strerror, str(where)),
                                        "cannot write the Parquet store"))


class ParquetColumns(Mapping):
    """A run's columns in its Parquet file, read when asked for and not kept:
    what ``RunFile.arrays`` is for a run parsed into its Parquet file
    (:class:`RunParquetStream`).  ``cols[c]`` reads column ``c`` whole (a numpy array,
    as the parser types it); :meth:`rows` reads rows ``lo`` to ``hi`` of it, from the row
    groups that hold them.

    Parameters
    ----------
    path : path
        The Parquet file.
    names : sequence of str
        Its run columns, in order (the test's columns and ``line``).
    n_rows : int
        Rows in the file [1].
    """

    def __init__(self, path, names, n_rows: int):
        self.path, self.names, self.n_rows = Path(path), list(names), int(n_rows)
        self._file: pq.ParquetFile | None = None
        self._starts: np.ndarray | None = None

    def __getitem__(self, c: str) -> np.ndarray:
        if c not in self.names:
            raise KeyError(c)
        return self.rows(c, 0, self.n_rows)

    def __contains__(self, c) -> bool:        # by name: Mapping's own would read the column
        return c in self.names

    def __iter__(self):
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def dtype(self, c: str) -> np.dtype:
        """The numpy type of column ``c`` (int64 for ``line`` and the integer columns)."""
        return np.dtype(np.int64) if c == "line" or c in INT_COLUMNS else np.dtype(np.float64)

    def rows(self, c: str, lo: int, hi: int) -> np.ndarray:
        """Rows ``lo`` to ``hi`` of column ``c``, read row group by row group into one
        array (the file's row groups are a parser chunk each)."""
        if self._file is None:
            # opened once, when first read (after the stream's commit): parsing the footer
            # of a 3 GB run (700 row groups) cost 3.7 ms a time, seven row-group reads
            self._file = pq.ParquetFile(self.path)
        pf = self._file
        if self._starts is None:
            md = pf.metadata
            self._starts = np.cumsum([0] + [md.row_group(i).num_rows
                                            for i in range(md.num_row_groups)])
        lo, hi = max(int(lo), 0), min(int(hi), self.n_rows)
        out = np.empty(max(hi - lo, 0), self.dtype(c))
        if hi <= lo:
            return out
        first = int(np.searchsorted(self._starts, lo, side="right")) - 1
        last = int(np.searchsorted(self._starts, hi, side="left"))
        for g in range(first, last):
            a, b = int(self._starts[g]), int(self._starts[g + 1])
            part = pf.read_row_group(g, columns=[c]).column(0).to_numpy()
            s, e = max(lo, a), min(hi, b)
            out[s - lo:e - lo] = part[s - a:e - a]
        return out


#: Rows of a run read back from Parquet after which Arrow's pool gives back what it freed.
BIG_READ_ROWS = 1 << 20


def read_run_parquet(path, blocks=None) -> RunFile:
    """Read back what :func:`write_run_parquet` wrote, as an equal RunFile.

    ``blocks``: a function ``blocks(test, n_rows, columns)`` of the run's test, its rows
    and its :class:`ParquetColumns`, giving the columns the run is to be taken as (a dict
    of arrays, and what to add to its metadata) or None to read it as it is: the science's
    block means of a long run (:func:`accelcal.fitting.data.block_means`), made
    from the file a column and a slice at a time."""
    pf = pq.ParquetFile(path)
    md = pf.schema_arrow.metadata or {}
    if META_KEY not in md:
        raise ValueError(f"{path}: not an accelcal run file (no {META_KEY.decode()} metadata)")
    info = json.loads(md[META_KEY])
    meta = info["meta"]
    test = str(meta["test"])
    names = list(COLUMNS[test]) + ["line"]
    taken = None if blocks is None else blocks(test, pf.metadata.num_rows,
                                               ParquetColumns(path, names, pf.metadata.num_rows))
    if taken is not None:
        data, more = taken
        meta = {**meta, **more}
    else:
        # numpy views of Arrow's buffers (copies only where a column has nulls or several
        # chunks): the run is in memory once, and no DataFrame is made unless one is asked
        # for (RunFile.data makes it from these arrays; the science reads the arrays)
        table = pf.read(columns=names)
        data = {c: table.column(c).to_numpy() for c in names}
        del table
        if pf.metadata.num_rows >= BIG_READ_ROWS:
            # Arrow's pool keeps what the copies freed (a column with nulls is copied)
            pa.default_memory_pool().release_unused()
    return RunFile(path=info["source_path"], sha256=info["sha256"], size_bytes=int(info["size_bytes"]),
                   meta=meta, meta_raw=info["meta_raw"], data=data,
                   header_line=int(info["header_line"]),
                   meta_lines={k: int(v) for k, v in info.get("meta_lines", {}).items()})
