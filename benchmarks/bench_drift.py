"""Back-test of the drift model and due dates (issue 29) on a simulated fleet.

A fleet of one unit model (QA-2000) with K0, K1 and K2 calibrated 4-8 times over 2-6
years, irregularly.  Each campaign's value is the unit's true line, plus a
between-campaign wander (sd tau, per unit and coefficient, 0-1 x u), plus the campaign's
measurement error with its stated u (which itself varies +-25 % between campaigns).

Kinds of unit: stable (no drift); linear drift in one of K0/K1/K2 at rates that use up
the tolerance in 1.5, 2.5 or 4 years, either sign; a step after a shock (0.4-0.8 x the
tolerance, in one coefficient, at least two campaigns before the last; on
a stable or drifting unit); adjusted (drifting, reset to nominal at a campaign in the
middle that is marked as an adjustment).

Measured (``python benchmarks/bench_drift.py [--units N] [--readme README.md]``):

* coverage: each series' last campaign held out, does the 95 % prediction interval
  (with that campaign's u) cover it?  (target 93-97 %)
* due dates: drifting coefficients, full history: due interval / true time to use up the
  tolerance from the value in use, within 0.8-1.2 in >= 90 % (target)
* stable units: none due within 3 years at 5 % risk
* steps: every simulated step flagged (and how many flags elsewhere)
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from accelcal import drift  # noqa: E402

G = 9.80665
#: coefficient: (nominal value, stated u, tolerance spec) in SI
COEFS = {
    "K0": (2.0e-3, 1.5e-5, {"absolute": 5.0e-4}),          # ~200 ug, u 1.5 ug, T 51 ug
    "K1": (0.1, 0.1 * 5e-6, {"relative": 2.0e-4}),          # u 5 ppm, T 200 ppm
    "K2": (4e-7, 2e-9, {"absolute": 1.0e-7}),               # ~3.9 ug/g2, u 0.02, T ~1 ug/g2
}
RISK = 0.05
YEARS_TO_TOL = (1.5, 2.5, 4.0)
KINDS = ("stable", "drift", "step", "adjusted")


def simulate_fleet(n_units: int, seed: int = 29) -> list[dict]:
    rng = np.random.default_rng(seed)
    units = []
    for j in range(n_units):
        kind = KINDS[j % len(KINDS)] if j % 10 not in (8, 9) else "drift"
        n = int(rng.integers(4, 9))
        span = float(rng.uniform(2.0, 6.0))
        gaps = rng.uniform(0.8, 1.2, n - 1)
        t = np.concatenate([[0.0], np.cumsum(gaps / gaps.sum() * span)]) + 2020.0
        which = ("K0", "K1", "K2")[j % 3]
        rate_years = YEARS_TO_TOL[(j // 3) % len(YEARS_TO_TOL)]
        sign = 1.0 if rng.random() < 0.5 else -1.0
        adjusted = np.zeros(n, bool)
        k_event = int(rng.integers(1, n - 1)) if n >= 3 else None   # <= n-2
        if kind == "adjusted":
            k_event = int(rng.integers(max(1, n - 4), n - 1))
            adjusted[k_event] = True
        series = {}
        for name, (nom, u_nom, tol_spec) in COEFS.items():
            tol = drift.tolerance_of(tol_spec, nom)
            b = 0.0
            if kind in ("drift", "adjusted") and name == which:
                b = sign * tol / rate_years
            tau = u_nom * rng.uniform(0.0, 1.0)
            u = u_nom * rng.uniform(0.8, 1.25, n)
            x0 = nom * (1 + 0.01 * rng.standard_normal())
            true = x0 + b * (t - t[0])
            step = 0.0
            if kind == "step" and name == which:
                step = sign * rng.uniform(0.4, 0.8) * tol
                true = true + step * (np.arange(n) >= k_event)
                b = b if j % 2 else 0.0
                true = x0 + b * (t - t[0]) + step * (np.arange(n) >= k_event)
            if kind == "adjusted" and name == which:
                true = np.where(np.arange(n) >= k_event,
                                x0 + b * (t - t[k_event]), true)
            x = true + tau * rng.standard_normal(n) + u * rng.standard_normal(n)
            series[name] = dict(t=t, x=x, u=u, true=true, b=b, tau=tau, tol_spec=tol_spec,
                                step_at=k_event if step else None)
        units.append(dict(serial=f"SIM-{j:04d}", kind=kind, which=which, n=n, span=span,
                          adjusted=adjusted, series=series))
    return units


def _prior(units, name, holdout: bool) -> drift.FleetPrior:
    ser = []
    for un in units:
        s = un["series"][name]
        end = len(s["t"]) - (1 if holdout else 0)
        adj = un["adjusted"][:end]
        start = drift.current_series_start(end, adj, [])
        if un["kind"] == "step" and s["step_at"] is not None and s["step_at"] < end:
            continue                     # a unit with a step (flagged) adds after it only
        ser.append((s["t"][start:end], s["x"][start:end], s["u"][start:end]))
    return drift.fleet_prior(ser)


def true_time_to_tolerance(s, t_last: float, v: float, tol: float) -> float:
    """Years from t_last until the true line is tol away from the value in use v."""
    b = s["b"]
    x_last = s["true"][-1]
    gap = tol - np.sign(b) * (x_last - v)
    return float(gap / abs(b))


def backtest(units) -> dict:
    priors_h = {n: _prior(units, n, True) for n in COEFS}
    priors = {n: _prior(units, n, False) for n in COEFS}
    cover, n_cover = 0, 0
    ratios, stable_due, steps_total, steps_found, false_steps = [], [], 0, 0, 0
    cover_by_kind: dict[str, list[int]] = {}
    for un in units:
        for name in COEFS:
            s = un["series"][name]
            c = drift.holdout_covers(s["t"], s["x"], s["u"], priors_h[name],
                                     adjusted=un["adjusted"])
            if c is not None:
                n_cover += 1
                cover += int(c)
                cover_by_kind.setdefault(un["kind"], [0, 0])
                cover_by_kind[un["kind"]][0] += int(c)
                cover_by_kind[un["kind"]][1] += 1
            f = drift.forecast(s["t"], s["x"], s["u"], s["tol_spec"], RISK,
                               adjusted=un["adjusted"], prior=priors[name])
            if s["step_at"] is not None:
                steps_total += 1
                steps_found += int(any(st.at == s["step_at"] for st in f.steps))
                false_steps += sum(st.at != s["step_at"] for st in f.steps)
            else:
                false_steps += len(f.steps)
            if s["b"] != 0 and un["kind"] in ("drift", "adjusted"):
                true = true_time_to_tolerance(s, f.t_last, f.value_in_use, f.tolerance)
                got = (f.due - f.t_last) if f.due is not None else np.inf
                ratios.append(got / true)
            if un["kind"] == "stable":
                stable_due.append((f.due - f.t_last) if f.due is not None else np.inf)
    ratios = np.array(ratios)
    stable_due = np.array(stable_due)
    return {
        "units": len(units), "series_held_out": n_cover,
        "coverage_95": cover / n_cover,
        "coverage_by_kind": {k: v[0] / v[1] for k, v in cover_by_kind.items()},
        "drifting_series": len(ratios),
        "due_within_20pct": float(np.mean((ratios >= 0.8) & (ratios <= 1.2))),
        "due_ratio_median": float(np.median(ratios)),
        "due_ratio_p5_p95": [float(np.percentile(ratios, 5)), float(np.percentile(ratios, 95))],
        "stable_series": len(stable_due),
        "stable_due_within_3y": int(np.sum(stable_due < 3.0)),
        "stable_min_due_years": float(np.min(stable_due)),
        "steps": steps_total, "steps_flagged": steps_found, "other_flags": int(false_steps),
        "targets_met": bool(0.93 <= cover / n_cover <= 0.97
                            and np.mean((ratios >= 0.8) & (ratios <= 1.2)) >= 0.90
                            and np.sum(stable_due < 3.0) == 0 and steps_found == steps_total
                            and len(units) >= 50),
    }


def readme_block(r: dict, seed: int, secs: float, others: dict | None = None) -> str:
    from readme_block import commit
    from accelcal.rounding import format_sig
    pct = lambda x: f"{x * 100:.1f} %"  # noqa: E731
    lo, hi = r["due_ratio_p5_p95"]
    return "\n".join([
        f"`python benchmarks/bench_drift.py --units {r['units']} --seed {seed} --readme README.md`, "
        f"commit {commit()}: {r['units']} simulated QA-2000 units (K0, K1, K2; 4-8 campaigns "
        "over 2-6 years; stable, drifting at three rates, a step after a shock, adjusted), "
        f"{format_sig(secs)} s.",
        "",
        "| check | target | measured |",
        "|---|---|---|",
        f"| last campaign held out: inside the 95 % prediction interval | 93-97 % | "
        f"{pct(r['coverage_95'])} of {r['series_held_out']} series |",
        f"| drifting: due interval / true time to use up the tolerance in 0.8-1.2 | >= 90 % | "
        f"{pct(r['due_within_20pct'])} of {r['drifting_series']} (median "
        f"{format_sig(r['due_ratio_median'])}, 5-95 %: {format_sig(lo)}-{format_sig(hi)}) |",
        f"| stable units due within 3 years (5 % risk) | 0 | {r['stable_due_within_3y']} of "
        f"{r['stable_series']} series (earliest: "
        + (f"{format_sig(r['stable_min_due_years'])} a) |" if np.isfinite(r["stable_min_due_years"])
           else "none within 10 years) |"),
        f"| steps flagged | all | {r['steps_flagged']} of {r['steps']} (other flags: "
        f"{r['other_flags']}) |",
        "",
        "All four targets met." if r["targets_met"] else "**Not every target met.**",
    ] + ([] if not others else [
        "",
        f"The same on {len(others)} other fleets (seeds {', '.join(str(k) for k in others)}): "
        f"coverage {pct(min(o['coverage_95'] for o in others.values()))}-"
        f"{pct(max(o['coverage_95'] for o in others.values()))}; due within ±20 % "
        f"{pct(min(o['due_within_20pct'] for o in others.values()))}-"
        f"{pct(max(o['due_within_20pct'] for o in others.values()))}; stable units due within "
        f"3 years {sum(o['stable_due_within_3y'] for o in others.values())}; steps flagged "
        f"{sum(o['steps_flagged'] for o in others.values())} of "
        f"{sum(o['steps'] for o in others.values())}; targets met on "
        f"{sum(o['targets_met'] for o in others.values())} of {len(others)}."]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=400, help="simulated units (>= 50)")
    ap.add_argument("--seed", type=int, default=29)
    ap.add_argument("--readme", type=Path, default=None)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--other-seeds", type=int, default=5, metavar="N",
                    help="also run N other fleets (seeds 1..N) and summarise them")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    r = backtest(simulate_fleet(a.units, a.seed))
    secs = time.perf_counter() - t0
    others = {k: backtest(simulate_fleet(a.units, k)) for k in range(1, a.other_seeds + 1)
              if k != a.seed}
    print(json.dumps({"seed": r, "others": others}, indent=1) if a.json
          else readme_block(r, a.seed, secs, others))
    if a.readme:
        from readme_block import write_block
        write_block(a.readme, "drift-backtest", readme_block(r, a.seed, secs, others))
    return 0 if r["targets_met"] else 1


if __name__ == "__main__":
    sys.exit(main())
