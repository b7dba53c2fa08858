"""Centrifuge science (paper 000): closed forms, a hand-made back-calculation, lack of fit
on data with a known missing term, and the truth behind the sample drop 2026-11-20."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from accelcal.constants import OMEGA_EARTH
from accelcal.estimators.campaign import process_campaign
from accelcal.estimators.crosscoupling import alignment, combine_second_order, delta_c2, eq2_row
from accelcal.estimators.radius import PairData, test_radius_iterative, test_radius_static
from accelcal.physics import rig_output
from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover

from conftest import TRUTH_20

DEG = math.pi / 180


def c2_ia_pa(K, phi0_rad):
    """Paper 000 eq 2 in the IA-PA plane: c2 = K2 cos^2 phi0 + Kpp sin^2 phi0 + Kip cos phi0 sin phi0."""
    c, s = math.cos(phi0_rad), math.sin(phi0_rad)
    return K["K2"] * c * c + K["Kpp"] * s * s + K["Kip"] * c * s


# ---------------------------------------------------------------- closed forms of the paper

def test_eq8_per_degree_at_45_and_90():
    """Paper 000: Delta c2 = -6.1e-9 per degree at 45 deg, -1.24e-8 per degree at 90 deg
    (K2 = 3.94e-7, Kpp = 4.7e-8, Kip = 7.1e-7)."""
    K = {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7}
    assert delta_c2(K, "IA-PA", 45 * DEG, 1 * DEG) == pytest.approx(-6.1e-9, rel=0.01)
    assert delta_c2(K, "IA-PA", 90 * DEG, 1 * DEG) == pytest.approx(-1.24e-8, rel=0.01)
    # and eq 8 is the derivative of eq 2: compare with a finite difference of c2
    for phi in (30, 45, 60, 90):
        h = 1e-6
        fd = (c2_ia_pa(K, phi * DEG + h) - c2_ia_pa(K, phi * DEG - h)) / (2 * h)
        assert delta_c2(K, "IA-PA", phi * DEG, 1.0) == pytest.approx(fd, rel=1e-6)


def test_eq2_at_45_gives_eq3_and_table5():
    K = {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7}
    row = eq2_row("IA-PA", 45 * DEG)
    assert sum(row[k] * K.get(k, 0.0) for k in row) == pytest.approx((K["K2"] + K["Kpp"] + K["Kip"]) / 2)
    # Table 5, LXJ-100 and LXJ-200 columns: the mounts 0, 90 and 45 deg combined give eq 3,
    # Kip = 2 c2(45) - (K2 + Kpp)
    for K2, Kpp, c2_45, Kip in ((3.94e-7, 0.47e-7, 5.76e-7, 7.10e-7), (4.13e-7, -0.15e-7, 5.33e-7, 6.67e-7)):
        pairs = [SimpleNamespace(plane="IA-PA", phi0_deg=phi, c2=c2, u_c2=1e-9)
                 for phi, c2 in ((0.0, K2), (90.0, Kpp), (45.0, c2_45))]
        assert combine_second_order(pairs).values["Kip"] == pytest.approx(Kip, abs=0.02e-7)


def test_alignment_formulas_of_section_2_2():
    """R = 500 mm, r = 0.5 mm: angle error 7.1e-4 rad at 45 deg (paper 000 §2.2), and the
    paper's R1, R2, dphi1, dphi2 closed forms."""
    R, r = 0.5, 0.5e-3
    al = alignment(R - r, R + r, "IA-PA", 45.0)
    assert al.R == pytest.approx(R) and al.r == pytest.approx(r)
    phi = 45 * DEG
    assert al.R1 == pytest.approx(math.sqrt((R - r * math.cos(phi)) ** 2 + (r * math.sin(phi)) ** 2))
    assert al.R2 == pytest.approx(math.sqrt((R + r * math.cos(phi)) ** 2 + (r * math.sin(phi)) ** 2))
    assert abs(al.dphi1) == pytest.approx(math.atan(r * math.sin(phi) / (R - r * math.cos(phi))))
    assert abs(al.dphi2) == pytest.approx(math.atan(r * math.sin(phi) / (R + r * math.cos(phi))))
    assert abs(al.dphi1) == pytest.approx(7.1e-4, rel=0.01)
    assert np.sign(al.dphi1) == -np.sign(al.dphi2)


