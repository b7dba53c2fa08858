"""Tests of the sinusoidal-rate disc centrifuge estimator (paper 002).

Truth values come from the sample drop's documentation (brief) and from synthetic
campaigns built with the shared forward model (accelcal.physics.rig_output); nothing is
compared with numbers the estimator printed.
"""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from accelcal.estimators.records import jsonable
from accelcal.estimators import sinusoidal as S
from accelcal.physics import rigs

from conftest import EXAMPLES  # noqa: E402  (../shared relative to the repository root)

SAMPLE = EXAMPLES / "drop-2026-11-19-sine"
TRUTH = {"K2": 3.94e-7, "K3": 1.5e-9, "Koq": 2e-8, "Kip": 7.1e-7, "Kpp": 4.7e-8, "Kio": 2.0e-7,
         "Koo": 3.0e-8}


def _parse(path: Path):
    """Small drop parser for the tests: '# key: value' lines, then CSV."""
    meta, lines = {}, path.read_text().splitlines()
    i = 0
    while lines[i].startswith("#"):
        k, v = lines[i][1:].split(":", 1)
        v = v.strip()
        try:
            v = float(v)
        except ValueError:
            pass
        meta[k.strip()] = v
        i += 1
    return meta, pd.read_csv(io.StringIO("\n".join(lines[i:])))


@pytest.fixture(scope="module")
def sample():
    if not SAMPLE.is_dir():
        pytest.skip("sample drop not available")
    return [_parse(p) for p in sorted(SAMPLE.glob("*.csv"))]


@pytest.fixture(scope="module")
def processed(sample):
    return S.process_sine_campaign(sample, "DC-1", compare_rate_sources=False)


# ----------------------------------------------------------------- synthetic campaigns

ATTITUDES = {"a": ("IA-PA", "+OA"), "b": ("OA-IA", "+PA"), "c": ("PA-OA", "+IA")}
COEFFS = {"K0": 4e-4, "K1": 0.1325, "Kp": 2e-5, "Ko": -1.5e-5, "K2": 3.94e-7, "K3": 1.5e-9,
          "Koq": 2e-8, "Kip": 7.1e-7, "Kio": 2.0e-7, "Kpo": 5e-8, "Kpp": 4.7e-8, "Koo": 3.0e-8}


def _meta(att: str, sense: str = "ccw") -> dict:
    plane, vert = ATTITUDES[att]
    return {"test": "sine_centrifuge", "run_id": f"SYN-{att}", "site_latitude_deg": 45.75,
            "g_local_m_s2": 9.8066, "output_unit": "mA", "arm_radius_m": 1.0, "rotation_sense": sense,
            "mount_plane": plane, "mount_angle_deg": 0.0, "vertical_axis": vert,
            "rate_amplitude_rad_s": 4 * np.pi, "rate_frequency_hz": 1.0}


def _campaign(coeffs, effects, sigma_out, rng, sigma_rate=0.0, n=1000, atts="abc", sense="ccw"):
    """Three-attitude campaign from the forward model; the logged rate is the drive plus
    noise (the true rate is the drive, times 1 + eps under rate_scale_error)."""
    runs = []
    t = np.arange(n) * 0.02
    for a in atts:
        m = _meta(a, sense)
        Om, f = m["rate_amplitude_rad_s"], m["rate_frequency_hz"]
        w = Om * np.sin(2 * np.pi * f * t)
        ang = np.degrees(Om / (2 * np.pi * f) * (1 - np.cos(2 * np.pi * f * t)))
        d = pd.DataFrame({"time_s": t, "table_rate_rad_s": w, "table_angle_deg": ang})
        E = rigs.rig_output("sine_centrifuge", m, d, coeffs, {**rigs.NOMINAL, **effects})
        d["output"] = E + sigma_out * rng.standard_normal(n)
        d["table_rate_rad_s"] = w + sigma_rate * rng.standard_normal(n)
        runs.append((m, d))
    return runs


# ----------------------------------------------------------------- the sample drop

def test_sample_truth_within_5pct_and_3sigma(processed):
    res, _ = processed
    by = {r.name: r for r in res}
    for name, truth in TRUTH.items():
        r = by[name]
        assert abs(r.value / truth - 1) < 0.05, (name, r.value)
        assert abs(r.value - truth) < 3 * r.std_uncertainty, (name, r.value, r.std_uncertainty)
        assert r.method == "sine_ls"
    assert by["K2"].unit == "s2/m" and by["K3"].unit == "s4/m2" and by["Kp"].unit == "rad"
    assert by["K0"].unit == "m/s2" and by["K1"].unit == "mA/(m/s2)"
    assert all(r.rig_id == "DC-1" for r in res)


