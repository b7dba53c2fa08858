"""Tests of the tumble estimator (paper 003) against known truth, closed forms and Monte Carlo.

Synthetic runs come from the one forward model (accelcal.physics.rig_output) with a known
truth and Gaussian noise; nothing here compares with numbers the code printed.
"""
from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from accelcal.estimators.tumble import fit_run, pool_runs, tumble_records, two_position
from accelcal.physics import rig_output

from conftest import EXAMPLES, needs_shared  # ../shared/examples relative to the repository root
G = 9.80122
# Truth close to the SNJ-1-03 of paper 000 (K2 3.94e-7 s2/m) with a mA output.
TRUTH = {"K0": 4.0e-4, "K1": 0.1325, "K2": 3.94e-7}


def read_run(path: Path) -> tuple[dict, pd.DataFrame]:
    """Minimal drop reader for the tests: '# key: value' lines, then CSV."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    meta, i = {}, 0
    while i < len(lines) and lines[i].startswith("#"):
        key, value = lines[i][1:].split(":", 1)
        meta[key.strip()] = value.strip()
        i += 1
    for k in ("g_local_m_s2", "site_latitude_deg", "sample_period_s"):
        meta[k] = float(meta[k])
    return meta, pd.read_csv(io.StringIO("\n".join(lines[i:])))


def tumble_meta(cos_axis="+IA", sin_axis="+OA", head_axis="PA", unit="mA") -> dict:
    return {"format": "accelcal-drop/1", "test": "tumble", "run_id": "SIM", "rig_id": "DH-1",
            "g_local_m_s2": G, "site_latitude_deg": 39.9, "output_unit": unit,
            "sample_period_s": 1.0, "head_axis": head_axis, "cos_axis": cos_axis, "sin_axis": sin_axis}


def tumble_data(step_deg=15.0, nrep=3) -> pd.DataFrame:
    angles = np.arange(0.0, 360.0, step_deg)
    pos = np.repeat(np.arange(angles.size), nrep)
    return pd.DataFrame({"time_s": np.arange(pos.size, dtype=float), "position": pos,
                         "angle_deg": angles[pos], "temp_c": np.full(pos.size, 23.0)})


def simulate(meta, data, coeffs, theta0, sigma, rng, effects=None) -> pd.DataFrame:
    eff = {"initial_misalignment": theta0, **(effects or {})}
    d = data.copy()
    d["output"] = rig_output("tumble", meta, d, coeffs, eff) + (rng.normal(0, sigma, len(d)) if sigma else 0)
    return d


def _within_3sigma(fit, truth: dict):
    for k, v in truth.items():
        z = (fit.values[k] - v) / fit.std_uncertainties[k]
        assert abs(z) < 3.0, f"{k}: fitted {fit.values[k]!r}, truth {v!r}, z = {z:.2f}"


@pytest.mark.parametrize("cos_axis,sin_axis,head", [("+IA", "+OA", "PA"), ("+OA", "-IA", "PA"),
                                                    ("-IA", "+PA", "OA")])
def test_recovers_truth_within_3_sigma(cos_axis, sin_axis, head):
    rng = np.random.default_rng(11)
    meta = tumble_meta(cos_axis, sin_axis, head)
    theta0 = np.radians(0.3)
    d = simulate(meta, tumble_data(), TRUTH, theta0, 3e-7, rng)
    fit = fit_run(meta, d)
    assert fit.result.converged
    assert fit.dof == len(d) - 4
    _within_3sigma(fit, {**TRUTH, "theta0": theta0})
    # the noise is white, so s estimates sigma and the lack-of-fit test sees nothing
    assert 0.8 < fit.s / 3e-7 < 1.2
    assert fit.lack_of_fit["p"] > 1e-3
    # uncertainties small enough that "within 3 sigma" is a real test
    assert fit.std_uncertainties["K2"] < 0.1 * TRUTH["K2"]


def test_stated_uncertainty_matches_monte_carlo_spread():
    rng = np.random.default_rng(2026)
    meta = tumble_meta()
    data = tumble_data(step_deg=15.0, nrep=2)
    theta0, sigma = np.radians(0.5), 3e-6
    clean = rig_output("tumble", meta, data, TRUTH, {"initial_misalignment": theta0})
    keys = ("K0", "K1", "K2", "theta0")
    est, stated = [], []
    for _ in range(200):
        d = data.copy()
        d["output"] = clean + rng.normal(0, sigma, len(d))
        f = fit_run(meta, d)
        est.append([f.values[k] for k in keys])
        stated.append([f.std_uncertainties[k] for k in keys])
    est, stated = np.array(est), np.array(stated)
    spread = est.std(axis=0, ddof=1)
    ratio = stated.mean(axis=0) / spread
    assert np.all((ratio > 0.8) & (ratio < 1.25)), dict(zip(keys, ratio))
    truth = np.array([TRUTH["K0"], TRUTH["K1"], TRUTH["K2"], theta0])
    # unbiased: the mean of 200 fits lies within 4 standard errors of the truth
    assert np.all(np.abs(est.mean(axis=0) - truth) < 4 * spread / np.sqrt(len(est)))


def test_covariance_is_s2_times_inverse_normal_matrix_of_the_closed_form_design():
    """Paper 003, +IA/+OA: E = K1 (K0 + g c + K2 g^2 c^2), c = cos(psi), psi = theta + theta0;
    dE/dK0 = K1, dE/dK1 = K0 + g c + K2 g^2 c^2, dE/dK2 = K1 g^2 c^2,
    dE/dtheta0 = -K1 g sin(psi) (1 + 2 K2 g c).  The fit's noise covariance is
    s^2 (X'X)^-1 of this design at its estimate, s^2 = RSS / (n - 4)."""
    rng = np.random.default_rng(7)
    meta = tumble_meta()
    d = simulate(meta, tumble_data(step_deg=15.0, nrep=3), TRUTH, np.radians(0.4), 3e-7, rng)
    fit = fit_run(meta, d)
    K0, K1, K2, t0 = (fit.values[k] for k in ("K0", "K1", "K2", "theta0"))
    psi = np.radians(d["angle_deg"].to_numpy()) + t0
    c = np.cos(psi)
    X = np.column_stack([np.full(c.size, K1), K0 + G * c + K2 * G**2 * c**2, K1 * G**2 * c**2,
                         -K1 * G * np.sin(psi) * (1 + 2 * K2 * G * c)])
    r = d["output"].to_numpy() - K1 * (K0 + G * c + K2 * G**2 * c**2)
    s2 = r @ r / (len(r) - 4)
    assert fit.s ** 2 == pytest.approx(s2, rel=1e-9)
    cov = s2 * np.linalg.inv(X.T @ X)
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(fit.result.cov_noise / np.outer(sd, sd), cov / np.outer(sd, sd), atol=1e-6)


@pytest.mark.parametrize("theta0_deg", [0.5, 1.0])
def test_misalignment_of_paper_003_recovered(theta0_deg):
    """Paper 003: runs offset by 0.5 and 1.0 deg gave 0.4998 and 0.9963 deg. ES-U2: 10 V/g
    nominal, +-2 g; a 0.5 deg step head; here 10 uV noise and 3 readings per position."""
    rng = np.random.default_rng(int(theta0_deg * 10))
    meta = tumble_meta(unit="V")
    coeffs = {"K0": 3e-3, "K1": 10.0 / 9.80665, "K2": 2e-6}
    theta0 = np.radians(theta0_deg)
    d = simulate(meta, tumble_data(step_deg=30.0, nrep=3), coeffs, theta0, 1e-5, rng)
    fit = fit_run(meta, d)
    _within_3sigma(fit, {**coeffs, "theta0": theta0})
    assert abs(np.degrees(fit.values["theta0"]) - theta0_deg) < 1e-4   # far better than 0.4998
    assert fit.start["theta0"] == 0.0


@pytest.mark.parametrize("theta0_deg", [0.0, 0.5, 1.0, 3.0])
def test_two_position_bias_is_the_closed_form(theta0_deg):
    """Noise-free: E_0/180 = K1 (K0 +- g cos t0 + K2 g^2 cos^2 t0), so SH = K1 cos t0 and
    KH = K1 (K0 + K2 g^2 cos^2 t0); the four-point form is exact."""
    meta = tumble_meta()
    t0 = np.radians(theta0_deg)
    d = simulate(meta, tumble_data(step_deg=90.0, nrep=1), TRUTH, t0, 0.0, None)
    tp = two_position(meta, d)
    K0, K1, K2 = TRUTH["K0"], TRUTH["K1"], TRUTH["K2"]
    E0 = K1 * (K0 + G * np.cos(t0) + K2 * G**2 * np.cos(t0) ** 2)
    E180 = K1 * (K0 - G * np.cos(t0) + K2 * G**2 * np.cos(t0) ** 2)
    assert tp["E_up"] == pytest.approx(E0, rel=1e-12)
    assert tp["E_down"] == pytest.approx(E180, rel=1e-12)
    assert tp["SH"] == pytest.approx(K1 * np.cos(t0), rel=1e-12)
    assert tp["KH"] == pytest.approx(K1 * (K0 + K2 * G**2 * np.cos(t0) ** 2), rel=1e-9)
    assert tp["K0"] == pytest.approx((K0 + K2 * G**2 * np.cos(t0) ** 2) / np.cos(t0), rel=1e-9)
    fp = tp["four_point"]
    assert fp["K1"] == pytest.approx(K1, rel=1e-12)
    assert fp["theta0"] == pytest.approx(t0, abs=1e-12)
    assert fp["K2"] == pytest.approx(K2, rel=1e-6)
    assert fp["K0"] == pytest.approx(K0, rel=1e-6)


def test_two_position_follows_ia_when_it_is_the_sin_axis():
    meta = tumble_meta(cos_axis="+OA", sin_axis="+IA")   # IA up at 90 deg
    d = simulate(meta, tumble_data(step_deg=90.0, nrep=2), TRUTH, 0.0, 0.0, None)
    tp = two_position(meta, d)
    assert tp["ia_phase_deg"] == 90.0
    assert tp["SH"] == pytest.approx(TRUTH["K1"], rel=1e-12)
    assert tp["four_point"]["K2"] == pytest.approx(TRUTH["K2"], rel=1e-6)


def test_ko_aliases_with_theta0_and_koo_with_k2():
    """Paper 003 note: Ko on OA shifts theta0 by -atan(Ko) (for +IA/+OA); Koo enters as
    K2 - Koo and K0 + Koo g^2. Noise-free data, so the identities are checked tightly."""
    meta = tumble_meta()
    data = tumble_data(step_deg=15.0, nrep=1)
    t0, Ko = np.radians(0.2), 2e-3
    f = fit_run(meta, simulate(meta, data, {**TRUTH, "Ko": Ko}, t0, 0.0, None))
    assert f.values["theta0"] == pytest.approx(t0 - np.arctan(Ko), abs=5e-9)
    assert f.values["K1"] == pytest.approx(TRUTH["K1"] * np.hypot(1, Ko), rel=1e-8)
    Koo = 5e-8
    f = fit_run(meta, simulate(meta, data, {**TRUTH, "Koo": Koo}, t0, 0.0, None))
    assert f.values["K2"] == pytest.approx(TRUTH["K2"] - Koo, rel=1e-7)
    assert f.values["K0"] == pytest.approx(TRUTH["K0"] + Koo * G**2, rel=1e-7)


def test_kio_extra_term_is_separable():
    rng = np.random.default_rng(5)
    meta = tumble_meta()
    truth = {**TRUTH, "Kio": 2e-7}
    d = simulate(meta, tumble_data(step_deg=15.0, nrep=3), truth, 1e-4, 2e-7, rng)
    plain = fit_run(meta, d)
    assert plain.lack_of_fit["p"] < 1e-6          # the sin(2 psi) term shows as lack of fit
    full = fit_run(meta, d, extra_terms=("Kio",))
    _within_3sigma(full, {**truth, "theta0": 1e-4})
    assert full.lack_of_fit["p"] > 1e-3
    with pytest.raises(ValueError):
        fit_run(meta, d, extra_terms=("Ko",))


def test_ia_on_head_axis_is_refused():
    meta = tumble_meta(cos_axis="+PA", sin_axis="+OA", head_axis="IA")
    d = tumble_data()
    d["output"] = 0.0
    with pytest.raises(ValueError, match="head axis"):
        fit_run(meta, d)


@needs_shared
def test_sample_run_k2_matches_truth_of_the_drop():
    meta, d = read_run(EXAMPLES / "drop-2026-11-20" / "DH1-20261120-0001.csv")
    fit = fit_run(meta, d)
    assert fit.result.converged and fit.n == 240
    z = (fit.values["K2"] - 3.94e-7) / fit.std_uncertainties["K2"]
    assert abs(z) < 3.0, z
    # the 4-term model leaves a sin(2 psi) lack of fit in this run; Kio + K3 remove it
    assert fit.lack_of_fit["p"] < 1e-6
    full = fit_run(meta, d, extra_terms=("Kio", "K3"))
    assert full.lack_of_fit["p"] > 0.01
    # A single tumble measures K2 - Koo; with Koo = 3.0e-8 and Kio = 2.0e-7 (the truth quoted
    # in accelcal/simulate/scenarios/snj103-lxj100.toml) the fuller fit agrees with both.
    assert abs(full.values["K2"] - (3.94e-7 - 3.0e-8)) < 3 * full.std_uncertainties["K2"]
    assert abs(full.values["Kio"] - 2.0e-7) < 3 * full.std_uncertainties["Kio"]
    res, _, corrected = tumble_records(pool_runs([fit]), out_unit=meta["output_unit"])
    assert [c.name for c in res] == ["K0", "K1", "K2", "theta0"] and not corrected
    assert [c.unit for c in res] == ["m/s2", "mA/(m/s2)", "s2/m", "rad"]
    assert all(c.method == "tumble_lm" and c.rig_id == "DH-1" and c.dof == 236 for c in res)
    assert "lack of fit" in res[2].note
    # one run: u is the fit's, its reading-noise part times the lack-of-fit factor sqrt(F)
    F = fit.lack_of_fit["F"]
    assert res[2].std_uncertainty == pytest.approx(fit.result.std_noise("K2") * math.sqrt(F), rel=1e-9)


@needs_shared
def test_small_run_fits_without_error():
    meta, d = read_run(EXAMPLES / "drop-bad" / "ok-small.csv")
    fit = fit_run(meta, d)
    assert fit.result.converged and fit.n == 12 and fit.dof == 8
    assert len(fit.position_means) == 4
    assert all(np.isfinite(v) and v > 0 for v in fit.std_uncertainties.values())
    tp = two_position(meta, d)
    assert tp["four_point"] is not None
    # with exactly 4 positions the LM fit is the four-point closed form
    for k in ("K0", "K1", "K2", "theta0"):
        assert fit.values[k] == pytest.approx(tp["four_point"][k], rel=1e-6, abs=1e-12)


# ----------------------------------------------------------------- several runs in a campaign

def _runs(specs, rng, extra=None):
    """Tumble runs (TumbleRun) from (cos_axis, sin_axis, head, K0, theta0, run_id) specs."""
    from accelcal.estimators.tumble import fit_tumble_run
    out = []
    for cos_axis, sin_axis, head, K0, th0, rid in specs:
        meta = {**tumble_meta(cos_axis, sin_axis, head), "run_id": rid}
        d = simulate(meta, tumble_data(), {**TRUTH, "K0": K0, **(extra or {})}, th0, 3e-7, rng)
        out.append(fit_tumble_run(meta, d))
    return out


def test_runs_that_agree_are_pooled_without_a_flag():
    from accelcal.estimators.tumble import pooling_flags
    rng = np.random.default_rng(3)
    runs = _runs([("+IA", "+OA", "PA", 4e-4, 1e-3, "A"), ("+IA", "+OA", "PA", 4e-4, 1e-3, "B")], rng)
    pooled = pool_runs(runs)
    k0 = pooled["K0"]
    u1, u2 = (r.std_uncertainties["K0"] for r in runs)
    assert k0.u_internal == pytest.approx(1 / math.sqrt(u1 ** -2 + u2 ** -2), rel=1e-12)
    assert not k0.disagree and not pooling_flags(pooled)
    assert abs(k0.value - 4e-4) < 3 * k0.u
    assert "theta0" in pooled and "theta0[PA]" not in pooled            # one head: plain name


def test_runs_that_disagree_are_flagged_and_their_u_scaled_by_birge():
    from accelcal.estimators.tumble import pooling_flags
    rng = np.random.default_rng(4)
    runs = _runs([("+IA", "+OA", "PA", 4e-4, 1e-3, "A"), ("+IA", "+OA", "PA", 4.5e-4, 1e-3, "B")], rng)
    pooled = pool_runs(runs)
    k0 = pooled["K0"]
    vals = np.array([r.values["K0"] for r in runs])
    us = np.array([r.std_uncertainties["K0"] for r in runs])
    w = us ** -2
    mean = np.sum(w * vals) / np.sum(w)
    chi2 = np.sum(w * (vals - mean) ** 2)                               # dof 1
    assert k0.disagree and k0.birge == pytest.approx(math.sqrt(chi2), rel=1e-9)
    assert k0.u == pytest.approx(math.sqrt(chi2) / math.sqrt(np.sum(w)), rel=1e-9)
    flags = pooling_flags(pooled)
    assert len(flags) == 1 and "disagree on K0" in flags[0] and "A" in flags[0] and "B" in flags[0]
    coeffs, budget, _ = tumble_records(pooled, out_unit="mA")
    c = next(c for c in coeffs if c.name == "K0")
    assert c.std_uncertainty == pytest.approx(k0.u, rel=1e-9) and "Birge" in c.note
    assert any("Birge" in b.quantity for b in budget if b.coefficient == "K0")


def test_theta0_is_never_pooled_across_heads():
    """Two heads about different axes, with different misalignments: one theta0 row per head."""
    rng = np.random.default_rng(5)
    th_pa, th_oa = np.radians(0.3), np.radians(-0.5)
    square = {"Koo": 3.0e-8, "Kpp": 4.7e-8}
    runs = _runs([("+IA", "+OA", "PA", 4e-4, th_pa, "HPA"), ("+IA", "+PA", "OA", 4e-4, th_oa, "HOA")], rng, square)
    pooled = pool_runs(runs)
    assert "theta0" not in pooled
    assert abs(pooled["theta0[PA]"].value - th_pa) < 3 * pooled["theta0[PA]"].u
    assert abs(pooled["theta0[OA]"].value - th_oa) < 3 * pooled["theta0[OA]"].u
    assert [r.run_id for r in pooled["theta0[PA]"].runs] == ["HPA"]
    coeffs, _, corrected = tumble_records(pooled, out_unit="mA")
    assert not corrected
    names = [c.name for c in coeffs]
    assert "theta0[PA]" in names and "theta0[OA]" in names and "theta0" not in names
    # without centrifuge square terms each head's K2 stays its own quantity (K2 - Koo, K2 - Kpp)
    assert "K2[PA]" in names and "K2[OA]" in names
    k2pa, k2oa = (next(c for c in coeffs if c.name == n) for n in ("K2[PA]", "K2[OA]"))
    assert abs(k2pa.value - (TRUTH["K2"] - square["Koo"])) < 3 * k2pa.std_uncertainty
    assert abs(k2oa.value - (TRUTH["K2"] - square["Kpp"])) < 3 * k2oa.std_uncertainty
    assert (k2pa.less, k2oa.less) == (("Koo",), ("Kpp",))        # what each estimates, typed
    # with them, both heads measure K2 and are pooled into one row
    coeffs, budget, corrected = tumble_records(pooled, square_terms={k: (v, 1e-9) for k, v in square.items()},
                                               out_unit="mA")
    assert corrected == {"K2"}
    k2 = next(c for c in coeffs if c.name == "K2")
    assert abs(k2.value - (TRUTH["K2"])) < 3 * k2.std_uncertainty and k2.less == ()
    assert {b.quantity.split(" ")[0] for b in budget if b.coefficient == "K2"} >= {"HPA:", "HOA:", "Koo", "Kpp"}


def test_real_imucal_heads_untestable_and_disagreeing(examples):
    """../shared/real/imucal-ferraris: four positions per run (untestable, flagged), theta0 per
    head equal in size to imucal's misalignment terms, K0 of the two heads flagged."""
    from accelcal.estimators.tumble import tumble_step
    from accelcal.schemas.dropformat import read_run as read_drop
    from accelcal.schemas.dropscan import discover
    real = examples.parent / "real" / "imucal-ferraris"
    if not real.is_dir():
        pytest.skip("real data not available")
    runs = [read_drop(p) for p in discover(real) if "EXAMPLE-X" in p.name]
    step = tumble_step(runs)
    assert sum("untestable" in f for f in step.flags) == 2
    assert any("disagree on K0" in f for f in step.flags)
    # imucal 2.6.0: misalignment x/z -0.00748, x/y -0.01483 rad (README; 5 digits)
    assert abs(step.pooled["theta0[PA]"].value) == pytest.approx(0.00748, abs=6e-6)
    assert abs(step.pooled["theta0[OA]"].value) == pytest.approx(0.01483, abs=6e-6)


def test_untestable_tumble_only_campaign_is_incomplete_without_a_joint_fit(monkeypatch):
    """Four head positions for four parameters leave no degrees of freedom: where the joint
    fit cannot run, the tumble runs' own lack-of-fit records (not text the campaign stored)
    make a tumble-only campaign incomplete."""
    from types import SimpleNamespace

    from accelcal.estimators import campaign, joint
    meta = {**tumble_meta(), "campaign": "C", "unit_serial": "U"}
    d = simulate(meta, tumble_data(step_deg=90.0, nrep=5), {**TRUTH}, 1e-4, 1e-6, np.random.default_rng(5))
    run = SimpleNamespace(meta=meta, data=d, sha256="0")

    def fails(*args, **kwargs):
        raise RuntimeError("no joint fit")
    monkeypatch.setattr(joint, "campaign_results", fails)
    res = campaign.process_campaign([run])
    assert any(c.method == "tumble_lm" for c in res.coefficients)
    assert res.completeness == "incomplete"
    assert any("as many head positions as fitted parameters" in r for r in res.completeness_reasons)
