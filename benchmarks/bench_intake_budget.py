#!/usr/bin/env python
"""Where ingest + validate spends its time, part by part, against the bare read (a script,
not a test).

    python benchmarks/bench_intake_budget.py [--campaigns 20 90] [--repeat 5]
                                             [--sim-cache DIR] [--readme README.md]

For each fleet size N (N simulated campaigns of 11 runs in one drop, as
benchmarks/bench_fleet.py makes them; the pipeline cuts a drop into batches of at most
1,000 files, so 20 campaigns are one batch of 220 files and 90 one batch of 990), on the
same files, in this process, imports done, each part alone and single-threaded, CPU time
(``time.process_time``), best of --repeat:

* **bare read**: ``pyarrow.csv.read_csv`` of each file's data part (bench_pipeline.floor);
* **sha256**: reading each file's bytes and hashing them (what lineage needs);
* **parse**: the drop-format parser on those bytes (dropformat.parse_runs, one joint call
  per batch, as ingest does);
* **Parquet**: one content-addressed Parquet file per run (tables.write_run_parquet); and,
  for comparison only, the same rows as one file per batch and test kind (what a layout
  without a file per run would cost; the pipeline does not write it);
* **derived columns + batch table**: what the suites check besides the raw columns;
* **great-expectations**: the batch's suite, BOOLEAN_ONLY, on its two tables; and the same
  suite on one row of each table: the part of its cost that does not depend on the data
  (graph building, metric configuration; per expectation);
* **validation**: the whole of it as the pipeline calls it (suites.validate_report with
  its Data Docs): the derived columns, the suite, the refusals' texts, the pages;
* **intake_batch**: the pipeline's own step on the same files (everything above, with its
  writes in threads): CPU time of all threads.

The budget line is 3 × the bare read (issue 13's must-hold).  Prints a markdown table;
--readme writes it between ``<!-- bench_intake_budget:begin -->`` and ``...:end -->``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _cpu_best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def _ge_suite_seconds(tables: dict, specs: list, repeat: int) -> float:
    """The batch's suite on ``tables``, BOOLEAN_ONLY, as suites._validate_batch runs it
    first (no re-run of failures: a clean batch has none)."""
    from accelcal.schemas import suites

    def once():
        for table, df in tables.items():
            which = [i for i, sp in enumerate(specs) if sp[1] == table]
            suites.run_suite(f"budget.{table}", table, df, specs, which,
                             {"result_format": "BOOLEAN_ONLY"})
    once()
    return _cpu_best(once, repeat)


def measure(drop: str, repeat: int) -> dict:
    """Every part, CPU seconds for all the drop's files (see the module doc)."""
    from bench_pipeline import floor

    from accelcal.flows.pipeline import batch_bytes, batch_files, file_batches
    from accelcal.schemas import suites
    from accelcal.schemas.dropformat import parse_runs
    from accelcal.schemas.dropscan import scan_drop
    from accelcal.schemas.tables import write_run_parquet
    from accelcal.tasks.validate import intake_batch

    entries = scan_drop(os.path.realpath(drop))
    batches = file_batches(entries, batch_files(), batch_bytes())
    paths = [[e.path for e in b] for b in batches]
    out: dict = {"files": len(entries), "batches": len(batches)}
    out["bare_read"] = floor([drop], repeat)["read"]

    def read_hash():
        raws = []
        for b in paths:
            for p in b:
                with open(p, "rb") as f:
                    raw = f.read()
                hashlib.sha256(raw).hexdigest()
                raws.append(raw)
        return raws
    raws = read_hash()
    out["sha256"] = _cpu_best(read_hash, repeat)
    by_batch, k = [], 0
    for b in paths:
        by_batch.append([(raws[k + i], p) for i, p in enumerate(b)])
        k += len(b)
    out["parse"] = _cpu_best(lambda: [parse_runs(x) for x in by_batch], repeat)
    runs = [parse_runs(x) for x in by_batch]
    tmp = Path(tempfile.mkdtemp(prefix="bench-intake-budget-"))
    try:
        def parquet():
            root = Path(tempfile.mkdtemp(dir=tmp))
            for b in runs:
                for r in b:
                    write_run_parquet(r, root)
        out["parquet"] = _cpu_best(parquet, repeat)

        def parquet_per_batch(row_group_per_run: bool):
            """Not what the pipeline writes: the same runs as one file per batch and test
            kind (the per-run metadata left out), to show what that layout would cost."""
            import pyarrow as pa
            import pyarrow.parquet as pq

            from accelcal.schemas import tables as T

            def write():
                root = Path(tempfile.mkdtemp(dir=tmp))
                for k, b in enumerate(runs):
                    kinds: dict = {}
                    for r in b:
                        kinds.setdefault(r.test, []).append(T.run_table(r).replace_schema_metadata(None))
                    for test, ts in kinds.items():
                        path = root / f"{k}-{test}.parquet"
                        if row_group_per_run:
                            with pq.ParquetWriter(path, ts[0].schema, compression="zstd") as w:
                                for t in ts:
                                    w.write_table(t)
                        else:
                            pq.write_table(pa.concat_tables(ts), path, compression="zstd")
            return _cpu_best(write, repeat)
        out["parquet_batch"] = parquet_per_batch(False)
        out["parquet_batch_rg"] = parquet_per_batch(True)

        def derive_and_table():
            made = []
            for b in runs:
                items = [(r, r.test, suites._derive(r.test, r)) for r in b]
                tables, columns, *_ = suites._batch_table(items)
                kinds = list(dict.fromkeys(r.test for r in b))
                made.append((tables, suites._batch_specs(kinds, columns)))
            return made
        made = derive_and_table()
        out["derive_table"] = _cpu_best(derive_and_table, repeat)
        out["expectations"] = sum(len(specs) for _, specs in made)
        out["ge"] = sum(_ge_suite_seconds(t, s, repeat) for t, s in made)
        out["ge_one_row"] = sum(_ge_suite_seconds({k: df.iloc[:1] for k, df in t.items()}, s, repeat)
                                for t, s in made)
        def with_docs():
            d = Path(tempfile.mkdtemp(dir=tmp))
            for k, b in enumerate(runs):
                suites.validate_report(b, d, f"part-{k}")
        out["validate_docs"] = _cpu_best(with_docs, repeat)

        def intake():
            w = Path(tempfile.mkdtemp(dir=tmp))
            for k, b in enumerate(batches):
                intake_batch(drop, b, str(w / "pq"), str(w), {}, str(w / "docs"),
                             None if len(batches) == 1 else k, True)
        intake()
        out["intake_batch"] = _cpu_best(intake, repeat)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def table(res: dict) -> list[str]:
    groups = list(res["groups"])
    lines = [f"Commit `{res['commit']}`; {res['cpus']} cpus, Python {res['python']}; CPU time "
             f"(process_time), each part alone, best of {res['repeat']}; ms per file.", "",
             "| part | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
    G = res["groups"]

    def row(name, get, f=lambda x: f"{x * 1e3:.2f}"):
        lines.append(f"| {name} | " + " | ".join(f(get(G[g])) for g in groups) + " |")
    per = lambda k: lambda g: g[k] / g["files"]         # noqa: E731
    row("files in batches", lambda g: (g["files"], g["batches"]), lambda x: f"{x[0]} in {x[1]}")
    row("**bare read** (`pyarrow.csv.read_csv`)", per("bare_read"))
    row("**budget: 3 × bare read**", lambda g: 3 * g["bare_read"] / g["files"])
    row("read + sha256", per("sha256"))
    row("parse (drop format, joint per batch)", per("parse"))
    row("Parquet, one file per run", per("parquet"))
    row("(not written: one file per batch and kind, one row group)", per("parquet_batch"))
    row("(not written: the same, a row group per run)", per("parquet_batch_rg"))
    row("validation, with Data Docs (suites.validate_report)", per("validate_docs"))
    row("… of which derived columns + batch table", per("derive_table"))
    row("… of which the great-expectations suite (BOOLEAN_ONLY)", per("ge"))
    row("… … of which the same suite on 1 row a table", per("ge_one_row"))
    row("expectations in the batch suite", lambda g: g["expectations"], lambda x: f"{x}")
    row("**sum of the parts**", lambda g: sum(g[k] for k in ("sha256", "parse", "parquet",
                                                              "validate_docs")) / g["files"])
    row("**intake_batch** (the pipeline's step, all threads)", per("intake_batch"))
    row("intake_batch / bare read", lambda g: g["intake_batch"] / g["bare_read"],
        lambda x: f"{x:.1f}×")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--campaigns", type=int, nargs="+", default=[20, 90])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--sim-cache", type=Path, help="keep the simulated drops here and reuse them")
    ap.add_argument("--readme", type=Path)
    args = ap.parse_args()
    from bench_fleet import cached_fleet, simulate_fleet
    from accelcal.flows.pipeline import quiet_prefect
    quiet_prefect()
    res = {"commit": commit(), "cpus": os.cpu_count(), "python": platform.python_version(),
           "repeat": args.repeat, "loadavg": os.getloadavg()[0],
           "argv": "python benchmarks/bench_intake_budget.py " + " ".join(sys.argv[1:]),
           "groups": {}}
    for n in args.campaigns:
        tmp = None
        if args.sim_cache:
            drops, _ = cached_fleet(n, n, args.sim_cache)
        else:
            tmp = Path(tempfile.mkdtemp(prefix="bench-intake-sim-"))
            drops, _ = simulate_fleet(n, tmp, per_drop=n)
        try:
            res["groups"][f"{n} campaigns"] = measure(str(drops[0]), args.repeat)
        finally:
            if tmp:
                shutil.rmtree(tmp, ignore_errors=True)
        print(f"{n} campaigns: {json.dumps(res['groups'][f'{n} campaigns'])}", file=sys.stderr)
    lines = table(res)
    print("\n".join(lines))
    out = ROOT / "bench-out"
    out.mkdir(exist_ok=True)
    (out / "bench-intake-budget.json").write_text(json.dumps(res, indent=2))
    if args.readme:
        RESULTS.mkdir(exist_ok=True)
        (RESULTS / "bench-intake-budget.json").write_text(json.dumps(res, indent=2))
        write_block(args.readme, "bench_intake_budget",
                    "\n".join([f"Written by `{res['argv']}`; raw figures in "
                               "`benchmarks/results/bench-intake-budget.json`.", ""] + lines))


if __name__ == "__main__":
    main()
