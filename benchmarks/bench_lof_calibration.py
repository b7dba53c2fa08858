#!/usr/bin/env python
"""How often the bare model's lack-of-fit test rejects clean campaigns (issue 26).

    python benchmarks/bench_lof_calibration.py [--n 1000] [--n-white 600] [--workers 2]
                                               [--readme README.md]

Clean centrifuge campaigns of the IEEE 836 mount sets (bench_mount_sets.py's campaigns:
the everyday unit, the diagnose-benchmark's DAQ noise), diagnosed with the effects they
have; the p-value of the bare model's lack of fit against the pure error is read from
each (``gap.significant_before``).  A calibrated test puts 5, 1 and 0.1 % of them below
0.05, 0.01 and 0.001.  The second row is the full set with white output noise only (every
other DAQ noise term removed): the rate-dependent noise term is then fitted to noise
that has none.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

LEVELS = (0.05, 0.01, 0.001)


def one(args):
    name, seed, white_only = args
    from accelcal.diagnosis import diagnose
    from accelcal.validation import diagnosis_benchmark as DB
    sc = DB.mount_set_scenario(name)
    if white_only:
        sc["noise"] = {"white_m_s2": sc["noise"]["white_m_s2"]}
    res = diagnose(DB.runs_of(sc, seed), DB.MOUNT_SET_BASELINE)
    return res["gap"]["significant_before"]["p_value"]


def main() -> None:
    from accelcal.validation.diagnosis_benchmark import MOUNT_SETS, rate_with_interval
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000, help="mount-set campaigns (spread over the sets)")
    ap.add_argument("--n-white", type=int, default=600, help="full-set campaigns with white noise only")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--readme", type=Path)
    a = ap.parse_args()
    t0 = time.time()
    sets = list(MOUNT_SETS)
    jobs = [(sets[i % len(sets)], 20261126 + i, False) for i in range(a.n)]
    jobs += [("full set", 30261126 + i, True) for i in range(a.n_white)]
    with ProcessPoolExecutor(a.workers) as ex:
        p = np.array(list(ex.map(one, jobs, chunksize=4)), float)
    rows = [("clean mount sets (all five), DAQ noise", p[:a.n]), ("full set, white output noise only", p[a.n:])]
    lines = [f"`python benchmarks/bench_lof_calibration.py --n {a.n} --n-white {a.n_white} --readme README.md`, "
             f"commit {commit()}, {time.time() - t0:.0f} s. Clean centrifuge campaigns, the everyday unit; the bare "
             "model's lack-of-fit p-value (share below each level, Wilson 95 % interval).", "",
             "| campaigns | n | " + " | ".join(f"p < {x:g}" for x in LEVELS) + " |",
             "|---|---|" + "---|" * len(LEVELS)]
    for label, q in rows:
        if q.size:
            lines.append(f"| {label} | {q.size} | "
                         + " | ".join(rate_with_interval(int(np.sum(q < x)), q.size) for x in LEVELS) + " |")
    text = "\n".join(lines)
    print(text)
    if a.readme:
        write_block(a.readme, "lof-calibration", text)


if __name__ == "__main__":
    main()