# ---------------------------------------------------------------- hand-made back-calculation

def _hand_centrifuge(phi_deg, K0, K1, lam, R, omega, lat, g, n=8):
    """A centrifuge run written by hand: two rest azimuths, one dwell at omega; the output
    follows E = K1 (K0 + a_IA) with a_IA = g sin(lam) + omega_z^2 R cos(lam) cos(phi)."""
    wz = omega + OMEGA_EARTH * math.sin(lat * DEG)
    rows = []
    for step, (rate, az) in enumerate([(0.0, 0.0), (0.0, 180.0), (omega, None)]):
        w = wz if rate else OMEGA_EARTH * math.sin(lat * DEG)
        a = g * math.sin(lam) + w**2 * R * math.cos(lam) * math.cos(phi_deg * DEG)
        for i in range(n):
            rows.append((step * 100 + 2 * i, step, rate, az, K1 * (K0 + a), 23.0))
    data = pd.DataFrame(rows, columns=["time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"])
    meta = {"test": "centrifuge", "g_local_m_s2": g, "site_latitude_deg": lat, "arm_radius_m": R,
            "rotation_sense": "ccw", "mount_plane": "IA-PA", "mount_angle_deg": phi_deg, "vertical_axis": "+OA",
            "run_id": f"HAND-{phi_deg}"}
    return meta, data


@pytest.mark.parametrize("phi", [0.0, 180.0])
def test_static_back_calculation_hand_case(phi):
    K0, K1, lam, R, lat, g = 2.0e-4, 0.13, 3.0e-4, 0.71, 39.9, 9.80122
    omega = math.sqrt(g / R)
    meta, data = _hand_centrifuge(phi, K0, K1, lam, R, omega, lat, g)
    s = test_radius_static(meta, data, K0, K1)
    # eq 4 takes the rest output as gravity only; the earth-rate centripetal term at rest
    # (Omega_e^2 R ~ 1.6e-9 m/s^2) is the only departure
    assert s.lambda_c_rad == pytest.approx(math.sin(lam), rel=1e-6)
    # eq 6 returns R cos(lam)/cos(sin lam) = R to 1e-11 relative
    assert s.radius_m == pytest.approx(R, rel=1e-9)
    assert s.polarity == ("+" if phi == 0 else "-")
    # the earth-rate term matters: the same run logged at the equator (no vertical earth
    # rate in the data) gives a radius larger by 2 Omega_e sin(lat) / omega (to first order)
    meta0, data0 = _hand_centrifuge(phi, K0, K1, lam, R, omega, 0.0, g)
    meta0["site_latitude_deg"] = lat                   # the data lack it, the metadata claims it
    s0 = test_radius_static(meta0, data0, K0, K1)
    assert s0.radius_m / R - 1 == pytest.approx(-2 * OMEGA_EARTH * math.sin(lat * DEG) / omega, rel=1e-3)


def test_static_uncertainty_printed_form_counts_K0_twice():
    """The GUM u(R) has no K0 term (it cancels); the printed form grows with u(K0)."""
    meta, data = _hand_centrifuge(0.0, 2e-4, 0.13, 3e-4, 0.71, math.sqrt(9.8 / 0.71), 39.9, 9.8)
    data["output"] += np.random.default_rng(1).normal(0, 1e-7, len(data))
    a = test_radius_static(meta, data, 2e-4, 0.13, u_K0=0.0, u_K1=1e-8)
    b = test_radius_static(meta, data, 2e-4, 0.13, u_K0=1e-5, u_K1=1e-8)
    assert b.std_uncertainty_m == pytest.approx(a.std_uncertainty_m)
    assert b.std_uncertainty_printed_m > 5 * a.std_uncertainty_printed_m


# ---------------------------------------------------------------- lack of fit with a known missing term

