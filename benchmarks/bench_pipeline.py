#!/usr/bin/env python
"""Benchmark the pipeline, stage by stage, against the floor (a script, not a test).

    python benchmarks/bench_pipeline.py [--drop DIR ...] [--sim N] [--repeat 3] [--runs 3]
                                        [--demo] [--readme README.md]

Each scenario runs in a fresh Python process (cold imports, cold Prefect):

* prefect start-up: import, first flow call (ephemeral server start), a second flow call;
* the drops end to end, engine 'local' (no Prefect) and 'prefect': every stage the
  pipeline times (summary['timings']: discover, ingest = hash + parse + Parquet,
  validate = the great-expectations suites, record, plan, load, science, store,
  snapshot), plus an idempotent re-run, best of --runs processes by total;  the 'ingest'
  and 'validate' of the first run include the one-time imports (great-expectations:
  seconds);
* in the same process run as the local pipeline, after it: ingest + validate again
  (as intake_batch does, warm, in the pipeline's batches, best of --repeat) and the
  floor on the same files -- a bare ``pyarrow.csv.read_csv`` of each file's data part and
  one numpy least-squares fit per run -- best of --repeat; the ratio
  (ingest + validate per file) / (bare read per file) is printed;
* optionally (--demo) ``accelcal demo`` wall time.

Default drops: every sample drop in ../shared/examples (drop-bad included).  --sim N adds
N simulated campaigns (11 runs each, as benchmarks/bench_fleet.py makes them).
Prints a markdown table; --readme FILE writes it between ``<!-- bench_pipeline:begin -->``
and ``<!-- bench_pipeline:end -->`` with the commit it ran on (and the raw numbers to
benchmarks/results/bench-pipeline.json); raw numbers always go to bench-out/bench.json.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
EXAMPLES = ROOT.parent / "shared" / "examples"
DEFAULT_DROPS = sorted(p for p in EXAMPLES.glob("drop-*") if p.is_dir()) or \
    [ROOT / "accelcal" / "demo_data" / "drop-demo"]
#: the stages a pipeline run times (summary['timings']), in order
STAGES = ("discover", "ingest", "validate", "record", "plan", "load", "science", "store",
          "snapshot")


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


def _drops(args) -> list[str]:
    return [str(d) for d in json.loads(args.drops)]


def child_pipeline(args) -> dict:
    from accelcal.flows.pipeline import quiet_prefect
    quiet_prefect()
    t0 = time.perf_counter()
    from accelcal.flows.pipeline import run_pipeline
    t_import = time.perf_counter() - t0
    drops = _drops(args)
    with tempfile.TemporaryDirectory() as tmp:
        db = Path(tmp) / "lab.duckdb"
        t0 = time.perf_counter()
        s1 = run_pipeline(drops, db, engine=args.engine, settle=0, allow_simulated=True)
        t_first = time.perf_counter() - t0
        t0 = time.perf_counter()
        s2 = run_pipeline(drops, db, engine=args.engine, settle=0, allow_simulated=True)
        t_rerun = time.perf_counter() - t0
    out = {"import": t_import, "first": t_first, "rerun": t_rerun,
           "stages": s1["timings"], "rerun_stages": s2["timings"],
           "files": sum(d["files"] for d in s1["drops"]),
           "accepted": sum(d["accepted"] for d in s1["drops"]),
           "refused": sum(d["refused"] for d in s1["drops"]),
           "campaigns": [c["status"] for c in s1["campaigns"]]}
    if args.engine == "local":      # the same process run: warm intake, then the floor
        groups = json.loads(args.groups) if args.groups else {"all drops": drops}
        out["intake"] = {g: warm_intake(ds, args.repeat) for g, ds in groups.items()}
        out["floor"] = {g: floor(ds, args.repeat) for g, ds in groups.items()}
    return out


def _best(fn, repeat: int):
    ts, val = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        val = fn()
        ts.append(time.perf_counter() - t0)
    return min(ts), val


def warm_intake(drops: list[str], repeat: int) -> dict:
    """ingest + validate of every file by the pipeline's own step (intake_batch, in the
    pipeline's batches), imports already done: best of ``repeat`` by wall time, split as the
    step splits it.  ``cpu``: the process's CPU time over the same work (every thread: the
    Parquet files are written in threads beside the parsing), so wall time gained by
    running two things at once is told apart from work saved."""
    from accelcal.flows.pipeline import batch_bytes, batch_files, file_batches
    from accelcal.schemas.dropscan import scan_drop
    from accelcal.tasks.validate import intake_batch
    batches = []
    for d in drops:
        bs = file_batches(scan_drop(os.path.realpath(d)), batch_files(), batch_bytes())
        batches += [(d, es, None if len(bs) == 1 else k) for k, es in enumerate(bs)]
    best = None
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            st = {"ingest": 0.0, "validate": 0.0, "files": 0}
            c0 = time.process_time()
            for d, es, part in batches:
                ing = intake_batch(d, es, f"{tmp}/pq", tmp, {}, f"{tmp}/docs", part, True)
                st["ingest"] += ing.stage_seconds["ingest"]
                st["validate"] += ing.stage_seconds["validate"]
                st["files"] += len(es)
            st["cpu"] = time.process_time() - c0
        if best is None or st["ingest"] + st["validate"] < best["ingest"] + best["validate"]:
            best = st
    best["batches"] = len(batches)
    return best


def floor(drops: list[str], repeat: int) -> dict:
    """The least any pipeline must do with the same files: a bare ``pyarrow.csv.read_csv``
    of each file's data part (where the header starts is found beforehand, untimed), then
    one numpy least-squares fit per run.  Files pyarrow cannot read are counted, not fitted."""
    import numpy as np
    import pyarrow.csv as pacsv

    from accelcal.schemas.dropscan import scan_drop
    files = [e.path for d in drops for e in scan_drop(os.path.realpath(d))
             if e.refusal is None]

    def skip_rows(p: str) -> int:
        n = 0
        with open(p, "rb") as f:
            for line in f:
                if line.startswith(b"#") or not line.strip():
                    n += 1
                else:
                    return n
        return n
    skips = {p: skip_rows(p) for p in files}

    def read():
        tables = []
        for p in files:
            try:
                tables.append(pacsv.read_csv(p, read_options=pacsv.ReadOptions(skip_rows=skips[p])))
            except Exception:
                tables.append(None)
        return tables

    def fit(tables):
        for t in tables:
            if t is None or "output" not in t.column_names:
                continue
            col = {c: t.column(c).to_numpy(zero_copy_only=False).astype(float)
                   for c in t.column_names}
            y = col["output"]
            if "step" in col and "table_rate_rad_s" in col:         # dwell means, poly in w^2
                step = np.nan_to_num(col["step"]).astype(int)
                cnt = np.bincount(step)
                ok = cnt > 0
                ym = (np.bincount(step, y) / np.maximum(cnt, 1))[ok]
                a = (np.bincount(step, col["table_rate_rad_s"] ** 2) / np.maximum(cnt, 1))[ok]
                X = np.vander(a, 4, increasing=True)
            else:                                                   # harmonics of the angle
                ang = col.get("angle_deg", col.get("rotation_deg", col.get("table_angle_deg")))
                th = np.radians(ang if ang is not None else np.zeros_like(y))
                X = np.column_stack([np.ones_like(th), np.cos(th), np.sin(th),
                                     np.cos(2 * th), np.sin(2 * th)])
                ym = y
            good = np.all(np.isfinite(X), axis=1) & np.isfinite(ym)
            if good.sum() >= X.shape[1]:
                np.linalg.lstsq(X[good], ym[good], rcond=None)

    tables = read()                         # warm the file cache and pyarrow
    t_read, tables = _best(read, repeat)
    t_fit, _ = _best(lambda: fit(tables), repeat)
    return {"files": len(files), "bytes": sum(os.path.getsize(p) for p in files),
            "rows": sum(t.num_rows for t in tables if t is not None),
            "unreadable": sum(t is None for t in tables),
            "read": t_read, "fit": t_fit}


def child_demo(args) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "accelcal", "demo", "--dir", tmp, "-q",
                            "--engine", args.engine], capture_output=True, text=True)
        wall = time.perf_counter() - t0
    return {"wall": wall, "rc": p.returncode, "stderr_tail": p.stderr[-500:]}


CHILDREN = {"prefect-startup": child_prefect_startup, "pipeline": child_pipeline,
            "demo": child_demo}


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


def table(res: dict) -> list[str]:
    """The markdown of a result (bench.json): stages on both engines, then the floor."""
    lo, pp = res["local"], res["prefect_pipeline"]
    lines = [f"Commit `{res['commit']}`; {res['cpus']} cpus, Python {res['python']}; drops: "
             f"{', '.join(res['drop_names'])}: {lo['files']} files, {lo['accepted']} accepted, "
             f"{lo['refused']} refused, {len(lo['campaigns'])} campaigns.", "",
             f"| stage (first run, cold imports; best of {res.get('runs', 1)} runs) "
             "| engine local | engine prefect |",
             "|---|---:|---:|"]
    stages = STAGES if "ingest" in lo["stages"] else \
        ("discover", "ingest+validate") + STAGES[3:]      # a version that timed them as one
    for k in stages:
        a, b = lo["stages"].get(k), pp["stages"].get(k)
        if a is not None or b is not None:
            lines.append(f"| {k} | {fmt(a)} | {fmt(b)} |")
    lines += [f"| **total** (wall) | {fmt(lo['first'])} | {fmt(pp['first'])} |",
              f"| re-run (nothing new) | {fmt(lo['rerun'])} | {fmt(pp['rerun'])} |"]
    if "prefect" in res:
        pf = res["prefect"]
        lines.append(f"| Prefect start-up (import + first flow call) | — | "
                     f"{fmt(pf['import_prefect'] + pf['first_flow'])} |")
    if "demo_local" in res:
        lines.append(f"| `accelcal demo` wall | {res['demo_local']['wall']:.1f} s | "
                     f"{res['demo_prefect']['wall']:.1f} s |")
    lines += ["", "A stage is the time inside it; with the prefect engine, tasks run side by side "
              "(thread runner), so its stages are summed over workers and exceed the wall time."]
    if res.get("loadavg"):
        lines[-1] += (f" Load average when the benchmark started: {res['loadavg']:.1f} on "
                      f"{res['cpus']} cpus (other jobs share the machine).")
    groups = list(lo["intake"])
    lines += ["", f"In the local run's process after it, imports done, best of {res['repeat']}; "
              "per file:", "",
              "| per file | " + " | ".join(groups) + " |",
              "|---|" + "---:|" * len(groups)]

    def row(name, get, fmt_=lambda x: f"{x * 1e3:.2f} ms"):
        lines.append(f"| {name} | " + " | ".join(fmt_(get(g)) for g in groups) + " |")
    iv, fl = lo["intake"], lo["floor"]
    n = {g: max(iv[g]["files"], 1) for g in groups}
    row("files (MB)", lambda g: (iv[g]["files"], fl[g]["bytes"] / 1e6),
        lambda x: f"{x[0]} ({x[1]:.2f} MB)")
    row("ingest: sha256 + parse + Parquet", lambda g: iv[g]["ingest"] / n[g])
    row("validate: great-expectations suites", lambda g: iv[g]["validate"] / n[g])
    row("**ingest + validate** (wall)", lambda g: (iv[g]["ingest"] + iv[g]["validate"]) / n[g])
    cpu = all("cpu" in iv[g] for g in groups)
    if cpu:
        row("ingest + validate, CPU time (all threads)", lambda g: iv[g]["cpu"] / n[g])
    row("floor: bare `pyarrow.csv.read_csv`", lambda g: fl[g]["read"] / n[g])
    row("floor: numpy least-squares fit", lambda g: fl[g]["fit"] / n[g])
    row("**ratio (ingest + validate) / bare read**",
        lambda g: (iv[g]["ingest"] + iv[g]["validate"]) / fl[g]["read"], lambda x: f"{x:.1f}×")
    if cpu:
        row("ratio, CPU time / bare read", lambda g: iv[g]["cpu"] / fl[g]["read"],
            lambda x: f"{x:.1f}×")
        lines += ["", "The Parquet files are written in threads beside the parsing, so on 2 "
                  "cores the wall time can be less than the CPU time; when every core is busy "
                  "(the fleet's 2 workers) the CPU row is the cost."]
    return lines


def write_readme(path: Path, lines: list[str], cmd: str) -> None:
    write_block(path, "bench_pipeline", "\n".join([f"Written by `{cmd}`; raw figures in "
                                                   "`benchmarks/results/bench-pipeline.json`.", ""] + lines))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--drop", type=Path, action="append", help="a drop (repeatable); "
                    "default: every sample drop")
    ap.add_argument("--sim", type=int, default=0, help="add N simulated campaigns")
    ap.add_argument("--repeat", type=int, default=3, help="best of N for the warm figures")
    ap.add_argument("--runs", type=int, default=3, help="pipeline runs per engine (best of N)")
    ap.add_argument("--engine", default="local")
    ap.add_argument("--demo", action="store_true", help="also time `accelcal demo`")
    ap.add_argument("--readme", type=Path, help="write the table into this README")
    ap.add_argument("--child", choices=sorted(CHILDREN))
    ap.add_argument("--drops", help=argparse.SUPPRESS)
    ap.add_argument("--groups", help=argparse.SUPPRESS)
    ap.add_argument("--from-json", type=Path, help="print (and --readme) the table of an "
                    "earlier run's bench.json instead of running")
    args = ap.parse_args()
    if args.from_json:
        lines = table(json.loads(args.from_json.read_text()))
        print("\n".join(lines))
        if args.readme:
            write_readme(args.readme, lines, "python benchmarks/bench_pipeline.py "
                         + " ".join(sys.argv[1:]))
        return
    if args.child:
        print(json.dumps(CHILDREN[args.child](args), default=str))
        return

    drops = [d.resolve() for d in (args.drop or DEFAULT_DROPS)]
    tmp = None
    if args.sim:
        tmp = Path(tempfile.mkdtemp(prefix="bench-pipeline-sim-"))
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from bench_fleet import simulate_fleet
        drops += simulate_fleet(args.sim, tmp, per_drop=max(args.sim, 1))[0]
    print(f"benchmarking on {len(drops)} drops ({os.cpu_count()} cpus, Python "
          f"{platform.python_version()})", file=sys.stderr)
    real = [d for d in drops if not tmp or tmp not in d.parents]
    res = {"commit": commit(), "drops": [str(d) for d in drops], "cpus": os.cpu_count(),
           "loadavg": os.getloadavg()[0],
           "argv": "python benchmarks/bench_pipeline.py " + " ".join(sys.argv[1:]),
           "python": platform.python_version(), "repeat": args.repeat,
           "drop_names": [d.name for d in real]
           + ([f"{args.sim} simulated campaigns"] if args.sim else [])}
    groups = {("sample drops" if not args.drop else "drops"): [str(d) for d in real]}
    if args.sim:
        groups[f"{args.sim} simulated campaigns"] = [str(d) for d in drops if d not in real]
    groups = {g: ds for g, ds in groups.items() if ds}
    try:
        dj = json.dumps(res["drops"])
        res["prefect"] = run_child("prefect-startup")
        # each pipeline run is a cold process: best of --runs (by total) of each engine
        local = [run_child("pipeline", drops=dj, engine="local", repeat=args.repeat,
                           groups=json.dumps(groups)) for _ in range(args.runs)]
        res["local"] = min(local, key=lambda r: r["first"])
        for g in groups:        # warm figures: the process whose ingest + validate was best
            best = min(local, key=lambda r: r["intake"][g]["ingest"] + r["intake"][g]["validate"])
            res["local"]["intake"][g], res["local"]["floor"][g] = best["intake"][g], best["floor"][g]
        res["prefect_pipeline"] = min((run_child("pipeline", drops=dj, engine="prefect",
                                                 repeat=args.repeat) for _ in range(args.runs)),
                                      key=lambda r: r["first"])
        res["runs"] = args.runs
        if args.demo:
            res["demo_prefect"] = run_child("demo", engine="prefect")
            res["demo_local"] = run_child("demo", engine="local")
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    out = ROOT / "bench-out"
    out.mkdir(exist_ok=True)
    (out / "bench.json").write_text(json.dumps(res, indent=2, default=str))
    lines = table(res)
    print("\n".join(lines))
    if args.readme:
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "bench-pipeline.json").write_text(json.dumps(res, indent=2, default=str))
        write_readme(args.readme, lines, res["argv"])


if __name__ == "__main__":
    main()
