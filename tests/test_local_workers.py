"""The local engine on several processes (issue 13: "at the speed of the machine").

``run_pipeline(..., engine='local', workers=N)`` runs the ingest/validate batches and the
campaign science in N worker processes while the flow process keeps every warehouse
write.  The warehouse it leaves must equal the one-process run's, table by table (the
speed-up is measured in benchmarks/bench_fleet.py, not here).
"""
from __future__ import annotations

import json
import os

import pytest

from accelcal.flows.pipeline import PipelineError, _local_pool, run_pipeline

from conftest import REFERENCE_DROPS
from test_faults import warehouse_contents


@pytest.mark.slow
def test_two_worker_processes_leave_the_same_warehouse(tmp_path, examples, reference_lab, monkeypatch):
    drops = [examples / x for x in REFERENCE_DROPS]
    one = reference_lab                                # the one-process run of the same drops
    s1 = json.loads((one.parent / "summary.json").read_text())
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "4")     # several batches, so both workers ingest
    two = tmp_path / "two" / "lab.duckdb"
    s2 = run_pipeline(drops, two, engine="local", workers=2)
    assert s1["workers"] == 1 and s2["workers"] == 2
    assert {c["status"] for c in s2["campaigns"]} == {"new"}
    assert [d["refused_files"] for d in s2["drops"]] == [d["refused_files"] for d in s1["drops"]]
    assert warehouse_contents(two) == warehouse_contents(one)
    # and a re-run on the pool adds nothing
    s3 = run_pipeline(drops, two, engine="local", workers=2)
    assert {c["status"] for c in s3["campaigns"]} == {"unchanged"}
    assert warehouse_contents(two) == warehouse_contents(one)


def test_the_pool_runs_steps_in_other_processes():
    with _local_pool(1) as none:
        assert none is None                        # one worker: the flow process itself
    with _local_pool(2) as pool:
        pids = {pool.submit(os.getpid).result() for _ in range(4)}
    assert os.getpid() not in pids


def test_workers_argument_is_checked(tmp_path, examples):
    drop = [examples / "drop-2026-11-20"]
    with pytest.raises(PipelineError, match="at least 1"):
        run_pipeline(drop, tmp_path / "a.duckdb", engine="local", workers=0)
    with pytest.raises(PipelineError, match="local engine"):
        run_pipeline(drop, tmp_path / "b.duckdb", engine="prefect", workers=2)
