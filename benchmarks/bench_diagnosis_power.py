#!/usr/bin/env python
"""Power of the diagnosis where a family is weak: a sweep hysteresis the omnibus test
dilutes, and clean campaigns whose output noise is AR(1).

    python benchmarks/bench_diagnosis_power.py [--draws 100] [--workers 1] [--readme README.md]

Hysteresis: the diagnose-benchmark's centrifuge (ten g levels up and down, six mounts,
DAQ noise, the case temperature held) with rising steps reading h a_IA above falling ones,
h set so that the targeted rising-minus-falling contrast (``shape_tests``) expects z =
0, 2.5, 3, 3.5, 4, 5 (h = z u, u the contrast's standard uncertainty of h on a clean draw).
Its power is the share of draws said to keep a gap; the rule checked is that no draw whose
contrast reads |z| >= 3.5 is called explained.

AR(1): a clean IA pair and a clean 24-position tumble whose 2e-6 m/s^2 output noise is
AR(1) between consecutive readings at rho = 0, 0.5, 0.8, 0.9, 0.95 (the diagnose-
benchmark's ``ar1_scenario``); a false "unexplained" is a gap said to remain, a false
verdict an effect named.  Rates with their Wilson 95 % intervals.
"""
from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from readme_block import commit, write_block  # noqa: E402

TARGET_Z = (0.0, 2.5, 3.0, 3.5, 4.0, 5.0)
RHOS = (0.0, 0.5, 0.8, 0.9, 0.95)
KINDS = ("centrifuge", "tumble")
#: a contrast reading at least this |z| must never be called explained
RULE_Z = 3.5


def hysteresis_scenario(h: float) -> dict:
    from accelcal.validation.diagnosis_benchmark import scenario
    sc = scenario("centrifuge", {}, {"sweep_hysteresis_rel": h})
    sc["test"][0]["temp_start_c"] = sc["test"][0]["temp_c"]
    return sc


def unit_uncertainty() -> float:
    """The contrast's standard uncertainty of h on a clean draw [1]."""
    from accelcal.diagnosis import diagnose
    from accelcal.fitting.model import processing_effects
    from accelcal.validation.diagnosis_benchmark import runs_of
    res = diagnose(runs_of(hysteresis_scenario(0.0), 999), processing_effects(["centrifuge"]))
    return res["shape_tests"][0]["std_uncertainty"]


def one(job):
    from accelcal.diagnosis import diagnose
    from accelcal.fitting.model import processing_effects
    from accelcal.validation.diagnosis_benchmark import DEV_BASELINE, ar1_scenario, runs_of
    fam, key, value, seed = job
    if fam == "hyst":
        res = diagnose(runs_of(hysteresis_scenario(value), seed), processing_effects(["centrifuge"]))
        z = max((abs(t["z"]) for t in res["shape_tests"]), default=0.0)
        return fam, key, res["explained"] is False, z, res["verdict"]
    res = diagnose(runs_of(ar1_scenario(key[0], key[1]), seed), DEV_BASELINE[key[0]])
    return fam, key, res["explained"] is False, None, res["verdict"]


def main() -> None:
    from accelcal.fitting.blas import single_thread
    from accelcal.validation.diagnosis_benchmark import rate_with_interval
    ap = argparse.ArgumentParser()
    ap.add_argument("--draws", type=int, default=100, help="campaigns per row")
    ap.add_argument("--workers", type=int, default=1, help="1: in this process")
    ap.add_argument("--readme", type=Path)
    a = ap.parse_args()
    t0 = time.time()
    with single_thread():
        u = unit_uncertainty()
        jobs = [("hyst", z, z * u, 31000 + 100 * k + i) for k, z in enumerate(TARGET_Z) for i in range(a.draws)]
        jobs += [("ar1", (kind, r), None, 20261200 + i) for kind in KINDS for r in RHOS for i in range(a.draws)]
        if a.workers > 1:
            with ProcessPoolExecutor(a.workers) as ex:
                rows = list(ex.map(one, jobs, chunksize=4))
        else:
            rows = [one(j) for j in jobs]
    lines = [f"`python benchmarks/bench_diagnosis_power.py --draws {a.draws} --workers {a.workers} --readme "
             f"README.md`, commit {commit()}, {time.time() - t0:.0f} s.", "",
             f"**Sweep hysteresis** (centrifuge, six mounts, ten g levels up and down, DAQ noise): rising steps "
             f"read h a_IA above falling ones, h = z u with u = {u:.2g} the targeted contrast's standard "
             "uncertainty of h; power = said a gap remains (Wilson 95 % interval).", "",
             "| targeted z | h | draws | said a gap remains | contrast read |z| >= 3.5 | of those, called explained |",
             "|---|---|---|---|---|---|"]
    for z in TARGET_Z:
        sel = [r for r in rows if r[0] == "hyst" and r[1] == z]
        hit = sum(r[2] for r in sel)
        big = [r for r in sel if r[3] >= RULE_Z]
        lines.append(f"| {z:g} | {z * u:.2g} | {len(sel)} | {hit} = {rate_with_interval(hit, len(sel))} | "
                     f"{len(big)} | {sum(not r[2] for r in big)} |")
    lines += ["", "**AR(1) output noise on clean campaigns** (2e-6 m/s^2 per reading, AR(1) between consecutive "
                  "readings, the temperature sensor's noise; no effect withheld):", "",
              "| test | rho | draws | false \"unexplained\" | false verdict |", "|---|---|---|---|---|"]
    for kind in KINDS:
        for r in RHOS:
            sel = [x for x in rows if x[0] == "ar1" and x[1] == (kind, r)]
            gap, named = sum(x[2] for x in sel), sum(x[4] is not None for x in sel)
            lines.append(f"| {'centrifuge IA pair' if kind == 'centrifuge' else 'tumble, 24 positions'} | {r:g} | "
                         f"{len(sel)} | {gap} = {rate_with_interval(gap, len(sel))} | "
                         f"{named} = {rate_with_interval(named, len(sel))} |")
    text = "\n".join(lines)
    print(text)
    if a.readme:
        write_block(a.readme, "bench-diagnosis-power", text)


if __name__ == "__main__":
    main()
