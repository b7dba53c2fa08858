"""Step 1: ingest a drop -- discover, hash, parse, write Parquet.  Plain functions.

The raw files are only read.  Files already in the warehouse (same bytes at the
same path) are not parsed again: their stored record stands.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..provenance import metadata_lines, simulated_line
from ..warehouse.db import Refusal, RunRecord
from ..warehouse.lineage import validator_version
from . import contracts, progress

_SNIFF_KEYS = ("run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id", "started_at")


@dataclass
class DropIngest:
    drop_name: str
    drop_path: str
    keys: list[tuple[str, str]] = field(default_factory=list)       # (sha256, source_path), all files
    records: list[RunRecord] = field(default_factory=list)          # files not yet in the warehouse
    parsed: dict[str, Any] = field(default_factory=dict)            # source_path -> RunFile
    errors: list[str] = field(default_factory=list)                 # unexpected failures (not recorded)
    known: int = 0
    #: simulated files not taken into the warehouse (no --allow-simulated): path, line
    simulated_held: list[dict[str, Any]] = field(default_factory=list)
    docs: str | None = None
    seconds: float = 0.0                                            # time spent in the step(s)


def sniff_meta(raw: bytes) -> dict[str, str]:
    """Best-effort metadata of a refused file (so the operator sees which run it was)."""
    out: dict[str, str] = {}
    for _, key, value in metadata_lines(raw):
        if key in _SNIFF_KEYS and key not in out and value:
            out[key] = value[:200]
    return out


def _relative(path: Path, root: Path) -> str:
    try:
        return os.path.relpath(path, root)
    except ValueError:
        return str(path)


def ingest_drop(drop_dir: str, parquet_root: str, warehouse_root: str,
                known: dict[tuple[str, str], str] | None = None,
                allow_simulated: bool = False) -> DropIngest:
    """Discover, hash, parse and write Parquet for the files of one drop.

    ``known`` maps files already recorded to the validator version of their
    latest verdict; those checked by the current version are skipped.
    """
    paths = contracts.discover(Path(drop_dir).resolve())
    progress.stage("ingest", len(paths))
    return ingest_files(drop_dir, paths, parquet_root, warehouse_root, known, allow_simulated)


def ingest_files(drop_dir: str, paths: list, parquet_root: str, warehouse_root: str,
                 known: dict[tuple[str, str], str] | None = None,
                 allow_simulated: bool = False) -> DropIngest:
    """:func:`ingest_drop` for some of the drop's files (the pipeline streams a drop in
    batches of these, so memory does not grow with the drop).

    A file that carries the simulator's mark (accelcal.provenance) is not taken in
    unless ``allow_simulated``: it is listed in ``simulated_held`` and nothing of it is
    written (no Parquet, no record), so a later run with the flag still sees it as new."""
    known = known or {}
    vv = validator_version()
    drop = Path(drop_dir).resolve()
    out = DropIngest(drop_name=drop.name, drop_path=str(drop))
    DropFormatError = contracts.drop_format_error()
    for p in paths:
        src = str(Path(p).resolve())
        try:
            raw = Path(src).read_bytes()
        except OSError as e:
            out.errors.append(f"{src}: cannot read: {e.strerror}")
            progress.advance("ingest")
            continue
        sha = hashlib.sha256(raw).hexdigest()
        out.keys.append((sha, src))
        if known.get((sha, src)) == vv:
            out.known += 1
            progress.advance("ingest", note=Path(src).name)
            continue
        sim_line = simulated_line(raw)
        if sim_line is not None and not allow_simulated:
            out.keys.pop()
            out.simulated_held.append({"path": src, "line": sim_line})
            progress.advance("ingest", note=Path(src).name)
            continue
        base = dict(sha256=sha, source_path=src, drop_name=out.drop_name,
                    drop_path=out.drop_path, size_bytes=len(raw), validator_version=vv,
                    simulated=sim_line is not None)
        try:
            run = contracts.read_run(src)
        except DropFormatError as e:
            meta = sniff_meta(raw)
            out.records.append(RunRecord(
                **base, status="refused",
                refusals=[Refusal(rule=e.rule, detail=e.detail, line=e.line, path=e.path)],
                **{k: meta.get(k) for k in _SNIFF_KEYS}))
            progress.advance("ingest", note=Path(src).name)
            continue
        except Exception as e:  # a parser bug: report, do not record a verdict
            out.keys.pop()
            out.errors.append(f"{src}: parser failed: {type(e).__name__}: {e}")
            progress.advance("ingest")
            continue
        if run.sha256 != sha:   # the file changed under our feet
            out.keys.pop()
            out.errors.append(f"{src}: changed while being read; not ingested")
            progress.advance("ingest")
            continue
        pq = contracts.write_run_parquet(run, parquet_root)
        m = run.meta
        out.records.append(RunRecord(
            **base, status="accepted", run_id=str(m["run_id"]), test=str(m["test"]),
            unit_serial=str(m["unit_serial"]), unit_model=str(m.get("unit_model", "")),
            campaign=str(m["campaign"]), rig_id=str(m.get("rig_id", "")),
            started_at=str(run.meta_raw.get("started_at", m.get("started_at", ""))),
            n_rows=int(len(run.data)), parquet_path=_relative(Path(pq), Path(warehouse_root))))
        out.parsed[src] = run
        progress.advance("ingest", note=Path(src).name)
    return out
