"""Does ``accelcal due``'s 95 % interval of the day a unit leaves its tolerance hold the
true day?  A fleet of N units (QA-2000, K1) drifting linearly at rates that use up the
tolerance (200 ppm) in 1 to 5 years, either sign; 2 to 6 calibrations a year or so apart;
each calibration's value is the true line plus its measurement error (stated u, 5 ppm)
plus a reproducibility error the campaign's budget does not hold (sd 5 ppm: mounting,
rig, temperature history).  The rows go through the computation of ``accelcal due``
(:func:`accelcal.ops.due.compute`: the fleet prior from the other units, steps,
prediction) as the warehouse would hand them.

The true exit of a unit is the first day after its last calibration on which its true
line lies more than the tolerance from the value in use (the last calibration's value).

``python benchmarks/bench_due_exit.py [--units 40] [--seed 43] [--readme README.md]``
"""
from __future__ import annotations

import argparse
import datetime as dt
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from accelcal.config import ForecastConfig  # noqa: E402
from accelcal.ops.due import SECONDS_PER_YEAR, compute, forecast_row  # noqa: E402

K1, U, REPRO, TOL = 0.1, 5e-6 * 0.1, 5e-6 * 0.1, 2e-4


def fleet(n_units: int, seed: int) -> tuple[list[dict], dict]:
    """Rows as ``unit_history`` gives them, and each unit's true line (a, b) [SI, a]."""
    rng = np.random.default_rng(seed)
    rows, truth = [], {}
    for j in range(n_units):
        n = 2 + j % 5
        t = 2020.0 + np.cumsum(np.r_[0.0, rng.uniform(0.8, 1.2, n - 1)])
        b = rng.choice([-1, 1]) * TOL * K1 / rng.uniform(1.0, 5.0)
        a = K1 * (1 + rng.uniform(-1e-3, 1e-3))
        x = a + b * (t - 2020.0) + U * rng.standard_normal(n) + REPRO * rng.standard_normal(n)
        serial = f"SIM-{j:02d}"
        truth[serial] = (a, b)
        for k in range(n):
            when = dt.datetime.fromtimestamp((t[k] - 1970.0) * SECONDS_PER_YEAR, dt.timezone.utc)
            rows.append({"unit_serial": serial, "unit_model": "QA-2000", "name": "K1",
                         "unit": "out/(m/s2)", "campaign": f"{serial}/{k}", "calibrated_at": when,
                         "value": float(x[k]), "std_uncertainty": U, "expanded_uncertainty": 2 * U,
                         "method": "tumble_lm", "rig_id": "DH-1", "result_id": f"{serial}-{k}",
                         "code_version": "bench", "calibration_no": k + 1})
    return rows, truth


def run(n_units: int, seed: int) -> dict:
    rows, truth = fleet(n_units, seed)
    cfg = ForecastConfig(tolerances={"QA-2000": {"K1": {"relative": TOL}}}, risk=0.05)
    t0 = time.perf_counter()
    out = compute(rows, set(), cfg)
    took = time.perf_counter() - t0
    dated = covered = own = 0
    widths = []
    for lst, f in out:
        if f.due is None or f.due_interval[0] is None:
            continue
        a, b = truth[lst[-1]["unit_serial"]]
        years = lambda y: y + 1970.0            # noqa: E731  (due's years since 1970 -> a)
        t_last = years(f.t_last)
        line_last = a + b * (t_last - 2020.0)
        exit_ = t_last + (np.sign(b) * f.tolerance - (line_last - f.value_in_use)) / b
        lo = years(f.due_interval[0])
        hi = np.inf if f.due_interval[1] is None else years(f.due_interval[1])
        dated += 1
        covered += lo <= exit_ <= hi
        own += f.basis.startswith("drift fit")
        widths.append((hi - lo) * 365.25 if np.isfinite(hi) else np.inf)
        forecast_row(lst, f)                  # the row the command prints is made as well
    return {"units": n_units, "dated": dated, "covered": covered, "own_rate": own,
            "median_width_days": float(np.median(widths)) if widths else None, "seconds": took}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--units", type=int, default=40)
    ap.add_argument("--seed", type=int, default=43)
    ap.add_argument("--readme", type=Path)
    a = ap.parse_args()
    r = run(a.units, a.seed)
    pct = 100.0 * r["covered"] / max(r["dated"], 1)
    line = (f"{r['units']} units (2-6 calibrations, K1 drifting 40-200 ppm/a, u 5 ppm plus 5 ppm "
            f"reproducibility not in u): {r['dated']} dated ({r['own_rate']} on their own drift "
            f"rate), the 95 % exit interval holds the true exit in {r['covered']} "
            f"({pct:.0f} %); median width {r['median_width_days']:.0f} days; {r['seconds']:.1f} s.")
    print(line)
    if a.readme:
        from readme_block import commit, write_block
        write_block(a.readme, "bench_due_exit",
                    f"`python benchmarks/bench_due_exit.py --units {a.units} --seed {a.seed} "
                    f"--readme README.md`, commit {commit()}: {line}\n")


if __name__ == "__main__":
    main()
