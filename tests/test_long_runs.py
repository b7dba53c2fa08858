"""Long run files in bounded memory (issue 28): a big file parsed into its Parquet file as it
is read, validated from that file a slice at a time, and taken by the science as block
means of its dwells.  Every check here is against the in-memory path or a hand count, never
against numbers the new path printed."""
from __future__ import annotations

import hashlib
import io
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from accelcal.fitting import data as fdata
from accelcal.fitting.data import block_bounds, block_means
from accelcal.schemas import derived, dropformat, suites, tables
from accelcal.schemas.dropspec import DropFormatError
from accelcal.schemas.rules import REST_RATE
from accelcal.tasks import ingest

from conftest import EXAMPLES, require_shared

require_shared()
RUNS = sorted(EXAMPLES.glob("**/*.csv"))


def _streamed(src: Path, root: Path):
    """parse_run of ``src`` with its rows going to its Parquet file (committed)."""
    raw = src.read_bytes()
    stream = tables.RunParquetStream(root, hashlib.sha256(raw).hexdigest(), len(raw))
    try:
        run = dropformat.parse_run(io.BytesIO(raw), str(src), stream)
        stream.commit()
    finally:
        stream.abort()
    return run


def _both(ref, df, root):
    """The run ``ref`` with the columns ``df``: in memory, and in its Parquet file (columns
    read when asked for, as a big file's run is)."""
    import pandas as pd
    kw = dict(path=ref.path, sha256=ref.sha256, size_bytes=ref.size_bytes, meta=ref.meta,
              meta_raw=ref.meta_raw, header_line=ref.header_line, meta_lines=ref.meta_lines)
    run = dropformat.RunFile(data=pd.DataFrame(df), **kw)
    p = tables.write_run_parquet(run, root)
    return run, dropformat.RunFile(data=tables.ParquetColumns(p, list(df.columns), len(df)), **kw)


