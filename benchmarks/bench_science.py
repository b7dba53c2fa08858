"""Benchmark: science per campaign (``process_campaign``), this code against a reference commit.

    python benchmarks/bench_science.py [--ref a893528] [--repeat 5] [--simulated 8] [--rounds 3]
                                       [--readme README.md]

The same inputs go through both versions in one run: the lab's sample drops (../shared),
and ``--simulated`` campaigns per shipped scenario written once as drop files by the current
simulator.  The reference commit is checked out in a temporary git worktree and run with
PYTHONPATH pointing at it, so both versions parse the same bytes with their own parser.
Every campaign is timed ``--repeat`` times in a warm process, in CPU seconds of that process
(BLAS on one thread), so other jobs on the machine do not enter the figure; the table gives
the median per campaign and the ratio current/reference.  Writes benchmarks/results/science-timing.md,
and with ``--readme`` the same table between the README's ``<!-- bench-science:begin/end -->``
markers.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402
SHARED = ROOT / ".." / "shared"
RESULTS = Path(__file__).with_name("results")
SAMPLES = {"drop-2026-11-20 (tumble + 10 mounts)": "examples/drop-2026-11-20",
           "drop-2026-11-21 (tumble + 6 mounts)": "examples/drop-2026-11-21",
           "drop-2026-11-18-thermal": "examples/drop-2026-11-18-thermal",
           "drop-2026-11-19-sine": "examples/drop-2026-11-19-sine",
           "imucal X (real, 2 tumbles)": "real/imucal-ferraris"}

WORKER = r'''
import json, sys, time, glob, statistics, warnings
import numpy as np
warnings.simplefilter("ignore")
from accelcal.schemas.dropformat import read_run
from accelcal.estimators.campaign import process_campaign
cases = json.loads(sys.argv[1]); repeat = int(sys.argv[2])
out = {}
for label, files in cases.items():
    runs = [read_run(p) for p in files]
    process_campaign(runs)                      # warm: imports, caches
    ts = []
    for _ in range(repeat):
        t = time.process_time(); process_campaign(runs); ts.append(time.process_time() - t)
    out[label] = statistics.median(ts)
print(json.dumps(out))
'''


def _git(*args) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout.strip()


def _cases(tmp: Path, n_sim: int) -> dict[str, list[str]]:
    cases = {}
    for label, rel in SAMPLES.items():
        files = sorted(str(p) for p in (SHARED / rel).rglob("*.csv"))
        if "imucal" in label:
            files = [f for f in files if "-X-" in f]
        cases[label] = files
    if n_sim:
        from accelcal.simulate import simulate_campaign
        from accelcal.simulate.io import write_drop
        for name in ("snj103-lxj100", "qa5512-sine", "hust-m07-thermal"):
            for seed in range(n_sim):
                d = tmp / f"{name}-{seed}"
                write_drop(simulate_campaign(name, seed), d)
                cases[f"sim {name} #{seed}"] = sorted(str(p) for p in d.rglob("*.csv"))
    return cases


def _time(code: Path, cases: dict, repeat: int) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    p = subprocess.run([sys.executable, "-c", WORKER, json.dumps(cases), str(repeat)], cwd=str(code),
                       env=env, capture_output=True, text=True, check=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref", default="a893528", help="reference commit (default: before issue 9)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--simulated", type=int, default=4, help="simulated campaigns per scenario")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds of reference and current")
    ap.add_argument("--readme", type=Path, help="also write the table into this README")
    args = ap.parse_args(argv)
    head = commit()
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        cases = _cases(tmp, args.simulated)
        ref_dir = tmp / "ref"
        _git("worktree", "add", "--detach", str(ref_dir), args.ref)
        try:
            # alternate the two versions round by round, so a change in the machine's load
            # during the run falls on both alike; per campaign the median over the rounds
            rounds = [(_time(ref_dir, cases, args.repeat), _time(ROOT, cases, args.repeat))
                      for _ in range(args.rounds)]
        finally:
            _git("worktree", "remove", "--force", str(ref_dir))
        ref = {k: statistics.median(r[k] for r, _ in rounds) for k in cases}
        cur = {k: statistics.median(c[k] for _, c in rounds) for k in cases}
    rows = ["| campaign | reference (s) | current (s) | current / reference |", "|---|---:|---:|---:|"]
    for label in cases:
        if not label.startswith("sim "):
            rows.append(f"| {label} | {ref[label]:.3f} | {cur[label]:.3f} | {cur[label] / ref[label]:.2f} |")
    groups: dict[str, list[str]] = {}
    for label in cases:
        if label.startswith("sim "):
            groups.setdefault(label.split(" #")[0], []).append(label)
    for g, labels in groups.items():
        r = statistics.median(ref[x] for x in labels)
        c = statistics.median(cur[x] for x in labels)
        rows.append(f"| {g} (median of {len(labels)}) | {r:.3f} | {c:.3f} | {c / r:.2f} |")
    all_r = statistics.median(ref.values())
    all_c = statistics.median(cur.values())
    rows.append(f"| **median over all campaigns** | **{all_r:.3f}** | **{all_c:.3f}** | **{all_c / all_r:.2f}** |")
    text = (f"Science per campaign (`process_campaign`, CPU seconds, median of {args.repeat} warm runs, one thread, "
            f"median over {args.rounds} alternating rounds), "
            f"current commit {head} against {args.ref}, "
            f"same inputs, one run of `python benchmarks/bench_science.py`:\n\n" + "\n".join(rows) + "\n")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "science-timing.md").write_text(text, encoding="utf-8")
    print(text)
    if args.readme:
        write_block(args.readme, "bench-science", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