def test_sample_extras_json_and_diagnostics(processed):
    _, ex = processed
    json.dumps(ex, allow_nan=False)
    d = ex["diagnostics"]
    assert d["rank"] == d["n_params"] and d["condition_number"] < 1e4
    assert {a["attitude"] for a in ex["aliasing"]} == {"a", "b", "c"}
    comp = ex["compensation"]
    assert set(comp["uncompensated"]) <= set(comp["compensated"])
    assert {"spindle_tilt", "mass_centre_offset", "rate_scale_error"} <= set(ex["tool_errors"])
    # the 2026-11-19 sample shows no tool error (each within 3 sigma of zero)
    for v in ex["tool_errors"].values():
        assert abs(v["value"]) < 3 * v["std"]


def test_sample_rate_derivative_drive_reproduces_data(sample):
    """The drive's analytic rate/derivative fits the sample at the output noise; the logged
    rate (centripetal) and its numerical derivative (tangential) do not."""
    drive = S.identify_sine_campaign(sample, rate_source="drive", reweight=False)
    logged = S.identify_sine_campaign(sample, rate_source="logged", reweight=False)
    numeric = S.identify_sine_campaign(sample, rate_source="drive", rate_derivative="numeric", reweight=False)
    lab = {v: k for k, v in drive.attitudes.items()}
    # attitude (a): IA senses the centripetal input -> noisy logged rate shows
    assert logged.residual_rms[lab["a"]] > 5 * drive.residual_rms[lab["a"]]
    # attitude (b): IA senses the tangential input -> numerical derivative shows
    assert numeric.residual_rms[lab["b"]] > 5 * drive.residual_rms[lab["b"]]


def test_aliasing_attitude_a_alone(processed):
    _, ex = processed
    rep = {a["attitude"]: a for a in ex["aliasing"]}
    assert S.aliased_together(rep["a"], "K2", "Koq")
    assert S.aliased_together(rep["a"], "Kp", "Kpo")
    assert not S.aliased_together(rep["b"], "K2", "Koq")      # tangential a_I changes sign
    assert "Koq" in rep["b"]["separable"]
    assert rep["a"]["rank"] < len(rep["a"]["parameters"])


def test_aliasing_single_attitude_campaign_detected():
    """A campaign of attitude (a) alone: the joint fit itself must report K2/Koq aliased."""
    rng = np.random.default_rng(1)
    runs = _campaign(COEFFS, {}, 1e-6, rng, atts="a")
    fit = S.identify_sine_campaign(runs, reweight=False)
    assert fit.diagnostics["rank"] < fit.diagnostics["n_params"]
    assert any({"K2", "Koq"} <= set(g) for g in fit.diagnostics["aliased_groups"])
    rep = S.aliasing_report(fit)[0]
    assert S.aliased_together(rep, "K2", "Koq")


# ----------------------------------------------------------------- synthetic recovery

def test_synthetic_tool_errors_recovered_and_compensated():
    rng = np.random.default_rng(7)
    effects = {"spindle_tilt": 3e-4, "mass_centre_offset": 2e-3, "rate_scale_error": 2e-4}
    truth = {**COEFFS, "Kp": -3e-5, "Kpo": -4e-8}
    runs = _campaign(truth, effects, 2e-6, rng, sigma_rate=1e-5, sense="cw")
    tools = {k: "shared" for k in effects}
    f1, f2, cmp = S.compare_compensation(runs, tools)
    assert not f2.dropped
    for k, v in {**truth, **effects}.items():
        assert abs(f2.values[k] - v) < 3 * f2.std[k] + 1e-12 * abs(v), (k, f2.values[k], v, f2.std[k])
    # ignoring the tool errors leaves a misfit and biased coefficients
    lab = {v: k for k, v in f1.attitudes.items()}
    assert f1.residual_rms[lab["a"]] > 3 * f2.residual_rms[lab["a"]]
    z1 = max(abs(f1.values[k] - truth[k]) / f1.std[k] for k in TRUTH)
    assert z1 > 5
    assert cmp["f_test_tool_errors"]["p_value"] < 1e-6
    json.dumps(jsonable(cmp), allow_nan=False)


def test_synthetic_sensor_lag_identified():
    rng = np.random.default_rng(11)
    # a lag of half the 20 ms sample period (a sampled lag of tau << dt is not in the data)
    effects = {"sensor_lag": 1e-2}
    runs = _campaign(COEFFS, effects, 2e-6, rng)
    fit = S.identify_sine_campaign(runs, tool_errors={"sensor_lag": "shared"}, reweight=False)
    assert abs(fit.values["sensor_lag"] - 1e-2) < 3 * fit.std["sensor_lag"]
    for k in TRUTH:
        assert abs(fit.values[k] - COEFFS[k]) < 3 * fit.std[k], k


