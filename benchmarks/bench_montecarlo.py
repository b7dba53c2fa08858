"""Benchmark: the Monte Carlo validity study (issue 3) on the shipped scenarios.

    python benchmarks/bench_montecarlo.py [--workers 2] [--budget 200] [--scenarios ...]

For each scenario one campaign is timed first; n is then the largest number of campaigns
that fits the time budget (seconds of wall time on ``--workers`` processes), clipped to
[--n-min, --n-max] (default 200..1000; n stays 200 when the budget allows fewer, which is
then said in the output).  Writes benchmarks/results/montecarlo-<scenario>.md (markdown
table, module accelcal.validation.montecarlo), with --json also a .json next to it.  Not part of CI.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from accelcal.validation import montecarlo as mc
from accelcal.simulate import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit  # noqa: E402

RESULTS = Path(__file__).with_name("results")
DEFAULT = ("snj103-lxj100", "hust-m07-thermal", "qa5512-sine")


def time_one(sc, seed: int = 10_000) -> float:
    t = time.perf_counter()
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        mc._campaign(sc, seed)
    return time.perf_counter() - t


def main(argv=None) -> int:
    code = commit()  # the code this run imports, before anything can move HEAD
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="*", default=list(DEFAULT))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--budget", type=float, default=200.0, help="wall seconds per scenario")
    ap.add_argument("--n-min", type=int, default=200)
    ap.add_argument("--n-max", type=int, default=1000)
    ap.add_argument("--n", type=int, default=None, help="force n")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="also write montecarlo-<scenario>.json")
    args = ap.parse_args(argv)
    RESULTS.mkdir(parents=True, exist_ok=True)
    for name in args.scenarios:
        sc = load_scenario(name)
        t1 = time_one(sc)
        n = args.n or int(min(args.n_max, max(args.n_min, args.budget * args.workers / (1.15 * t1))))
        print(f"{name}: one campaign {t1:.2f} s -> n = {n}", flush=True)
        t0 = time.perf_counter()
        res = mc.run_study(sc, n=n, seed=args.seed, workers=args.workers)
        wall = time.perf_counter() - t0
        head = (f"<!-- bench_montecarlo.py at commit {code}: {name}, n = {n}, seed {args.seed}, "
                f"{args.workers} workers; one "
                f"campaign {t1:.2f} s; study {res.seconds:.0f} s, total with CRB {wall:.0f} s -->\n")
        (RESULTS / f"montecarlo-{name}.md").write_text(head + res.to_markdown(), encoding="utf-8")
        if args.json:
            (RESULTS / f"montecarlo-{name}.json").write_text(json.dumps(res.to_dict(), indent=1, default=str),
                                                             encoding="utf-8")
        print(res.to_markdown(), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
