"""Tests of accelcal.simulate: nominal inputs against the drop-format closed forms, the
sample drops reproduced statistically, seeds and the written format."""
from __future__ import annotations

import glob
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from accelcal.simulate import (SCENARIO_DIR, ScenarioError, load_scenario, simulate_campaign,
                               simulate_to_drop, write_drop)

from conftest import EXAMPLES, needs_shared  # ../shared/examples relative to the repository root
OMEGA_E = 7.292115e-5
G = 9.80122
LAT = 39.9


# ----------------------------------------------------------------- a tiny independent reader
def read_drop_file(path):
    """Minimal drop-format reader written for the test: '# key: value' lines, a header, rows."""
    text = Path(path).read_bytes().decode("utf-8")
    assert "\r" not in text and text.endswith("\n")
    meta, rows, header = {}, [], None
    for line in text.split("\n")[:-1]:
        if header is None and line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            assert sep == ":" and line.startswith("# ")
            meta[key.strip()] = value.strip()
        elif header is None:
            header = line.split(",")
        else:
            cells = line.split(",")
            assert len(cells) == len(header), line
            rows.append([float(c) if c != "" else np.nan for c in cells])
    return meta, pd.DataFrame(rows, columns=header)


def _base(kind_test: dict, coeffs=None, effects=None, noise=None):
    return {"seed": 3, "unit": {"serial": "T-1", "model": "M", "output_unit": "m/s2",
                                "coefficients": coeffs or {"K1": 1.0}},
            "site": {"latitude_deg": LAT, "g_local_m_s2": G},
            "effects": effects if effects is not None else {"earth_rate": 1.0},
            "noise": noise or {}, "test": [kind_test]}


# ----------------------------------------------------------------- nominal closed forms
AXIDX = {"IA": 0, "PA": 1, "OA": 2}
CF_MOUNTS = [("IA-PA", "+OA"), ("IA-PA", "-OA"), ("PA-IA", "+OA"), ("IA-OA", "-PA"), ("IA-OA", "+PA"),
             ("OA-IA", "+PA"), ("PA-OA", "+IA"), ("OA-PA", "-IA")]


def _signed(a):
    return AXIDX[a.lstrip("+-")], (-1.0 if a.startswith("-") else 1.0)


@pytest.mark.parametrize("sense", ["ccw", "cw"])
@pytest.mark.parametrize("plane,vertical", CF_MOUNTS)
def test_centrifuge_nominal_closed_form(plane, vertical, sense):
    """An ideal IA-only instrument (K1 = 1): first plane axis omega_z^2 R cos(phi), second
    omega_z^2 R sin(phi), vertical +-g; omega_z = s omega + Omega_e sin(lat)."""
    R = 0.7102845
    angles = [0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0]
    sc = _base({"kind": "centrifuge", "arm_radius_m": R, "rotation_sense": sense, "readings": 2,
                "g_levels": [1, 10, 25],
                "mounts": [{"plane": plane, "angle_deg": a, "vertical": vertical} for a in angles]})
    # read each instrument axis by making it the only sensitive one
    for probe, coeffs in (("IA", {"K1": 1.0}),):
        runs = simulate_campaign(load_scenario(_base(sc["test"][0], coeffs)))
        for run, phi in zip(runs, angles):
            d = run.data
            s = 1.0 if sense == "ccw" else -1.0
            wz = s * d.table_rate_rad_s.to_numpy() + OMEGA_E * np.sin(np.radians(LAT))
            a = wz ** 2 * R
            p1, p2 = (AXIDX[x] for x in plane.split("-"))
            iv, sv = _signed(vertical)
            f = np.zeros((len(d), 3))
            f[:, p1] = a * np.cos(np.radians(phi))
            f[:, p2] = a * np.sin(np.radians(phi))
            f[:, iv] = sv * G
            np.testing.assert_allclose(d.output.to_numpy(), f[:, 0], atol=1e-9 * 250 + 1e-12)
            # logged levels: omega_z^2 R = L g with the nominal radius
            lv = d[d.step >= 4].groupby("step").table_rate_rad_s.first().to_numpy()
            wz_l = s * lv + OMEGA_E * np.sin(np.radians(LAT))
            np.testing.assert_allclose(wz_l ** 2 * R / G, [1, 10, 25, 10, 1], rtol=1e-8)


