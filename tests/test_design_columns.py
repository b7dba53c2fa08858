"""Every paper method's regressors are derivatives of the one forward model (issue 9).

For each estimator the design columns it fits with are compared with central differences
of :func:`accelcal.physics.rig_output`, computed here independently of the estimator: a
column that rebuilt the kinematics by hand, with another sign, radius or angle
convention, would fail.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

from accelcal.physics import rig_output

G = 9.80122


def central(test, meta, data, coeffs, effects, name, h, *, effect=False, **kw):
    """d rig_output / d name by central differences (a coefficient, or an effect)."""
    def at(v):
        c, e = dict(coeffs), dict(effects)
        (e if effect else c)[name] = (e if effect else c).get(name, 0.0) + v
        return rig_output(test, meta, data, c, e, **kw)
    return (at(h) - at(-h)) / (2 * h)


def assert_columns_equal(a, b, rtol=1e-7, what=""):
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.max(np.abs(b))
    assert scale > 0, what
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * scale, err_msg=what)


# ----------------------------------------------------------------- paper 003: tumble

def _tumble(cos_axis="+IA", sin_axis="+OA", head="PA"):
    meta = {"test": "tumble", "run_id": "T", "g_local_m_s2": G, "site_latitude_deg": 39.9,
            "output_unit": "mA", "head_axis": head, "cos_axis": cos_axis, "sin_axis": sin_axis}
    ang = np.repeat(np.arange(0.0, 360.0, 30.0), 2)
    data = pd.DataFrame({"angle_deg": ang, "position": np.repeat(np.arange(12), 2),
                         "time_s": np.arange(ang.size, dtype=float)})
    return meta, data


def test_tumble_design_columns_are_derivatives_of_rig_output():
    from accelcal.estimators.tumble import fit_run
    rng = np.random.default_rng(1)
    for axes in (("+IA", "+OA", "PA"), ("+OA", "-IA", "PA"), ("-IA", "+PA", "OA")):
        meta, data = _tumble(*axes)
        extras = ("K3", "Koq", "Kio" if axes[2] == "PA" else "Kip")
        truth = dict(zip(("K0", "K1", "K2", *extras), (4e-4, 0.1325, 3.9e-7, 2e-10, 3e-8, 2e-7)))
        data["output"] = (rig_output("tumble", meta, data, truth, {"initial_misalignment": 2e-3})
                          + rng.normal(0, 1e-6, len(data)))
        fit = fit_run(meta, data, extras)
        p = fit.values
        coeffs = {k: p[k] for k in ("K0", "K1", "K2", *extras)}
        eff = {"initial_misalignment": p["theta0"]}
        J = fit.result.J * fit.s                       # the design at the solution, unwhitened
        steps = {"K0": 1e-3, "K1": 1e-3, "K2": 1e-6, "K3": 1e-9, "Koq": 1e-7, "Kio": 1e-6, "Kip": 1e-6}
        for j, name in enumerate(fit.result.names):
            if name == "theta0":
                col = central("tumble", meta, data, coeffs, eff, "initial_misalignment", 1e-5, effect=True)
                assert_columns_equal(J[:, j], col, rtol=1e-6, what=name)
            else:
                assert_columns_equal(J[:, j], central("tumble", meta, data, coeffs, eff, name, steps[name]),
                                     what=name)


# ----------------------------------------------------------------- paper 001: tilted rotation

def test_thermal_point_columns_are_derivatives_of_rig_output():
    from accelcal.estimators.thermal import point_design, temperature_design
    for sin_axis, cos_axis, normal, cross in (("+IA", "+PA", "+OA", "Kp"), ("-IA", "-OA", "+PA", "Ko"),
                                               ("+PA", "+IA", "-OA", "Kp")):
        meta = {"test": "tilt_rotation", "g_local_m_s2": 9.7936, "tilt_deg": 0.45, "sin_axis": sin_axis,
                "cos_axis": cos_axis, "normal_axis": normal, "positions": 12}
        th = np.arange(12) * 30.0
        data = pd.DataFrame({"rotation_deg": th, "time_s": np.zeros(12)})
        X = point_design(meta, th)
        c = {"K1": 1.0, "K0": 0.0}
        # dE/dK0 / K1, dE/dK1 (at K0 = 0), dE/dKx / K1 of the forward model
        assert_columns_equal(X[:, 0], central("tilt_rotation", meta, data, c, {}, "K0", 1e-4))
        assert_columns_equal(X[:, 1], central("tilt_rotation", meta, data, c, {}, "K1", 1e-4))
        assert_columns_equal(X[:, 2], central("tilt_rotation", meta, data, c, {}, cross, 1e-4))
    # the temperature lines: dE/dK0 and dE/dK0T at K1 = 1
    T = np.array([20.0, 25.0, 30.0, 35.0, 40.0])
    data = pd.DataFrame({"rotation_deg": np.zeros(5), "time_s": np.zeros(5), "temp_c": T})
    Xt = temperature_design(T)
    assert_columns_equal(Xt[:, 0], central("tilt_rotation", meta, data, {"K1": 1.0}, {}, "K0", 1e-4))
    assert_columns_equal(Xt[:, 1], central("tilt_rotation", meta, data, {"K1": 1.0}, {}, "K0T", 1e-4))


# ----------------------------------------------------------------- paper 002: sinusoidal centrifuge

def test_sine_columns_are_derivatives_of_rig_output():
    from accelcal.estimators import sinusoidal as S
    t = np.arange(200) * 0.02
    runs = []
    for plane, vert in (("IA-PA", "+OA"), ("OA-IA", "+PA"), ("PA-OA", "+IA")):
        meta = {"test": "sine_centrifuge", "run_id": plane, "site_latitude_deg": 45.75, "g_local_m_s2": 9.8066,
                "output_unit": "mA", "arm_radius_m": 1.0, "rotation_sense": "cw", "mount_plane": plane,
                "mount_angle_deg": 0.0, "vertical_axis": vert, "rate_amplitude_rad_s": 4 * np.pi,
                "rate_frequency_hz": 1.0}
        w = 4 * np.pi * np.sin(2 * np.pi * t)
        ang = np.degrees(2 * (1 - np.cos(2 * np.pi * t)))
        runs.append((meta, pd.DataFrame({"time_s": t, "table_rate_rad_s": w, "table_angle_deg": ang,
                                          "output": np.zeros(t.size)})))
    prep = S.prepare_runs(runs)
    tools = {"spindle_tilt": "shared", "mass_centre_offset": "shared", "rate_scale_error": "shared",
             "sensor_lag": "shared"}
    params = S._build_params(prep, False, (), tools, 0.13)
    truth = {"K0": 4e-4, "K1": 0.1325, "Kp": 2e-5, "Ko": -1.5e-5, "K2": 3.94e-7, "K3": 1.5e-9, "Koq": 2e-8,
             "Kip": 7.1e-7, "Kio": 2.0e-7, "Kpo": 5e-8, "Kpp": 4.7e-8, "Koo": 3.0e-8, "spindle_tilt": 3e-4,
             "mass_centre_offset": 2e-3, "rate_scale_error": 2e-4, "sensor_lag": 1e-2}  # a sampled lag: tau ~ dt
    x = np.array([truth[p.name] for p in params])
    coeffs = {k: v for k, v in truth.items() if k[0] == "K"}
    effects = {"earth_rate": 1.0, **{k: v for k, v in truth.items() if k[0] != "K"}}
    for i, run in enumerate(prep):
        J = S._jacobian_run(params, x, run, i)
        for j, p in enumerate(params):
            tool = p.group == "tool"
            h = 3e-3 * p.scale if tool else p.scale       # (the estimator steps 1e-2 scale)
            col = central("sine_centrifuge", run.meta, run.cols, coeffs, effects, p.name, h, effect=tool)
            # the estimator's tool columns are central differences with step 1e-2 of the scale:
            # O(h^2) agreement; the coefficient columns are exact
            assert_columns_equal(J[:, j], col, rtol=1e-4 if tool else 1e-7, what=f"{run.meta['run_id']} {p.name}")


# ----------------------------------------------------------------- paper 000: centrifuge

def _pair(plane="IA-PA", phi=0.0, R=0.71):
    """A mount pair (phi, phi + 180) of dwells: two rest azimuths, then rising rates."""
    rates = [0.0, 0.0] + [math.sqrt(L * 9.80665 / R) for L in (1, 3, 7, 14, 25)]
    runs = []
    for ang, pol in ((phi, 1), (phi + 180.0, -1)):
        rows = []
        for step, w in enumerate(rates):
            for i in range(4):
                rows.append((100.0 * step + i, step, w, (180.0 * step) if w == 0 else np.nan, 0.0, 23.0))
        d = pd.DataFrame(rows, columns=["time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"])
        meta = {"test": "centrifuge", "g_local_m_s2": G, "site_latitude_deg": 39.9, "arm_radius_m": R,
                "rotation_sense": "cw", "mount_plane": plane, "mount_angle_deg": ang,
                "vertical_axis": "+OA" if "OA" not in plane else "-PA", "run_id": f"P{ang:g}"}
        runs.append((meta, d, pol))
    return runs


def _dwell_rows(pair, pol):
    """The pair's dwell rows of one polarity as a run table for rig_output (mean rate)."""
    T = pair.table[pair.table["pol"] == pol]
    return pair.metas[pol], pd.DataFrame({"table_rate_rad_s": T["rate"].to_numpy(), "time_s": T["time_mid"].to_numpy()})


