"""diagnose-benchmark: simulate campaigns (accelcal.simulate) with one catalogue effect present
and withheld from the baseline, at sizes given in noise sigmas, plus clean and two-effect
cases; score the diagnosis.

Effect size k sigma: the parameter is scaled so that the effect's signature, projected off
what the baseline absorbs, reaches k noise sigmas (of a cell mean) at its largest cell.
An effect the baseline absorbs (observable fraction < 1e-3) is scored as a success when the
diagnosis reports it as not observable and gives no verdict.
"""
from __future__ import annotations

import time

import numpy as np

from ..effects import EFFECTS
from ..simulate import load_scenario, simulate_campaign
from ._blas import single_thread
from .core import _basis, _fit_set, _perp, default_baseline, diagnose
from .data import make_cells

COEFFS = {"K0": 2.5e-4, "K1": 0.1325, "K2": 3.94e-7}
SITE = {"latitude_deg": 39.9, "g_local_m_s2": 9.80122}


def scenario(kind: str, effects: dict, noise_scale: float = 1.0, test_effects=None) -> dict:
    noise = {"white_m_s2": 2e-6 * noise_scale, "rate_jitter_rel": 2.5e-6 * noise_scale, "temp_noise_c": 0.02}
    eff = {"earth_rate": 1.0, **effects} if kind in ("centrifuge", "sine_centrifuge") else dict(effects)
    if kind == "centrifuge":
        test = {"kind": "centrifuge", "rig_id": "LXJ-100", "arm_radius_m": 0.71,
                "mounts": [{"plane": "IA-PA", "angle_deg": a, "vertical": "+OA"} for a in (0, 180, 45, 225)],
                "g_levels": [1, 2, 3, 5, 7, 10, 14, 18, 21, 25]}
    elif kind == "tumble":
        test = {"kind": "tumble", "rig_id": "DH-1", "positions": 24, "readings": 10}
    elif kind == "tilt_rotation":
        test = {"kind": "tilt_rotation", "rig_id": "TT-1", "tilt_deg": 0.45, "positions": 12,
                "readings": 10, "sweeps": 2, "soak_s": 1800}
        noise["white_m_s2"] = 2e-7 * noise_scale
    else:
        test = {"kind": "sine_centrifuge", "rig_id": "DC-1", "arm_radius_m": 1.0,
                "rate_amplitude_rad_s": 4 * np.pi, "rate_frequency_hz": 1.0,
                "attitudes": [{"plane": "IA-PA", "angle_deg": 0, "vertical": "+OA"},
                              {"plane": "IA-PA", "angle_deg": 90, "vertical": "+OA"}]}
        noise["rate_jitter_rel"] = 0.0
        noise["white_m_s2"] = 1e-4 * noise_scale
    return {"name": f"bench-{kind}", "unit": {"serial": "BENCH-1", "model": "QA-2000",
                                              "campaign": f"BENCH-1/{kind}", "output_unit": "mA",
                                              "coefficients": dict(COEFFS)},
            "site": dict(SITE), "effects": eff, "noise": noise, "test": [test]}


def _cells(sc: dict, seed: int):
    return [make_cells(r.meta, r.data, r.meta["run_id"]) for r in simulate_campaign(load_scenario(sc), seed)]


def calibrate(kind: str, effect: str, baseline: list, noise_scale: float, seed: int = 999):
    """Parameter per sigma of peak projected signature, and the observable fraction."""
    runs = _cells(scenario(kind, {}, noise_scale), seed)
    f = _fit_set(runs, baseline, [])
    j = f.model.signature(f.p, effect)
    if not np.any(j):
        return None, 0.0
    jp = _perp(_basis(f.J), j)
    frac = float(np.linalg.norm(jp) / np.linalg.norm(j))
    peak = float(np.max(np.abs(jp)))
    return (1.0 / peak if peak > 0 else None), frac


def run_benchmark(quick: bool = False, seeds=None, log=print) -> dict:
    t0 = time.perf_counter()
    kinds = ["centrifuge", "tumble", "tilt_rotation", "sine_centrifuge"]
    sizes = [10.0] if quick else [10.0, 30.0]
    noises = [1.0] if quick else [1.0, 3.0]
    n_clean = 3 if quick else 15
    cases = []
    with single_thread():
        for kind in kinds:
            base_all = default_baseline([kind])
            effs = [e for e, d in EFFECTS.items() if kind in d.tests]
            for e in effs:
                base = [b for b in base_all if b != e]
                for ns in noises:
                    per_sigma, frac = calibrate(kind, e, base, ns)
                    for k in sizes:
                        seed = 1000 + len(cases)
                        val = (k * per_sigma) if per_sigma else EFFECT_DEFAULT(e)
                        if e == "earth_rate":   # withheld earth rate: the physical one
                            val = 1.0
                        runs = _cells(scenario(kind, {e: val}, ns), seed)
                        t1 = time.perf_counter()
                        res = diagnose(runs, base, separate=False, strict_check=False)
                        dt = time.perf_counter() - t1
                        cases.append(_score("single", kind, {e: val}, k, ns, res, frac, dt))
                        log(_line(cases[-1]))
            for s in range(n_clean):
                runs = _cells(scenario(kind, {}, 1.0), 5000 + 17 * s + len(cases))
                t1 = time.perf_counter()
                res = diagnose(runs, base_all, separate=False, strict_check=False)
                cases.append(_score("clean", kind, {}, 0, 1.0, res, None, time.perf_counter() - t1))
                log(_line(cases[-1]))
        for pair in ([("odd_quadratic", 1.5e-8), ("bias_drift", 2e-9)], [("cubic", 2e-10), ("earth_rate", 1.0)]):
            base = [b for b in default_baseline(["centrifuge"]) if b not in dict(pair)]
            runs = _cells(scenario("centrifuge", dict(pair)), 7000 + len(cases))
            t1 = time.perf_counter()
            res = diagnose(runs, base, separate=False, strict_check=False)
            cases.append(_score("two", "centrifuge", dict(pair), None, 1.0, res, None, time.perf_counter() - t1))
            log(_line(cases[-1]))
    return summarise(cases, time.perf_counter() - t0)


