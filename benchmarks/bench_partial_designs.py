#!/usr/bin/env python
"""Partial designs of the lab's sample drops (issue 30): every coefficient row is within
4 u of the truth, or a flag names it as aliased or undetermined; no joint fit is inadequate.

The designs are subsets of the runs of ../shared/examples, which an independent reference
simulator made with known instrument values (the issues quote them; the scenario files
``accelcal/simulate/scenarios/snj103-*.toml`` and ``qa5512-sine.toml`` copy them):

* LXJ-100 (drop-2026-11-20) and LXJ-200 (drop-2026-11-21) are the two "seeds" of each
  centrifuge design: the tumble alone; tumble + IA pair; + 45/225; + 90/270; full set; IA pair alone;
  IA pair + 45/225; IA pair + 90/270 + 45/225 without the tumble;
* the sine drop (drop-2026-11-19-sine) with each one and each two of its three attitudes.

    python benchmarks/bench_partial_designs.py [--examples DIR] [--readme README.md] [--verbose]

A row is *flagged* when its note or name says what it measures is aliased or undetermined
(``aliased``, ``not determined``, ``combination``); flagged rows are listed but not counted
against the 4 u rule.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from accelcal.effects import split_combination
from accelcal.estimators.campaign import process_campaign
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_block import commit, write_block  # noqa: E402

G = 9.80122
#: the instrument of SNJ-1-03 as the reference simulator made it (issues; scenario files)
UNIT = {"K0": 4.0e-4, "K1": 0.1325631, "Kp": 2.0e-5, "Ko": -1.5e-5, "K2": 3.94e-7, "Kpp": 4.7e-8,
        "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8, "Koq": 3.0e-8, "K3": 2.0e-10, "Kpo": 0.0,
        "theta0": 0.0}
SINE = {**UNIT, "K3": 1.5e-9, "Koq": 2.0e-8}
#: mounts (plane, angle) of each centrifuge design; "T" = with the drop's tumble
CENTRIFUGE_DESIGNS = {
    "tumble alone": (True, set()),
    "T + IA pair": (True, {0, 180}),
    "T + IA pair + 45/225": (True, {0, 180, 45, 225}),
    "T + IA pair + 90/270": (True, {0, 180, 90, 270}),
    "T + full IA-PA set": (True, {0, 180, 90, 270, 45, 225}),
    "IA pair alone": (False, {0, 180}),
    "IA pair + 45/225": (False, {0, 180, 45, 225}),
    "IA-PA set, no tumble": (False, {0, 180, 90, 270, 45, 225}),
}
SINE_DESIGNS = {"sine a": (1,), "sine b": (2,), "sine c": (3,), "sine a+b": (1, 2), "sine a+c": (1, 3),
                "sine b+c": (2, 3), "sine a+b+c": (1, 2, 3)}
FLAG_WORDS = ("aliased", "not determined", "undetermined", "combination")


def truth_of(c, truth: dict) -> float | None:
    """Truth of a coefficient row or of a determined combination (``K2(Koo)``, ``K0(Koo)``:
    the quantity plus the row's factors times the terms)."""
    base, terms = split_combination(c.name)[0], c.factors
    if base not in truth or any(k not in truth for k in terms):
        return None
    return truth[base] + sum(f * truth[k] for k, f in terms.items())


def designs(examples: Path):
    """(design, drop, runs, truth) of every partial design."""
    for drop in ("drop-2026-11-20", "drop-2026-11-21"):
        runs = [read_run(p) for p in discover(examples / drop)]
        for name, (tumble, angles) in CENTRIFUGE_DESIGNS.items():
            sub = [r for r in runs if (r.meta["test"] == "tumble" and tumble) or (
                r.meta["test"] == "centrifuge" and r.meta.get("mount_plane") == "IA-PA"
                and float(r.meta["mount_angle_deg"]) in angles)]
            yield name, drop, sub, UNIT
    runs = [read_run(p) for p in discover(examples / "drop-2026-11-19-sine")]
    for name, idx in SINE_DESIGNS.items():
        yield name, "drop-2026-11-19-sine", [runs[i - 1] for i in idx], SINE


def judge(res, truth: dict):
    """(worst unflagged row, [(row text, z, flagged)], inadequate) of one campaign result."""
    rows, worst, worst_all = [], None, None
    for c in res.coefficients:
        t = truth_of(c, truth)
        if t is None or not (c.std_uncertainty > 0) or not math.isfinite(c.value):
            continue
        z = (c.value - t) / c.std_uncertainty
        flagged = any(w in (c.note + " " + c.name).lower() for w in FLAG_WORDS)
        rows.append((f"{c.method}{'*' if c.adopted else ''} {c.name}", z, flagged))
        if not flagged and (worst is None or abs(z) > abs(worst[1])):
            worst = (f"{c.method} {c.name}", z)
        if worst_all is None or abs(z) > abs(worst_all[1]):
            worst_all = (f"{c.method} {c.name}", z)
    lof = res.extras.get("joint", {}).get("lack_of_fit", {})
    inadequate = any("inadequate" in f for f in res.flags if "joint" in f or "model" in f)
    return worst, worst_all, rows, inadequate, lof


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--examples", type=Path, default=ROOT.parent / "shared" / "examples")
    ap.add_argument("--readme", type=Path)
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--only", help="substring of the design names to run")
    args = ap.parse_args()
    out = [f"`python benchmarks/bench_partial_designs.py --readme README.md`, commit {commit()}. "
           "Subsets of the sample drops (independent simulator); error / u of a row named as a "
           "combination (`K2-Koo`) is against the combination of the truths; worst unflagged = the "
           "largest |error| / u of a row no flag names as aliased or undetermined; worst of all rows "
           "counts the flagged ones too.", "",
           "| design | drop | worst unflagged row | error / u | rows flagged | worst of all rows | error / u | joint fit |",
           "|---|---|---|---|---|---|---|---|"]
    fails = 0
    for name, drop, runs, truth in designs(args.examples):
        if args.only and args.only not in name:
            continue
        t0 = time.perf_counter()
        res = process_campaign(runs)
        worst, worst_all, rows, inadequate, lof = judge(res, truth)
        nflag = sum(f for *_, f in rows)
        bad = inadequate or (worst is not None and abs(worst[1]) > 4)
        fails += bad
        F = lof.get("F")
        fit = ("inadequate" if inadequate else "adequate") + (f" (F = {F:.3g})" if F else "")
        cell = (lambda w: f"{w[0]} | {w[1]:+.1f}" if w else "— | —")
        out.append(f"| {name} | {drop[5:]} | {cell(worst)} | {nflag} | {cell(worst_all)} | {fit} |")
        if args.verbose:
            print(f"--- {name} {drop} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
            for text, z, f in rows:
                print(f"    {text:40s} {z:+10.2f}{'  [flagged]' if f else ''}", file=sys.stderr)
            for f in res.flags:
                print(f"    flag: {f[:150]}", file=sys.stderr)
    out += ["", f"{fails} design(s) with an unflagged row beyond 4 u or an inadequate joint fit."]
    text = "\n".join(out)
    print(text)
    if args.readme:
        write_block(args.readme, "partial-designs", text)


if __name__ == "__main__":
    main()