@pytest.mark.parametrize("plane,vertical", CF_MOUNTS)
def test_centrifuge_nominal_all_axes(plane, vertical):
    """Each axis probed through its own linear coefficient (Kp, Ko): A = a_i + Kp a_p + Ko a_o."""
    R, phi = 0.65, 30.0
    t = {"kind": "centrifuge", "arm_radius_m": R, "readings": 1, "g_levels": [5],
         "rest_azimuths_deg": [0, 180], "sweep": "up", "mounts": [{"plane": plane, "angle_deg": phi, "vertical": vertical}]}
    r0 = simulate_campaign(load_scenario(_base(t, {"K1": 1.0})))[0].data
    rp = simulate_campaign(load_scenario(_base(t, {"K1": 1.0, "Kp": 1.0})))[0].data
    ro = simulate_campaign(load_scenario(_base(t, {"K1": 1.0, "Ko": 1.0})))[0].data
    wz = r0.table_rate_rad_s.to_numpy() + OMEGA_E * np.sin(np.radians(LAT))
    a = wz ** 2 * R
    f = np.zeros((len(r0), 3))
    p1, p2 = (AXIDX[x] for x in plane.split("-"))
    iv, sv = _signed(vertical)
    f[:, p1] = a * np.cos(np.radians(phi))
    f[:, p2] = a * np.sin(np.radians(phi))
    f[:, iv] = sv * G
    np.testing.assert_allclose(r0.output, f[:, 0], atol=1e-8)
    np.testing.assert_allclose(rp.output - r0.output, f[:, 1], atol=1e-7)
    np.testing.assert_allclose(ro.output - r0.output, f[:, 2], atol=1e-7)


@pytest.mark.parametrize("head,cos_axis,sin_axis", [("PA", "+IA", "+OA"), ("OA", "-IA", "+PA"), ("PA", "+OA", "-IA")])
def test_tumble_nominal_closed_form(head, cos_axis, sin_axis):
    t = {"kind": "tumble", "heads": [{"head_axis": head, "cos_axis": cos_axis, "sin_axis": sin_axis}],
         "positions": 24, "readings": 2}
    run = simulate_campaign(load_scenario(_base(t, {"K1": 1.0})))[0]
    th = np.radians(run.data.angle_deg.to_numpy())
    np.testing.assert_allclose(run.data.angle_deg.iloc[::2], 15.0 * np.arange(24))
    ic, sc_ = _signed(cos_axis)
    is_, ss = _signed(sin_axis)
    f = np.zeros((len(th), 3))
    f[:, ic] = sc_ * G * np.cos(th)
    f[:, is_] = ss * G * np.sin(th)
    np.testing.assert_allclose(run.data.output, f[:, 0], atol=1e-9)
    assert run.meta["head_axis"] == head


def test_tilt_rotation_nominal_closed_form():
    t = {"kind": "tilt_rotation", "tilt_deg": 0.45, "sin_axis": "+IA", "cos_axis": "+PA", "normal_axis": "+OA",
         "positions": 12, "temp_set_c": [20, 30], "readings": 3}
    run = simulate_campaign(load_scenario(_base(t, {"K1": 1.0})))[0]
    d = run.data
    gam = np.radians(0.45)
    th = np.radians(d.rotation_deg.to_numpy())
    np.testing.assert_allclose(d.output, G * np.sin(gam) * np.sin(th), atol=1e-12)
    assert sorted(set(d.rotation_deg)) == [30.0 * k for k in range(12)]
    # the cos axis: PA via Kp
    t2 = dict(t, sin_axis="-PA", cos_axis="+IA", normal_axis="-OA")
    # -PA x ... the triad must stay right-handed: IA x PA = OA -> (+IA) x (-PA) = -OA
    run2 = simulate_campaign(load_scenario(_base(t2, {"K1": 1.0})))[0]
    np.testing.assert_allclose(run2.data.output, G * np.sin(gam) * np.cos(np.radians(run2.data.rotation_deg)),
                               atol=1e-12)


