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
from pathlib import Path
from urllib.parse import quote

import pyarrow as pa
import pyarrow.parquet as pq

from ..fileio import atomic_write
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
        arrays = []
        for f in schema:
            if f.name in ("run_id", "sha256"):      # a constant: repeated in Arrow, no Python list
                arrays.append(pa.repeat(pa.scalar(getattr(run, f.name), pa.string()), b - a))
            else:
                arrays.append(pa.array(cols[f.name][a:b], type=f.type))
        yield pa.RecordBatch.from_arrays(arrays, schema=schema)


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


#: Rows of a run read back from Parquet after which Arrow's pool gives back what it freed.
BIG_READ_ROWS = 1 << 20


def read_run_parquet(path) -> RunFile:
    """Read back what :func:`write_run_parquet` wrote, as an equal RunFile."""
    pf = pq.ParquetFile(path)
    md = pf.schema_arrow.metadata or {}
    if META_KEY not in md:
        raise ValueError(f"{path}: not an accelcal run file (no {META_KEY.decode()} metadata)")
    info = json.loads(md[META_KEY])
    meta = info["meta"]
    test = str(meta["test"])
    table = pf.read(columns=list(COLUMNS[test]) + ["line"])
    # one column at a time, each Arrow buffer freed once converted: the run is in memory
    # once, not twice
    data = table.to_pandas(split_blocks=True, self_destruct=True)
    del table
    data = data[list(COLUMNS[test]) + ["line"]]
    if len(data) >= BIG_READ_ROWS:
        # Arrow's pool keeps what the conversion freed (60 MB of a 5 M-row run, issue 28)
        pa.default_memory_pool().release_unused()
    return RunFile(path=info["source_path"], sha256=info["sha256"], size_bytes=int(info["size_bytes"]),
                   meta=meta, meta_raw=info["meta_raw"], data=data,
                   header_line=int(info["header_line"]),
                   meta_lines={k: int(v) for k, v in info.get("meta_lines", {}).items()})
