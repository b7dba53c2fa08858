"""Faults of the places a run writes and reads (issue 12): the warehouse is checked before it
is touched, a full or read-only store stops the run with one line and a re-run completes
it exactly once, killed writers leave nothing behind, readers wait instead of breaking a
run, and nothing a run starts outlives it.  The real-fault versions (tmpfs disk full, bind
mounts, 30 SIGKILLs under Prefect) are in benchmarks/bench_faults.py."""
from __future__ import annotations

import errno
import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from accelcal import cli
from accelcal.fileio import StoreError
from accelcal.flows.pipeline import run_pipeline
from accelcal.warehouse import Warehouse, WarehouseError

from conftest import marked_pids
from test_faults import warehouse_contents

FAST = dict(engine="local", settle=0)


def _cli(capsys, *args) -> tuple[int, str, str]:
    rc = cli.main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("accelcal: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def clean(tmp_path_factory, examples):
    """A clean run of the sample drop 2026-11-20 (copied to a fixed place) to compare with."""
    base = tmp_path_factory.mktemp("clean")
    drop = base / "drop"
    shutil.copytree(examples / "drop-2026-11-20", drop)
    wh = base / "clean" / "lab.duckdb"
    run_pipeline([drop], wh, **FAST)
    return drop, wh, warehouse_contents(wh)


# ------------------------------------------------------- the warehouse file --

def test_warehouse_folder_must_exist_unless_create(tmp_path, capsys, clean):
    drop = clean[0]
    rc, out, err = _cli(capsys, "run", drop, "-w", tmp_path / "no" / "such" / "lab.duckdb",
                        "--engine", "local", "-q")
    assert rc == 1 and "does not exist" in _one_line(err) and "--create" in err
    assert not (tmp_path / "no").exists()


def test_wrong_file_type_or_a_place_in_the_drop_is_refused_untouched(tmp_path, capsys, examples):
    drop = tmp_path / "drop"
    shutil.copytree(examples / "drop-2026-11-20", drop)
    listing = sorted(drop.rglob("*"))
    csv = drop / "DH1-20261120-0001.csv"
    before = csv.read_bytes()
    rc, out, err = _cli(capsys, "run", drop, "-w", csv, "--engine", "local", "-q")
    assert rc == 1 and "is not a DuckDB warehouse" in _one_line(err)
    rc, out, err = _cli(capsys, "run", drop, "-w", drop / "new.duckdb", "--engine", "local", "-q")
    assert rc == 1 and "inside the drop" in _one_line(err)
    assert sorted(drop.rglob("*")) == listing and csv.read_bytes() == before   # no stray .lock


def test_truncated_warehouse_is_refused_and_not_modified(tmp_path, capsys, clean):
    drop, wh0, _ = clean
    wh = tmp_path / "lab.duckdb"
    shutil.copy(wh0, wh)
    data = wh.read_bytes()
    for size in (len(data) // 2, 100):
        wh.write_bytes(data[:size])
        sha = hashlib.sha256(wh.read_bytes()).hexdigest()
        rc, out, err = _cli(capsys, "run", drop, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        line = _one_line(err)
        assert rc == 1 and "is truncated" in line and "not modified" in line
        rc, out, err = _cli(capsys, "sql", "SELECT 1", "-w", wh)
        assert rc == 1 and _one_line(err)
        assert hashlib.sha256(wh.read_bytes()).hexdigest() == sha
        assert not list(tmp_path.glob("lab.duckdb.wal"))


# ------------------------------------------- the places a run writes: faults --

def test_disk_full_in_the_parquet_store_stops_the_run_then_a_rerun_equals_a_clean_run(
        tmp_path, clean, monkeypatch):
    """A full disk is simulated where the Parquet store is written (the real tmpfs probe is
    in bench_faults): the run stops with StoreError, records no verdict for files it could
    not store, and after 'space is freed' a re-run leaves the clean run's warehouse."""
    from accelcal.schemas import tables
    drop, _, want = clean
    real = tables.write_run_parquet
    calls = []

    def full(run, root):
        calls.append(run.path)
        if len(calls) > 4:
            raise OSError(errno.ENOSPC, "No space left on device", str(Path(root) / "x.parquet"))
        return real(run, root)
    wh = tmp_path / "lab.duckdb"
    monkeypatch.setattr(tables, "write_run_parquet", full)
    with pytest.raises(StoreError) as e:
        run_pipeline([drop], wh, **FAST)
    assert "No space left" in str(e.value) and "free space" in str(e.value)
    assert "\n" not in str(e.value)
    monkeypatch.setattr(tables, "write_run_parquet", real)
    run_pipeline([drop], wh, **FAST)
    assert warehouse_contents(wh) == want


def _nopriv() -> list[str] | None:
    """A prefix that makes permission bits bind (root without CAP_DAC_OVERRIDE), or None."""
    if os.geteuid() != 0:
        return []
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search", "--"] \
        if shutil.which("setpriv") else None


@pytest.mark.skipif(_nopriv() is None, reason="as root, needs setpriv")
def test_read_only_folders_give_one_line_and_a_rerun_completes(tmp_path, clean, examples):
    drop, wh0, _ = clean
    wh = tmp_path / "w" / "lab.duckdb"
    wh.parent.mkdir()
    run_pipeline([drop], wh, **FAST)
    new = tmp_path / "d21"
    shutil.copytree(examples / "drop-2026-11-21", new)

    def run(*args):
        return subprocess.run(_nopriv() + [sys.executable, "-m", "accelcal", *map(str, args)],
                              capture_output=True, text=True, timeout=300,
                              env={**os.environ, "PREFECT_LOGGING_LEVEL": "ERROR"})
    pq = wh.parent / "lab-parquet"
    ro = [pq, *[p for p in pq.rglob("*") if p.is_dir()]]
    for p in ro:
        os.chmod(p, 0o555)
    try:
        p = run("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
    finally:
        for q in ro:
            os.chmod(q, 0o755)
    assert p.returncode == 1 and "cannot write the Parquet store" in _one_line(p.stderr)
    os.chmod(wh.parent, 0o555)
    try:
        p = run("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
        assert p.returncode == 1 and "cannot write in the warehouse folder" in _one_line(p.stderr)
        q = run("sql", "SELECT count(*) AS n FROM runs", "-w", wh)     # readers still read
        assert q.returncode == 0 and "11" in q.stdout, q.stderr
    finally:
        os.chmod(wh.parent, 0o755)
    p = run("run", new, "-w", wh, "--engine", "local", "-q", "--settle", "0")
    assert p.returncode == 0, p.stderr
    assert Warehouse(wh).query("SELECT count(*) AS n FROM runs WHERE status = 'accepted'")[0]["n"] == 18


# ------------------------------------------------------ after a killed writer --

def test_stale_temp_files_of_killed_writers_are_removed_by_the_next_run(tmp_path, clean):
    drop, wh0, want = clean
    wh = tmp_path / "lab.duckdb"
    run_pipeline([drop], wh, **FAST)
    pq = next((wh.parent / "lab-parquet").rglob("*.parquet")).parent
    left = [pq / ".LXJ100-0002__abc.parquet.k3j9x_q2.tmp", wh.parent / ".lab.duckdb.a1b2c3d4.tmp",
            wh.parent / ".lab-snapshot.duckdb.zz99yy88.tmp"]
    for p in left:
        p.write_bytes(b"half a file")
    keep = pq / "notes.tmp.txt"
    keep.write_text("not ours")
    s = run_pipeline([drop], wh, **FAST)
    assert s["removed_temp_files"] == 3 and not any(p.exists() for p in left) and keep.exists()
    keep.unlink()
    assert warehouse_contents(wh) == want


def test_new_warehouse_is_created_whole(tmp_path, monkeypatch):
    """A kill while a warehouse is created leaves no half file under its name: it is made as
    a temporary file and renamed."""
    import duckdb
    seen = []
    real = duckdb.connect

    def spy(path=":memory:", *a, **kw):
        seen.append((str(path), os.path.exists(tmp_path / "lab.duckdb")))
        return real(path, *a, **kw)
    monkeypatch.setattr(duckdb, "connect", spy)
    Warehouse(tmp_path / "lab.duckdb").init()
    assert seen[0][0].endswith(".tmp") and seen[0][1] is False
    assert (tmp_path / "lab.duckdb").exists() and not list(tmp_path.glob("*.tmp*"))


# ------------------------------------------------------------------ readers --

def test_sql_waits_for_a_writer_prints_table_and_csv_and_stays_read_only(tmp_path, capsys, clean):
    _, wh0, _ = clean
    wh = tmp_path / "lab.duckdb"
    shutil.copy(wh0, wh)
    holder = subprocess.Popen(
        [sys.executable, "-c", "import time; from accelcal.warehouse import warehouse_lock\n"
         f"with warehouse_lock({str(wh)!r}):\n    print('locked', flush=True); time.sleep(2)"],
        stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "locked"
    t0 = time.monotonic()
    rc, out, err = _cli(capsys, "sql", "SELECT status, count(*) AS n FROM runs GROUP BY 1", "-w", wh)
    assert rc == 0 and time.monotonic() - t0 > 1.0 and "accepted" in out and "11" in out, err
    holder.wait()
    rc, out, err = _cli(capsys, "sql", "SELECT run_id, status FROM runs ORDER BY run_id", "-w", wh, "--csv")
    assert rc == 0 and out.splitlines()[0] == "run_id,status" and len(out.splitlines()) == 12
    rc, out, err = _cli(capsys, "sql", "DELETE FROM run_files", "-w", wh)
    assert rc == 1 and "read-only" in _one_line(err)
    rc, out, err = _cli(capsys, "sql", "SELEC 1", "-w", wh)
    assert rc == 1 and _one_line(err).startswith("accelcal: error: SQL: ")
    holder = subprocess.Popen(
        [sys.executable, "-c", "import time; from accelcal.warehouse import warehouse_lock\n"
         f"with warehouse_lock({str(wh)!r}):\n    print('locked', flush=True); time.sleep(20)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        rc, out, err = _cli(capsys, "sql", "SELECT 1", "-w", wh, "--lock-timeout", "0.5")
        assert rc == 1 and f"in use by pid {holder.pid}" in _one_line(err) and "--snapshot" in err
        rc, out, err = _cli(capsys, "sql", "SELECT count(*) AS n FROM runs", "-w", wh, "--snapshot")
        assert rc == 1 and "snapshot" in _one_line(err)             # this copy has none
    finally:
        holder.kill()
        holder.wait()


def test_a_run_publishes_a_read_only_snapshot_when_it_wrote(tmp_path, clean):
    import duckdb
    drop, _, want = clean
    wh = tmp_path / "lab.duckdb"
    s = run_pipeline([drop], wh, **FAST)
    snap = Path(s["snapshot"])
    assert snap == tmp_path / "lab-snapshot.duckdb" and oct(snap.stat().st_mode & 0o777) == "0o444"
    assert warehouse_contents(snap)["run_files"] == want["run_files"]
    con = duckdb.connect(str(snap), read_only=True)       # a dashboard holding it open ...
    try:
        ino = snap.stat().st_ino
        s = run_pipeline([drop], wh, **FAST)                 # ... a run that writes nothing
        assert s["snapshot"] is None and snap.stat().st_ino == ino
        assert con.execute("SELECT count(*) FROM coefficients").fetchall()[0][0] > 0
    finally:
        con.close()


# ------------------------------------------------------- the CLI's promises --

def test_empty_drop_warns_and_exits_0(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    rc, out, err = _cli(capsys, "run", tmp_path / "empty", "-w", tmp_path / "lab.duckdb",
                        "--engine", "local", "-q", "--settle", "0")
    assert rc == 0 and "accelcal: warning: drop" in err and "holds no *.csv file" in err


def test_an_unexpected_exception_is_one_line_exit_3_with_the_traceback_saved(capsys, monkeypatch):
    @cli.subcommand("boom")
    def _reg(sub):
        p = sub.add_parser("boom")
        p.set_defaults(func=lambda args: {}["[/x] :x:"])
    try:
        rc, out, err = _cli(capsys, "boom")
    finally:
        del cli.SUBCOMMANDS["boom"]
    line = _one_line(err)
    assert rc == cli.EXIT_BUG == 3 and "internal error: KeyError" in line
    path = line.rsplit("traceback saved in ", 1)[1]
    assert "Traceback" in Path(path).read_text()
    Path(path).unlink()


@pytest.mark.slow
def test_sigkill_under_prefect_leaves_no_process_and_a_rerun_equals_a_clean_run(tmp_path, clean):
    """`accelcal run` (Prefect engine) killed with SIGKILL once its ephemeral Prefect server
    is up: the process guard stops the server (no process carrying this run's environment
    is left), and a re-run leaves the clean run's warehouse.  30 random kills: bench_faults."""
    drop, _, want = clean
    wh = tmp_path / "lab.duckdb"
    mark = uuid.uuid4().hex
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "ERROR", "TEST_FAULTS_MARK": mark}
    p = subprocess.Popen([sys.executable, "-m", "accelcal", "run", drop, "-w", wh, "-q", "--settle", "0"],
                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def marked() -> list[int]:
        return marked_pids("TEST_FAULTS_MARK", mark)
    t_end = time.time() + 240
    server = None
    while time.time() < t_end and p.poll() is None and server is None:
        for q in marked():
            try:
                if b"uvicorn" in Path(f"/proc/{q}/cmdline").read_bytes():
                    server = q
            except OSError:
                pass
        time.sleep(0.2)
    assert server is not None, "the Prefect server never started"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    t_end = time.time() + 15
    while time.time() < t_end and marked():
        time.sleep(0.2)
    left = marked()
    for q in left:
        os.kill(q, signal.SIGKILL)
    assert left == [], f"processes outlived the killed run: {left}"
    run_pipeline([drop], wh, **FAST)
    assert warehouse_contents(wh) == want
    assert not [f for f in tmp_path.rglob("*") if f.name.endswith(".tmp")]