@pytest.mark.parametrize("sense", ["ccw", "cw"])
@pytest.mark.parametrize("plane,vertical", CF_MOUNTS)
@pytest.mark.parametrize("phi", [0.0, 60.0, 90.0, 180.0])
def test_sine_nominal_closed_form(plane, vertical, sense, phi):
    """Tangential R d(omega)/dt along sin(phi) e1 - cos(phi) e2 for ccw with e1 x e2 up,
    opposite when cw or down; centripetal omega_z^2 R as for the centrifuge."""
    R, Om, f = 1.0, 4 * np.pi, 1.0
    t = {"kind": "sine_centrifuge", "arm_radius_m": R, "rotation_sense": sense, "rate_amplitude_rad_s": Om,
         "rate_frequency_hz": f, "samples": 60, "attitudes": [{"plane": plane, "angle_deg": phi, "vertical": vertical}]}
    runs = [simulate_campaign(load_scenario(_base(t, c)))[0].data
            for c in ({"K1": 1.0}, {"K1": 1.0, "Kp": 1.0}, {"K1": 1.0, "Ko": 1.0})]
    d = runs[0]
    tt = d.time_s.to_numpy()
    np.testing.assert_allclose(d.table_rate_rad_s, Om * np.sin(2 * np.pi * f * tt), atol=1e-8)
    np.testing.assert_allclose(d.table_angle_deg, np.degrees(Om / (2 * np.pi * f) * (1 - np.cos(2 * np.pi * f * tt))),
                               atol=1e-8)
    s = 1.0 if sense == "ccw" else -1.0
    wz = s * Om * np.sin(2 * np.pi * f * tt) + OMEGA_E * np.sin(np.radians(LAT))
    wdot = Om * 2 * np.pi * f * np.cos(2 * np.pi * f * tt)
    p1, p2 = (AXIDX[x] for x in plane.split("-"))
    iv, sv = _signed(vertical)
    third = 3 - p1 - p2
    eps = 1.0 if (p2 - p1) % 3 == 1 else -1.0
    up = eps * sv                           # +1 when e1 x e2 points up
    ph = np.radians(phi)
    sign = (1.0 if sense == "ccw" else -1.0) * up
    F = np.zeros((len(tt), 3))
    F[:, p1] = wz ** 2 * R * np.cos(ph) + sign * R * wdot * np.sin(ph)
    F[:, p2] = wz ** 2 * R * np.sin(ph) - sign * R * wdot * np.cos(ph)
    F[:, iv] = sv * G
    assert iv == third
    np.testing.assert_allclose(runs[0].output, F[:, 0], atol=1e-7)
    np.testing.assert_allclose(runs[1].output - runs[0].output, F[:, 1], atol=1e-6)
    np.testing.assert_allclose(runs[2].output - runs[0].output, F[:, 2], atol=1e-6)


# ----------------------------------------------------------------- seeds and format
def test_same_seed_same_bytes(tmp_path):
    p1 = simulate_to_drop(SCENARIO_DIR / "demo.toml", tmp_path / "a", seed=7)
    p2 = simulate_to_drop(SCENARIO_DIR / "demo.toml", tmp_path / "b", seed=7)
    p3 = simulate_to_drop(SCENARIO_DIR / "demo.toml", tmp_path / "c", seed=8)
    assert [p.name for p in p1] == [p.name for p in p2] and len(p1) == 11
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(p1, p2))
    assert any(a.read_bytes() != c.read_bytes() for a, c in zip(p1, p3))


