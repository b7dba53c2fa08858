#!/usr/bin/env python
"""Process the lab's sample drops (../shared/examples) and compare every coefficient with
the truth they were made from (quoted in the issues).  Prints the README's markdown table.

    python benchmarks/sample_truth_table.py [--examples DIR] [--readme README.md]

With ``--readme`` the table is also written between the ``<!-- sample-truth:begin -->`` /
``<!-- sample-truth:end -->`` markers, stamped with the commit it ran on.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from accelcal.effects import coefficient_spec, split_combination
from accelcal.estimators.campaign import process_campaign
from accelcal.rounding import round_gum_sci
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402
CENTRIFUGE = {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8,
              "Koq": 3.0e-8, "K3": 2.0e-10, "Kp": 2.0e-5, "Ko": -1.5e-5, "Kpo": 0.0, "theta0": 0.0}
TRUTH = {
    "drop-2026-11-20": CENTRIFUGE,
    # made with the same instrument values on LXJ-200 (accelcal/simulate/scenarios/snj103-lxj200.toml)
    "drop-2026-11-21": CENTRIFUGE,
    "drop-2026-11-18-thermal": {"K1T": -1.2e-4, "K0T": 3.96e-6},
    "drop-2026-11-19-sine": {"K2": 3.94e-7, "K3": 1.5e-9, "Koq": 2e-8, "Kip": 7.1e-7, "Kpp": 4.7e-8,
                             "Kio": 2.0e-7, "Koo": 3.0e-8},
}
RADII = {"drop-2026-11-20": {"+": 0.714775, "-": 0.705794}}
#: significant digits of a truth as the issues quote it: error / u is shown only where the
#: rounding of the truth is smaller than u
DIGITS = {("drop-2026-11-18-thermal", "K0T"): 3}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", default=str(ROOT.parent / "shared" / "examples"))
    ap.add_argument("--readme", type=Path, help="write the table into this README's sample-truth block")
    args = ap.parse_args()
    out = [f"`python benchmarks/sample_truth_table.py --readme README.md`, commit {commit()}. "
           "U = k·u (k = 2 unless shown), error / u in standard uncertainties; bold: the adopted "
           "value (joint fit), the other rows are the papers' methods kept as the cross-check.", "",
           "| drop | coefficient | method | estimate | U | truth | error | error / u |",
           "|---|---|---|---|---|---|---|---|"]
    row = out.append
    timings = []
    for drop, truth in TRUTH.items():
        t0 = time.perf_counter()
        res = process_campaign([read_run(p) for p in discover(Path(args.examples) / drop)])
        dt = time.perf_counter() - t0
        rows = sorted(res.coefficients, key=lambda c: (not c.adopted, c.method))
        for c in rows:
            base, terms = split_combination(c.name)[0], c.factors
            if base not in truth or any(k not in truth for k in terms):
                continue
            # a row named as a combination (a tumble's K2(Koo)) against that combination, its factors
            t = truth[base] + sum(f * truth[k] for k, f in terms.items())
            f = coefficient_spec(c.name).display_factor
            du = coefficient_spec(c.name).display_unit
            method = f"**{c.method}** (adopted)" if c.adopted else c.method
            k = c.coverage_factor
            rounding = 0.5 * 10 ** (math.floor(math.log10(abs(t))) - DIGITS[(drop, c.name)] + 1) \
                if (drop, c.name) in DIGITS and t else 0.0
            z = "—" if rounding > c.std_uncertainty else f"{(c.value - t) / c.std_uncertainty:+.2f}"
            kk = "" if k == 2 else f" (k={k:.3g})"
            v, U = round_gum_sci(c.value / f, k * c.std_uncertainty / f)      # U to 2 digits, the value to U's
            row(f"| {drop} | {c.name} | {method} | {v} {du} | {U}{kk} | "
                  f"{t / f:.4g} | {f'{100 * (c.value / t - 1):+.2f} %' if t else '—'} | {z} |")
        for r in res.radii:
            if drop not in RADII:
                continue
            if r.method in ("joint_ml", "static", "static_corrected", "iterative_corrected") or (
                    r.method == "iterative" and r.model_order in (2, 3) and r.g_max and r.g_max > 24):
                t = RADII[drop][r.polarity]
                order = "" if r.model_order is None else f" o{r.model_order}"
                m = f"**{r.method}** (adopted)" if r.method == "joint_ml" else r.method
                row(f"| {drop} | R{r.polarity} | {m}{order} | {r.radius_m:.7f} m | "
                      f"{2e6 * r.std_uncertainty_m:.2f} µm | {t:.6f} | {1e6 * (r.radius_m - t):+.1f} µm | "
                      f"{(r.radius_m - t) / r.std_uncertainty_m:+.2f} |")
        timings.append(f"{drop} {dt:.2f} s")
    out += ["", "Science per drop: " + ", ".join(timings) + "."]
    text = "\n".join(out)
    sys.stdout.write(text + "\n")
    if args.readme:
        write_block(args.readme, "sample-truth", text)


if __name__ == "__main__":
    main()
