"""Tests of accelcal.estimators.thermal (paper 001, tilted multi-position rotation).

Expected values come from the sample drop's stated truth, from the known inputs of
synthetic runs made with the one forward model (accelcal.physics.rig_output), and from
paper 001's closed forms -- never from numbers the estimator printed.
"""
from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from accelcal.constants import M2_PERIOD_S, MICRO_G
from accelcal.estimators import thermal as th
from accelcal.physics import rig_output

from conftest import EXAMPLES, needs_shared  # noqa: E402  (../shared relative to the repository root)

SAMPLE = EXAMPLES / "drop-2026-11-18-thermal" / "TT1-20261118-0001.csv"
G = 9.7936
TILT = 0.45
TRUTH = {"K0": 3.0e-4, "K1": 50.0, "K0T": 2.0e-6, "K1T": -1.2e-4}


# ----------------------------------------------------------------- helpers

def read_sample(path: Path) -> tuple[dict, pd.DataFrame]:
    """Minimal reader of a drop file: '# key: value' lines, then a CSV header and rows."""
    lines = path.read_text(encoding="utf-8").splitlines()
    meta: dict = {}
    i = 0
    while i < len(lines) and lines[i].startswith("#"):
        key, value = lines[i][1:].split(":", 1)
        meta[key.strip()] = value.strip()
        i += 1
    for key in ("g_local_m_s2", "tilt_deg", "site_latitude_deg", "sample_period_s"):
        meta[key] = float(meta[key])
    meta["positions"] = int(meta["positions"])
    data = pd.read_csv(io.StringIO("\n".join(l for l in lines[i:] if l.strip())))
    return meta, data


def make_meta(n_pos=12, tilt_deg=TILT) -> dict:
    return {"test": "tilt_rotation", "g_local_m_s2": G, "tilt_deg": tilt_deg, "sin_axis": "+IA",
            "cos_axis": "+PA", "normal_axis": "+OA", "positions": n_pos, "output_unit": "V"}


def make_schedule(n_pos=12, temps=(20.0, 25.0, 30.0, 35.0, 40.0), sweeps=2, readings=4,
                  soak_s=3600.0, step_s=50.0, temp_offset=0.3, temp_noise=0.0, rng=None) -> pd.DataFrame:
    """Rows of a tilt_rotation run (no output yet): sweeps x set-points x positions x readings,
    with the columns ``sweep_true`` and ``point_true`` the test knows by construction."""
    rows = []
    t = 0.0
    point = 0
    for s in range(sweeps):
        for T in temps:
            t += soak_s
            for k in range(n_pos):
                for r in range(readings):
                    rows.append((t + r, T, T + temp_offset, 360.0 * k / n_pos, s, point))
                t += step_s
            point += 1
    d = pd.DataFrame(rows, columns=["time_s", "temp_set_c", "temp_c", "rotation_deg", "sweep_true", "point_true"])
    if temp_noise:
        d["temp_c"] += rng.normal(0.0, temp_noise, len(d))
    return d


def simulate(meta, sched, coeffs=TRUTH, effects=None, sigma=0.0, rng=None) -> pd.DataFrame:
    d = sched.copy()
    d["output"] = rig_output("tilt_rotation", meta, d, coeffs, effects or {})
    if sigma:
        d["output"] += rng.normal(0.0, sigma, len(d))
    return d


def expected_points(sched, effects, coeffs=TRUTH, tilt_deg=TILT):
    """Paper 001 closed forms per point: K1_j = K1(T_j) * (gamma + d_gamma)/gamma (d_gamma the
    sin^2(theta)-weighted base-tilt change over the point; exact sin form), and
    K0_j * K1_j = K1(T_j) * (K0(T_j) + g c cos(gamma) (T_j - 20))."""
    gam = math.radians(tilt_deg)
    c = effects.get("fixture_thermal_tilt", 0.0)
    out = []
    for _, grp in sched.groupby("point_true"):
        t = grp["time_s"].to_numpy()
        gamma_t = (gam + effects.get("base_tilt_drift", 0.0) * t
                   + effects.get("tilt_tide", 0.0) * np.sin(2 * np.pi * t / M2_PERIOD_S))
        w = np.sin(np.radians(grp["rotation_deg"].to_numpy())) ** 2
        factor = float(np.sum(w * np.sin(gamma_t)) / np.sum(w) / math.sin(gam))
        T = float(grp["temp_c"].mean())
        K1T_ = coeffs["K1"] * (1 + coeffs["K1T"] * (T - 20.0))
        K0T_ = coeffs["K0"] + (coeffs["K0T"] + G * c * math.cos(gam)) * (T - 20.0)
        K1j = K1T_ * factor
        out.append({"T": T, "K1": K1j, "K0": K0T_ * K1T_ / K1j, "factor": factor})
    return out