def test_written_file_parses_and_matches_memory(tmp_path):
    runs = simulate_campaign(load_scenario(SCENARIO_DIR / "demo.toml"), seed=11)
    runs += simulate_campaign(load_scenario(SCENARIO_DIR / "qa5512-sine.toml"), seed=11)[:1]
    paths = write_drop(runs, tmp_path)
    required = ["format", "run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id", "started_at",
                "site_latitude_deg", "g_local_m_s2", "output_unit", "sample_period_s"]
    cols = {"tumble": ["time_s", "position", "angle_deg", "output", "temp_c"],
            "centrifuge": ["time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"],
            "sine_centrifuge": ["time_s", "table_rate_rad_s", "table_angle_deg", "output"]}
    for run, p in zip(runs, paths):
        meta, data = read_drop_file(p)
        assert meta["format"] == "accelcal-drop/1"
        assert all(k in meta for k in required)
        assert list(data.columns) == cols[meta["test"]]
        assert meta["run_id"] == run.meta["run_id"] and p.name == meta["run_id"] + ".csv"
        for k, v in run.meta.items():
            assert (float(meta[k]) == v) if isinstance(v, (int, float)) else (meta[k] == v)
        assert np.isfinite(data.output).all() and (np.diff(data.time_s) >= 0).all()
        if meta["test"] == "centrifuge":
            assert (data.table_rate_rad_s >= 0).all()
            for k in ("arm_radius_m", "rotation_sense", "mount_plane", "mount_angle_deg", "vertical_axis",
                      "reading_window_s"):
                assert k in meta
        np.testing.assert_array_equal(data.to_numpy(float), run.data[list(data.columns)].to_numpy(float))


def test_bad_scenarios_refused():
    good = _base({"kind": "tumble"})
    load_scenario(good)
    for bad in (dict(good, effects={"no_such_effect": 1.0}),
                dict(good, test=[{"kind": "spin"}]),
                dict(good, test=[{"kind": "centrifuge", "arm_radius_m": 1.0,
                                  "mounts": [{"plane": "IA-IA", "vertical": "+OA"}]}]),
                dict(good, test=[{"kind": "centrifuge", "arm_radius_m": 1.0,
                                  "mounts": [{"plane": "IA-PA", "vertical": "+PA"}]}]),
                dict(good, noise={"white": 1.0})):
        with pytest.raises(ScenarioError):
            load_scenario(bad)


def test_noise_model_statistics():
    """White noise and rate jitter have the scenario's sizes (estimated from many readings)."""
    t = {"kind": "centrifuge", "arm_radius_m": 0.7, "readings": 400, "g_levels": [20], "sweep": "up",
         "rest_azimuths_deg": [0, 180], "mounts": [{"plane": "IA-PA", "angle_deg": 0, "vertical": "+OA"}]}
    noise = {"white_m_s2": 3e-6, "rate_jitter_rel": 4e-6}
    run = simulate_campaign(load_scenario(_base(t, {"K1": 2.0}, noise=noise)), seed=5)[0]
    d = run.data
    rest = d[d.step < 2].output / 2.0
    assert rest.std() == pytest.approx(3e-6, rel=0.1)
    spin = d[d.step == 2]
    a = 20 * G
    expect = np.hypot(3e-6, 4e-6 * a)
    assert (spin.output / 2.0).std() == pytest.approx(expect, rel=0.1)


def test_bias_random_walk():
    t = {"kind": "tumble", "positions": 4, "readings": 2000, "dwell_period_s": 2000.0}
    run = simulate_campaign(load_scenario(_base(t, {"K1": 1.0}, effects={}, noise={"bias_walk_m_s2_rt_s": 1e-6})),
                            seed=2)[0]
    d = run.data[run.data.position == 0].output.to_numpy() - G
    inc = np.diff(d)
    assert inc.std() == pytest.approx(1e-6, rel=0.1)       # increments over 1 s


