#!/usr/bin/env python
"""The diagnosis' naming rule on big designs, with and without the five-sigma held-out path
(issue 26).

    python benchmarks/bench_naming_rule.py [--seeds 2]

Runs the diagnose-benchmark's big-design family (40 g levels x 6 mounts, each observable
centrifuge candidate at z = 10; accelcal.validation.diagnosis_benchmark) twice: with the
verdict's held-out gate as shipped (shrink >= 0.5 or held-out z >= 5) and with the shrink
alone (HELDOUT_Z set to infinity), and prints how many were named within 25 %.
"""
from __future__ import annotations

import argparse
import math

import accelcal.diagnosis.core as core
from accelcal.validation.diagnosis_benchmark import run_section1


def named(seeds: int) -> tuple[int, int]:
    rows = [r for r in run_section1(seeds=seeds, n_clean=0, only="centrifuge/*/big", log=lambda *a: None)
            if r["category"] == "big"]
    return sum(r["right"] for r in rows), len(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2)
    a = ap.parse_args()
    shipped = named(a.seeds)
    keep, core.HELDOUT_Z = core.HELDOUT_Z, math.inf
    try:
        shrink_only = named(a.seeds)
    finally:
        core.HELDOUT_Z = keep
    print(f"named within 25 %: shipped rule {shipped[0]} of {shipped[1]}; "
          f"held-out shrink alone {shrink_only[0]} of {shrink_only[1]}")


if __name__ == "__main__":
    main()