def line_fit(points):
    """OLS of the expected per-point values -> expected K0, K0T, K1, K1T."""
    T = np.array([p["T"] for p in points]) - 20.0
    b0, a0 = np.polyfit(T, [p["K0"] for p in points], 1)
    b1, a1 = np.polyfit(T, [p["K1"] for p in points], 1)
    return {"K0": a0, "K0T": b0, "K1": a1, "K1T": b1 / a1}


def coeff_map(coeffs):
    return {c.name: c for c in coeffs}


# ----------------------------------------------------------------- the sample drop

@pytest.fixture(scope="module")
def sample():
    meta, data = read_sample(SAMPLE)
    coeffs, extras = th.process_thermal_run(meta, data, "TT-1")
    return meta, data, coeffs, extras


@needs_shared
def test_sample_truth(sample):
    meta, data, coeffs, extras = sample
    c = coeff_map(coeffs)
    assert c["K1T"].value == pytest.approx(-1.2e-4, rel=0.03)
    assert c["K0T"].value == pytest.approx(3.96e-6, rel=0.05)
    # the fixture's part of K0T is about 1.96e-6 m/s2/degC, i.e. c = 2e-7 rad/degC:
    assert (c["K0T"].value - 2.0e-6) / (G * math.cos(math.radians(TILT))) == pytest.approx(2.0e-7, rel=0.1)
    assert {k: (v.unit, v.method) for k, v in c.items()} == {
        "K0": ("m/s2", "tilt_rotation_ls"), "K1": ("V/(m/s2)", "tilt_rotation_ls"),
        "K0T": ("m/s2/degC", "tilt_rotation_ls"), "K1T": ("1/degC", "tilt_rotation_ls")}
    assert "fixture_thermal_tilt" in c["K0T"].note and "cannot separate" in c["K0T"].note
    assert all(v.rig_id == "TT-1" and v.std_uncertainty > 0 for v in coeffs)
    json.dumps(extras, allow_nan=False)


@needs_shared
def test_sample_structure(sample):
    meta, data, coeffs, extras = sample
    pts = extras["points"]
    assert len(pts) == 15
    assert [p["sweep"] for p in pts] == [0] * 5 + [1] * 5 + [2] * 5
    assert [p["temp_set_c"] for p in pts] == [20.0, 25.0, 30.0, 35.0, 40.0] * 3
    assert all(p["n_positions"] == 12 and p["n_readings"] == 240 for p in pts)
    assert extras["repeatability"]["n_sweeps"] == 3
    # paper 001: single-position K1T+ and K1T- disagree, the rotation method does not
    comp = extras["method_comparison"]
    assert comp["K1T_single_plus"]["value"] > -1.0e-4 > -1.4e-4 > comp["K1T_single_minus"]["value"]
    assert comp["K1T"]["two_position"] == pytest.approx(-1.2e-4, rel=0.03)
    # compensation removes the output-temperature sensitivity (~0.4 ug/degC before)
    before = extras["compensation"]["before"]["slope_ug_per_degC"]
    after = extras["compensation"]["after"]["slope_ug_per_degC"]
    assert before == pytest.approx(3.96e-6 / MICRO_G, rel=0.1)
    assert abs(after) < 0.02 * abs(before)


# ----------------------------------------------------------------- segmentation

