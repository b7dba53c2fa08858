"""Parquet tests (accelcal.schemas.tables): round trip, idempotency, revisions, atomic write."""
from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from accelcal.schemas import tables
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover
from accelcal.schemas.dropspec import COLUMNS
from accelcal.schemas.tables import (META_KEY, SCHEMAS, parquet_path, read_run_parquet,
                                     write_run_parquet)

from conftest import EXAMPLES, require_shared  # ../shared/examples relative to the repository root

require_shared()
ALL = [p for d in ("drop-2026-11-18-thermal", "drop-2026-11-19-sine", "drop-2026-11-20",
                   "drop-2026-11-21") for p in discover(EXAMPLES / d)] + [EXAMPLES / "drop-bad/nan-output.csv"]


def test_round_trip_every_example(tmp_path):
    seen = set()
    for p in ALL:
        r = read_run(p)
        q = write_run_parquet(r, tmp_path)
        assert q not in seen
        seen.add(q)
        assert q == tmp_path / f"test={r.test}" / f"unit_serial={r.meta['unit_serial']}" / \
            f"{r.run_id}__{r.sha256[:16]}.parquet"
        back = read_run_parquet(q)
        assert back == r, p
        assert back.meta == r.meta and back.data.dtypes.equals(r.data.dtypes)
        # metadata twice: key-value file metadata and constant columns
        pf = pq.ParquetFile(q)
        info = json.loads(pf.schema_arrow.metadata[META_KEY])
        assert info["meta_raw"] == r.meta_raw and info["sha256"] == r.sha256
        assert info["source_path"] == str(p)
        t = pf.read(columns=["run_id", "sha256"])
        assert set(t.column("run_id").to_pylist()) == {r.run_id}
        assert set(t.column("sha256").to_pylist()) == {r.sha256}
        assert pf.schema_arrow.remove_metadata().equals(SCHEMAS[r.test])
    assert not list(tmp_path.rglob("*.tmp"))


def test_nan_survives(tmp_path):
    r = read_run(EXAMPLES / "drop-2026-11-20/centrifuge/LXJ100-20261120-0002.csv")
    assert r.data["table_angle_deg"].isna().any()
    back = read_run_parquet(write_run_parquet(r, tmp_path))
    assert back.data["table_angle_deg"].isna().sum() == r.data["table_angle_deg"].isna().sum()


def test_idempotent_not_rewritten(tmp_path, monkeypatch):
    r = read_run(ALL[1])
    q = write_run_parquet(r, tmp_path)
    stat = q.stat()

    def boom(*a, **k):
        raise AssertionError("rewritten")
    monkeypatch.setattr(tables.pq, "write_table", boom)
    assert write_run_parquet(read_run(ALL[1]), tmp_path) == q
    assert q.stat().st_mtime_ns == stat.st_mtime_ns and q.stat().st_ino == stat.st_ino
    assert len(list(tmp_path.rglob("*.parquet"))) == 1


def test_revision_kept_apart(tmp_path):
    src = EXAMPLES / "drop-bad/ok-small.csv"
    a = read_run(src)
    rev = tmp_path / "rev.csv"
    rev.write_text(src.read_text().replace("1.29933875", "1.29933876"))
    b = read_run(rev)
    assert a.run_id == b.run_id and a.sha256 != b.sha256
    root = tmp_path / "pq"
    qa, qb = write_run_parquet(a, root), write_run_parquet(b, root)
    assert qa != qb and qa.exists() and qb.exists()
    assert read_run_parquet(qa) == a and read_run_parquet(qb) == b


def test_atomic_write_leaves_nothing_on_crash(tmp_path, monkeypatch):
    r = read_run(ALL[0])
    real = pq.write_table

    def crash(table, where, **kw):
        real(table.slice(0, 10), where, **kw)  # some bytes reach the disk...
        raise KeyboardInterrupt("killed")       # ...then the writer dies
    monkeypatch.setattr(tables.pq, "write_table", crash)
    with pytest.raises(KeyboardInterrupt):
        write_run_parquet(r, tmp_path)
    assert not parquet_path(r, tmp_path).exists()
    assert [p for p in tmp_path.rglob("*") if p.is_file()] == []
    monkeypatch.setattr(tables.pq, "write_table", real)
    q = write_run_parquet(r, tmp_path)  # a later run writes the whole file
    assert read_run_parquet(q) == r


def test_unsafe_names_stay_inside_root(tmp_path):
    src = (EXAMPLES / "drop-bad/ok-small.csv").read_text()
    p = tmp_path / "x.csv"
    p.write_text(src.replace("# run_id: BAD-0001", "# run_id: ../../evil/x").replace(
        "# unit_serial: SNJ-1-03", "# unit_serial: .."))
    r = read_run(p)
    root = tmp_path / "pq"
    q = write_run_parquet(r, root)
    assert root.resolve() in q.resolve().parents
    assert read_run_parquet(q) == r


def test_science_can_run_from_parquet(tmp_path):
    from accelcal.schemas.suites import validate_runs
    runs = [read_run(p) for p in discover(EXAMPLES / "drop-2026-11-21")]
    back = [read_run_parquet(write_run_parquet(r, tmp_path)) for r in runs]
    assert back == runs
    assert all(v == [] for v in validate_runs(back, None, "from-parquet").values())
    assert list(back[0].data.columns) == list(COLUMNS[back[0].test]) + ["line"]


@pytest.mark.parametrize("torn", [b"", b"\0" * 4096, b"PAR1" + b"\0" * 100])
def test_a_file_torn_by_a_power_loss_is_written_again(tmp_path, torn):
    """Files are renamed into place unflushed and made durable a batch at a time
    (fileio.sync_files); a power loss before that flush can leave the name with an empty
    or zero-filled file.  Such a file has no Parquet footer: it is written again, never
    taken as the run's."""
    r = read_run(ALL[0])
    q = parquet_path(r, tmp_path)
    q.parent.mkdir(parents=True)
    q.write_bytes(torn)
    assert write_run_parquet(r, tmp_path) == q
    assert read_run_parquet(q) == r


@pytest.mark.parametrize("with_syncfs", [True, False])
def test_sync_files_flushes_files_and_their_folders(tmp_path, monkeypatch, with_syncfs):
    from accelcal import fileio
    paths = []
    for k in range(3):
        (tmp_path / f"d{k}").mkdir()
        p = tmp_path / f"d{k}" / "f.bin"
        p.write_bytes(b"x" * 10)
        paths.append(p)
    calls = []
    if with_syncfs:
        real = fileio._syncfs()
        if real is None:
            pytest.skip("no syncfs here")
        monkeypatch.setattr(fileio, "_SYNCFS", lambda fd: calls.append(fd) or real(fd))
    else:
        monkeypatch.setattr(fileio, "_SYNCFS", None)
        real_fsync = fileio.os.fsync
        monkeypatch.setattr(fileio.os, "fsync", lambda fd: calls.append(fd) or real_fsync(fd))
    fileio.sync_files(paths)
    # one syncfs for the one file system; else each file and each folder
    assert len(calls) == (1 if with_syncfs else 6)
    fileio.sync_files([])
