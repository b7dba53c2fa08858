"""Benchmark: science per campaign (``process_campaign``), this code against a reference commit.

    python benchmarks/bench_science.py [--ref ee91499 --ref 0bb4def] [--repeat 5] [--simulated 4]
                                       [--rounds 3] [--readme README.md] [--instructions]

The same inputs go through every version in one run: the lab's sample drops (../shared),
and ``--simulated`` campaigns per shipped scenario written once as drop files by the current
simulator.  Each reference commit is checked out in a temporary git worktree and run with
PYTHONPATH pointing at it, so every version parses the same bytes with its own parser.
Every campaign is timed ``--repeat`` times in a warm process, in CPU seconds of that process
(BLAS on one thread), the versions of a round at the same time, so other jobs on the machine
enter the figure only through shared caches, and alike for every version; the table gives the median per campaign and the ratio current/reference per
reference.  Writes benchmarks/results/science-timing.md,
and with ``--readme`` the same table between the README's ``<!-- bench-science:begin/end -->``
markers.

``--instructions`` counts each campaign's machine instructions with valgrind's callgrind
instead (one round; benchmarks/results/science-instructions.md, the README's
``bench-science-instructions`` block): a figure the machine's other work does not move,
for changes smaller than the CPU seconds' noise.
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
import json, os, subprocess, sys, time, glob, statistics, warnings
import numpy as np
warnings.simplefilter("ignore")
from accelcal.schemas.dropformat import read_run
from accelcal.estimators.campaign import process_campaign
cases = json.loads(sys.argv[1]); repeat = int(sys.argv[2])
out = {}
count = os.environ.get("BENCH_CALLGRIND_DUMPS")     # under callgrind: count, do not time
def callgrind(*a):
    subprocess.run(["callgrind_control", *a, str(os.getpid())], capture_output=True, check=True)
for k, (label, files) in enumerate(cases.items()):
    runs = [read_run(p) for p in files]
    process_campaign(runs)                      # warm: imports, caches
    if count:
        callgrind("-z"); callgrind("-i", "on")
        for _ in range(repeat):
            process_campaign(runs)
        callgrind("-i", "off"); callgrind("-d", f"case{k}")
        continue
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


def _time(codes: dict[str, Path], cases: dict, repeat: int) -> dict[str, dict[str, float]]:
    """Each version's timings, the versions run at the same time (one process each), so
    that the machine's other work falls on every version alike: run one after the other
    on a shared machine, their ratios moved by up to 1.5 x with the load between them."""
    procs = {}
    for v, code in codes.items():
        env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
        procs[v] = subprocess.Popen([sys.executable, "-c", WORKER, json.dumps(cases), str(repeat)],
                                    cwd=str(code), env=env, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
    out = {}
    for v, p in procs.items():
        stdout, stderr = p.communicate()
        if p.returncode:
            raise RuntimeError(f"{v}: {stderr[-2000:]}")
        out[v] = json.loads(stdout.strip().splitlines()[-1])
    return out


def _instructions(codes: dict[str, Path], cases: dict, repeat: int, tmp: Path) -> dict[str, dict[str, float]]:
    """Each version's machine instructions per warm campaign, counted by valgrind's
    callgrind (``repeat`` runs of each campaign, the count divided by ``repeat``): the same
    number on a busy machine as on a quiet one, where CPU seconds move by a third.
    Under valgrind numpy takes its AVX2 loops, not AVX-512: a count, not a time."""
    procs = {}
    for v, code in codes.items():
        out = tmp / f"callgrind-{v}" / "cg.out"
        out.parent.mkdir()
        env = {**os.environ, "PYTHONPATH": str(code), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
               "BENCH_CALLGRIND_DUMPS": "1"}
        procs[v] = (out, subprocess.Popen(
            ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}",
             os.path.realpath(sys.executable), "-c", WORKER, json.dumps(cases), str(repeat)],
            cwd=str(code), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    counts = {}
    for v, (out, p) in procs.items():
        _, stderr = p.communicate()
        if p.returncode:
            raise RuntimeError(f"{v}: {stderr[-2000:]}")
        got = {}
        for dump in out.parent.glob("cg.out.*"):
            text = dump.read_text(errors="replace")
            trigger = next(ln.split("dump ", 1)[1] for ln in text.splitlines() if ln.startswith("desc: Trigger"))
            total = next(int(ln.split()[1]) for ln in text.splitlines() if ln.startswith("totals:"))
            got[trigger] = total / repeat
        counts[v] = {label: got[f"case{k}"] for k, label in enumerate(cases)}
    return counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref", action="append", default=None,
                    help="reference commit, repeatable (default: ee91499, before the test-design flags)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--simulated", type=int, default=4, help="simulated campaigns per scenario")
    ap.add_argument("--rounds", type=int, default=3, help="rounds, each running the references and current at once")
    ap.add_argument("--readme", type=Path, help="also write the table into this README")
    ap.add_argument("--instructions", action="store_true",
                    help="count machine instructions with valgrind's callgrind instead of timing (one round; "
                         "the README block bench-science-instructions)")
    args = ap.parse_args(argv)
    refs = args.ref or ["ee91499"]
    head = commit()
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        cases = _cases(tmp, args.simulated)
        dirs = {r: tmp / f"ref-{r}" for r in refs}
        for r, d in dirs.items():
            _git("worktree", "add", "--detach", str(d), r)
        try:
            # every round runs all versions at once; per campaign the median over the rounds
            rounds = ([_instructions({**dirs, head: ROOT}, cases, args.repeat, tmp)] if args.instructions
                      else [_time({**dirs, head: ROOT}, cases, args.repeat) for _ in range(args.rounds)])
        finally:
            for d in dirs.values():
                _git("worktree", "remove", "--force", str(d))
    t = {v: {k: statistics.median(rd[v][k] for rd in rounds) for k in cases} for v in [*refs, head]}
    groups: dict[str, list[str]] = {}
    for label in cases:
        groups.setdefault(label.split(" #")[0] + (f" (median of {args.simulated})" if label.startswith("sim ")
                                                  else ""), []).append(label)
    groups["**median over all campaigns**"] = list(cases)
    unit, scale, fmt = ("M instructions", 1e-6, "{:.0f}") if args.instructions else ("s", 1.0, "{:.3f}")
    rows = ["| campaign | " + " | ".join(f"{r} ({unit})" for r in refs) + f" | {head} ({unit}) | "
            + " | ".join(f"{head} / {r}" for r in refs) + " |", "|---|" + "---:|" * (2 * len(refs) + 1)]
    for g, labels in groups.items():
        med = {v: statistics.median(t[v][x] for x in labels) for v in t}
        rows.append(f"| {g} | " + " | ".join(fmt.format(med[v] * scale) for v in [*refs, head]) + " | "
                    + " | ".join(f"{med[head] / med[r]:.2f}" for r in refs) + " |")
    command = (f"python benchmarks/bench_science.py {' '.join(f'--ref {r}' for r in refs)} --repeat {args.repeat} "
               f"--simulated {args.simulated}")
    if args.instructions:
        text = (f"Science per campaign (`process_campaign`, machine instructions counted by valgrind's callgrind, "
                f"mean of {args.repeat} warm runs), current commit {head} against {', '.join(refs)}, same inputs, "
                f"one run of `{command} --instructions`:\n\n" + "\n".join(rows) + "\n")
        name, block = "science-instructions.md", "bench-science-instructions"
    else:
        text = (f"Science per campaign (`process_campaign`, CPU seconds, median of {args.repeat} warm runs, one "
                f"thread, median over {args.rounds} rounds, the versions of a round run at once), current commit "
                f"{head} against {', '.join(refs)}, same inputs, one run of `{command} --rounds {args.rounds}`:\n\n"
                + "\n".join(rows) + "\n")
        name, block = "science-timing.md", "bench-science"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / name).write_text(text, encoding="utf-8")
    print(text)
    if args.readme:
        write_block(args.readme, block, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
