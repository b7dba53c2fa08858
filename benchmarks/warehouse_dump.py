#!/usr/bin/env python
"""Dump every warehouse table canonically, to compare two versions of the code.

    python benchmarks/warehouse_dump.py dump --campaigns N --work DIR --out FILE
    python benchmarks/warehouse_dump.py compare A B

``dump`` runs the pipeline (local engine, settle 0) on the lab's sample drops
(``../shared/examples/drop-*``, into one warehouse) and on N simulated campaigns
(``bench_fleet.simulate_fleet``, made once under DIR/sim and reused, so two dumps see the
same absolute paths; into a second warehouse), then writes every base table of both
warehouses: all rows, sorted, floats as ``float.hex`` (bit-exact), one JSON line per row.
The accelcal code that runs is whichever ``import accelcal`` finds (PYTHONPATH).

Left out, because they differ between two runs of the same inputs by construction:

* ``ingested_at``, ``checked_at``, ``computed_at``, ``activated_at``: wall-clock time of
  the run;
* ``flow_run_id``: a uuid per run;
* ``code_version``: the digest of the accelcal sources, which is what differs between
  the two versions compared;
* ``result_id`` (results and every table keyed by it) is sha256(campaign, inputs,
  code_version, parameters), so it changes with code_version: it is replaced by
  ``<campaign>|<sha256 of the result's input_sha256 and parameters>``, which names the
  same result in both dumps.

Nothing else is left out: sequence numbers (verdict and activation order), revisions,
paths, JSON texts and every float are compared exactly.

``compare`` says per table whether the two dumps are equal, and for rows that differ
(matched by their key columns) which columns and, for floats, by how much.
"""
from __future__ import annotations

import argparse
import glob
import hashlib
import json
import math
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT.parent / "shared" / "examples"

VOLATILE = {"ingested_at", "checked_at", "computed_at", "activated_at", "flow_run_id",
            "code_version"}
#: Columns that identify a row within its table (for reporting differences).
KEYS = {"run_files": ("sha256", "source_path"),
        "run_verdicts": ("sha256", "source_path", "validator_version"),
        "refusals": ("sha256", "source_path", "validator_version", "seq"),
        "results": ("result_id",), "result_activations": ("campaign", "result_id"),
        "lineage": ("result_id", "sha256"), "campaign_actions": ("seq",),
        "schema_info": ("key",)}


def _value(v):
    if isinstance(v, float):
        return "nan" if math.isnan(v) else v.hex()
    if isinstance(v, (list, tuple)):
        return [_value(x) for x in v]
    return v if v is None or isinstance(v, (int, str, bool)) else str(v)


def dump_warehouse(path: Path, label: str) -> list[dict]:
    import duckdb
    con = duckdb.connect(str(path), read_only=True)
    try:
        names = {}
        for rid, camp, inputs, params in con.execute(
                "SELECT result_id, campaign, input_sha256, parameters FROM results").fetchall():
            names[rid] = f"{camp}|{hashlib.sha256((inputs + params).encode()).hexdigest()[:16]}"
        tables = [t for (t,) in con.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_type = 'BASE TABLE' "
            "ORDER BY table_name").fetchall()]
        out = []
        for t in tables:
            cols = [c for (c,) in con.execute(
                "SELECT column_name FROM information_schema.columns WHERE table_name = ? "
                "ORDER BY ordinal_position", [t]).fetchall()]
            keep = [c for c in cols if c not in VOLATILE]
            rows = []
            for r in con.execute(f"SELECT {', '.join(keep)} FROM {t}").fetchall():
                row = dict(zip(keep, (_value(v) for v in r)))
                if "result_id" in row:
                    row["result_id"] = names.get(row["result_id"], "?" + str(row["result_id"]))
                rows.append(row)
            rows.sort(key=lambda d: json.dumps(d, sort_keys=True))
            out.append({"warehouse": label, "table": t, "columns": keep,
                        "excluded": [c for c in cols if c in VOLATILE], "n": len(rows)})
            out.extend({"warehouse": label, "table": t, "row": r} for r in rows)
        return out
    finally:
        con.close()


