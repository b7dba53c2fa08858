#!/usr/bin/env python
"""False alarms of the diagnosis on clean campaigns whose output noise is AR(1) between
consecutive readings (issue 26).

    python benchmarks/bench_coloured_noise.py [--n 100] [--workers 2] [--readme README.md]

A centrifuge IA pair (0/180 deg, the diagnose-benchmark's ten g levels) and a 24-position
tumble, each with white output noise (2e-6 m/s^2 per reading) made AR(1) with lag-1
correlation rho between consecutive readings (a DAQ's anti-alias filter, a slowly
wandering environment), the marginal size unchanged, and the temperature sensor's own
noise; no effect withheld.  A false alarm is a verdict, or a gap said to remain.  Each rho
draws ``--n`` campaigns of each kind.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

RHOS = (0.0, 0.6, 0.75, 0.9)
KINDS = ("centrifuge", "tumble")


def one(args):
    kind, rho, seed = args
    from accelcal.diagnosis import diagnose
    from accelcal.validation.diagnosis_benchmark import DEV_BASELINE, ar1_scenario, runs_of, score_case
    res = diagnose(runs_of(ar1_scenario(kind, rho), seed), DEV_BASELINE[kind])
    # a false alarm: a verdict, or a gap said to remain
    return kind, rho, seed, not score_case(res, None, None)["right"], res["verdict"]


def main() -> None:
    from accelcal.validation.diagnosis_benchmark import rate_with_interval
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100, help="campaigns per kind and rho")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--readme", type=Path)
    a = ap.parse_args()
    t0 = time.time()
    jobs = [(k, r, 20261200 + i) for k in KINDS for r in RHOS for i in range(a.n)]
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(one, jobs, chunksize=4))
    lines = [f"`python benchmarks/bench_coloured_noise.py --n {a.n} --readme README.md`, commit {commit()}, "
             f"{time.time() - t0:.0f} s. Clean campaigns, output noise AR(1) between consecutive readings; a "
             "false alarm is a verdict or a gap said to remain (Wilson 95 % interval).", "",
             "| test | rho | campaigns | false alarms | rate (95 % interval) |", "|---|---|---|---|---|"]
    for k in KINDS:
        for r in RHOS:
            sel = [x for x in rows if x[0] == k and x[1] == r]
            bad = sum(x[3] for x in sel)
            lines.append(f"| {'centrifuge IA pair' if k == 'centrifuge' else 'tumble, 24 positions'} | {r:g} | "
                         f"{len(sel)} | {bad} | {rate_with_interval(bad, len(sel))} |")
    text = "\n".join(lines)
    print(text)
    if a.readme:
        write_block(a.readme, "coloured-noise", text)


if __name__ == "__main__":
    main()
