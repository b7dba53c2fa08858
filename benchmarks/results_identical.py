#!/usr/bin/env python
"""Do two versions of accelcal store the same results?  (issue 13: "results identical,
table by table, before and after")

    # dump what one version stores (run it once per version, PYTHONPATH picks the version)
    PYTHONPATH=/tmp/base python benchmarks/results_identical.py dump --campaigns 200 \\
        --sim-dir /tmp/ri-sim --out /tmp/ri-base.json
    PYTHONPATH=.          python benchmarks/results_identical.py dump --campaigns 200 \\
        --sim-dir /tmp/ri-sim --out /tmp/ri-new.json
    python benchmarks/results_identical.py compare /tmp/ri-base.json /tmp/ri-new.json

``dump`` runs the pipeline (engine local unless --engine / --task-runner say otherwise,
settle 0, simulated files allowed) on the sample drops (``../shared/examples/drop-*``,
drop-bad included) and on N simulated campaigns (scenario snj103-lxj100, as
benchmarks/bench_fleet.py makes them; written once to ``--sim-dir`` and reused, so both
versions read the very same files at the same paths), into a fresh warehouse, then writes
every warehouse table and every Parquet file canonically: rows sorted, floats as
``float.hex`` (bit-exact), one sha256 per table.

Columns left out, and why (they differ between any two runs, or by definition between two
versions of the code, whatever the results):

* ``ingested_at``, ``checked_at``, ``computed_at``, ``activated_at``, ``acted_at``: the
  wall-clock time of the run;
* ``flow_run_id``: a new uuid per pipeline run;
* ``code_version`` (results, lineage): the digest of accelcal's source, which any change
  changes;
* ``validator_version`` (run_verdicts, refusals): the digest of the parser + suites
  source, likewise;
* ``schema_info`` rows ``schema_version`` and ``extras_dir`` (``SCHEMA_KEYS_EXCLUDED``):
  the layout of the warehouse, not its results; left out of both sides by ``compare``;
* ``results.extras_sha256`` (schema 3) is replaced by ``extras``: the JSON text of the file
  it names, read (and checked against the sha256) -- the very text schema 2 stored in the
  ``extras`` column, so a dump compares with one made before the extras became files;
* ``result_id`` is *not* left out but replaced by ``<campaign>#<k>`` (k: its rank among
  the campaign's results by the sorted input hashes): it is a hash over code_version, so
  it differs whenever code_version does; the campaign and the inputs it names do not.
  The same replacement is made where a result id is quoted in a ``parameters`` JSON
  (``prior_results``: the results a campaign was offered as priors).

The Parquet files are compared by their path under the warehouse, schema and every
value (their schema metadata minus ``validator_version`` / ``code_version`` keys, if any).
``compare`` prints, per table, equal or the rows only in one side; where a row differs in
floats only it prints the largest absolute and relative difference -- no tolerance.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared" / "examples"

#: columns never compared (see the module docstring for why)
EXCLUDED = {"ingested_at", "checked_at", "computed_at", "activated_at", "acted_at",
            "flow_run_id", "code_version", "validator_version"}
#: schema_info keys never compared (see the module docstring)
SCHEMA_KEYS_EXCLUDED = {"schema_version", "extras_dir"}
_META_EXCLUDED = {b"validator_version", b"code_version", b"accelcal_validator_version",
                  b"accelcal_code_version"}


def simulate(n: int, out: Path, per_drop: int = 50) -> list[Path]:
    """N campaigns as bench_fleet makes them, written once to ``out`` (reused after)."""
    done = out / f".done-{n}"
    if done.exists():
        return sorted(p for p in out.iterdir() if p.is_dir())
    if out.exists():
        shutil.rmtree(out)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_fleet import simulate_fleet
    drops, _ = simulate_fleet(n, out, per_drop)
    done.write_text("")
    return drops


def _cell(v):
    if isinstance(v, float):
        return "nan" if math.isnan(v) else v.hex()
    if isinstance(v, (list, tuple)):
        return [_cell(x) for x in v]
    if isinstance(v, dict):
        return {k: _cell(x) for k, x in v.items()}
    if v is None or isinstance(v, (bool, int, str)):
        return v
    return str(v)


def dump_warehouse(db: Path) -> dict:
    import duckdb
    con = duckdb.connect(str(db), read_only=True)
    tables = [r[0] for r in con.execute(
        "SELECT table_name FROM information_schema.tables WHERE table_type = 'BASE TABLE' "
        "AND table_schema = 'main' ORDER BY table_name").fetchall()]
    rid = {}
    res = con.execute("SELECT result_id, campaign, input_sha256 FROM results").fetchall()
    by_camp: dict[str, list] = {}
    for r, c, inp in res:
        by_camp.setdefault(c, []).append((inp, r))
    for c, lst in by_camp.items():
        for k, (_, r) in enumerate(sorted(lst)):
            rid[r] = f"{c}#{k}"
    extras_text = None
    if "extras_sha256" in {c for (c,) in con.execute(
            "SELECT column_name FROM information_schema.columns WHERE table_name = 'results'"
            ).fetchall()}:
        from accelcal.warehouse.extras import extras_root_of, read_extras_text
        root = extras_root_of(con, db)

        def extras_text(sha):
            return None if sha is None else read_extras_text(root, sha)
    out = {}
    for t in tables:
        cur = con.execute(f'SELECT * FROM "{t}"')
        cols = [d[0] for d in cur.description]
        keep = [i for i, c in enumerate(cols) if c not in EXCLUDED]
        rows = []
        for row in cur.fetchall():
            rec = {}
            for i in keep:
                v = row[i]
                if cols[i] == "result_id" and v in rid:
                    v = rid[v]
                if cols[i] == "parameters" and isinstance(v, str) and "prior_results" in v:
                    for r, alias in rid.items():
                        v = v.replace(r, alias)
                if cols[i] == "extras_sha256" and extras_text is not None:
                    rec["extras"] = extras_text(v)
                    continue
                rec[cols[i]] = _cell(v)
            rows.append(rec)
        rows.sort(key=lambda r: json.dumps(r, sort_keys=True))
        out[t] = {"columns": [c if c != "extras_sha256" or extras_text is None else "extras"
                              for c in (cols[i] for i in keep)],
                  "excluded": [c for c in cols if c in EXCLUDED], "rows": rows}
    con.close()
    return out


def dump_parquet(root: Path) -> dict:
    import pyarrow.parquet as pq
    out = {}
    for p in sorted(root.rglob("*.parquet")):
        t = pq.read_table(p)
        meta = {k.decode(): v.decode("utf-8", "replace")
                for k, v in (t.schema.metadata or {}).items() if k not in _META_EXCLUDED}
        h = hashlib.sha256()
        for name, col in zip(t.column_names, t.columns):
            h.update(f"{name}:{col.type}\0".encode())
            h.update(json.dumps(_cell(col.to_pylist())).encode())
        out[str(p.relative_to(root))] = {"rows": t.num_rows, "data_sha256": h.hexdigest(),
                                         "schema_metadata": meta}
    return out


def cmd_dump(args) -> int:
    import accelcal
    from accelcal.flows.pipeline import run_pipeline
    samples = sorted(str(p) for p in EXAMPLES.glob("drop-*") if p.is_dir())
    sim = [str(p) for p in simulate(args.campaigns, Path(args.sim_dir))] if args.campaigns else []
    work = Path(tempfile.mkdtemp(prefix="results-identical-"))
    try:
        db = work / "lab.duckdb"
        t0 = time.perf_counter()
        s = run_pipeline(samples + sim, db, engine=args.engine, task_runner=args.task_runner,
                         settle=0, allow_simulated=True)
        secs = time.perf_counter() - t0
        tables = dump_warehouse(db)
        pq_root = next((p for p in work.iterdir() if p.is_dir() and any(p.rglob("*.parquet"))),
                       None)
        parquet = dump_parquet(pq_root) if pq_root else {}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    digest = {t: hashlib.sha256(json.dumps(v["rows"], sort_keys=True).encode()).hexdigest()
              for t, v in tables.items()}
    doc = {"accelcal": accelcal.__file__, "campaigns": args.campaigns, "drops": samples + sim,
           "pipeline_seconds": secs, "table_sha256": digest, "excluded_columns": sorted(EXCLUDED),
           "tables": tables, "parquet": parquet,
           "summary": {"accepted": sum(d["accepted"] for d in s["drops"]),
                       "refused": sum(d["refused"] for d in s["drops"]),
                       "campaigns": len(s["campaigns"])}}
    Path(args.out).write_text(json.dumps(doc, sort_keys=True))
    print(f"{args.out}: {doc['summary']}, pipeline {secs:.1f} s ({accelcal.__file__})")
    for t, d in sorted(digest.items()):
        print(f"  {t:24s} {len(tables[t]['rows']):7d} rows  {d[:16]}")
    return 0


def _floats_only_diff(a: dict, b: dict):
    """(max abs, max rel, columns) when rows a and b differ in float cells only, else None."""
    if a.keys() != b.keys():
        return None
    worst_abs = worst_rel = 0.0
    cols = []
    for k in a:
        x, y = a[k], b[k]
        if x == y:
            continue
        try:
            fx, fy = float.fromhex(x), float.fromhex(y)
        except (TypeError, ValueError):
            return None
        d = abs(fx - fy)
        worst_abs = max(worst_abs, d)
        worst_rel = max(worst_rel, d / max(abs(fx), abs(fy), 1e-300))
        cols.append(k)
    return worst_abs, worst_rel, cols


def _comparable(table: str, rows: list | None) -> list | None:
    """The rows compared: schema_info without the layout keys (SCHEMA_KEYS_EXCLUDED)."""
    if table != "schema_info" or rows is None:
        return rows
    return [r for r in rows if r.get("key") not in SCHEMA_KEYS_EXCLUDED]


def cmd_compare(args) -> int:
    A = json.loads(Path(args.a).read_text())
    B = json.loads(Path(args.b).read_text())
    print(f"A: {args.a} ({A['accelcal']}), {A['campaigns']} simulated campaigns, {A['summary']}")
    print(f"B: {args.b} ({B['accelcal']}), {B['campaigns']} simulated campaigns, {B['summary']}")
    print(f"excluded columns: {', '.join(A['excluded_columns'])}")
    same = True
    for t in sorted(set(A["tables"]) | set(B["tables"])):
        ra = _comparable(t, A["tables"].get(t, {}).get("rows"))
        rb = _comparable(t, B["tables"].get(t, {}).get("rows"))
        if ra == rb:
            print(f"  {t:24s} identical ({len(ra)} rows)")
            continue
        same = False
        if ra is None or rb is None:
            print(f"  {t:24s} only in {'B' if ra is None else 'A'}")
            continue
        sa = {json.dumps(r, sort_keys=True) for r in ra}
        sb = {json.dumps(r, sort_keys=True) for r in rb}
        only_a = [json.loads(x) for x in sorted(sa - sb)]
        only_b = [json.loads(x) for x in sorted(sb - sa)]
        print(f"  {t:24s} DIFFERS: {len(ra)} vs {len(rb)} rows, {len(only_a)} only in A, "
              f"{len(only_b)} only in B")
        if A["tables"][t]["columns"] != B["tables"][t]["columns"]:
            print(f"    columns: {A['tables'][t]['columns']} vs {B['tables'][t]['columns']}")
        for x, y in zip(only_a, only_b):
            d = _floats_only_diff(x, y)
            if d is not None:
                print(f"    floats differ in {d[2]}: max abs {d[0]:.3g}, max rel {d[1]:.3g}")
            else:
                print(f"    A: {json.dumps(x)[:300]}\n    B: {json.dumps(y)[:300]}")
            if args.verbose < 1:
                break
    pa_, pb = A["parquet"], B["parquet"]
    if pa_ == pb:
        print(f"  {'parquet files':24s} identical ({len(pa_)} files, every value)")
    else:
        same = False
        diff = sorted(k for k in set(pa_) | set(pb) if pa_.get(k) != pb.get(k))
        print(f"  {'parquet files':24s} DIFFER: {len(diff)} of {len(set(pa_) | set(pb))}, "
              f"e.g. {diff[:3]}")
        for k in diff[:3]:
            print(f"    {k}: A {pa_.get(k)}\n    {' ' * len(k)}  B {pb.get(k)}")
    print("IDENTICAL" if same else "NOT IDENTICAL")
    return 0 if same else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("--campaigns", type=int, default=20)
    d.add_argument("--sim-dir", default=str(Path(tempfile.gettempdir()) / "results-identical-sim"))
    d.add_argument("--out", required=True)
    d.add_argument("--engine", default="local", choices=("local", "prefect"),
                   help="the engine that runs the pipeline (default local)")
    d.add_argument("--task-runner", default="thread",
                   help="with --engine prefect: thread, dask or a scheduler address")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    c.add_argument("-v", "--verbose", action="count", default=0)
    args = ap.parse_args(argv)
    os.environ.setdefault("GX_ANALYTICS_ENABLED", "False")
    return cmd_dump(args) if args.cmd == "dump" else cmd_compare(args)


if __name__ == "__main__":
    raise SystemExit(main())