def _sim_pair(rng, coeffs, R=0.71, levels=(1, 2, 3, 5, 7, 10, 14, 18, 21, 25), n=8, s0=2e-6, k=4e-7):
    """IA pair made with the forward model: rest at 4 azimuths, up/down sweep; white noise s0
    (m/s^2) plus noise proportional to the centripetal term (k per m/s^2)."""
    g = 9.80122
    runs = []
    for phi, pol in ((0.0, 1), (180.0, -1)):
        rates = [0.0] * 4 + [math.sqrt(L * 9.80665 / R) for L in levels] + [math.sqrt(L * 9.80665 / R) for L in levels[-2::-1]]
        rows = []
        t = 0.0
        for step, w in enumerate(rates):
            for i in range(n):
                rows.append((t, step, w, 90.0 * step if w == 0 else np.nan, 23.0))
                t += 2.0
            t += 20.0
        d = pd.DataFrame(rows, columns=["time_s", "step", "table_rate_rad_s", "table_angle_deg", "temp_c"])
        meta = {"test": "centrifuge", "g_local_m_s2": g, "site_latitude_deg": 39.9, "arm_radius_m": R,
                "rotation_sense": "ccw", "mount_plane": "IA-PA", "mount_angle_deg": phi, "vertical_axis": "+OA",
                "run_id": f"SIM-{phi:g}"}
        E = rig_output("centrifuge", meta, d, coeffs, {"earth_rate": 1.0})
        a = d["table_rate_rad_s"].to_numpy() ** 2 * R
        E = E + coeffs["K1"] * rng.normal(0, 1, len(E)) * np.sqrt(s0**2 + (k * a) ** 2)
        d["output"] = E
        runs.append((meta, d, pol))
    return runs


def test_lack_of_fit_detects_a_missing_cubic():
    rng = np.random.default_rng(7)
    coeffs = {"K0": 1e-4, "K1": 0.13, "K2": 4e-7, "K3": 3e-10}
    runs = _sim_pair(rng, coeffs)
    pair = PairData.from_runs(runs, coeffs["K1"])
    f2 = test_radius_iterative(pair, 0.71, 0.71, 2).fit
    f3 = test_radius_iterative(pair, 0.71, 0.71, 3).fit
    assert f2.p_value < 1e-3 and not f2.adequate
    assert f3.adequate
    assert f3.value("c3") == pytest.approx(3e-10, abs=3 * f3.std_error("c3"))


def test_lack_of_fit_false_alarm_rate_on_adequate_model():
    """With the cubic in the model the LOF test at alpha = 0.01 rejects rarely (binomial bound)."""
    rng = np.random.default_rng(11)
    coeffs = {"K0": 1e-4, "K1": 0.13, "K2": 4e-7, "K3": 3e-10}
    rej, n = 0, 60
    pvals = []
    for _ in range(n):
        pair = PairData.from_runs(_sim_pair(rng, coeffs), coeffs["K1"])
        f = test_radius_iterative(pair, 0.71, 0.71, 3).fit
        pvals.append(f.p_value)
        rej += f.p_value < 0.01
    assert rej <= 4                      # P(Binomial(60, 0.01) > 4) < 0.001
    assert 0.3 < np.mean(pvals) < 0.7    # p-values roughly uniform


def test_radius_uncertainty_matches_monte_carlo_spread():
    rng = np.random.default_rng(5)
    coeffs = {"K0": 1e-4, "K1": 0.13, "K2": 4e-7, "K3": 3e-10}
    est, us = [], []
    for _ in range(40):
        pair = PairData.from_runs(_sim_pair(rng, coeffs), coeffs["K1"])
        it = test_radius_iterative(pair, 0.71, 0.71, 3)
        est.append(it.R_plus)
        us.append(it.u_plus)
    ratio = np.std(est, ddof=1) / np.mean(us)
    assert 0.7 < ratio < 1.4
    assert abs(np.mean(est) - 0.71) < 3 * np.std(est, ddof=1) / math.sqrt(len(est)) + 1e-9


# ---------------------------------------------------------------- the sample drop and its truth

@pytest.fixture(scope="module")
def result_20(examples):
    runs = [read_run(p) for p in discover(examples / "drop-2026-11-20")]
    return process_campaign(runs)


def _coef(res, name, method="centrifuge_eq9"):
    return next(c for c in res.coefficients if c.name == name and c.method == method)


