#!/usr/bin/env python
"""Peak memory of ``accelcal run`` on one big raw run file (issue 28, "Big files in bounded
memory").

    python benchmarks/bench_bigfile.py [--cases centrifuge-200 thermal-200 centrifuge-1000]
                                       [--keep DIR] [--readme README.md]

Each case copies a sample drop (``../shared/examples``) into a temporary drop folder and
makes one of its runs about N MB by giving every dwell more readings, in the DAQ's exact
format: each dwell's rows are repeated, their ``time_s`` continuing at the run's sample
period, every other cell written exactly as the DAQ wrote it (so the dwell means are those
of the sample).  Then ``accelcal run`` (engine local, one process, settle 0) runs on that
drop in a subprocess, and its peak RSS is measured twice: sampled with psutil over the
process tree every 50 ms, and as ``ru_maxrss`` of the finished child
(``resource.getrusage(RUSAGE_CHILDREN)``, from a fresh helper process per case so no
earlier case counts).  The table gives the file size, rows, wall time, both peaks, and
whether the run was accepted and its campaign computed.

--readme writes the table between ``<!-- bench_bigfile:begin -->`` and ``...:end -->``.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = Path(os.environ.get("ACCELCAL_SHARED", ROOT.parent / "shared")) / "examples"
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402

#: case -> (sample drop, the run file made big, the columns that name a dwell, MB)
CASES = {
    "centrifuge-200": ("drop-2026-11-20", "centrifuge/LXJ100-20261120-0002.csv", ("step",), 200),
    "thermal-200": ("drop-2026-11-18-thermal", "TT1-20261118-0001.csv",
                    ("temp_set_c", "rotation_deg"), 200),
    "centrifuge-1000": ("drop-2026-11-20", "centrifuge/LXJ100-20261120-0002.csv", ("step",), 1000),
    "thermal-1000": ("drop-2026-11-18-thermal", "TT1-20261118-0001.csv",
                     ("temp_set_c", "rotation_deg"), 1000),
    # no bound: that the peak no longer grows with the file (issue 28, "What to build")
    "centrifuge-3000": ("drop-2026-11-20", "centrifuge/LXJ100-20261120-0002.csv", ("step",), 3000),
}
#: the bounds issue 28 asks for (MB of peak RSS), by file size
BOUND_MB = {200: 1000, 1000: 1500}


def _fmt_time(t: float) -> str:
    s = repr(float(t))
    return s[:-2] if s.endswith(".0") else s


def make_big_run(src: Path, dst: Path, dwell_cols: tuple[str, ...], mb: float) -> int:
    """Write ``src`` with every dwell's readings repeated (k times, k chosen so the file is
    about ``mb`` MB) to ``dst``; return the number of data rows written.

    A dwell is a maximal block of consecutive rows with the same ``dwell_cols`` cells.  Its
    i-th repeat is the dwell's rows with ``time_s`` moved by i times the dwell's length
    (last minus first time plus one sample period); every later row moves by the time the
    repeats added, so time still increases and the gaps between dwells are kept.  Only
    ``time_s`` is rewritten; every other cell is the DAQ's text."""
    lines = src.read_text(encoding="utf-8").splitlines()
    meta = [ln for ln in lines if ln.startswith("#")]
    header = lines[len(meta)]
    rows = [ln for ln in lines[len(meta) + 1:] if ln.strip()]
    names = header.split(",")
    period = float(next(ln.split(":", 1)[1] for ln in meta if ln.startswith("# sample_period_s")))
    ti = names.index("time_s")
    keys = [names.index(c) for c in dwell_cols]
    cells = [r.split(",") for r in rows]
    dwells: list[list[list[str]]] = []
    for c in cells:
        if dwells and all(dwells[-1][0][k] == c[k] for k in keys):
            dwells[-1].append(c)
        else:
            dwells.append([c])
    body = sum(len(r) + 1 for r in rows)
    head = sum(len(ln) + 1 for ln in meta) + len(header) + 1
    k = max(1, round((mb * 1e6 - head) / body))
    # the repeats' times are longer numbers than the sample's: size k on the last time's
    spans = sum(float(d[-1][ti]) - float(d[0][ti]) + period for d in dwells)
    t_end = float(cells[-1][ti]) + (k - 1) * spans
    body = body - sum(len(c[ti]) for c in cells) + len(cells) * len(_fmt_time(t_end))
    k = max(1, round((mb * 1e6 - head) / body))
    n = 0
    with open(dst, "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(meta) + "\n" + header + "\n")
        shift = 0.0
        for d in dwells:
            t = [float(c[ti]) for c in d]
            span = t[-1] - t[0] + period
            rest = [(c[:ti], c[ti + 1:]) for c in d]
            for i in range(k):
                dt = shift + i * span
                f.write("".join(",".join(a + [_fmt_time(tt + dt)] + b) + "\n"
                                for tt, (a, b) in zip(t, rest)))
            n += k * len(d)
            shift += (k - 1) * span
    return n


MEASURE = r'''
import json, resource, subprocess, sys, time
t = time.perf_counter()
p = subprocess.run(sys.argv[1:], capture_output=True, text=True)
out = {"rc": p.returncode, "seconds": time.perf_counter() - t,
       "maxrss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
       "err": p.stderr[-4000:]}
try:
    s = json.loads(p.stdout)
    out["files"] = sum(d["files"] for d in s["drops"])
    out["accepted"] = sum(d["accepted"] for d in s["drops"])
    out["campaigns"] = [c["status"] for c in s["campaigns"]]
except (ValueError, KeyError, TypeError):
    out["stdout"] = p.stdout[-2000:]
print(json.dumps(out))
'''


def sampled_peak(cmd, env) -> tuple[dict, float]:
    """Run ``cmd`` (the MEASURE helper); its result and the peak RSS (MB) of its process
    tree, sampled every 50 ms."""
    import psutil
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    peak = 0.0
    while p.poll() is None:
        try:
            pr = psutil.Process(p.pid)
            kids = pr.children(recursive=True)
            rss = sum(c.memory_info().rss for c in kids)      # the helper itself not counted
            peak = max(peak, rss / 2 ** 20)
        except psutil.Error:
            pass
        time.sleep(0.05)
    out, err = p.communicate()
    if p.returncode != 0:
        raise SystemExit(f"measuring helper failed: {err.decode()[-2000:]}")
    return json.loads(out), peak


def run_case(name: str, work: Path, size_mb: float | None = None) -> dict:
    drop_name, rel, dwell_cols, mb = CASES[name]
    mb = size_mb or mb
    drop = work / name / drop_name
    shutil.copytree(EXAMPLES / drop_name, drop)
    big = drop / rel
    os.chmod(big.parent, 0o755)
    big.unlink()
    t0 = time.perf_counter()
    rows = make_big_run(EXAMPLES / drop_name / rel, big, dwell_cols, mb)
    t_make = time.perf_counter() - t0
    wh = work / name / "wh" / "lab.duckdb"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(__import__("accelcal").__file__).resolve().parents[1])]
        + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    cmd = [sys.executable, "-c", MEASURE, sys.executable, "-m", "accelcal", "run", str(drop),
           "-w", str(wh), "--create", "--engine", "local", "--settle", "0", "-q", "--json"]
    res, peak = sampled_peak(cmd, env)
    ok = res["rc"] == 0
    accepted = f"{res['accepted']}/{res['files']}" if "files" in res else None
    computed = bool(res.get("campaigns")) and all(c == "new" for c in res["campaigns"])
    return {"case": name, "size_mb": big.stat().st_size / 1e6, "rows": rows, "make_s": t_make,
            "rc": res["rc"], "ok": ok, "seconds": res["seconds"], "maxrss_mb": res["maxrss_mb"],
            "sampled_mb": peak, "bound_mb": BOUND_MB.get(mb), "accepted": accepted,
            "computed": computed, "err": "" if ok else res["err"][-600:]}


