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

import json
from pathlib import Path
from urllib.parse import quote

import pyarrow as pa
import pyarrow.parquet as pq

from ..fileio import atomic_write
from .dropformat import COLUMNS, INT_COLUMNS, RunFile

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


def _part(value: str) -> str:
    """A path component that is safe and reversible (percent-encoding)."""
    q = quote(str(value), safe="-_+@")
    q = q.replace(".", "%2E") if q.strip(".") == "" or q.startswith(".") else q
    return q or "%00"


def parquet_path(run: RunFile, root: Path) -> Path:
    """Where :func:`write_run_parquet` puts ``run`` under ``root`` (content addressed)."""
    return (Path(root) / f"test={_part(run.test)}" / f"unit_serial={_part(run.meta['unit_serial'])}"
            / f"{_part(run.run_id)}__{run.sha256[:16]}.parquet")


def run_table(run: RunFile) -> pa.Table:
    """The run as an Arrow table of :func:`run_schema` with the metadata attached."""
    schema = SCHEMAS[run.test]
    n = len(run.data)
    arrays = []
    for f in schema:
        if f.name == "run_id":
            arrays.append(pa.array([run.run_id] * n, pa.string()))
        elif f.name == "sha256":
            arrays.append(pa.array([run.sha256] * n, pa.string()))
        else:
            arrays.append(pa.array(run.data[f.name].to_numpy(), type=f.type))
    info = {
        "layout_version": LAYOUT_VERSION, "source_path": run.path, "sha256": run.sha256,
        "size_bytes": run.size_bytes, "header_line": run.header_line, "meta_raw": run.meta_raw,
        "meta": run.meta, "meta_lines": run.meta_lines,
    }
    md = {META_KEY: json.dumps(info, sort_keys=False).encode("utf-8"),
          b"accelcal.run_id": run.run_id.encode("utf-8"),
          b"accelcal.sha256": run.sha256.encode("ascii")}
    return pa.Table.from_arrays(arrays, schema=schema.with_metadata(md))


def write_run_parquet(run: RunFile, root: Path) -> Path:
    """Write ``run`` under ``root`` (see module doc) and return the file's path.

    Idempotent: when the content-addressed file already exists it is left alone.
    Atomic: written to a temporary file in the target folder, then ``os.replace``-d, so a
    killed writer leaves no partial ``*.parquet``.
    """
    target = parquet_path(run, root)
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    table = run_table(run)
    atomic_write(target, lambda fh: pq.write_table(table, fh, compression="zstd"), "wb", fsync=True)
    return target


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
    data = table.to_pandas()
    data = data[list(COLUMNS[test]) + ["line"]]
    return RunFile(path=info["source_path"], sha256=info["sha256"], size_bytes=int(info["size_bytes"]),
                   meta=meta, meta_raw=info["meta_raw"], data=data,
                   header_line=int(info["header_line"]),
                   meta_lines={k: int(v) for k, v in info.get("meta_lines", {}).items()})
