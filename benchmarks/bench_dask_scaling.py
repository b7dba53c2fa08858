#!/usr/bin/env python
"""Dask scale-out benchmark (issue 13): 1 worker against 2 on the same simulated campaigns.

    python benchmarks/bench_dask_scaling.py --campaigns 200 --pairs 2
                                            [--cluster standing per-run]
                                            [--sim-cache DIR] [--readme README.md]

Each timed run is ``run_pipeline(drops, <fresh warehouse>, engine='prefect',
task_runner=...)`` in a fresh child process, on the same drops (bench_fleet's simulated
fleet, scenario snj103-lxj100, 11 runs a campaign).  The child first imports what
run_pipeline imports on first use (Prefect's flow engine, prefect-dask: ~1.2 s), timed
apart as ``imports_s``: a served run's process has them loaded; the table shows the
speed-up with and without them.  Two ways to have a Dask cluster:

``per-run``   ``--task-runner dask``: the flow starts a local cluster of N one-thread
              workers and stops it at the end, so each run pays the workers' start and
              their first imports (great-expectations, ~3 s a process).
``standing``  a cluster that stays up, as a lab processing drops every night runs it:
              ``dask scheduler --preload accelcal.ops.dask_preload`` + ``dask worker
              --nworkers N --nthreads 1 --preload accelcal.ops.dask_preload``, started
              before the timed run and waited for
              (all N workers connected and warmed), then ``--task-runner tcp://...``.

Both use a running Prefect server: $PREFECT_API_URL if set, else one the benchmark
starts (``prefect server start``, in a temporary PREFECT_HOME) and stops.  The 1- and
2-worker runs alternate (1, 2, then 2, 1, ...) so that a drift of the machine's load
falls on both.  Prints a markdown table (every run, and the speed-up from the medians);
raw numbers to <out>/bench-dask.json; --readme writes the table between
<!-- bench_dask:begin --> and <!-- bench_dask:end -->, headed by the commit that ran.
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(check, timeout: float, what: str) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            if check():
                return
        except Exception:
            pass
        time.sleep(0.5)
    raise RuntimeError(f"{what} did not come up within {timeout:.0f} s")


@contextmanager
def prefect_api():
    """$PREFECT_API_URL, or a `prefect server` started for the benchmark."""
    if os.environ.get("PREFECT_API_URL"):
        yield os.environ["PREFECT_API_URL"]
        return
    home = tempfile.mkdtemp(prefix="bench-dask-prefect-")
    port = free_port()
    url = f"http://127.0.0.1:{port}/api"
    log = open(Path(home) / "server.log", "w")
    p = subprocess.Popen(["prefect", "server", "start", "--host", "127.0.0.1", "--port", str(port)],
                         env={**os.environ, "PREFECT_HOME": home}, stdout=log, stderr=log)
    try:
        wait_until(lambda: urllib.request.urlopen(url + "/health", timeout=2).status == 200,
                   120, "the Prefect server")
        yield url
    finally:
        p.terminate()
        p.wait(30)
        log.close()


@contextmanager
def standing_cluster(n: int, env: dict):
    """A scheduler and n one-thread workers with accelcal's preload, all connected."""
    port = free_port()
    addr = f"tcp://127.0.0.1:{port}"
    logs = tempfile.mkdtemp(prefix="bench-dask-cluster-")
    sch = subprocess.Popen(["dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                            "--no-dashboard", "--preload", "accelcal.ops.dask_preload"], env=env,
                           stdout=open(Path(logs) / "scheduler.log", "w"), stderr=subprocess.STDOUT)
    wk = None
    try:
        wk = subprocess.Popen(["dask", "worker", addr, "--nworkers", str(n), "--nthreads", "1",
                               "--no-dashboard", "--preload", "accelcal.ops.dask_preload"],
                              env=env, stdout=open(Path(logs) / "workers.log", "w"),
                              stderr=subprocess.STDOUT)
        from distributed import Client
        t0 = time.perf_counter()
        with Client(addr, timeout=60) as c:
            c.wait_for_workers(n, timeout=180)
        yield addr, time.perf_counter() - t0
    finally:
        for p in (wk, sch):
            if p is not None:
                p.terminate()
                try:
                    p.wait(30)
                except subprocess.TimeoutExpired:
                    p.kill()


def child(args) -> dict:
    """One timed run, in this (fresh) process."""
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    from bench_fleet import cached_fleet
    from accelcal.flows.pipeline import run_pipeline
    drops, n_runs = cached_fleet(args.n, args.per_drop, Path(args.sim_cache))
    wh = Path(tempfile.mkdtemp(prefix="bench-dask-wh-")) / "lab.duckdb"
    # what run_pipeline imports on first use (Prefect, its Dask runner), timed apart: a
    # served run (accelcal serve: flow runs in a process that has Prefect loaded) does
    # not pay it, a first `accelcal run` in a fresh process does (imports_s)
    t0 = time.perf_counter()
    import prefect.flow_engine  # noqa: F401
    import prefect_dask  # noqa: F401
    from accelcal.flows.pipeline import pipeline_flow
    pipeline_flow()
    imports = time.perf_counter() - t0
    t0 = time.perf_counter()
    s = run_pipeline([str(d) for d in drops], wh, engine="prefect", task_runner=args.runner,
                     allow_simulated=True)
    wall = time.perf_counter() - t0
    statuses: dict[str, int] = {}
    for c in s["campaigns"]:
        statuses[c["status"]] = statuses.get(c["status"], 0) + 1
    return {"pipeline_s": wall, "imports_s": imports, "runs": n_runs, "statuses": statuses,
            "timings": s["timings"], "load_before": os.getloadavg()[0]}


def timed_run(n_campaigns: int, args, runner: str, env: dict) -> dict:
    cmd = [sys.executable, __file__, "--child", "--n", str(n_campaigns), "--per-drop",
           str(args.per_drop), "--runner", runner, "--sim-cache", args.sim_cache]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    line = next((l for l in p.stdout.splitlines() if l.startswith("RESULT ")), None)
    if p.returncode != 0 or line is None:
        raise RuntimeError(p.stderr[-3000:])
    return json.loads(line[7:])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, default=200)
    ap.add_argument("--per-drop", type=int, default=50)
    ap.add_argument("--pairs", type=int, default=2, help="1-worker/2-worker pairs per cluster")
    ap.add_argument("--cluster", nargs="+", default=["standing", "per-run"],
                    choices=("standing", "per-run"))
    ap.add_argument("--sim-cache", default=str(ROOT / "bench-out" / "sim-cache"))
    ap.add_argument("--out", default=str(ROOT / "bench-out" / "dask"))
    ap.add_argument("--readme", default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--runner", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print("RESULT " + json.dumps(child(args), default=str))
        return 0
    Path(args.sim_cache).mkdir(parents=True, exist_ok=True)
    from bench_fleet import cached_fleet
    cached_fleet(args.campaigns, args.per_drop, Path(args.sim_cache))  # simulate once, untimed
    runs: list[dict] = []
    with prefect_api() as api:
        env = {**os.environ, "PREFECT_API_URL": api, "PREFECT_LOGGING_LEVEL": "WARNING"}
        for mode in args.cluster:
            for k in range(args.pairs):
                for n in ((1, 2) if k % 2 == 0 else (2, 1)):
                    start = None
                    if mode == "standing":
                        with standing_cluster(n, env) as (addr, start):
                            r = timed_run(args.campaigns, args, addr, env)
                    else:
                        r = timed_run(args.campaigns, args, "dask",
                                      {**env, "ACCELCAL_DASK_WORKERS": str(n)})
                    r.update(cluster=mode, workers=n, pair=k, cluster_start_s=start)
                    runs.append(r)
                    print(f"{mode} cluster, {n} worker(s), pair {k}: {r['pipeline_s']:.1f} s"
                          + (f" (cluster up and warm in {start:.1f} s, not timed)" if start else "")
                          + f"; statuses {r['statuses']}", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench-dask.json").write_text(json.dumps(runs, indent=1, default=str))
    md = report(runs, args)
    print("\n" + md)
    if args.readme:
        write_block(Path(args.readme), "bench_dask", md)
    return 0


def report(runs: list[dict], args) -> str:
    lines = [f"Dask scale-out (`python benchmarks/bench_dask_scaling.py --campaigns "
             f"{args.campaigns} --pairs {args.pairs} --cluster {' '.join(args.cluster)}`), "
             f"commit {commit()}, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, "
             f"{args.campaigns} campaigns ({runs[0]['runs']} runs), a running Prefect server. "
             "Pipeline wall time in s (`run_pipeline`, Prefect and its Dask runner already "
             "imported, as in a served run), each run in a fresh process on a fresh "
             "warehouse; the 1- and 2-worker runs alternate. The last column adds each "
             "run's own imports (a first `accelcal run` in a fresh process).",
             "",
             "| cluster | 1 worker (s) | 2 workers (s) | speed-up (medians) | pairs | "
             "with the imports |",
             "|---|---|---|---|---|---|"]
    for mode in dict.fromkeys(r["cluster"] for r in runs):
        sel = [r for r in runs if r["cluster"] == mode]
        one = [r["pipeline_s"] for r in sel if r["workers"] == 1]
        two = [r["pipeline_s"] for r in sel if r["workers"] == 2]
        one_i = [r["pipeline_s"] + r["imports_s"] for r in sel if r["workers"] == 1]
        two_i = [r["pipeline_s"] + r["imports_s"] for r in sel if r["workers"] == 2]
        pairs = " ".join(f"{a / b:.2f}×" for a, b in zip(one, two))
        what = ("standing (started and warmed before the run)" if mode == "standing"
                else "per run (`--task-runner dask`, started by the flow)")
        lines.append(f"| {what} | {' / '.join(f'{x:.1f}' for x in one)} | "
                     f"{' / '.join(f'{x:.1f}' for x in two)} | "
                     f"**{statistics.median(one) / statistics.median(two):.2f}×** | {pairs} | "
                     f"{statistics.median(one_i):.1f} / {statistics.median(two_i):.1f} s: "
                     f"{statistics.median(one_i) / statistics.median(two_i):.2f}× |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
