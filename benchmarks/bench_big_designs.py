#!/usr/bin/env python
"""Naming on big designs (issue 26): a catalogue effect at z = 10 on a centrifuge with
BIG_LEVELS g levels in six mounts, over many noise draws.

    python benchmarks/bench_big_designs.py [--n 50] [--workers 2] [--readme README.md]

The diagnose-benchmark's big family (accelcal.validation.diagnosis_benchmark) with more
draws: for each observable centrifuge candidate outside the processing model, ``--n``
campaigns with the effect at z = BIG_SNR (its size from the projected signature of a clean
campaign, alternating sign) and the benchmark's DAQ noise, each a fresh noise draw.  Right
is the benchmark's rule for the family: the effect is the verdict (or among its aliases)
and its estimate is within 25 % of the truth.  The must-hold is >= 95 % of draws.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402


def one(args):
    effect, seed, sign = args
    from accelcal.diagnosis import diagnose
    from accelcal.validation import diagnosis_benchmark as DB
    base = DB.processing_effects(["centrifuge"])
    per, _ = DB.snr_scale("centrifuge", effect, base, 999, DB.BIG_LEVELS)
    size = float(sign * DB.BIG_SNR * per)
    res = diagnose(DB.runs_of(DB.scenario("centrifuge", {effect: size}, levels=DB.BIG_LEVELS), seed), base)
    s = DB.score_case(res, effect, size, None, False, True)
    return effect, seed, s["right"], s["why"]


def big_effects() -> list[str]:
    """The candidates the diagnose-benchmark's big family injects (observable ones)."""
    from accelcal.effects import EFFECTS
    from accelcal.validation import diagnosis_benchmark as DB
    base = DB.processing_effects(["centrifuge"])
    return [e for e in EFFECTS if "centrifuge" in EFFECTS[e].tests and e not in base
            and DB.snr_scale("centrifuge", e, base, 999, DB.BIG_LEVELS)[0] is not None]


def main() -> None:
    from accelcal.validation.diagnosis_benchmark import BIG_LEVELS, BIG_SNR, rate_with_interval
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=50, help="noise draws per effect")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--readme", type=Path)
    a = ap.parse_args()
    t0 = time.time()
    effects = big_effects()
    jobs = [(e, 40000 + 100 * k + i, (-1) ** i) for k, e in enumerate(effects) for i in range(a.n)]
    with ProcessPoolExecutor(a.workers) as ex:
        rows = list(ex.map(one, jobs, chunksize=2))
    lines = [f"`python benchmarks/bench_big_designs.py --n {a.n} --readme README.md`, commit {commit()}, "
             f"{time.time() - t0:.0f} s. Centrifuge, {BIG_LEVELS} g levels x 6 mounts, one catalogue effect at "
             f"z = {BIG_SNR:g}, DAQ noise, a fresh draw per campaign; right = named (verdict or alias) and "
             "within 25 % (Wilson 95 % interval of the rate right).", "",
             "| effect | campaigns | right | rate (95 % interval) |", "|---|---|---|---|"]
    for e in effects:
        r = [x for x in rows if x[0] == e]
        k = sum(x[2] for x in r)
        lines.append(f"| {e} | {len(r)} | {k} | {rate_with_interval(k, len(r))} |")
    k = sum(x[2] for x in rows)
    lines.append(f"| **all** | {len(rows)} | {k} | {rate_with_interval(k, len(rows))} |")
    misses = [f"{x[0]} seed {x[1]}: {x[3]}" for x in rows if not x[2]]
    if misses:
        lines += ["", "misses: " + "; ".join(misses)]
    text = "\n".join(lines)
    print(text)
    if a.readme:
        write_block(a.readme, "big-designs", text)


if __name__ == "__main__":
    main()