# ----------------------------------------------------------------- the sample drops
def _read_sample(pattern):
    out = []
    for f in sorted(glob.glob(str(EXAMPLES / pattern), recursive=True)):
        meta, data = read_drop_file(f)
        meta = {k: (float(v) if _isnum(v) else v) for k, v in meta.items()}
        out.append((meta, data))
    return out


def _isnum(v):
    try:
        float(v)
        return True
    except ValueError:
        return False


def _dwell_chi2(meta, data, coeffs, effects):
    """Per-run linear fit E = a + b * A(truth, without K0) on dwell means, weighted by a
    variance a + b omega^4 fitted to the dwells' scatter (a dwell's own 8-reading scatter
    would make the chi-square heavy-tailed); returns chi2, dof."""
    from accelcal.physics import indicated_acceleration, specific_force
    F = specific_force(meta["test"], meta, data, effects)
    c = {k: v for k, v in coeffs.items() if k not in ("K0", "K1")}
    d = data.assign(A=indicated_acceleration(c, F), w4=data.table_rate_rad_s ** 4)
    g = d.groupby("step").agg(E=("output", "mean"), A=("A", "mean"), sd=("output", "std"), n=("output", "size"),
                              w4=("w4", "mean"))
    s2, w4 = g.sd.to_numpy() ** 2, g.w4.to_numpy()
    rest = w4 == 0
    a = float(np.median(s2[rest]))
    b = max(float(np.median((s2[~rest] - a) / w4[~rest])), 0.0)
    w = np.sqrt(g.n.to_numpy() / (a + b * w4))
    X = np.c_[np.ones(len(g)), g.A]
    sol = np.linalg.lstsq(X * w[:, None], g.E.to_numpy() * w, rcond=None)[0]
    r = (g.E.to_numpy() - X @ sol) * w
    return float(r @ r), len(g) - 2


def _level_sd(runs, R, g=G):
    """Within-dwell output scatter per g level, pooled over the mounts where IA sees at least
    0.7 of the centripetal term; each dwell's scatter is divided by |cos(phi)| (rest: by 1)."""
    out = {}
    for meta, d in runs:
        c = abs(np.cos(np.radians(meta["mount_angle_deg"])))
        if c < 0.7:
            continue
        lv = np.round(d.table_rate_rad_s ** 2 * R / g)
        for L, sd in d.assign(L=lv).groupby(["L", "step"]).output.std().groupby(level=0):
            out.setdefault(L, []).extend(list(sd / (c if L > 0 else 1.0)))
    return {L: float(np.sqrt(np.mean(np.square(v)))) for L, v in out.items()}


@pytest.mark.parametrize("name,pattern", [("snj103-lxj100", "drop-2026-11-20/**/LXJ*.csv"),
                                          ("snj103-lxj200", "drop-2026-11-21/LXJ*.csv")])
