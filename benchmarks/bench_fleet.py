#!/usr/bin/env python
"""Fleet benchmark (issue 5): many simulated campaigns through the pipeline.

    python benchmarks/bench_fleet.py --campaigns 20 100 [--per-drop 50] [--engine local]
                                     [--task-runner thread|dask] [--workers N]
                                     [--out bench-out/fleet]
                                     [--readme README.md]

For each size N (a fresh child process, so peak memory is per size):
  1. simulate N campaigns with accelcal.simulate (scenario snj103-lxj100: one tumble +
     10 centrifuge runs each), units SNF-0000.. of two models, written as drops of
     --per-drop campaigns;
  2. run the pipeline on all drops (one call), timing every step (summary['timings']);
  3. apply views.sql and time the history / change / fleet / rig views;
  4. the floor, in the same child process, before and after the pipeline (the ratio is to
     their mean): read every file's data with pyarrow's CSV
     reader and do one numpy least-squares fit per run (dwell means + polynomial in the
     table rate for a centrifuge run, harmonics of the head angle for a tumble run) --
     the least any pipeline must do; the ratio pipeline / floor is printed.
Every stage is timed on both engines, as wall time of the flow process (the columns sum
to the pipeline time; 'other' is what no stage claims), and, for the stages that run as
tasks, as time inside the tasks summed over workers.
Prints a markdown table; raw numbers to <out>/bench-fleet.json; with --readme FILE the
table replaces what stands between <!-- bench_fleet:begin --> and <!-- bench_fleet:end -->,
headed by the commit of the accelcal code that ran.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def simulate_fleet(n: int, out: Path, per_drop: int, seed0: int = 1000) -> tuple[list[Path], int]:
    from accelcal.simulate import SCENARIO_DIR, load_scenario, simulate_campaign, write_drop
    sc = load_scenario(SCENARIO_DIR / "snj103-lxj100.toml")
    drops: list[Path] = []
    n_runs = 0
    for k in range(n):
        runs = simulate_campaign(sc, seed=seed0 + k)
        serial = f"SNF-{k // 4:04d}"                       # 4 calibrations per unit
        model = "QA-2000" if (k // 4) % 2 == 0 else "QA-3000"
        for r in runs:
            r.meta["run_id"] = f"{r.meta['run_id']}-{k:05d}"
            r.meta["unit_serial"] = serial
            r.meta["unit_model"] = model
            r.meta["campaign"] = f"{serial}/cal-{k % 4}"
            r.meta["started_at"] = f"202{k % 4 + 2}-0{(k % 9) + 1}-1{k % 10}T09:00:00+08:00"
        drop = out / f"drop-{k // per_drop:04d}"
        if not drops or drops[-1] != drop:
            drops.append(drop)
        write_drop(runs, drop)
        n_runs += len(runs)
    return drops, n_runs


def cached_fleet(n: int, per_drop: int, cache: Path) -> tuple[list[Path], int]:
    """simulate_fleet's drops kept under ``cache`` and reused (the simulation is the same
    for the same n, per_drop and seeds; it is not part of what is timed).  The pipeline
    only reads a drop, so one copy serves every run."""
    d = cache / f"n{n}-per{per_drop}"
    done = d / "complete.json"
    if done.exists():
        info = json.loads(done.read_text())
        return [d / x for x in info["drops"]], int(info["runs"])
    drops, n_runs = simulate_fleet(n, d, per_drop)
    done.write_text(json.dumps({"drops": [x.name for x in drops], "runs": n_runs}))
    return drops, n_runs


def numpy_floor(files: list[Path]) -> dict:
    """Read (pyarrow CSV reader) + one least-squares fit per run with bare numpy (the floor)."""
    import numpy as np
    from pyarrow import csv as pacsv
    t0 = time.perf_counter()
    t_read = 0.0
    for f in files:
        ta = time.perf_counter()
        with open(f, "rb") as fh:
            skip = 0
            for line in fh:
                if not line.startswith(b"#"):
                    break
                skip += 1
        tbl = pacsv.read_csv(f, read_options=pacsv.ReadOptions(skip_rows=skip))
        col = {h: tbl.column(h).to_numpy(zero_copy_only=False).astype(float)
               for h in tbl.column_names}
        t_read += time.perf_counter() - ta
        y = col["output"]
        if "table_rate_rad_s" in col:
            step = col["step"].astype(int)
            w = col["table_rate_rad_s"]
            cnt = np.bincount(step)
            ok = cnt > 0
            ym = (np.bincount(step, y) / np.maximum(cnt, 1))[ok]
            a = (np.bincount(step, w * w) / np.maximum(cnt, 1))[ok] * 0.71
            good = np.isfinite(ym) & np.isfinite(a)
            X, ym = np.vander(a[good], 4, increasing=True), ym[good]
        else:
            th = np.radians(col["angle_deg"])
            X = np.column_stack([np.ones_like(th), np.cos(th), np.sin(th), np.cos(2 * th),
                                 np.sin(2 * th)])
            good = np.isfinite(y) & np.isfinite(th)
            X, ym = X[good], y[good]
        np.linalg.lstsq(X, ym, rcond=None)
    total = time.perf_counter() - t0
    return {"seconds": total, "read_seconds": t_read, "runs_per_s": len(files) / total,
            "reader": "pyarrow.csv"}


#: Stages as the flow process lives them (wall time; they sum to the pipeline time but
#: for 'other'): name -> the summary['timings'] keys that make it.  A stage that runs as
#: tasks is the submit (the local engine runs the task there) plus the wait for results.
FLOW_STAGES = {
    "discover": ("discover",),
    "ingest+validate": ("ingest+validate (submit)", "ingest+validate (wait)"),
    "record": ("record",),
    "plan": ("plan",),
    "load+science": ("science (submit)", "science (wait)"),
    "store": ("store",),
    "summary": ("summary",),
    "snapshot": ("snapshot",),
}
#: Time inside the tasks (summed over workers): where the flow's waiting goes; and the
#: CPU seconds the workers spent in them (``<stage> cpu``), which on a machine with other
#: work say what a task costs when its wall time says how long it waited for a core.
TASK_STAGES = ("ingest+validate", "load", "science")


def stage_times(r: dict) -> dict[str, float]:
    t = r["timings"]
    out = {k: sum(t.get(x, 0.0) for x in keys) for k, keys in FLOW_STAGES.items()}
    out["other"] = r["pipeline_s"] - sum(out.values())
    for k in TASK_STAGES:
        out[f"task {k}"] = t.get(k, 0.0)
        out[f"cpu {k}"] = t.get(f"{k} cpu", 0.0)
    return out


def worker_count(summary: dict, runner: str) -> int:
    """Worker processes besides the flow process: the local engine's pool, or Dask's."""
    if runner == "dask":
        return int(os.environ.get("ACCELCAL_DASK_WORKERS") or os.cpu_count() or 1)
    n = int(summary.get("workers") or 1)
    return n if n > 1 else 0


def peak_rss_total(r: dict) -> float:
    """Peak RSS of the flow process plus, for each worker process, the largest peak any
    ended child had (an upper bound of what the workers held at once) [MB]."""
    return r["peak_rss_mb"] + (r.get("workers") or 0) * (r.get("peak_rss_children_mb") or 0.0)


def child(args) -> dict:
    n, per_drop, engine, runner, keep = args.n, args.per_drop, args.engine, args.task_runner, args.keep
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench-fleet-"))
    root.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    drops, n_runs = cached_fleet(n, per_drop, Path(args.sim_cache)) if args.sim_cache \
        else simulate_fleet(n, root / "watch", per_drop)
    t_sim = time.perf_counter() - t0
    files = sorted(p for d in drops for p in d.rglob("*.csv"))
    # every file read once first, untimed, so the floors and the pipeline all find them in
    # the page cache (a floor reading them from disk took 6.1 s where it took 2.2 s after)
    for f in files:
        f.read_bytes()
    # the floor before the pipeline and again after it: this machine's speed moves by half
    # within minutes, and one floor taken in a fast or slow moment moved the ratio by as much
    floor_before = numpy_floor(files)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    load_before = os.getloadavg()[0]
    from accelcal.flows.pipeline import run_pipeline
    from accelcal.warehouse import ensure_views
    wh = root / "lab.duckdb"
    cpu0 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    s = run_pipeline([str(d) for d in drops], wh, engine=engine, task_runner=runner,
                     allow_simulated=True)
    t_pipe = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    # CPU seconds of the flow process and of the ended children (Dask workers): on a busy
    # machine they say more than wall times
    cpu_flow, cpu_children = ((b.ru_utime + b.ru_stime) - (a.ru_utime + a.ru_stime)
                              for a, b in zip(cpu0, cpu1))
    rss_peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    rss_children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss   # Dask workers, ended
    statuses: dict[str, int] = {}
    for c in s["campaigns"]:
        statuses[c["status"]] = statuses.get(c["status"], 0) + 1
    ensure_views(wh)
    import duckdb
    con = duckdb.connect(str(wh), read_only=True)
    queries = {
        "unit_history (one unit)": "SELECT * FROM unit_history WHERE unit_serial = 'SNF-0001'",
        "coefficient_changes (all)": "SELECT count(*) FROM coefficient_changes WHERE exceeds_uncertainty",
        "fleet_stats": "SELECT * FROM fleet_stats",
        "fleet_outliers": "SELECT * FROM fleet_outliers",
        "rig_comparison": "SELECT * FROM rig_comparison",
        "unit_history_as_of(now)": "SELECT count(*) FROM unit_history_as_of(now())",
    }
    lat = {}
    for name, q in queries.items():
        best = 1e9
        for _ in range(3):
            ta = time.perf_counter()
            con.execute(q).fetchall()
            best = min(best, time.perf_counter() - ta)
        lat[name] = best
    n_coef = con.execute("SELECT count(*) FROM coefficient_history").fetchall()[0][0]
    n_out = con.execute("SELECT count(*) FROM fleet_outliers").fetchall()[0][0]
    n_exc = con.execute("SELECT count(*) FROM coefficient_changes WHERE exceeds_uncertainty").fetchall()[0][0]
    n_chg = con.execute("SELECT count(*) FROM coefficient_changes").fetchall()[0][0]
    con.close()
    floor = numpy_floor(files)
    floor_mean = (floor_before["seconds"] + floor["seconds"]) / 2
    # idempotent re-run: nothing new
    t0 = time.perf_counter()
    s2 = run_pipeline([str(d) for d in drops], wh, engine=engine, task_runner=runner,
                      allow_simulated=True)
    t_rerun = time.perf_counter() - t0
    return {"campaigns": n, "runs": n_runs, "drops": len(drops), "engine": engine,
            "commit": commit(), "load_before": load_before, "load_after": os.getloadavg()[0],
            "task_runner": runner, "simulate_s": t_sim, "pipeline_s": t_pipe,
            "runs_per_s": n_runs / t_pipe, "timings": s["timings"], "statuses": statuses,
            "cpu_flow_s": cpu_flow, "cpu_children_s": cpu_children,
            "peak_rss_mb": rss_peak / 1024, "rss_before_pipeline_mb": rss_before / 1024,
            "peak_rss_children_mb": rss_children / 1024, "workers": worker_count(s, runner),
            "batch_files": int(os.environ.get("ACCELCAL_BATCH_FILES", 0)) or None,
            "in_flight": int(os.environ.get("ACCELCAL_IN_FLIGHT", 0)) or None,
            "query_latency_s": lat, "coefficient_rows": n_coef, "changes": n_chg,
            "changes_exceeding_U": n_exc, "fleet_outliers": n_out,
            "numpy_floor": floor, "numpy_floor_before": floor_before,
            "ratio_pipeline_to_floor": t_pipe / floor_mean,
            "ratio_range": sorted(t_pipe / f["seconds"] for f in (floor_before, floor)),
            "rerun_s": t_rerun,
            "rerun_statuses": sorted({c["status"] for c in s2["campaigns"]})}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--campaigns", type=int, nargs="+", default=[20, 100])
    ap.add_argument("--per-drop", type=int, default=50)
    ap.add_argument("--engine", default="local", choices=("local", "prefect"))
    ap.add_argument("--task-runner", default="thread", choices=("thread", "dask"))
    ap.add_argument("--workers", type=int, default=None,
                    help="worker processes: for --engine local, the local engine's pool "
                         "(sets ACCELCAL_WORKERS; default 1, the flow process itself); for "
                         "--task-runner dask, Dask workers of one thread each (sets "
                         "ACCELCAL_DASK_WORKERS; default one per core)")
    ap.add_argument("--out", default=str(ROOT / "bench-out" / "fleet"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--keep", default=None, help="keep the simulated drops + warehouse here")
    ap.add_argument("--sim-cache", default=None,
                    help="simulate each fleet once into this folder and reuse it")
    ap.add_argument("--readme", default=None,
                    help="write the table into this file between <!-- bench_fleet:begin --> "
                         "and <!-- bench_fleet:end -->")
    args = ap.parse_args(argv)
    if args.child:
        print("RESULT " + json.dumps(child(args), default=str))
        return 0
    if args.workers is not None:
        if args.task_runner == "dask":
            os.environ["ACCELCAL_DASK_WORKERS"] = str(max(1, args.workers))
        elif args.engine == "local":
            os.environ["ACCELCAL_WORKERS"] = str(max(1, args.workers))
        else:
            ap.error("--workers needs --engine local or --task-runner dask")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for n in args.campaigns:
        cmd = [sys.executable, __file__, "--child", "--n", str(n), "--per-drop", str(args.per_drop),
               "--engine", args.engine, "--task-runner", args.task_runner] \
            + (["--sim-cache", args.sim_cache] if args.sim_cache else []) \
            + (["--keep", str(Path(args.keep) / f"n{n}")] if args.keep else [])
        p = subprocess.run(cmd, capture_output=True, text=True)
        line = next((l for l in p.stdout.splitlines() if l.startswith("RESULT ")), None)
        if p.returncode != 0 or line is None:
            print(p.stderr[-3000:], file=sys.stderr)
            return 1
        r = json.loads(line[7:])
        results.append(r)
        print(f"{n} campaigns: {r['runs']} runs in {r['pipeline_s']:.1f} s "
              f"({r['runs_per_s']:.1f} runs/s), peak RSS {r['peak_rss_mb']:.0f} MB; CPU s "
              f"flow {r['cpu_flow_s']:.1f} + ended children {r['cpu_children_s']:.1f}; load "
              f"{r['load_before']:.1f} -> {r['load_after']:.1f}", flush=True)
        st = stage_times(r)
        print("  " + ", ".join(f"{k} {v:.1f}" for k, v in st.items()), flush=True)
        print("  CPU in tasks a campaign: " + ", ".join(
            f"{k} {1e3 * st['cpu ' + k] / n:.0f} ms" for k in TASK_STAGES), flush=True)
        print(f"  floor {_floors(r)} s, ratio {r['ratio_pipeline_to_floor']:.1f}×{_ratio_range(r)}, "
              f"re-run {r['rerun_s']:.1f} s", flush=True)
    meta = {"python": sys.version.split()[0], "machine": platform.machine(),
            "cpus": os.cpu_count()}
    (out / "bench-fleet.json").write_text(json.dumps({"meta": meta, "results": results},
                                                     indent=1, default=str))
    md = report(results, args)
    print()
    print(md)
    if args.readme:
        write_block(Path(args.readme), "bench_fleet", md)
    return 0


def _floors(r: dict) -> str:
    """The floor before / after the pipeline [s] (one figure for a result that has one)."""
    before = r.get("numpy_floor_before")
    after = f"{r['numpy_floor']['seconds']:.2f}"
    return f"{before['seconds']:.2f} / {after}" if before else after


def _ratio_range(r: dict) -> str:
    """The ratio to each floor alone, when they differ in the rounding shown."""
    lo, hi = r.get("ratio_range") or (None, None)
    return f" ({lo:.0f}–{hi:.0f})" if lo is not None and f"{lo:.0f}" != f"{hi:.0f}" else ""


def report(results: list[dict], args) -> str:
    """The markdown: one row per size, every stage; the floor and the ratio; re-run time."""
    engine = args.engine + (f" + {args.task_runner}" if args.engine == "prefect" else "")
    workers = os.environ.get("ACCELCAL_DASK_WORKERS")
    if args.task_runner == "dask":
        engine += f" ({workers or os.cpu_count()} workers)"
    flag = f" --workers {workers}" if args.task_runner == "dask" and workers else ""
    if args.engine == "local" and int(os.environ.get("ACCELCAL_WORKERS") or 1) > 1:
        n = os.environ["ACCELCAL_WORKERS"]
        engine += f" ({n} worker processes + the flow process, which writes the warehouse)"
        flag = f" --workers {n}"
    r0 = results[0]
    lines = [f"Fleet benchmark (`python benchmarks/bench_fleet.py --campaigns "
             f"{' '.join(str(r['campaigns']) for r in results)} --engine {args.engine}"
             + (f" --task-runner {args.task_runner}" if args.task_runner != "thread" else "")
             + flag
             + f"`), commit {r0['commit']}, {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores "
             f"(load average {r0['load_before']:.1f} at the start), engine {engine}.",
             "",
             "Stage times in s, wall time of the flow process (they sum to the pipeline time; "
             "'other' is what no stage claims: opening the warehouse, Prefect and Dask start). "
             "'in tasks' is time inside the ingest/validate and load/science tasks, summed over "
             "workers; 'CPU a campaign' the CPU time the workers spent in them, per campaign. "
             "Floor: pyarrow CSV read + one numpy least-squares fit per run, same "
             "process, run before and after the pipeline; the ratio is to their mean (in "
             "brackets, to each alone, when they differ).",
             "",
             "| campaigns | runs | pipeline s | runs/s | peak RSS MB | "
             + " | ".join(FLOW_STAGES) + " | other | in tasks: ingest+validate / load / science "
             "| CPU a campaign ms: ingest+validate / load / science "
             "| floor s | ratio to floor | re-run s |",
             "|---|---|---|---|---|" + "---|" * (len(FLOW_STAGES) + 6)]
    for r in results:
        st = stage_times(r)
        rss = f"{r['peak_rss_mb']:.0f}"
        if r.get("workers") and r.get("peak_rss_children_mb"):
            rss += (f" + {r['workers']} × {r['peak_rss_children_mb']:.0f} workers "
                    f"= {peak_rss_total(r):.0f}")
        elif r.get("peak_rss_children_mb"):
            rss += f" + {r['peak_rss_children_mb']:.0f} workers"
        lines.append(
            f"| {r['campaigns']} | {r['runs']} | {r['pipeline_s']:.1f} | {r['runs_per_s']:.1f} "
            f"| {rss} | " + " | ".join(f"{st[k]:.1f}" for k in FLOW_STAGES)
            + f" | {st['other']:.1f} | "
            + " / ".join(f"{st['task ' + k]:.1f}" for k in TASK_STAGES) + " | "
            + " / ".join(f"{1e3 * st['cpu ' + k] / r['campaigns']:.0f}" for k in TASK_STAGES)
            + f" | {_floors(r)} | {r['ratio_pipeline_to_floor']:.0f}×{_ratio_range(r)} "
            f"| {r['rerun_s']:.1f} |")
    lines += ["", "| query | " + " | ".join(f"{r['campaigns']} campaigns" for r in results) + " |",
              "|---|" + "---|" * len(results)]
    for q in r0["query_latency_s"]:
        lines.append(f"| {q} | " + " | ".join(f"{1e3 * r['query_latency_s'][q]:.1f} ms"
                                             for r in results) + " |")
    if len(results) >= 2:
        a, b = results[0], results[-1]
        lines += ["", f"Peak RSS {b['campaigns']} / {a['campaigns']} campaigns"
                      + (" (flow process + workers)" if a.get("workers") else "") + ": "
                      f"{peak_rss_total(b) / peak_rss_total(a):.2f}×; time per campaign "
                      f"{a['pipeline_s'] / a['campaigns']:.3f} → "
                      f"{b['pipeline_s'] / b['campaigns']:.3f} s."]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