def test_unidentifiable_tool_error_is_dropped_not_fitted():
    """mass_centre_offset per run plus a shared rate_scale_error: attitude (a) sees
    2 eps - r_a/R, (b) eps - r_b/R and (c) hardly any: not all can be identified."""
    rng = np.random.default_rng(3)
    runs = _campaign(COEFFS, {}, 2e-6, rng)
    fit = S.identify_sine_campaign(runs, reweight=False, tool_errors={"mass_centre_offset": "per_run",
                                                                      "rate_scale_error": "shared"})
    assert fit.dropped
    assert fit.diagnostics["rank"] == fit.diagnostics["n_params"]


def test_monte_carlo_stated_uncertainty_matches_spread():
    """~50 replicates: the stated u(K2) matches the spread of K2 (ratio 0.7-1.4)."""
    rng = np.random.default_rng(2026)
    base = _campaign(COEFFS, {}, 0.0, rng)
    prep = S.prepare_runs(base)
    clean = [r.y_rows.copy() for r in prep]
    sig = 3e-6
    est, unc = [], []
    for _ in range(50):
        for r, y0 in zip(prep, clean):
            r.y_rows = y0 + sig * rng.standard_normal(y0.size)
        fit = S.identify_sine_campaign(None, prepared=prep, reweight=False)
        est.append(fit.values["K2"])
        unc.append(fit.std["K2"])
    spread = np.std(est, ddof=1)
    ratio = np.mean(unc) / spread
    assert 0.7 < ratio < 1.4, (ratio, spread, np.mean(unc))
    assert abs(np.mean(est) - COEFFS["K2"]) < 4 * spread / np.sqrt(len(est))


# ----------------------------------------------------------------- lack of fit (pure error of the drive's phases)

def _pure_error_F(fit, runs):
    """F of the fit's weighted residuals: between the drive's phases (one cell per sample of the
    1-Hz period at 50 Hz, per run) against within them, derived here independently."""
    z, between, within, cells, a = fit.result.z, 0.0, 0.0, 0, 0
    for meta, data in runs:
        phase = np.rint(np.asarray(data["time_s"]) * 50.0).astype(int) % 50
        zr, a = z[a:a + phase.size], a + phase.size
        for k in range(50):
            zk = zr[phase == k]
            between += zk.size * zk.mean() ** 2
            within += np.sum((zk - zk.mean()) ** 2)
            cells += 1
    n, p = z.size, len(fit.names)
    return (between / (cells - p)) / (within / (n - cells)), cells - p, n - cells


def test_sample_lack_of_fit_is_a_pure_error_test(processed):
    _, ex = processed
    lof = ex["lack_of_fit"]
    assert (lof["df1"], lof["df2"]) == (3 * 50 - 15, 3 * (1000 - 50))    # 15 parameters, 50 phases a run
    # the sample is made by the model paper 002 fits: no lack of fit
    assert lof["status"] == "adequate" and lof["p_value"] > 0.01


def test_lack_of_fit_detects_an_unmodelled_tool_error():
    """Tool errors left out of the model show as a lack of fit between the drive's phases;
    with them identified the fit is adequate.  The F statistic is checked against an
    independent derivation."""
    rng = np.random.default_rng(5)
    effects = {"spindle_tilt": 3e-4, "mass_centre_offset": 2e-3, "rate_scale_error": 2e-4}
    runs = _campaign(COEFFS, effects, 2e-6, rng)
    nominal = S.identify_sine_campaign(runs, reweight=False)
    F, df1, df2 = _pure_error_F(nominal, runs)
    lof = nominal.result.lof
    assert lof.status == "inadequate" and lof.p_value < 1e-6
    assert (lof.dof_lof, lof.dof_pe) == (df1, df2) and lof.statistic == pytest.approx(F, rel=1e-9)
    full = S.identify_sine_campaign(runs, reweight=False, tool_errors={k: "shared" for k in effects})
    assert full.result.lof.status == "adequate"
    assert full.result.lof.statistic == pytest.approx(_pure_error_F(full, runs)[0], rel=1e-9)


def test_certificate_lists_the_lack_of_fit(processed):
    _, ex = processed
    checks = S.fit_checks({"sine": {"DC-1": ex}})
    lof = [c for c in checks if c.check.startswith("lack of fit")]
    assert len(lof) == 1 and lof[0].p == ex["lack_of_fit"]["p_value"] and lof[0].yes == "adequate"
    assert lof[0].dof == "135 / 2850"