def table(results: list[dict], before: dict[str, dict] | None = None) -> str:
    b_col = before is not None
    out = ["| case | file | rows | wall | peak RSS (ru_maxrss) | peak RSS (sampled, tree) | bound | accepted | campaign computed |"
           + (" before: peak RSS, wall |" if b_col else ""),
           "|---|---|---|---|---|---|---|---|---|" + ("---|" if b_col else "")]
    for r in results:
        extra = ""
        if b_col:
            o = (before or {}).get(r["case"])
            extra = (f" {max(o['maxrss_mb'], o['sampled_mb']):.0f} MB, {o['seconds']:.0f} s |"
                     if o and o.get("rows") == r["rows"] else " — |")
        peak = max(r["maxrss_mb"], r["sampled_mb"])
        within = "" if r["bound_mb"] is None else (" ✓" if peak <= r["bound_mb"] else " ✗")
        out.append(f"| {r['case']} | {r['size_mb']:.0f} MB | {r['rows']:,} | {r['seconds']:.0f} s | "
                   f"{r['maxrss_mb']:.0f} MB | {r['sampled_mb']:.0f} MB | "
                   f"{'—' if r['bound_mb'] is None else str(r['bound_mb']) + ' MB' + within} | "
                   f"{r['accepted']} | {'yes' if r['computed'] else 'NO'} |{extra}")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["centrifuge-200", "thermal-200", "centrifuge-1000",
                                                   "thermal-1000", "centrifuge-3000"],
                    choices=sorted(CASES))
    ap.add_argument("--size-mb", type=float, help="make every case's run this big instead "
                    "(a quick check; no bound applies)")
    ap.add_argument("--keep", type=Path, help="make the drops and warehouses here and keep them")
    ap.add_argument("--json", type=Path, help="also write the results as JSON")
    ap.add_argument("--before", type=Path, help="a --json of another version (e.g. PYTHONPATH="
                    "naming the code before a change): its peak and wall time as a column")
    ap.add_argument("--readme", type=Path)
    args = ap.parse_args(argv)
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench-bigfile-"))
    work.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for name in args.cases:
            r = run_case(name, work, args.size_mb)
            results.append(r)
            print(f"{name}: {json.dumps({k: v for k, v in r.items() if k != 'err'})}", flush=True)
            if r["err"]:
                print(r["err"], file=sys.stderr)
            if not args.keep:
                shutil.rmtree(work / name, ignore_errors=True)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    before, before_commit = None, "?"
    if args.before:
        b = json.loads(args.before.read_text())
        before = {r["case"]: r for r in b["results"]}
        before_commit = b.get("commit", "?")
    text = table(results, before)
    print(text)
    if args.json:
        args.json.write_text(json.dumps({"commit": commit(), "results": results}, indent=1))
    if args.readme:
        c = commit()
        body = (f"`python benchmarks/bench_bigfile.py --readme README.md`, commit {c}; "
                f"2 cores, engine local, one process.  Peak RSS of `accelcal run` on a drop "
                f"whose one run is made N MB (a sample run with every dwell's readings repeated "
                f"in the DAQ's format)"
                + (f"; before: the same drops with the code of commit {before_commit}"
                   if args.before else "")
                + f":\n\n{text}\n")
        write_block(args.readme, "bench_bigfile", body)
    return 0 if all(r["ok"] for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