@needs_shared
def test_centrifuge_sample_reproduced(name, pattern):
    sc = load_scenario(SCENARIO_DIR / f"{name}.toml")
    sims = [r for r in simulate_campaign(sc, seed=1) if r.meta["test"] == "centrifuge"]
    samples = _read_sample(pattern)
    assert len(sims) == len(samples)
    coeffs = sc.coefficients
    for r, (meta, d) in zip(sims, samples):
        assert list(r.data.columns) == list(d.columns)
        for k in ("run_id", "mount_plane", "vertical_axis", "rotation_sense", "campaign", "rig_id", "started_at"):
            assert r.meta[k] == meta[k], k
        for k in ("mount_angle_deg", "arm_radius_m", "g_local_m_s2", "site_latitude_deg", "sample_period_s"):
            assert r.meta[k] == pytest.approx(meta[k]), k
        np.testing.assert_array_equal(r.data.step, d.step)
        np.testing.assert_allclose(r.data.time_s, d.time_s)
        np.testing.assert_array_equal(r.data.table_angle_deg.isna(), d.table_angle_deg.isna())
        # rates within the logged jitter (a few 1e-7 relative)
        np.testing.assert_allclose(r.data.table_rate_rad_s, d.table_rate_rad_s, rtol=3e-6, atol=0)
        eff = r.truth["effects"]
        c_sim, dof = _dwell_chi2(r.meta, r.data, coeffs, eff)
        c_smp, dof2 = _dwell_chi2(meta, d, coeffs, eff)
        assert dof == dof2 == 21
        # chi2 with 21 dof: 99.9 % below 46; the sample itself (LXJ-200 with the instrument's
        # coefficients) reaches 36
        assert 4 < c_sim < 50 and 4 < c_smp < 50, (meta["run_id"], c_sim, c_smp)
    R = float(samples[0][0]["arm_radius_m"])
    more = [r for seed in (2, 3) for r in simulate_campaign(sc, seed=seed) if r.meta["test"] == "centrifuge"]
    sd_sim = _level_sd([(r.meta, r.data) for r in sims + more], R)
    sd_smp = _level_sd(samples, R)
    assert sd_sim.keys() == sd_smp.keys()
    for L in sd_smp:
        assert 1 / 1.5 < sd_sim[L] / sd_smp[L] < 1.5, (L, sd_sim[L], sd_smp[L])


@needs_shared
def test_tumble_sample_reproduced():
    sc = load_scenario(SCENARIO_DIR / "snj103-lxj100.toml")
    sim = [r for r in simulate_campaign(sc, seed=1) if r.meta["test"] == "tumble"][0]
    (meta, d), = _read_sample("drop-2026-11-20/DH1*.csv")
    assert list(sim.data.columns) == list(d.columns)
    np.testing.assert_allclose(sim.data[["time_s", "position", "angle_deg"]], d[["time_s", "position", "angle_deg"]])
    ms, md = (x.groupby("position").output.mean().to_numpy() for x in (sim.data, d))
    ss, sd = (np.sqrt((x.groupby("position").output.std() ** 2).mean()) for x in (sim.data, d))
    assert 1 / 1.5 < ss / sd < 1.5
    # same unit: position means agree to a few noise widths (K0, K1, Ko from the sample)
    assert np.abs(ms - md).max() < 10 * sd
    for k in ("head_axis", "cos_axis", "sin_axis", "run_id", "campaign"):
        assert sim.meta[k] == meta[k]


@needs_shared
def test_thermal_sample_reproduced():
    sc = load_scenario(SCENARIO_DIR / "hust-m07-thermal.toml")
    sim, = simulate_campaign(sc, seed=1)
    (meta, d), = _read_sample("drop-2026-11-18-thermal/*.csv")
    assert list(sim.data.columns) == list(d.columns)
    np.testing.assert_allclose(sim.data[["time_s", "temp_set_c", "rotation_deg"]],
                               d[["time_s", "temp_set_c", "rotation_deg"]])
    assert sim.meta["positions"] == int(meta["positions"]) and sim.meta["tilt_deg"] == meta["tilt_deg"]
    key = ["temp_set_c", "rotation_deg"]
    for x in (sim.data, d):
        x["blk"] = (x.time_s.diff() != 1).cumsum()
    # temperature: offset and reading noise
    for col in ("temp_c",):
        a, b = (x.groupby("blk")[col].std().mean() for x in (sim.data, d))
        assert 1 / 1.5 < a / b < 1.5
    assert sim.data.temp_c.mean() == pytest.approx(d.temp_c.mean(), abs=0.02)
    # output per block: means to a few noise widths, scatter within a factor 1.5 per position
    ms = sim.data.groupby(key).output.mean()
    md = d.groupby(key).output.mean()
    sd_d = d.groupby(key).output.std()
    assert ((ms - md).abs() < 5 * sd_d / np.sqrt(60) + 2e-6).all()
    # reading scatter per table position (it depends on the position through K0T, K1T and
    # the temperature noise), pooled over the 15 dwells of each position
    sd_s, sd_d = (np.sqrt((x.groupby("blk").output.std() ** 2).groupby(x.groupby("blk").rotation_deg.first()).mean())
                  for x in (sim.data, d))
    ratio = (sd_s / sd_d).to_numpy()
    assert len(ratio) == 12
    assert (ratio > 1 / 1.5).all() and (ratio < 1.5).all()


