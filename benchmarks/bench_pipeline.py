#!/usr/bin/env python
"""Benchmark the pipeline on the sample drop (a script, not a test).

    python benchmarks/bench_pipeline.py [--drop DIR] [--repeat N] [--skip-demo]

Each scenario runs in a fresh Python process (cold imports, cold Prefect):

* prefect start-up: import, first flow call (ephemeral server start), a second flow call;
* the sample drop end to end, engine 'local' (no Prefect) and 'prefect', stage by stage,
  plus an idempotent re-run;
* ingest (discover + sha256 + parse + Parquet) against a bare ``pyarrow.csv.read_csv``
  of the same files (data part only), best of N;
* ``accelcal demo`` wall time.

Prints a markdown table to paste into the README; raw numbers go to bench-out/bench.json.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DROP = ROOT.parent / "shared" / "examples" / "drop-2026-11-20"
if not DEFAULT_DROP.is_dir():
    DEFAULT_DROP = ROOT / "accelcal" / "demo_data" / "drop-demo"


# ------------------------------------------------------------------ children --

def child_prefect_startup(_args) -> dict:
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    t0 = time.perf_counter()
    from prefect import flow, task
    from prefect.cache_policies import NO_CACHE
    t_import = time.perf_counter() - t0

    @task(cache_policy=NO_CACHE)
    def noop(i):
        return i

    @flow
    def empty():
        return 0

    @flow
    def twenty_tasks():
        return [noop(i) for i in range(20)]

    t0 = time.perf_counter()
    empty()
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    empty()
    t_second = time.perf_counter() - t0
    t0 = time.perf_counter()
    twenty_tasks()
    t_tasks = time.perf_counter() - t0
    return {"import_prefect": t_import, "first_flow": t_first, "next_flow": t_second,
            "flow_with_20_tasks": t_tasks}


def child_pipeline(args) -> dict:
    from accelcal.flows.pipeline import quiet_prefect
    quiet_prefect()
    t0 = time.perf_counter()
    from accelcal.flows.pipeline import run_pipeline
    t_import = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "lab.duckdb"
        t0 = time.perf_counter()
        s1 = run_pipeline([args.drop], db, engine=args.engine)
        t_first = time.perf_counter() - t0
        t0 = time.perf_counter()
        s2 = run_pipeline([args.drop], db, engine=args.engine)
        t_rerun = time.perf_counter() - t0
    return {"import": t_import, "first": t_first, "rerun": t_rerun,
            "stages": s1["timings"], "rerun_stages": s2["timings"],
            "accepted": sum(d["accepted"] for d in s1["drops"]),
            "campaigns": [c["status"] for c in s1["campaigns"]]}


def child_ingest(args) -> dict:
    import hashlib

    import pyarrow.csv as pacsv

    from accelcal.tasks import contracts
    from accelcal.tasks.ingest import ingest_drop
    files = [Path(p) for p in contracts.discover(args.drop)]
    nbytes = sum(p.stat().st_size for p in files)
    nrows = 0

    def skip_rows(p: Path) -> int:
        n = 0
        with open(p, "rb") as f:
            for line in f:
                if line.startswith(b"#") or not line.strip():
                    n += 1
                else:
                    return n
        return n
    skips = {p: skip_rows(p) for p in files}

    def bare():
        nonlocal nrows
        nrows = 0
        for p in files:
            t = pacsv.read_csv(p, read_options=pacsv.ReadOptions(skip_rows=skips[p]))
            nrows += t.num_rows

    def bare_hash():
        for p in files:
            hashlib.sha256(p.read_bytes()).hexdigest()
            pacsv.read_csv(p, read_options=pacsv.ReadOptions(skip_rows=skips[p]))

    def parse_only():
        for p in files:
            contracts.read_run(p)

    def ingest(tmp):
        ingest_drop(str(args.drop), str(Path(tmp) / "pq"), tmp, {})

    def best(fn, *a):
        ts = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            fn(*a)
            ts.append(time.perf_counter() - t0)
        return min(ts)

    bare()  # warm the file cache and pyarrow
    out = {"files": len(files), "bytes": nbytes, "rows": nrows,
           "pyarrow_read_csv": best(bare), "pyarrow_read_csv_plus_sha256": best(bare_hash),
           "read_run": best(parse_only)}
    with tempfile.TemporaryDirectory() as tmp:
        ingest(tmp)   # warm-up
    ts = []
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            ingest(tmp)
            ts.append(time.perf_counter() - t0)
    out["ingest_drop"] = min(ts)
    return out


def child_demo(args) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "accelcal", "demo", "--dir", tmp, "-q",
                            "--engine", args.engine], capture_output=True, text=True)
        wall = time.perf_counter() - t0
    return {"wall": wall, "rc": p.returncode, "stderr_tail": p.stderr[-500:]}


CHILDREN = {"prefect-startup": child_prefect_startup, "pipeline": child_pipeline,
            "ingest": child_ingest, "demo": child_demo}


# -------------------------------------------------------------------- parent --

def run_child(name: str, **kw) -> dict:
    cmd = [sys.executable, __file__, "--child", name]
    for k, v in kw.items():
        cmd += [f"--{k.replace('_', '-')}", str(v)]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"benchmark child {name} failed:\n{p.stderr[-2000:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["process_wall"] = wall
    return out


def fmt(x: float | None) -> str:
    if x is None:
        return "—"
    return f"{x * 1e3:.1f} ms" if x < 0.1 else f"{x:.2f} s"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drop", type=Path, default=DEFAULT_DROP)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--engine", default="prefect")
    ap.add_argument("--skip-demo", action="store_true")
    ap.add_argument("--child", choices=sorted(CHILDREN))
    args = ap.parse_args()
    if args.child:
        print(json.dumps(CHILDREN[args.child](args), default=str))
        return

    drop = args.drop.resolve()
    print(f"benchmarking on {drop} ({os.cpu_count()} cpus, Python {platform.python_version()})",
          file=sys.stderr)
    res = {"drop": str(drop), "cpus": os.cpu_count(), "python": platform.python_version()}
    res["prefect"] = run_child("prefect-startup")
    res["local"] = run_child("pipeline", drop=drop, engine="local")
    res["prefect_pipeline"] = run_child("pipeline", drop=drop, engine="prefect")
    res["ingest"] = run_child("ingest", drop=drop, repeat=args.repeat)
    if not args.skip_demo:
        res["demo_prefect"] = run_child("demo", engine="prefect")
        res["demo_local"] = run_child("demo", engine="local")
    out = ROOT / "bench-out"
    out.mkdir(exist_ok=True)
    (out / "bench.json").write_text(json.dumps(res, indent=2, default=str))

    pf, lo, pp, ing = res["prefect"], res["local"], res["prefect_pipeline"], res["ingest"]
    st = lo["stages"]
    n = ing["files"]
    mb = ing["bytes"] / 1e6
    rows = [
        ("Prefect import", fmt(pf["import_prefect"]), ""),
        ("Prefect start-up (first flow call: ephemeral server)", fmt(pf["first_flow"]), ""),
        ("Prefect per flow run after start-up", fmt(pf["next_flow"]), ""),
        ("Prefect flow with 20 trivial tasks", fmt(pf["flow_with_20_tasks"]), ""),
        ("sample drop, engine local: total", fmt(lo["first"]),
         f"ingest {st.get('ingest', 0):.2f}, validate {st.get('validate', 0):.2f}, "
         f"record {st.get('record', 0):.2f}, science {st.get('science', 0):.2f}, "
         f"store {st.get('store', 0):.2f}"),
        ("sample drop, engine prefect: total", fmt(pp["first"]),
         f"of which Prefect ≈ {pp['first'] - lo['first']:.2f} s"),
        ("re-run (nothing new), local / prefect", f"{lo['rerun']:.2f} s / {pp['rerun']:.2f} s", ""),
        (f"ingest {n} files ({mb:.2f} MB): discover+sha256+parse+Parquet",
         fmt(ing["ingest_drop"]), f"{mb / ing['ingest_drop']:.1f} MB/s"),
        ("  read_run only (parse + checks)", fmt(ing["read_run"]),
         f"{mb / ing['read_run']:.1f} MB/s"),
        ("  bare pyarrow.csv.read_csv, same files", fmt(ing["pyarrow_read_csv"]),
         f"{mb / ing['pyarrow_read_csv']:.1f} MB/s; ingest/bare = "
         f"{ing['ingest_drop'] / ing['pyarrow_read_csv']:.1f}×"),
    ]
    if "demo_prefect" in res:
        rows.append(("`accelcal demo` wall (prefect / local engine)",
                     f"{res['demo_prefect']['wall']:.1f} s / {res['demo_local']['wall']:.1f} s",
                     "fresh process, cold imports"))
    print(f"\nSample drop `{drop.name}`, {res['cpus']} cpus, Python {res['python']}\n")
    print("| measure | time | notes |")
    print("|---|---:|---|")
    for a, b, c in rows:
        print(f"| {a} | {b} | {c} |")


if __name__ == "__main__":
    main()