def test_eq9_c2_column_is_the_derivative_of_rig_output():
    """eq 9's c2 column = d rig_output/dK2 / K1 at the IA mount, d/dKpp / K1 at the 90 deg mount,
    with the turning centre and the mass-centre offset of the test radii."""
    from accelcal.estimators.crosscoupling import alignment
    from accelcal.estimators.radius import PairData, polarity_design
    Rp, Rm = 0.714775, 0.705794
    for plane, phi, coef in (("IA-PA", 0.0, "K2"), ("IA-PA", 90.0, "Kpp"), ("IA-OA", 90.0, "Koo")):
        runs = _pair(plane, phi)
        pair = PairData.from_runs(runs, 0.13)
        geo = alignment(Rp, Rm, plane, phi)
        a = pair.inputs(geo.R, geo.r)
        X, names = polarity_design(a, pair.table["pol"].to_numpy(), 3)
        c2 = X[:, names.index("c2")]
        for pol in (1, -1):
            meta, d = _dwell_rows(pair, pol)
            eff = {"earth_rate": 1.0, "mass_centre_offset": geo.r}
            col = central("centrifuge", meta, d, {"K1": 1.0}, eff, coef, 1e-6, radius_m=geo.R)
            assert_columns_equal(c2[pair.table["pol"].to_numpy() == pol], col, what=f"{plane} {phi} {pol}")


