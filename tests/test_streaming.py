"""Streaming (issue 5, Scale): a drop is processed in batches of files and campaigns are
computed a few at a time, so memory does not grow with the drop, and the warehouse a
batched run leaves is the one a single-batch run leaves.
"""
from __future__ import annotations

import gc
import shutil
import weakref
from pathlib import Path

import pytest

from accelcal.flows.pipeline import run_pipeline
from accelcal.warehouse import Warehouse

from test_faults import warehouse_contents


def test_batched_run_equals_one_batch_run(tmp_path, examples, monkeypatch):
    drops = [examples / "drop-2026-11-20", examples / "drop-bad", examples / "drop-2026-11-21"]
    one = tmp_path / "one" / "lab.duckdb"
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "100000")
    s1 = run_pipeline(drops, one, engine="local")
    many = tmp_path / "many" / "lab.duckdb"
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "3")      # 11 files -> 4 batches
    monkeypatch.setenv("ACCELCAL_IN_FLIGHT", "2")
    s2 = run_pipeline(drops, many, engine="local")
    assert warehouse_contents(many) == warehouse_contents(one)
    strip = ("path", "docs")
    for a, b in zip(s1["drops"], s2["drops"]):
        assert {k: v for k, v in a.items() if k not in strip} == \
               {k: v for k, v in b.items() if k not in strip}
    assert [c["status"] for c in s1["campaigns"]] == [c["status"] for c in s2["campaigns"]]
    # each batch of a streamed drop has its own Data Docs under the drop's folder
    docs = Warehouse(many).docs_root / "drop-2026-11-20"
    parts = sorted(p.parent.name for p in docs.rglob("index.html"))
    assert parts == ["part-0000", "part-0001", "part-0002", "part-0003"], parts


def _drop_of_copies(src: Path, dst: Path, copies: int) -> Path:
    """A drop holding ``copies`` copies of a sample drop's files in sub-folders: more files,
    the same runs (same bytes -> the same run revision, one campaign)."""
    for k in range(copies):
        shutil.copytree(src, dst / f"copy-{k:03d}")
    return dst


class _LiveRuns:
    """Counts parsed runs (RunFile objects from the parser -- read_run, parse_run on an
    open file, parse_runs on files held as bytes, as ingest calls them -- or from Parquet)
    alive at once.  The schema functions are replaced with ``monkeypatch.setattr`` on
    their modules, where ingest and science look them up at call time."""

    def __init__(self, monkeypatch):
        from accelcal.schemas import dropformat, tables
        self.monkeypatch, self.live, self.peak = monkeypatch, weakref.WeakSet(), 0
        self.real = {(m, n): getattr(m, n) for m, n in (
            (dropformat, "read_run"), (dropformat, "parse_run"), (dropformat, "parse_runs"),
            (tables, "read_run_parquet"))}

    def _count(self, run) -> None:
        self.live.add(run)
        # count runs still reachable, not garbage awaiting the collector; a collection
        # only lowers the count, so it is needed only when the count would raise the peak
        if len(self.live) > self.peak:
            gc.collect()
            self.peak = max(self.peak, len(self.live))

    def _wrap(self, key):
        real = self.real[key]
        if key[1] == "parse_runs":
            def f(items):
                out = real(items)
                for run in out:
                    if not isinstance(run, BaseException):
                        self._count(run)
                return out
            return f

        def g(*a, **kw):
            run = real(*a, **kw)
            self._count(run)
            return run
        return g

    def __enter__(self):
        for key in self.real:
            self.monkeypatch.setattr(key[0], key[1], self._wrap(key))
        # what exists now is set aside from the collections (gc.freeze): no run is among
        # it, nor can garbage frozen now refer to one, so each collection finds the same
        # runs unreachable, looking only at what the run made
        gc.collect()
        gc.freeze()
        return self

    def __exit__(self, *exc):
        gc.unfreeze()
        for (mod, name), fn in self.real.items():
            self.monkeypatch.setattr(mod, name, fn)


@pytest.mark.slow
def test_parsed_runs_alive_at_once_bounded_by_batch_not_drop(tmp_path, examples, monkeypatch):
    """At most one batch of parsed files (plus a campaign's runs) is in memory at a time,
    whatever the drop's size; without batching, the whole drop is (the control, so this
    test can fail).  Peak RSS on the fleet is in benchmarks/bench_fleet.py."""
    src = examples / "drop-2026-11-20"
    drop = _drop_of_copies(src, tmp_path / "drop", 8)                  # 88 files
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "11")
    monkeypatch.setenv("ACCELCAL_IN_FLIGHT", "1")
    gc.collect()
    with _LiveRuns(monkeypatch) as streamed:
        s = run_pipeline([drop], tmp_path / "a" / "lab.duckdb", engine="local")
    assert s["drops"][0]["files"] == 88 and s["drops"][0]["accepted"] == 88
    assert [c["status"] for c in s["campaigns"]] == ["new"]
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "100000")
    gc.collect()
    with _LiveRuns(monkeypatch) as whole:
        run_pipeline([drop], tmp_path / "b" / "lab.duckdb", engine="local")
    print(f"\nparsed runs alive at once: {streamed.peak} streamed (batches of 11), "
          f"{whole.peak} in one batch")
    assert streamed.peak <= 11 + 1, streamed.peak
    assert whole.peak >= 88, whole.peak


def _chunks(total: int, most: int, in_flight: int) -> list[int]:
    from accelcal.flows.pipeline import guided_chunk
    out = []
    while sum(out) < total:
        out.append(min(guided_chunk(total - sum(out), most, in_flight), total - sum(out)))
    return out


def test_guided_chunks_shrink_toward_the_end_and_cover_every_campaign():
    """Science tasks carry ``most`` campaigns, then fewer as the run nears its end
    (remaining / in-flight, never below the local engine's 4), so the workers finish
    together; the local engine's 4 a task is left as it was."""
    sizes = _chunks(200, 25, 4)
    assert sum(sizes) == 200
    assert sizes[0] == 25 and sizes == sorted(sizes, reverse=True)
    assert min(sizes[:-1]) >= 4 and sizes[-1] <= 4
    # by hand: 200 -> 25 x 5 (ceil(remaining / 4) >= 25 until 100 are left), then
    # ceil(75/4) = 19, ceil(56/4) = 14, ceil(42/4) = 11, 8, 6, 5, 4, 4, 4
    assert sizes == [25, 25, 25, 25, 25, 19, 14, 11, 8, 6, 5, 4, 4, 4]
    assert set(_chunks(200, 4, 4)) == {4}
    assert _chunks(3, 25, 4) == [3]