def dump(args) -> int:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_fleet import simulate_fleet
    import accelcal
    from accelcal.flows.pipeline import run_pipeline
    work = Path(args.work)
    sim = work / "sim"
    done = sim / f".done-{args.campaigns}"
    if not done.exists():
        import shutil
        shutil.rmtree(sim, ignore_errors=True)
        sim.mkdir(parents=True)
        simulate_fleet(args.campaigns, sim, per_drop=50)
        done.write_text("")
    sim_drops = sorted(str(p) for p in sim.glob("drop-*"))
    samples = sorted(glob.glob(str(EXAMPLES / "drop-*")))
    out_rows = []
    with tempfile.TemporaryDirectory(prefix="wh-dump-", dir=work) as tmp:
        for label, drops in (("samples", samples), (f"fleet-{args.campaigns}", sim_drops)):
            if not drops:
                continue
            wh = Path(tmp) / label / "lab.duckdb"
            s = run_pipeline(drops, wh, engine="local", settle=0, create=True,
                             allow_simulated=True)
            st = {}
            for c in s["campaigns"]:
                st[c["status"]] = st.get(c["status"], 0) + 1
            print(f"{label}: {len(drops)} drops, campaigns {st}, "
                  f"{s['timings']['total']:.1f} s", file=sys.stderr)
            out_rows += dump_warehouse(wh, label)
            pq = wh.parent / "lab-parquet"
            out_rows.append({"warehouse": label, "table": "(parquet files)", "files": sorted(
                str(p.relative_to(pq)) for p in pq.rglob("*.parquet"))})
    with open(args.out, "w") as f:
        f.write(json.dumps({"accelcal": accelcal.__file__, "campaigns": args.campaigns,
                            "samples": samples, "excluded": sorted(VOLATILE)}) + "\n")
        for r in out_rows:
            f.write(json.dumps(r, sort_keys=True) + "\n")
    print(f"wrote {args.out}: {len(out_rows)} lines", file=sys.stderr)
    return 0


def _load(path: str) -> dict:
    tables: dict = {}
    with open(path) as f:
        next(f)
        for line in f:
            d = json.loads(line)
            key = (d["warehouse"], d["table"])
            tables.setdefault(key, []).append(d.get("row", d))
    return tables


def _fdiff(a, b) -> str:
    try:
        x, y = float.fromhex(a), float.fromhex(b)
    except (TypeError, ValueError):
        return ""
    rel = abs(x - y) / max(abs(x), abs(y)) if max(abs(x), abs(y)) else 0.0
    return f" (|Δ| {abs(x - y):.3g}, relative {rel:.3g})"


def compare(args) -> int:
    a, b = _load(args.a), _load(args.b)
    same = True
    for key in sorted(set(a) | set(b)):
        ra, rb = a.get(key, []), b.get(key, [])
        if ra == rb:
            n = len(ra[0]["files"]) if key[1] == "(parquet files)" else len(ra) - 1
            print(f"{key[0]:>12} {key[1]:<22} equal ({n} {'files' if 'files' in ra[0] else 'rows'})")
            continue
        same = False
        print(f"{key[0]:>12} {key[1]:<22} DIFFERS: {len(ra)} vs {len(rb)} lines")
        kc = KEYS.get(key[1], ("result_id", "seq"))
        ia = {tuple(r.get(c) for c in kc): r for r in ra if "columns" not in r}
        ib = {tuple(r.get(c) for c in kc): r for r in rb if "columns" not in r}
        shown = 0
        for k in sorted(set(ia) | set(ib), key=str):
            x, y = ia.get(k), ib.get(k)
            if x == y:
                continue
            if shown < args.show:
                if x is None or y is None:
                    print(f"    {k}: only in {'B' if x is None else 'A'}")
                else:
                    for c in x:
                        if x[c] != y.get(c):
                            print(f"    {k}: {c}: {x[c]!r} vs {y.get(c)!r}{_fdiff(x[c], y.get(c))}")
            shown += 1
        if shown > args.show:
            print(f"    ... {shown - args.show} more rows differ")
    print("IDENTICAL" if same else "DIFFERENT")
    return 0 if same else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("dump")
    d.add_argument("--campaigns", type=int, default=20)
    d.add_argument("--work", required=True, help="folder for the simulated drops (reused)")
    d.add_argument("--out", required=True)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    c.add_argument("--show", type=int, default=5)
    args = ap.parse_args(argv)
    os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
    return dump(args) if args.cmd == "dump" else compare(args)


if __name__ == "__main__":
    sys.exit(main())
