"""Scale-out (issue 5): the same flow on Dask workers through prefect-dask, unchanged.

A real Dask scheduler with two worker processes is started here (as a lab would run
one on a cluster), the pipeline is pointed at its address, and the warehouse it leaves
must equal the one the in-process engine leaves, table by table.  The speed-up is
measured in benchmarks/bench_fleet.py, not here.
"""
from __future__ import annotations

import os

import pytest

from accelcal.flows.pipeline import _prefect_api, quiet_prefect, run_pipeline
from accelcal.flows.runners import RunnerError, task_runner_for

from conftest import REFERENCE_DROPS
from test_faults import warehouse_contents

quiet_prefect("ERROR")


def test_task_runner_specs(monkeypatch):
    from prefect_dask import DaskTaskRunner
    assert task_runner_for("thread") is None and task_runner_for(None) is None
    monkeypatch.setenv("ACCELCAL_DASK_WORKERS", "2")
    r = task_runner_for("dask")
    assert isinstance(r, DaskTaskRunner)
    assert r.cluster_kwargs == {"n_workers": 2, "threads_per_worker": 1}
    r = task_runner_for("dask://10.0.0.5:8786")
    assert isinstance(r, DaskTaskRunner) and r.address == "tcp://10.0.0.5:8786"
    with pytest.raises(RunnerError, match="unknown task runner"):
        task_runner_for("ray")


@pytest.mark.slow
def test_flow_on_an_existing_dask_scheduler_equals_local_run(tmp_path, examples, reference_lab, monkeypatch):
    distributed = pytest.importorskip("distributed")
    drops = [examples / x for x in REFERENCE_DROPS]
    local = reference_lab                              # the one-process run of the same drops
    monkeypatch.setenv("ACCELCAL_BATCH_FILES", "4")     # several batches, so both workers ingest
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    # A lab's own scheduler comes with the lab's Prefect server: one server, whose address
    # (PREFECT_API_URL) the workers inherit as they start and the flow finds, rather than a
    # temporary server in each of the three processes.
    with _prefect_api("dask"), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                     dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask = tmp_path / "dask" / "lab.duckdb"
        s = run_pipeline(drops, on_dask, engine="prefect", task_runner=cluster.scheduler_address)
        # the tasks really ran on the workers (both of them)
        seen = client.run(lambda dask_worker: len(dask_worker.data) + dask_worker.state.executed_count)
    assert all(n > 0 for n in seen.values()), seen
    assert {c["status"] for c in s["campaigns"]} == {"new"}
    assert warehouse_contents(on_dask) == warehouse_contents(local)


@pytest.mark.slow
def test_local_dask_workers_share_the_flows_prefect_server(monkeypatch):
    """A local cluster's workers inherit the address of the flow's temporary Prefect server
    (PREFECT_API_URL) instead of each starting a server of their own; the variable is put
    back afterwards, and nothing is set for the thread runner."""
    from prefect.server.api.server import SubprocessASGIServer

    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    with _prefect_api("thread"):
        assert "PREFECT_API_URL" not in os.environ
    with _prefect_api("dask"):
        server = SubprocessASGIServer()
        assert server.running and os.environ["PREFECT_API_URL"] == server.api_url
    assert "PREFECT_API_URL" not in os.environ
