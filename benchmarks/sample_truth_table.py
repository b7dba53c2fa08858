#!/usr/bin/env python
"""Process the lab's sample drops (../shared/examples) and compare every coefficient with
the truth they were made from (quoted in the issues).  Prints the README's markdown table.

    python benchmarks/sample_truth_table.py [--examples DIR]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from accelcal.effects import COEFFICIENTS
from accelcal.estimators.campaign import process_campaign
from accelcal.schemas.dropformat import discover, read_run

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {
    "drop-2026-11-20": {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8,
                        "Koq": 3.0e-8, "K3": 2.0e-10},
    "drop-2026-11-18-thermal": {"K1T": -1.2e-4, "K0T": 3.96e-6},
    "drop-2026-11-19-sine": {"K2": 3.94e-7, "K3": 1.5e-9, "Koq": 2e-8, "Kip": 7.1e-7, "Kpp": 4.7e-8,
                             "Kio": 2.0e-7, "Koo": 3.0e-8},
}
RADII = {"+": 0.714775, "-": 0.705794}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", default=str(ROOT.parent / "shared" / "examples"))
    args = ap.parse_args()
    print("| drop | coefficient | method | estimate | U (k=2) | truth | error | error / u |")
    print("|---|---|---|---|---|---|---|---|")
    for drop, truth in TRUTH.items():
        t0 = time.perf_counter()
        res = process_campaign([read_run(p) for p in discover(Path(args.examples) / drop)])
        dt = time.perf_counter() - t0
        for c in res.coefficients:
            if c.name not in truth or (c.name == "K2" and c.method == "tumble_lm" and drop != "drop-2026-11-20"):
                continue
            t = truth[c.name]
            f = COEFFICIENTS[c.name].display_factor
            du = COEFFICIENTS[c.name].display_unit
            print(f"| {drop} | {c.name} | {c.method} | {c.value / f:.4g} {du} | {2 * c.std_uncertainty / f:.2g} | "
                  f"{t / f:.4g} | {100 * (c.value / t - 1):+.2f} % | {(c.value - t) / c.std_uncertainty:+.2f} |")
        for r in res.radii:
            if r.method in ("static", "static_corrected", "iterative_corrected") or (
                    r.method == "iterative" and r.model_order in (2, 3) and r.g_max and r.g_max > 24):
                t = RADII[r.polarity]
                order = "" if r.model_order is None else f" o{r.model_order}"
                print(f"| {drop} | R{r.polarity} | {r.method}{order} | {r.radius_m:.6f} m | "
                      f"{2e6 * r.std_uncertainty_m:.2f} µm | {t:.6f} | {1e6 * (r.radius_m - t):+.1f} µm | "
                      f"{(r.radius_m - t) / r.std_uncertainty_m:+.2f} |")
        print(f"<!-- {drop}: science {dt:.2f} s -->")


if __name__ == "__main__":
    main()