def EFFECT_DEFAULT(e):
    from .model import EFFECT_STEP
    return 10 * EFFECT_STEP[e]


def _score(kind_case, test, truth, k, ns, res, frac, dt):
    sel = res["selected"]
    aliases = set(res.get("verdict_aliases") or [])
    unobs = {u["effect"] for u in res["unobservable"]}
    c = {"case": kind_case, "test": test, "truth": truth, "size_sigma": k, "noise_scale": ns,
         "verdict": res["verdict"], "aliases": sorted(aliases), "selected": sel, "seconds": dt,
         "observable_fraction": frac, "shrink_heldout": res["gap"]["shrink_heldout"],
         "shrink_in_sample": res["gap"]["shrink_in_sample"]}
    if kind_case == "single":
        (e, v), = truth.items()
        c["effect"] = e
        c["unobservable_truth"] = e in unobs
        if e in unobs:
            c["correct"] = res["verdict"] is None
            c["kind"] = "unobservable"
        else:
            c["kind"] = "observable"
            c["correct"] = res["verdict"] == e or e in aliases
            est = next((r["estimate"] for r in res["ranking"] if r["effect"] == e), None)
            c["estimate"] = est
            c["rel_error"] = abs(est - v) / abs(v) if (c["correct"] and est is not None and res["verdict"] == e) else None
    elif kind_case == "clean":
        c["correct"] = res["verdict"] is None
    else:
        c["correct"] = set(truth) <= set(sel) | set(a for r in res["ranking"] if r["effect"] in sel for a in r["aliases"])
    return c


def _line(c):
    return (f"{c['case']:6s} {c['test']:15s} {','.join(c['truth']) or '-':30s} k={c['size_sigma']} "
            f"noise x{c['noise_scale']} -> {c['verdict']} {'OK' if c['correct'] else 'MISS'} "
            f"heldout {c['shrink_heldout'] if c['shrink_heldout'] is None else round(c['shrink_heldout'], 2)} "
            f"({c['seconds']:.1f} s)")


def summarise(cases, elapsed) -> dict:
    obs = [c for c in cases if c["case"] == "single" and c["kind"] == "observable"]
    uno = [c for c in cases if c["case"] == "single" and c["kind"] == "unobservable"]
    clean = [c for c in cases if c["case"] == "clean"]
    two = [c for c in cases if c["case"] == "two"]
    rel = [c["rel_error"] for c in obs if c.get("rel_error") is not None]
    sh = [c["shrink_heldout"] for c in obs if c["correct"] and c["shrink_heldout"] is not None]
    out = {
        "accuracy_top1_alias_aware": float(np.mean([c["correct"] for c in obs])) if obs else None,
        "n_observable_cases": len(obs),
        "unobservable_reported": float(np.mean([c["correct"] for c in uno])) if uno else None,
        "n_unobservable_cases": len(uno),
        "false_alarm_rate": float(np.mean([not c["correct"] for c in clean])) if clean else None,
        "n_clean": len(clean),
        "estimate_within_25pct": float(np.mean([r <= 0.25 for r in rel])) if rel else None,
        "median_rel_error": float(np.median(rel)) if rel else None,
        "median_heldout_shrink": float(np.median(sh)) if sh else None,
        "heldout_shrink_ge_0.5": float(np.mean([s >= 0.5 for s in sh])) if sh else None,
        "two_effect_both_found": float(np.mean([c["correct"] for c in two])) if two else None,
        "median_seconds_per_diagnosis": float(np.median([c["seconds"] for c in cases])),
        "elapsed_s": elapsed,
        "cases": cases,
    }
    out["markdown"] = markdown(out)
    return out


def markdown(s) -> str:
    L = ["| metric | value |", "|---|---|"]
    for k in ("accuracy_top1_alias_aware", "n_observable_cases", "unobservable_reported", "n_unobservable_cases",
              "false_alarm_rate", "n_clean", "estimate_within_25pct", "median_rel_error", "median_heldout_shrink",
              "heldout_shrink_ge_0.5", "two_effect_both_found", "median_seconds_per_diagnosis"):
        v = s[k]
        L.append(f"| {k} | {v:.3g} |" if isinstance(v, float) else f"| {k} | {v} |")
    L += ["", "Confusion (true effect -> verdict; per test kind; unobservable = reported absorbed):", "",
          "| test | true effect | cases | verdicts |", "|---|---|---|---|"]
    rows: dict = {}
    for c in s["cases"]:
        if c["case"] != "single" and c["case"] != "clean":
            continue
        key = (c["test"], c.get("effect", "(clean)") + (" [unobservable]" if c.get("unobservable_truth") else ""))
        rows.setdefault(key, []).append(str(c["verdict"]))
    for (t, e), vs in rows.items():
        cnt: dict = {}
        for v in vs:
            cnt[v] = cnt.get(v, 0) + 1
        L.append(f"| {t} | {e} | {len(vs)} | " + ", ".join(f"{k}: {n}" for k, n in cnt.items()) + " |")
    return "\n".join(L)