def test_eq7_input_and_eq6_regressor_are_derivatives_of_rig_output():
    """eq 7's a_i+- = d rig_output/dK1 (K1 = 1, K0 = 0) at the polarity radii; eq 6's
    denominator = d a_IA/dR of rig_output with IA tilted by lambda_c."""
    from accelcal.estimators.radius import PairData, static_radius_column
    runs = _pair("IA-PA", 0.0)
    pair = PairData.from_runs(runs, 0.13)
    R = {1: 0.714775, -1: 0.705794}
    a = pair.inputs(R)
    pol = pair.table["pol"].to_numpy()
    for p in (1, -1):
        meta, d = _dwell_rows(pair, p)
        col = central("centrifuge", meta, d, {"K1": 1.0}, {"earth_rate": 1.0}, "K1", 1e-4, radius_m=R[p])
        assert_columns_equal(a[pol == p], col)
        lam = 3e-4
        cR = static_radius_column(meta, d["table_rate_rad_s"].to_numpy(), lam)
        dR = (rig_output("centrifuge", meta, d, {"K1": 1.0}, {"earth_rate": 1.0, "ia_tilt": lam}, radius_m=1.0 + 1e-3)
              - rig_output("centrifuge", meta, d, {"K1": 1.0}, {"earth_rate": 1.0, "ia_tilt": lam}, radius_m=1.0 - 1e-3)) / 2e-3
        assert_columns_equal(cR, dR)


def test_eq2_row_is_the_derivative_of_rig_output_per_unit_centripetal_input():
    from accelcal.estimators.crosscoupling import UNKNOWNS, eq2_row, mount_meta
    for plane, phi in (("IA-PA", 45.0), ("IA-OA", 30.0), ("PA-OA", 120.0)):
        row = eq2_row(plane, math.radians(phi))
        meta = {**mount_meta(plane, phi), "g_local_m_s2": G}
        d = pd.DataFrame({"table_rate_rad_s": [1.0], "time_s": [0.0]})
        for k in UNKNOWNS:
            # rig_output at omega = 1 rad/s, R = 1 m: the a^2 coefficient is dE/dK minus the
            # gravity part (rate 0)
            d0 = d.assign(table_rate_rad_s=[0.0])
            col = (central("centrifuge", meta, d, {"K1": 1.0}, {}, k, 1e-3)
                   - central("centrifuge", meta, d0, {"K1": 1.0}, {}, k, 1e-3))
            # the cross terms with gravity (linear in a) are not eq 2's: remove them by
            # symmetry, using the mount turned by 180 deg (a -> -a)
            meta2 = {**meta, "mount_angle_deg": phi + 180.0}
            col2 = (central("centrifuge", meta2, d, {"K1": 1.0}, {}, k, 1e-3)
                    - central("centrifuge", meta2, d0, {"K1": 1.0}, {}, k, 1e-3))
            assert abs(row[k] - (col[0] + col2[0]) / 2) < 1e-9, (plane, phi, k)