def test_segment_run_sweeps_and_points():
    sched = make_schedule(n_pos=6, sweeps=3, readings=2)
    lab = th.segment_run(sched, positions=6)
    assert (lab["point"].to_numpy() == sched["point_true"].to_numpy()).all()
    assert (lab["sweep"].to_numpy() == sched["sweep_true"].to_numpy()).all()
    assert (lab["position"].to_numpy() == np.rint(sched["rotation_deg"] / 60).astype(int)).all()
    # descending sweeps: a new sweep starts when the set-point goes back up
    down = make_schedule(n_pos=4, temps=(40.0, 30.0, 20.0), sweeps=2, readings=1)
    lab = th.segment_run(down, positions=4)
    assert (lab["sweep"].to_numpy() == down["sweep_true"].to_numpy()).all()
    # a run with a single sweep of two points
    one = make_schedule(n_pos=4, temps=(20.0, 30.0), sweeps=1, readings=1)
    assert th.segment_run(one, 4)["sweep"].max() == 0


# ----------------------------------------------------------------- closed forms

def test_n4_closed_form_equals_least_squares():
    rng = np.random.default_rng(1)
    E = rng.normal(0.0, 1.0, 4) + np.array([0.1, 3.9, 0.1, -3.7])
    fit = th.fit_point(make_meta(4), [0, 90, 180, 270], E)
    cf = th.closed_form_n4(E, G, TILT)
    A = G * math.sin(math.radians(TILT))
    assert cf["K1"] == pytest.approx((E[1] - E[3]) / (2 * A), rel=1e-14)
    assert fit["K1"] == pytest.approx(cf["K1"], rel=1e-12)
    assert fit["K0"] == pytest.approx(cf["K0"], rel=1e-12)
    assert fit["K0"] * fit["K1"] == pytest.approx(E.mean(), rel=1e-12)
    assert fit["cos_term"] == pytest.approx((E[0] - E[2]) / 2, rel=1e-12)
    # and through a whole n = 4 run
    meta = make_meta(4)
    d = simulate(meta, make_schedule(n_pos=4, readings=2), sigma=1e-5, rng=rng)
    _, ex = th.process_thermal_run(meta, d)
    assert ex["closed_form_check"]["max_rel_diff_K1"] < 1e-12


def test_fixture_thermal_tilt_enters_K0T_only():
    meta = make_meta()
    sched = make_schedule()
    c = 3e-7  # rad/degC
    ref = coeff_map(th.process_thermal_run(meta, simulate(meta, sched))[0])
    tilt = coeff_map(th.process_thermal_run(meta, simulate(meta, sched, effects={"fixture_thermal_tilt": c}))[0])
    gam = math.radians(TILT)
    assert tilt["K0T"].value - ref["K0T"].value == pytest.approx(G * c * math.cos(gam), rel=1e-4)
    assert tilt["K1T"].value == pytest.approx(ref["K1T"].value, rel=1e-7)
    assert ref["K1T"].value == pytest.approx(TRUTH["K1T"], rel=1e-7)
    assert ref["K0T"].value == pytest.approx(TRUTH["K0T"], rel=1e-6)


def test_base_tilt_change_scales_K1():
    meta = make_meta()
    sched = make_schedule(sweeps=1)
    dgam = 5e-6  # rad, about 1 arc-second
    tilted = make_meta(tilt_deg=TILT + math.degrees(dgam))
    ref = th.fit_points(meta, simulate(meta, sched))[0]
    chg = th.fit_points(meta, simulate(tilted, sched))[0]
    gam = math.radians(TILT)
    for p, q in zip(ref, chg):
        assert q["K1"] / p["K1"] == pytest.approx((gam + dgam) / gam, rel=1e-6)
        # the bias output (K0 in output units, paper 001's K0) is left alone
        assert q["K0"] * q["K1"] == pytest.approx(p["K0"] * p["K1"], rel=1e-9)


def test_base_tilt_drift_and_tide_per_point():
    meta = make_meta()
    sched = make_schedule(sweeps=2)
    eff = {"base_tilt_drift": 2e-10, "tilt_tide": 2e-7}
    pts = th.fit_points(meta, simulate(meta, sched, effects=eff))[0]
    exp = expected_points(sched, eff)
    for p, e in zip(pts, exp):
        assert p["K1"] == pytest.approx(e["K1"], rel=1e-9)
    # the drift is large enough to matter (~ 1000 ppm over the run), and is flagged
    assert exp[-1]["factor"] - exp[0]["factor"] > 5e-4
    _, ex = th.process_thermal_run(meta, simulate(meta, sched, effects={"base_tilt_drift": 2e-10}))
    assert ex["scale_factor_time_trend"]["significant"]
    assert any("base_tilt_drift" in f for f in ex["flags"])