@pytest.mark.parametrize("src", RUNS, ids=lambda p: p.name)
def test_streamed_parse_and_validation_equal_the_in_memory_ones(src, tmp_path, monkeypatch):
    # slices of a few rows, so every sliced path is taken on the samples' short runs; about
    # six a file on the long ones (each slice is one suite run of great-expectations)
    monkeypatch.setattr(suites, "VALIDATE_ROWS", max(37, src.read_bytes().count(b"\n") // 6))
    monkeypatch.setattr(derived, "_STEP_ROWS", 29)
    try:
        ref = dropformat.read_run(src)
    except DropFormatError as e:
        with pytest.raises(DropFormatError) as got:
            _streamed(src, tmp_path)
        assert str(got.value) == str(e)
        # a refused file leaves nothing in the store, not even a temporary file
        assert [f for _, _, fs in os.walk(tmp_path) for f in fs] == []
        return
    run = _streamed(src, tmp_path)
    assert isinstance(run.arrays, tables.ParquetColumns)
    assert run == ref                                      # every value, line and key
    assert tables.read_run_parquet(tables.parquet_path(run, tmp_path)) == ref
    assert suites.validate_runs([run]) == suites.validate_runs([ref])
    # every derived column the suites check, row by row (NaN where NaN)
    got, want = derived._derive(run.test, run), derived._derive(ref.test, ref)
    assert set(want) <= set(got)
    for c in want:
        np.testing.assert_array_equal(got[c][:], want[c][:], err_msg=c)


def test_a_batch_of_streamed_and_in_memory_runs_validates_as_in_memory(tmp_path, monkeypatch):
    monkeypatch.setattr(suites, "VALIDATE_ROWS", 53)
    bad = sorted((EXAMPLES / "drop-bad").glob("*.csv"))
    good = sorted((EXAMPLES / "drop-2026-11-20").glob("**/*.csv"))[:3]
    refs, mixed = [], []
    for k, src in enumerate(good + bad):
        try:
            ref = dropformat.read_run(src)
        except DropFormatError:
            continue
        refs.append(ref)
        mixed.append(_streamed(src, tmp_path) if k % 2 else ref)
    assert len(refs) >= 5
    assert suites.validate_runs(mixed) == suites.validate_runs(refs)


def test_ingest_of_a_big_file_writes_its_parquet_as_it_parses(tmp_path, monkeypatch):
    monkeypatch.setattr(ingest, "SMALL_FILE", 1000)       # every sample file is "big"
    drop = tmp_path / "drop"
    shutil.copytree(EXAMPLES / "drop-2026-11-20", drop)
    bad = drop / "centrifuge" / "LXJ100-20261120-0003.csv"
    os.chmod(bad.parent, 0o755)
    text = bad.read_text().splitlines()
    bad.unlink()
    bad.write_text("\n".join(text[:-40] + ["1,2,x"] + text[-39:]) + "\n")
    pq_root = tmp_path / "pq"
    old = os.umask(0o022)
    try:
        out = ingest.ingest_drop(str(drop), str(pq_root), str(tmp_path))
    finally:
        os.umask(old)
    # written as it was parsed, each file follows the umask like every other (0644)
    assert {oct(p.stat().st_mode & 0o777) for p in pq_root.rglob("*.parquet")} == {"0o644"}
    status = {Path(r.source_path).name: r.status for r in out.records}
    assert status.pop("LXJ100-20261120-0003.csv") == "refused"
    assert set(status.values()) == {"accepted"}
    files = sorted(p.name for p in pq_root.rglob("*") if p.is_file())
    assert not [f for f in files if f.endswith(".tmp")]
    assert len(files) == len(status)                      # the refused file left nothing
    for rec in out.records:
        if rec.status == "accepted":
            got = tables.read_run_parquet(tmp_path / rec.parquet_path)
            assert got == dropformat.read_run(rec.source_path)


def _bounds(cols: dict, test: str, most: int, rows_at_once=fdata.ROW_SLICE):
    return block_bounds(lambda c, lo, hi: cols[c][lo:hi], test, len(next(iter(cols.values()))),
                        most, rows_at_once)


@pytest.mark.parametrize("rows_at_once", [fdata.ROW_SLICE, 5, 1])
def test_block_bounds_cut_each_dwell_into_near_equal_blocks(rows_at_once):
    # dwells of 5, 23, 1 and 40 readings, at most 7 a block: by hand, ceil(m / 7) blocks
    # of floor or ceil of m / q: 5 | 5 6 6 6 | 1 | 6 7 7 6 7 7 (found whole or in slices)
    step = np.repeat([0, 1, 2, 3], [5, 23, 1, 40])
    b = _bounds({"step": step}, "centrifuge", 7, rows_at_once=rows_at_once)
    assert np.diff(b).tolist() == [5, 5, 6, 6, 6, 1, 6, 7, 7, 6, 7, 7]
    assert b[-1] == step.size
    assert all(np.unique(step[lo:hi]).size == 1 for lo, hi in zip(b[:-1], b[1:]))
    # two keys: a change of either starts a dwell
    b2 = _bounds({"temp_set_c": np.r_[np.zeros(4), np.ones(6)], "rotation_deg": np.r_[np.zeros(7), 90 * np.ones(3)]},
                 "tilt_rotation", 100, rows_at_once=rows_at_once)
    assert b2.tolist() == [0, 4, 7, 10]
    # a logged angle's noise within the cells' tolerance is one dwell, a step beyond it two
    # (the cells of make_run: fitting.data.CELL_KEYS)
    ang = np.r_[90 + 0.05 * np.sin(np.arange(8)), 180 + 0.05 * np.cos(np.arange(6))]
    b3 = _bounds({"position": np.zeros(14), "angle_deg": ang}, "tumble", 100, rows_at_once)
    assert b3.tolist() == [0, 8, 14]


def test_block_means_are_each_blocks_mean_over_its_finite_readings():
    rng = np.random.default_rng(5)
    step = np.repeat([0, 1, 2], [9, 31, 17])
    temp = np.where(rng.random(step.size) < 0.4, np.nan, rng.normal(20, 1, step.size))
    temp[:4] = np.nan                                     # a block with no temperature
    cols = {"step": step, "output": rng.normal(size=step.size), "temp_c": temp,
            "line": np.arange(step.size) + 12}
    b = _bounds({"step": step}, "centrifuge", 4)
    got = block_means(lambda c, lo, hi: cols[c][lo:hi], list(cols), b, ("step", "line"),
                      rows_at_once=10)
    for k, (lo, hi) in enumerate(zip(b[:-1], b[1:])):
        assert got["step"][k] == step[lo] and got["line"][k] == lo + 12
        assert got["output"][k] == pytest.approx(sum(cols["output"][lo:hi]) / (hi - lo), rel=1e-13)
        t = [x for x in temp[lo:hi] if x == x]
        assert (np.isnan(got["temp_c"][k]) if not t else
                got["temp_c"][k] == pytest.approx(sum(t) / len(t), rel=1e-13))
    assert got["step"].dtype == np.int64 and got["line"].dtype == np.int64


def test_a_run_taken_as_block_means_gives_the_in_memory_results(tmp_path, monkeypatch):
    """The sample SNJ-1-03 campaign with every reading repeated four times, taken as block
    means of at most four readings (BLOCK_READINGS lowered so these runs count as long):
    each block is then one reading of the sample, so every coefficient and uncertainty is
    the in-memory result on the sample itself (to the rounding of a mean of four equal
    numbers) -- the blocks' bounds, means, keys and lines all go through the science."""
    import pandas as pd
    from accelcal.estimators.campaign import process_campaign
    files = sorted((EXAMPLES / "drop-2026-11-20").glob("**/*.csv"))
    runs = [dropformat.read_run(f) for f in files]
    whole = process_campaign(runs)
    monkeypatch.setattr(fdata, "BLOCK_READINGS", 240)     # 4 x 184 and 4 x 240: blocks of 4
    taken = []
    for r in runs:
        four = dropformat.RunFile(path=r.path, sha256=r.sha256, size_bytes=r.size_bytes,
                                  meta=r.meta, meta_raw=r.meta_raw,
                                  data=pd.DataFrame({c: np.repeat(v, 4) for c, v in r.arrays.items()}),
                                  header_line=r.header_line, meta_lines=r.meta_lines)
        p = tables.write_run_parquet(four, tmp_path)
        taken.append(tables.read_run_parquet(p, blocks=fdata.long_run_blocks))
        assert taken[-1].meta[fdata.BLOCK_META_KEY] == [4 * r.n_rows, r.n_rows, 4]
        assert taken[-1].arrays["line"].tolist() == r.arrays["line"].tolist()
    blocks = process_campaign(taken)
    a = {(c.name, c.method): c for c in whole.coefficients}
    b = {(c.name, c.method): c for c in blocks.coefficients}
    assert a.keys() == b.keys()
    for k in a:
        u = a[k].std_uncertainty
        assert b[k].value == pytest.approx(a[k].value, abs=1e-9 * u, rel=1e-12), k
        assert b[k].std_uncertainty == pytest.approx(u, rel=1e-6), k
    note = [f for f in blocks.flags if "blocks of at most 4" in f]
    assert len(note) == len(runs)


def test_a_full_store_while_a_big_file_is_parsed_stops_the_run_and_leaves_nothing(tmp_path, monkeypatch):
    """The Parquet store cannot take a streamed run's rows (ENOSPC from the writer): the
    ingest stops with the store's one-line error (no verdict is recorded for the file),
    and no temporary file is left."""
    import errno
    import pyarrow.parquet as pq
    from accelcal.fileio import StoreError
    monkeypatch.setattr(ingest, "SMALL_FILE", 1000)
    drop = tmp_path / "drop"
    drop.mkdir()
    shutil.copy(EXAMPLES / "drop-2026-11-20" / "DH1-20261120-0001.csv", drop)

    def full(self, batch, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(pq.ParquetWriter, "write_batch", full)
    with pytest.raises(StoreError) as err:
        ingest.ingest_drop(str(drop), str(tmp_path / "pq"), str(tmp_path))
    msg = str(err.value)
    assert "cannot write the Parquet store" in msg and "No space left" in msg
    assert "\n" not in msg
    assert [p for p in (tmp_path / "pq").rglob("*") if p.is_file()] == []


def test_positions_per_temperature_point_found_in_slices_as_whole(tmp_path, monkeypatch):
    """A tilt-rotation run whose second temperature point has a 13th rotation: the counts
    per point, found a few rows at a time from its Parquet file, are the whole run's, and
    the run is refused alike."""
    monkeypatch.setattr(derived, "_STEP_ROWS", 31)
    ref = dropformat.read_run(EXAMPLES / "drop-2026-11-18-thermal" / "TT1-20261118-0001.csv")
    df = ref.data.copy()
    seg = np.flatnonzero(np.r_[True, np.diff(df["temp_set_c"].to_numpy()) != 0])
    lo = int(seg[1])
    df.loc[lo + 3:lo + 9, "rotation_deg"] = 15.0
    changed, lazy = _both(ref, df, tmp_path)
    got = derived._derive("tilt_rotation", lazy)["positions_error"][:]
    want = derived._derive("tilt_rotation", changed)["positions_error"][:]
    np.testing.assert_array_equal(got, want)
    assert np.nanmax(want) >= 1
    v = suites.validate_runs([lazy])[ref.path]
    assert v == suites.validate_runs([changed])[ref.path]
    assert any(r.rule == "positions-mismatch" for r in v)


@pytest.mark.parametrize("change", ["steps go down", "never turns", "one turning step twice"])
def test_centrifuge_dwell_checks_read_a_dwell_at_a_time_as_whole(change, tmp_path, monkeypatch):
    """The 1 g and rest-dwell figures of a centrifuge run in its Parquet file, read a dwell
    at a time, on runs that take each branch: turning steps that go down (the whole-run
    groupby), a run that never turns, a step turning in two dwells with a rest between."""
    monkeypatch.setattr(derived, "_STEP_ROWS", 23)
    ref = dropformat.read_run(EXAMPLES / "drop-2026-11-20" / "centrifuge" / "LXJ100-20261120-0002.csv")
    df = ref.data.copy()
    step = df["step"].to_numpy()
    if change == "steps go down":
        df["step"] = np.where(step > 2, 100 - step, step)
    elif change == "never turns":
        df["table_rate_rad_s"] = 0.0
    else:
        top = step == step.max()
        df.loc[top, "step"] = step.max() - 2
    run, lazy = _both(ref, df, tmp_path)
    # the per-step means of the dwell scan are the whole run's, bit for bit (or both absent)
    means_l = derived._centrifuge_dwells(lazy.arrays, lazy.n_rows).means
    rate, step = run.arrays["table_rate_rad_s"], run.arrays["step"]
    turning = rate >= REST_RATE
    if means_l is not None and turning.any():
        want_means = pd.Series(rate[turning]).groupby(step[turning]).mean().to_numpy()
        np.testing.assert_array_equal(means_l, want_means)
    got = derived._derive("centrifuge", lazy)
    want = derived._derive("centrifuge", run)
    for c in ("one_g_error", "rest_dwell_error_deg"):
        np.testing.assert_array_equal(got[c][:], want[c][:], err_msg=c)
    assert suites.validate_runs([lazy]) == suites.validate_runs([run])


@pytest.mark.parametrize("size", [1, 2, 7, 8, 1001, 1000])
def test_median_of_counts_is_numpys_median(size):
    rng = np.random.default_rng(size)
    x = rng.choice(np.array([0.01, 0.0099999999, 0.0100000001, 0.02, 1e-3]), size) + \
        (rng.random(size) < 0.1) * rng.random(size)
    vals, counts = np.unique(x, return_counts=True)
    assert derived._median_of_counts(vals, counts) == np.median(x)


def test_parquet_columns_are_read_only_when_a_value_is_asked_for(tmp_path, monkeypatch):
    """``in``, ``keys()``, ``len`` and the dtypes of a run in its Parquet file read no column
    (Mapping's own ``in`` reads the value: a whole column of a 3 GB run, several times
    over in the validation)."""
    run = _streamed(RUNS[0], tmp_path)
    cols = run.arrays
    reads = []
    real = cols.rows
    monkeypatch.setattr(cols, "rows", lambda *a: reads.append(a) or real(*a))
    assert "output" in cols and "nope" not in cols and "line" in cols.keys()
    assert {"time_s", "output"} <= cols.keys() and len(cols) == len(list(cols))
    assert run.n_rows == len(cols["output"]) and reads == [("output", 0, run.n_rows)]


def test_diagnosis_reads_a_big_run_file_as_the_pipeline_does(tmp_path, monkeypatch):
    """``accelcal diagnose`` / ``design`` on run files: a file over SMALL_FILE is parsed into
    a temporary Parquet file and read back -- whole when short (the RunFile read_run
    gives), as block means of its dwells when long -- and the temporary folder is gone."""
    import tempfile
    from accelcal.diagnosis import runfiles
    monkeypatch.setattr(runfiles, "SMALL_FILE", 1000)        # every sample file is "big"
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    drop = EXAMPLES / "drop-2026-11-20"
    files = sorted(drop.glob("**/*.csv"))
    got = runfiles.read_paths([drop])
    assert [r.path for r in got] == [str(f) for f in files]
    assert all(a == dropformat.read_run(f) for a, f in zip(got, files))
    monkeypatch.setattr(fdata, "BLOCK_READINGS", 100)
    long = runfiles.read_paths([drop])
    assert all(fdata.BLOCK_META_KEY in r.meta and r.n_rows < o.n_rows for r, o in zip(long, got))
    assert list(tmp_path.iterdir()) == []


def test_an_azimuth_logged_about_zero_is_averaged_on_the_circle():
    """A rest dwell at azimuth 0 logged as 359.99 and 0.01 (a DAQ's [0, 360)): its block
    means are near 0, not 180; a block away from the wrap keeps its plain mean exactly."""
    az = np.r_[359.99, 0.01, 359.98, 0.02, 359.99, 0.01, 90.01, 89.99, 90.02, 89.98]
    cols = {"step": np.repeat([0, 1], [6, 4]), "table_angle_deg": az,
            "line": np.arange(10)}
    b = _bounds({"step": cols["step"]}, "centrifuge", 10)
    got = block_means(lambda c, lo, hi: cols[c][lo:hi], list(cols), b, ("step", "line"))
    dev = np.mod(got["table_angle_deg"][0] + 180.0, 360.0) - 180.0
    assert abs(dev) < 1e-9
    assert got["table_angle_deg"][1] == np.sum(az[6:]) / 4