@pytest.mark.parametrize("name", ["K2", "Kpp", "Kip", "Kio", "Koo", "Koq", "K3"])
def test_sample_coefficients_within_stated_uncertainty(result_20, name):
    c = _coef(result_20, name)
    assert abs(c.value - TRUTH_20[name]) <= 2 * c.std_uncertainty      # expanded U, k = 2


def test_sample_K2_and_Kip_within_2_and_3_percent(result_20):
    assert _coef(result_20, "K2").value == pytest.approx(TRUTH_20["K2"], rel=0.02)
    assert _coef(result_20, "Kip").value == pytest.approx(TRUTH_20["Kip"], rel=0.03)


def test_sample_radii(result_20):
    for r in result_20.radii:
        truth = TRUTH_20["R+"] if r.polarity == "+" else TRUTH_20["R-"]
        if r.method == "static" or (r.method == "iterative" and r.model_order in (2, 3)):
            assert abs(r.radius_m - truth) < 10e-6, r
        if r.method != "iterative" or r.model_order in (2, 3):
            # within U (k=2); the truth is quoted to 1 um
            assert abs(r.radius_m - truth) <= 2 * r.std_uncertainty_m + 0.5e-6, r


def test_sample_first_order_radius_drifts_with_range_like_table_2(result_20):
    first = sorted((r for r in result_20.radii if r.method == "iterative" and r.model_order == 1),
                   key=lambda r: r.g_max)
    plus = [r.radius_m for r in first if r.polarity == "+"]
    minus = [r.radius_m for r in first if r.polarity == "-"]
    assert len(plus) >= 3
    assert all(np.diff(plus) > 0) and all(np.diff(minus) < 0)    # + grows, - shrinks (Table 2)
    assert plus[-1] - TRUTH_20["R+"] > 10e-6                       # the drift is not small


def test_sample_adequacy_choice_is_recorded(result_20):
    chosen = [a for a in result_20.adequacy if a.chosen and a.fit.startswith("radius")]
    assert len(chosen) == 1 and chosen[0].adequate
    # the truth has a cubic term: the order-1 fit must be judged inadequate
    assert all(not a.adequate for a in result_20.adequacy if a.fit.startswith("radius") and a.model_order == 1)


def test_sample_eq10_printed_differs_from_gum(result_20):
    e = next(iter(result_20.extras["eq10"].values()))
    assert e["differ"] and e["gum"] > e["printed"]


def test_sample_tumble_K2_corrected_and_Kio(result_20):
    """The tumble alone measures K2 − Koo; with the centrifuge Koo added it must meet the
    truth, and the IA-OA cross term the tumble separates must meet Kio's truth."""
    k2 = _coef(result_20, "K2", "tumble_lm")
    assert abs(k2.value - TRUTH_20["K2"]) <= 2 * k2.std_uncertainty
    kio = _coef(result_20, "Kio", "tumble_lm")
    assert abs(kio.value - TRUTH_20["Kio"]) <= 2 * kio.std_uncertainty


def test_a_rig_without_an_ia_pair_makes_the_campaign_incomplete_by_a_typed_record(monkeypatch):
    """Paper 000 needs the IA mount pair (phi = 0/180 deg) for the test radius and K2: a rig
    without one is flagged, and the campaign is incomplete for that reason, which the
    centrifuge step states as data (``CentrifugeStep.without_ia_pair``), not as text the
    campaign searches its flags for."""
    from accelcal.estimators import centrifuge
    from accelcal.estimators.campaign import _assess_completeness
    from accelcal.results import CampaignResult

    monkeypatch.setattr(centrifuge, "process_rig", lambda runs, tumble: ("C9: no IA mount pair (phi = 0/180 deg)",))
    runs = [SimpleNamespace(meta={"rig_id": "C9"}), SimpleNamespace(meta={"rig_id": "C9"})]
    step = centrifuge.campaign_rigs(runs, {})
    assert step.rigs == () and step.without_ia_pair == ("C9",) and len(step.flags) == 1
    res = CampaignResult("c", "u", "m", ["centrifuge"], ["C9"], [])
    for rec in centrifuge.campaign_records(runs, {centrifuge.METHOD: step}):
        rec.add_to(res)
    _assess_completeness(res)
    assert res.completeness == "incomplete"
    assert res.completeness_reasons == ["no coefficient could be determined from these runs", centrifuge.NO_IA_PAIR]