# ----------------------------------------------------------------- recovery with noise

@pytest.mark.parametrize("seed", [11, 12])
def test_recovery_with_effects_and_noise(seed):
    rng = np.random.default_rng(seed)
    meta = make_meta()
    sched = make_schedule(sweeps=3, readings=5, temp_noise=0.02, rng=rng)
    eff = {"fixture_thermal_tilt": 2e-7, "base_tilt_drift": 2e-12, "tilt_tide": 5e-8}
    d = simulate(meta, sched, effects=eff, sigma=2e-5, rng=rng)
    coeffs, extras = th.process_thermal_run(meta, d, "SIM")
    c = coeff_map(coeffs)
    exp = line_fit(expected_points(sched, eff))
    gam = math.radians(TILT)
    # the closed form of the fixture tilt is in the expectation, and it is not small
    assert exp["K0T"] == pytest.approx(TRUTH["K0T"] + G * 2e-7 * math.cos(gam), rel=1e-3)
    for k in ("K0", "K1", "K0T", "K1T"):
        assert abs(c[k].value - exp[k]) < 3 * c[k].std_uncertainty, k
        lo, hi = extras["temperature_model"]["interval_" + k]
        assert lo < c[k].value < hi
    # noise large enough that the check has teeth: K1T resolved to ~1 %, not to 1e-6
    assert 1e-9 < c["K1T"].std_uncertainty < 1.2e-6
    json.dumps(extras, allow_nan=False)


def test_monte_carlo_uncertainty_of_K1T():
    rng = np.random.default_rng(7)
    meta = make_meta()
    sched = make_schedule(sweeps=2, readings=3)
    clean = simulate(meta, sched)
    est, unc, unc_pt = [], [], []
    for _ in range(100):
        d = clean.copy()
        d["output"] = d["output"] + rng.normal(0.0, 5e-5, len(d))
        pts, _ = th.fit_points(meta, d)
        f = th.fit_temperature_model([p["temp_c"] for p in pts], [p["K0"] for p in pts],
                                     [p["u_K0_pooled"] for p in pts], [p["K1"] for p in pts],
                                     [p["u_K1_pooled"] for p in pts])
        est.append(f["K1T"])
        unc.append(f["u_K1T"])
        unc_pt.append(pts[0]["u_K1_pooled"])
    est, unc = np.array(est), np.array(unc)
    ratio = np.sqrt(np.mean(unc**2)) / np.std(est, ddof=1)
    assert 0.75 < ratio < 1.33, ratio
    assert abs(est.mean() - TRUTH["K1T"]) < 3 * np.std(est, ddof=1) / 10
    # and the stated value against the closed form of the design: a position mean has noise
    # s = 5e-5/sqrt(3); b has s*sqrt(2/n); K1_j = b/(g sin gamma); slope/K1 over Sxx = sum (T - Tbar)^2
    s = 5e-5 / math.sqrt(3)
    u_K1j = s * math.sqrt(2 / 12) / (G * math.sin(math.radians(TILT)))
    T = np.array([20.0, 25.0, 30.0, 35.0, 40.0] * 2)
    u_theory = u_K1j / math.sqrt(np.sum((T - T.mean()) ** 2)) / TRUTH["K1"]
    assert np.sqrt(np.mean(unc**2)) == pytest.approx(u_theory, rel=0.1)
    assert np.sqrt(np.mean(np.square(unc_pt))) == pytest.approx(u_K1j, rel=0.05)


# ----------------------------------------------------------------- fixed-point method

def test_fixed_point_single_positions_take_the_fixture_tilt():
    meta = make_meta()
    sched = make_schedule(sweeps=1)
    c = 3e-7
    _, ex = th.process_thermal_run(meta, simulate(meta, sched, effects={"fixture_thermal_tilt": c}))
    fp = ex["fixed_point"]
    gam = math.radians(TILT)
    A = G * math.sin(gam)
    k0t_app = TRUTH["K0T"] + G * c * math.cos(gam)
    assert fp["two_position"]["K1T"] == pytest.approx(TRUTH["K1T"], rel=1e-6)
    assert fp["two_position"]["K0T"] == pytest.approx(k0t_app, rel=1e-4)
    assert fp["zero_input"]["K0T"] == pytest.approx(k0t_app, rel=1e-4)
    assert fp["single_plus"]["K1T"] - TRUTH["K1T"] == pytest.approx(k0t_app / (A + TRUTH["K0"]), rel=0.01)
    assert fp["single_minus"]["K1T"] - TRUTH["K1T"] == pytest.approx(-k0t_app / (A - TRUTH["K0"]), rel=0.01)


