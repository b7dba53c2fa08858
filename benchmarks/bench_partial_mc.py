#!/usr/bin/env python
"""Monte Carlo study of partial designs (issue 30): every value or combination the joint fit
reports within 0.8–1.3 x its Cramér–Rao bound, with 90–99 % coverage.

The designs are the shipped scenarios with runs taken away, as a lab would run them:

* ``snj103-lxj200``: tumble + IA pair; tumble + IA pair + 45/225; IA pair alone (no tumble);
  IA pair + 45/225 (no tumble);
* ``qa5512-sine``: attitude (a) alone; attitudes (a) and (b).

    python benchmarks/bench_partial_mc.py [--n 200] [--workers 2] [--readme README.md]

Our own simulator makes the campaigns (it is a study of the estimator's variance against
its bound, not evidence of the model: that is ``bench_partial_designs.py`` on the
independent sample drops).  A row named as a combination (``K2-Koo``) is compared with the
combination of the truths and with the bound of its coefficient with the terms it takes up
held out (:func:`accelcal.validation.montecarlo.combination_truth`).
"""
from __future__ import annotations

import argparse
import copy
import math
import sys
from types import SimpleNamespace
from pathlib import Path

from accelcal.simulate import load_scenario
from accelcal.validation.montecarlo import run_study

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402


def _mounts(sc, angles, tumble=True):
    out = copy.deepcopy(sc)
    out.tests = [t for t in out.tests if t["kind"] != "tumble" or tumble]
    for t in out.tests:
        if t["kind"] == "centrifuge":
            t["mounts"] = [m for m in t["mounts"] if float(m["angle_deg"]) in angles]
    return out


def _attitudes(sc, keep):
    out = copy.deepcopy(sc)
    for t in out.tests:
        if t["kind"] == "sine_centrifuge":
            t["attitudes"] = [m for i, m in enumerate(t["attitudes"]) if "abc"[i] in keep]
    return out


def designs():
    lxj = load_scenario("snj103-lxj200")
    sine = load_scenario("qa5512-sine")
    return {
        "T + IA pair": _mounts(lxj, {0, 180}),
        "T + IA pair + 45/225": _mounts(lxj, {0, 180, 45, 225}),
        "IA pair alone": _mounts(lxj, {0, 180}, tumble=False),
        "IA pair + 45/225": _mounts(lxj, {0, 180, 45, 225}, tumble=False),
        "sine a": _attitudes(sine, "a"),
        "sine a+b": _attitudes(sine, "ab"),
    }


def merged_rigs(rows):
    """One row per joint coefficient: the joint fit labels a row with the rig that carries
    most of its information, and where a tumble and a centrifuge carry about as much (Koo of
    a tumble + IA pair) that label changes from one campaign to the next.  The groups are
    pooled exactly: n-weighted mean and coverage, the variance by the parallel-axis rule."""
    by = {}
    for c in rows:
        by.setdefault(c.name, []).append(c)
    out = []
    for name, group in by.items():
        n = sum(c.n for c in group)
        mean = sum(c.n * c.mean for c in group) / n
        ss = sum((c.n - 1) * c.sd ** 2 + c.n * (c.mean - mean) ** 2 for c in group)
        var = ss / (n - 1)
        out.append(SimpleNamespace(name=name, n=n, var_over_crb=var / group[0].crb_sd ** 2,
                                   coverage=sum(c.n * c.coverage for c in group) / n,
                                   bias_z=(mean - group[0].truth) / math.sqrt(var / n)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--only", help="substring of the design names to run")
    ap.add_argument("--readme", type=Path)
    args = ap.parse_args()
    out = [f"`python benchmarks/bench_partial_mc.py --n {args.n} --readme README.md`, commit {commit()}. "
           "Joint-fit rows (the adopted values) with a truth and a bound: the range over them of "
           "var/CRB and of the coverage of ±2u (n campaigns each).", "",
           "| design | rows | var/CRB range | coverage range | rows outside 0.8–1.3 or 90–99 % |",
           "|---|---|---|---|---|"]
    bad_total = 0
    for name, sc in designs().items():
        if args.only and args.only not in name:
            continue
        res = run_study(sc, n=args.n, workers=args.workers)
        rows = merged_rigs([c for c in res.coefficients if c.method == "joint_ml" and c.crb_sd
                            and c.coverage is not None])
        bad = [c for c in rows if not (0.8 <= c.var_over_crb <= 1.3) or not (0.90 <= c.coverage <= 0.99)]
        bad_total += len(bad)
        vr = [c.var_over_crb for c in rows]
        cv = [c.coverage for c in rows]
        rng = (lambda v, f: f"{f(min(v))}–{f(max(v))}" if v else "—")
        out.append(f"| {name} | {len(rows)} | {rng(vr, lambda x: f'{x:.2f}')} | "
                   f"{rng(cv, lambda x: f'{100 * x:.1f} %')} | "
                   + (", ".join(f"{c.name} ({c.var_over_crb:.2f}, {100 * c.coverage:.1f} %)" for c in bad) or "none")
                   + " |")
        print(f"--- {name}: {len(res.failures)} failures, {res.seconds:.0f} s", file=sys.stderr)
        for c in res.coefficients:
            if c.method == "joint_ml":
                print(f"    {c.name:28s} truth {c.truth!s:>12.12} var/CRB {c.var_over_crb!s:.6} "
                      f"cov {c.coverage!s:.5} {c.truth_note[:60]}", file=sys.stderr)
    out += ["", f"{bad_total} row(s) outside the bounds."]
    text = "\n".join(out)
    print(text)
    if args.readme:
        write_block(args.readme, "partial-mc", text)


if __name__ == "__main__":
    main()