@needs_shared
def test_sine_sample_reproduced():
    from accelcal.physics import rig_output
    sc = load_scenario(SCENARIO_DIR / "qa5512-sine.toml")
    sims = simulate_campaign(sc, seed=1)
    samples = _read_sample("drop-2026-11-19-sine/*.csv")
    assert len(sims) == len(samples) == 3
    for r, (meta, d) in zip(sims, samples):
        assert list(r.data.columns) == list(d.columns)
        for k in ("mount_plane", "vertical_axis", "notes", "run_id"):
            assert r.meta[k] == meta[k]
        np.testing.assert_allclose(r.data.time_s, d.time_s)
        np.testing.assert_allclose(r.data.table_angle_deg, d.table_angle_deg, atol=1e-6)
        np.testing.assert_allclose(r.data.table_rate_rad_s, d.table_rate_rad_s, atol=1e-4)
        # residual of each against the truth model: same size within 1.5
        res = []
        for m, x in ((r.meta, r.data), (meta, d)):
            E = rig_output("sine_centrifuge", m, x, sc.coefficients, r.truth["effects"])
            res.append(np.std(x.output - E))
        assert 1 / 1.5 < res[0] / res[1] < 1.5, (meta["run_id"], res)


# ----------------------------------------------------------------- what real DAQs add (issue 10)
def test_logged_angle_noise_quantum_and_spikes():
    """The logged angle carries its own noise while the output follows the true angle; the
    output is in counts of the quantum; spikes come at their rate."""
    t = {"kind": "tumble", "positions": 8, "readings": 500, "dwell_period_s": 600.0}
    noise = {"angle_log_deg": 0.01, "output_quantum": 1e-5, "spike_rate": 0.01, "spike_m_s2": 1e-3,
             "white_m_s2": 2e-6}
    run = simulate_campaign(load_scenario(_base(t, effects={}, noise=noise)), seed=4)[0]
    d = run.data
    nominal = 360.0 * d.position / 8
    assert (d.angle_deg - nominal).std() == pytest.approx(0.01, rel=0.1)
    q = d.output.to_numpy() / 1e-5
    np.testing.assert_allclose(q, np.round(q), atol=1e-6)
    clean = G * np.cos(np.radians(nominal))           # the output follows the true angle
    dev = d.output - clean
    spikes = np.abs(dev) > 5e-4
    assert spikes.mean() == pytest.approx(0.01, abs=0.004)
    assert np.abs(dev[~spikes]).max() < 2e-5


def test_disturbances_outside_the_catalogue():
    t = {"kind": "tumble", "positions": 4, "readings": 10, "temp_c": 30.0}
    base = _base(t, effects={})
    base["disturbance"] = {"bias_temp_quadratic_m_s2_c2": 1e-6, "bias_periodic_m_s2": 2e-6,
                           "bias_periodic_period_s": 100.0}
    run = simulate_campaign(load_scenario(base), seed=1)[0]
    d = run.data
    expect = G * np.cos(np.radians(d.angle_deg)) + 1e-6 * 100.0 + 2e-6 * np.sin(2 * np.pi * d.time_s / 100.0)
    np.testing.assert_allclose(d.output, expect, atol=1e-12)
    assert run.truth["disturbance"]["bias_periodic_period_s"] == 100.0
    with pytest.raises(ScenarioError):
        load_scenario(dict(base, disturbance={"bias_cubic": 1.0}))