# ----------------------------------------------------------------- compensation

def test_compensation_removes_temperature_correlation():
    rng = np.random.default_rng(3)
    t = np.arange(20000.0)
    T = 25.0 + 8.0 * np.sin(2 * np.pi * t / 7000.0) + rng.normal(0, 0.05, t.size)
    true = {"K0": 2e-5, "K1": 10.0, "K0T": 44.0 * MICRO_G, "K1T": 1.831e-3}
    acc = 3e-4 + rng.normal(0.0, 5.0 * MICRO_G, t.size)     # constant input + noise, m/s2
    dT = T - 20.0
    E = true["K1"] * (1 + true["K1T"] * dT) * (true["K0"] + true["K0T"] * dT + acc)
    before = th.temperature_correlation(th.compensate(E, T, {"K0": true["K0"], "K1": true["K1"]}), T)
    res = th.compensate(E, T, true, input_m_s2=3e-4)
    after = th.temperature_correlation(res, T)
    # before: K0T plus K1T times the (bias + input) level
    exp_before = (true["K0T"] + true["K1T"] * (true["K0"] + 3e-4)) / MICRO_G
    assert before["slope_ug_per_degC"] == pytest.approx(exp_before, rel=0.02)
    assert abs(after["slope_ug_per_degC"]) < 3 * after["u_slope_ug_per_degC"] + 1e-9
    assert abs(after["slope_ug_per_degC"]) < 0.01 * abs(before["slope_ug_per_degC"])
    assert abs(after["r"]) < 0.05 < before["r"]
    assert np.std(res) == pytest.approx(5.0 * MICRO_G, rel=0.05)


def test_rejects_ia_out_of_plane():
    meta = make_meta()
    meta.update(sin_axis="+PA", cos_axis="+OA", normal_axis="+IA")
    with pytest.raises(ValueError):
        th.rig_geometry(meta)


@pytest.mark.parametrize("n_pos,sin_axis,cos_axis,method", [
    (3, "+IA", "+PA", "tilt_rotation_ls"),            # no residual dof: within-position scatter
    (8, "+PA", "-IA", "tilt_rotation_ls"),            # IA the (negative) cos axis
    (12, "-IA", "+PA", "tilt_rotation_ls"),
    (2, "+PA", "+IA", "tilt_rotation_two_position"),  # fixed positions 0/180 only
])
def test_other_geometries(n_pos, sin_axis, cos_axis, method):
    rng = np.random.default_rng(n_pos)
    meta = make_meta(n_pos)
    meta.update(sin_axis=sin_axis, cos_axis=cos_axis)
    d = simulate(meta, make_schedule(n_pos=n_pos, readings=4), sigma=1e-5, rng=rng)
    coeffs, extras = th.process_thermal_run(meta, d)
    for c in coeffs:
        assert c.method == method
        assert abs(c.value - TRUTH[c.name]) < 3 * c.std_uncertainty, c
    json.dumps(extras, allow_nan=False)


def test_position_keys_counted_not_sorted_are_numpys_unique():
    """position_means and a run's cells find their groups by counting small integer keys
    (issue 28: no sort of a long run); the three arrays must be np.unique's, dtype included,
    on keys in runs of repeats as a run's dwells give them, and on keys in any order."""
    import numpy as np

    from accelcal.fitting.data import unique_small_ints as _unique_small

    rng = np.random.default_rng(28)
    for _ in range(300):
        m = int(rng.integers(1, 60))
        key = np.repeat(rng.integers(0, 40, m), rng.integers(1, 5, m))
        if _ % 2:
            key = rng.permutation(key)
        for a, b in zip(np.unique(key, return_index=True, return_inverse=True), _unique_small(key)):
            assert np.array_equal(a, b) and a.dtype == b.dtype
