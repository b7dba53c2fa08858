"""An independent rigid-body computation of the specific force on each rig, compared with
``accelcal.physics.specific_force``.

The reference below does not use accelcal.physics: it builds the table orientation as a
rotation matrix in an inertial (local-level, z up) frame, places the effective mass centre
on the table (turning centre at the arm radius, mass-centre offset along the first plane
axis), differentiates the inertial position twice numerically (4th-order stencil), subtracts
gravity and projects on the instrument axes, themselves built as rotation matrices from
mount plane / angle / vertical axis (and the tilts).  The earth rate enters as the rotation of
the local frame about the vertical at Omega_e sin(latitude) (drop-format.md uses omega_z only;
``test_horizontal_earth_rate_averages_out`` shows the horizontal part averages out over a
revolution).
"""
from __future__ import annotations


import numpy as np
import pandas as pd
import pytest

OMEGA_E = 7.292115e-5
G = 9.80122
LAT = 39.9
AX = {"IA": 0, "PA": 1, "OA": 2}


# ----------------------------------------------------------------- reference (no accelcal)
def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rot(axis, a):
    """Rodrigues rotation about a unit vector."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def signed(text):
    text = text.strip()
    sgn = -1.0 if text.startswith("-") else 1.0
    return AX[text.lstrip("+-")], sgn


def instrument_axes_in_table(plane, phi, vertical, lam=0.0):
    """Columns: IA, PA, OA unit vectors in table coordinates.  The table's x axis points from
    the spindle outwards through the turning centre (so 'towards the spindle' is -x), z is the
    table normal (up).  The direction to the spindle makes angle phi with e1 towards e2."""
    i1, i2 = (AX[p] for p in plane.split("-"))
    iv, sv = signed(vertical)
    # e1 in the plane at azimuth a; e2 = h (z x e1); u = -x must be cos phi e1 + sin phi e2
    # handedness of the instrument triad: e_i1 x e_i2 = eps * e_third (IA x PA = OA)
    third = 3 - i1 - i2
    eps = 1.0 if (i2 - i1) % 3 == 1 else -1.0
    h = eps * sv                      # +1 when e1 x e2 points up
    u = np.array([-1.0, 0.0, 0.0])
    a = np.pi - h * phi                # candidate; checked against the defining equations below
    e1 = np.array([np.cos(a), np.sin(a), 0.0])
    e2 = h * np.cross([0.0, 0.0, 1.0], e1)
    assert abs(u @ e1 - np.cos(phi)) < 1e-12 and abs(u @ e2 - np.sin(phi)) < 1e-12
    assert np.allclose(np.cross(e1, e2), [0, 0, h])
    up = np.array([0.0, 0.0, 1.0])
    # ia_tilt: the first plane axis tilts towards up by lam (rotation in the e1-up plane)
    e1t = np.cos(lam) * e1 + np.sin(lam) * up
    upt = np.cos(lam) * up - np.sin(lam) * e1
    M = np.zeros((3, 3))
    M[:, i1] = e1t
    M[:, i2] = e2
    M[:, iv] = sv * upt
    assert iv == third
    return M, e1t


def centrifuge_reference(*, plane, phi_deg, vertical, sense, R, t, alpha_fn, r=0.0, lam=0.0,
                         dphi=0.0, beta=0.0, kappa=0.0, rate_fn=None, earth=1.0,
                         earth_vector=False, lat=LAT, h=1e-3):
    """Specific force on (IA, PA, OA) by differentiating the inertial position twice.

    alpha_fn(t): table angle (rad) about the spindle relative to the spindle frame, positive in
    the table's sense of rotation (so ccw angle = s*alpha_fn).  rate_fn(t): table rate, for
    the arm stretch only (constant-rate runs)."""
    s = 1.0 if sense == "ccw" else -1.0
    M, e1 = instrument_axes_in_table(plane, np.radians(phi_deg) + dphi, vertical, lam)
    oe_v = earth * OMEGA_E * np.sin(np.radians(lat))
    oe_h = OMEGA_E * np.cos(np.radians(lat))

    def earth(tt):
        """The local-level frame (z up, x north) seen from inertial space."""
        if earth_vector:
            # full earth rotation vector: (north, 0, up) components in local level axes
            w = np.array([oe_h, 0.0, OMEGA_E * np.sin(np.radians(lat))])
            return Rot(w, np.linalg.norm(w) * tt)
        return Rz(oe_v * tt)

    def frame(tt):
        return earth(tt) @ Ry(beta) @ Rz(s * alpha_fn(tt))

    def pos(tt):
        Rt = R
        if kappa:
            wz = s * rate_fn(tt) + oe_v
            Rt = R * (1 + kappa * wz ** 2)
        p_T = np.array([Rt, 0.0, 0.0]) + r * e1
        return frame(tt) @ p_T

    out = []
    for tt in np.atleast_1d(t):
        P = [pos(tt + k * h) for k in (-2, -1, 0, 1, 2)]
        acc = (-P[0] + 16 * P[1] - 30 * P[2] + 16 * P[3] - P[4]) / (12 * h * h)
        f = acc + earth(tt) @ np.array([0.0, 0.0, G])   # acceleration minus gravity (g = -G up)
        C = frame(tt)
        out.append((C @ M).T @ f)
    return np.array(out)


# ----------------------------------------------------------------- comparisons
def physics_centrifuge(meta, data, effects):
    from accelcal.physics import specific_force
    return specific_force(meta["test"], meta, data, effects)


PLANES = [("IA-PA", "+OA"), ("IA-PA", "-OA"), ("PA-IA", "+OA"), ("IA-OA", "-PA"), ("OA-IA", "+PA"),
          ("PA-OA", "+IA"), ("OA-PA", "-IA"), ("IA-OA", "+PA")]


def _meta(plane, vertical, phi, sense, R, test="centrifuge", **kw):
    m = {"test": test, "site_latitude_deg": LAT, "g_local_m_s2": G, "arm_radius_m": R,
         "rotation_sense": sense, "mount_plane": plane, "mount_angle_deg": phi, "vertical_axis": vertical}
    m.update(kw)
    return m


@pytest.mark.parametrize("plane,vertical", PLANES)
@pytest.mark.parametrize("sense", ["ccw", "cw"])
@pytest.mark.parametrize("phi", [0.0, 45.0, 90.0, 180.0, 225.0, 300.0])
def test_centrifuge_constant_rate(plane, vertical, sense, phi):
    R, w = 0.7102845, 11.7
    eff = {"earth_rate": 1.0, "mass_centre_offset": -4.49e-3, "ia_tilt": 2.9e-4,
           "mount_angle_error": 3e-3, "rate_scale_error": 2e-5}
    ref = centrifuge_reference(plane=plane, phi_deg=phi, vertical=vertical, sense=sense, R=R, t=[0.3],
                               alpha_fn=lambda tt: (1 + 2e-5) * w * tt, r=-4.49e-3, lam=2.9e-4, dphi=3e-3)
    got = physics_centrifuge(_meta(plane, vertical, phi, sense, R),
                             pd.DataFrame({"time_s": [0.3], "table_rate_rad_s": [w]}), eff)
    np.testing.assert_allclose(got, ref, atol=2e-6 * w * w * R + 1e-7)


@pytest.mark.parametrize("phi,rho", [(0.0, "R-r"), (180.0, "R+r")])
def test_mass_centre_offset_paper_geometry(phi, rho):
    """paper 000 2.2: for phi = 0 the test radius is R - r, for phi = 180 it is R + r."""
    R, r, w = 0.7102845, -4.49e-3, 18.0
    ref = centrifuge_reference(plane="IA-PA", phi_deg=phi, vertical="+OA", sense="ccw", R=R, t=[0.1],
                               alpha_fn=lambda tt: w * tt, r=r, earth=0.0)
    expect = (R - r) if rho == "R-r" else (R + r)
    assert ref[0, 0] * np.cos(np.radians(phi)) == pytest.approx(w * w * expect, rel=1e-7)
    got = physics_centrifuge(_meta("IA-PA", "+OA", phi, "ccw", R),
                             pd.DataFrame({"time_s": [0.1], "table_rate_rad_s": [w]}), {"mass_centre_offset": r})
    np.testing.assert_allclose(got, ref, atol=1e-6)


@pytest.mark.parametrize("sense", ["ccw", "cw"])
def test_earth_rate_in_centripetal(sense):
    R, w = 0.65, 3.8
    ref = centrifuge_reference(plane="IA-PA", phi_deg=0, vertical="+OA", sense=sense, R=R, t=[1.0],
                               alpha_fn=lambda tt: w * tt, earth=1.0)
    ref0 = centrifuge_reference(plane="IA-PA", phi_deg=0, vertical="+OA", sense=sense, R=R, t=[1.0],
                                alpha_fn=lambda tt: w * tt, earth=0.0)
    got = physics_centrifuge(_meta("IA-PA", "+OA", 0, sense, R),
                             pd.DataFrame({"time_s": [1.0], "table_rate_rad_s": [w]}), {"earth_rate": 1.0})
    d_ref = ref[0, 0] - ref0[0, 0]
    s = 1 if sense == "ccw" else -1
    assert d_ref == pytest.approx(2 * s * w * OMEGA_E * np.sin(np.radians(LAT)) * R, rel=1e-3)
    np.testing.assert_allclose(got, ref, atol=1e-8)


def test_arm_stretch():
    R, w, kappa = 0.7102845, 15.0, 3e-7
    ref = centrifuge_reference(plane="IA-PA", phi_deg=45, vertical="+OA", sense="ccw", R=R, t=[0.2],
                               alpha_fn=lambda tt: w * tt, kappa=kappa, rate_fn=lambda tt: w)
    got = physics_centrifuge(_meta("IA-PA", "+OA", 45, "ccw", R),
                             pd.DataFrame({"time_s": [0.2], "table_rate_rad_s": [w]}),
                             {"earth_rate": 1.0, "arm_stretch": kappa})
    np.testing.assert_allclose(got, ref, atol=1e-6)


SINE_OM, SINE_F = 4 * np.pi, 1.0


def _sine_alpha(tt, eps=0.0):
    return (1 + eps) * SINE_OM / (2 * np.pi * SINE_F) * (1 - np.cos(2 * np.pi * SINE_F * tt))


@pytest.mark.parametrize("plane,vertical", PLANES)
@pytest.mark.parametrize("sense", ["ccw", "cw"])
@pytest.mark.parametrize("phi", [0.0, 30.0, 90.0, 180.0])
def test_sine_tangential_and_centripetal(plane, vertical, sense, phi):
    R = 1.0
    t = np.array([0.0, 0.13, 0.25, 0.61, 0.9])
    eff = {"earth_rate": 1.0, "mass_centre_offset": 2e-3, "ia_tilt": -1e-4, "rate_scale_error": 1e-4}
    ref = centrifuge_reference(plane=plane, phi_deg=phi, vertical=vertical, sense=sense, R=R, t=t,
                               alpha_fn=lambda tt: _sine_alpha(tt, 1e-4), r=2e-3, lam=-1e-4)
    meta = _meta(plane, vertical, phi, sense, R, test="sine_centrifuge",
                 rate_amplitude_rad_s=SINE_OM, rate_frequency_hz=SINE_F)
    data = pd.DataFrame({"time_s": t, "table_rate_rad_s": SINE_OM * np.sin(2 * np.pi * SINE_F * t),
                         "table_angle_deg": np.degrees(_sine_alpha(t))})
    got = physics_centrifuge(meta, data, eff)
    np.testing.assert_allclose(got, ref, atol=2e-6)


def _spindle_tilt_case(t):
    R, beta = 1.0, 2e-3
    ref = centrifuge_reference(plane="IA-PA", phi_deg=0, vertical="+OA", sense="ccw", R=R, t=t,
                               alpha_fn=_sine_alpha, beta=beta, earth=0.0)
    meta = _meta("IA-PA", "+OA", 0, "ccw", R, test="sine_centrifuge",
                 rate_amplitude_rad_s=SINE_OM, rate_frequency_hz=SINE_F)
    data = pd.DataFrame({"time_s": t, "table_rate_rad_s": SINE_OM * np.sin(2 * np.pi * SINE_F * t),
                         "table_angle_deg": np.degrees(_sine_alpha(t))})
    got = physics_centrifuge(meta, data, {"spindle_tilt": beta})
    return ref, got


def test_spindle_tilt_radial_and_vertical():
    """effects.md: gravity adds g sin(beta) cos(alpha) along the inward radial (here -IA)."""
    t = np.array([0.05, 0.2, 0.37, 0.5, 0.77])
    ref, got = _spindle_tilt_case(t)
    np.testing.assert_allclose(got[:, [0, 2]], ref[:, [0, 2]], atol=2e-6)


def test_spindle_tilt_tangential_component():
    """effects.md (complete definition): g sin(beta) sin(alpha) along the ccw direction of
    motion, here PA for IA-PA at phi = 0 with +OA up."""
    t = np.array([0.05, 0.2, 0.37, 0.5, 0.77])
    ref, got = _spindle_tilt_case(t)
    np.testing.assert_allclose(got[:, 1], ref[:, 1], atol=2e-6)


def test_horizontal_earth_rate_averages_out():
    """The horizontal earth-rate component (ignored by drop-format's omega_z) gives terms at
    the table frequency that average out over whole revolutions (to < 1e-7 of the centripetal)."""
    R, w = 0.7102845, 5.0
    period = 2 * np.pi / w
    t = np.linspace(0, period, 64, endpoint=False) + 0.01
    full = centrifuge_reference(plane="IA-PA", phi_deg=0, vertical="+OA", sense="ccw", R=R, t=t,
                                alpha_fn=lambda tt: w * tt, earth_vector=True, h=1e-3)
    vert = centrifuge_reference(plane="IA-PA", phi_deg=0, vertical="+OA", sense="ccw", R=R, t=t,
                                alpha_fn=lambda tt: w * tt, h=1e-3)
    diff = full - vert
    assert np.abs(diff).max() > 1e-4                      # instantaneous: visible (~2 w Omega_h R)
    assert np.abs(diff.mean(axis=0)).max() < 1e-7 * w * w * R


# ----------------------------------------------------------------- tumble, tilt_rotation
HEADS = [("PA", "+IA", "+OA"), ("PA", "+OA", "-IA"), ("OA", "+IA", "-PA"), ("IA", "-PA", "+OA"),
         ("IA", "+OA", "+PA")]


@pytest.mark.parametrize("head,cos_axis,sin_axis", HEADS)
def test_tumble(head, cos_axis, sin_axis):
    from accelcal.physics import specific_force
    theta0 = 1.5e-3
    th = np.radians(np.arange(0, 360, 15.0))
    ic, sc = signed(cos_axis)
    is_, ss = signed(sin_axis)
    c = np.zeros(3); c[ic] = sc
    s = np.zeros(3); s[is_] = ss
    n = np.cross(c, s)                      # the head axis (horizontal), about which we turn
    assert abs(n[AX[head]]) == 1.0
    ref = []
    for a in th + theta0:
        # up, seen from the instrument, turns about the head axis from cos_axis towards sin_axis
        up = Rot(n, a) @ c
        ref.append(G * up)
    meta = {"test": "tumble", "g_local_m_s2": G, "head_axis": head, "cos_axis": cos_axis, "sin_axis": sin_axis}
    got = specific_force("tumble", meta, pd.DataFrame({"time_s": np.arange(th.size) * 40.0,
                                                       "angle_deg": np.degrees(th)}),
                         {"initial_misalignment": theta0})
    np.testing.assert_allclose(got, np.array(ref), atol=1e-12)


def test_tilt_rotation():
    from accelcal.physics import specific_force
    gamma0, c_tilt, drift, tide = np.radians(0.45), 2e-7, 1e-10, 2e-7
    t = np.array([0.0, 3600.0, 20000.0, 44712.0 / 4, 60000.0])
    theta = np.radians(np.array([0.0, 30.0, 90.0, 210.0, 300.0]))
    temp = np.array([20.3, 25.3, 30.3, 35.3, 40.3])
    ref = []
    for tt, th, T in zip(t, theta, temp):
        gamma = gamma0 + drift * tt + tide * np.sin(2 * np.pi * tt / 44712.0)
        C = Ry(gamma) @ Rz(th)              # table frame in the level frame
        up_T = C.T @ np.array([0, 0, 1.0])
        # instrument axes in table coordinates: sin_axis = +IA = y_T, cos_axis = +PA = -x_T,
        # normal = +OA = z_T; then IA tilts towards the normal by c (T - 20)
        d = c_tilt * (T - 20.0)
        ia = np.cos(d) * np.array([0, 1.0, 0]) + np.sin(d) * np.array([0, 0, 1.0])
        oa = np.cos(d) * np.array([0, 0, 1.0]) - np.sin(d) * np.array([0, 1.0, 0])
        pa = np.array([-1.0, 0, 0])
        ref.append(G * np.array([ia @ up_T, pa @ up_T, oa @ up_T]))
    meta = {"test": "tilt_rotation", "g_local_m_s2": G, "tilt_deg": 0.45, "sin_axis": "+IA",
            "cos_axis": "+PA", "normal_axis": "+OA", "positions": 12}
    data = pd.DataFrame({"time_s": t, "rotation_deg": np.degrees(theta), "temp_c": temp})
    got = specific_force("tilt_rotation", meta, data, {"fixture_thermal_tilt": c_tilt,
                                                       "base_tilt_drift": drift, "tilt_tide": tide})
    np.testing.assert_allclose(got, np.array(ref), atol=1e-12)


# ----------------------------------------------------------------- sensor_lag
@pytest.mark.parametrize("tau_over_dt", [0.05, 0.2, 1.0, 4.0])
def test_sampled_lag_frequency_response(tau_over_dt):
    """The recorded lag is the digital first-order lag at the DAQ's sample times: in steady
    state a sampled sinusoid comes out multiplied by (1 - a) / (1 - a e^{-i w dt}),
    a = exp(-dt / tau) (reference computed here from that transfer function, not from
    accelcal)."""
    from accelcal.physics.instrument import first_order_lag
    dt, f = 0.02, 2.0
    tau = tau_over_dt * dt
    t = np.arange(4000) * dt
    w = 2 * np.pi * f
    y = first_order_lag(np.sin(w * t), t, tau)
    a = np.exp(-dt / tau)
    H = (1 - a) / (1 - a * np.exp(-1j * w * dt))
    ref = np.imag(H * np.exp(1j * w * t))
    np.testing.assert_allclose(y[2000:], ref[2000:], atol=1e-12)
    # irregular sampling takes the same recursion step by step
    t2 = t + 1e-4 * np.sin(t)
    y2 = first_order_lag(np.sin(w * t2), t2, tau)
    a2 = np.exp(-np.diff(t2) / tau)
    ref2 = np.empty_like(t2)
    ref2[0] = 0.0
    for n in range(1, t2.size):
        ref2[n] = a2[n - 1] * ref2[n - 1] + (1 - a2[n - 1]) * np.sin(w * t2[n])
    np.testing.assert_allclose(y2, ref2, atol=1e-12)


@pytest.mark.parametrize("irregular", [False, True])
def test_lag_of_columns_side_by_side_is_the_lag_of_each(irregular):
    """Series side by side (n, k) are lagged each as alone, to the last bit: the Jacobian lags
    its exact columns in blocks, and a fit must not move with the block size."""
    from accelcal.physics.instrument import first_order_lag
    rng = np.random.default_rng(7)
    t = np.arange(3001) * 0.005
    if irregular:
        t = t + 1e-4 * np.sin(t)
    X = rng.standard_normal((t.size, 5)) * np.array([1.0, 1e-3, 1e3, 9.81, 1e-9])
    X[:, 1] = 0.25                                # a constant column (K0 at a constant K1)
    Y = first_order_lag(X, t, 0.0137)
    for k in range(X.shape[1]):
        assert np.array_equal(Y[:, k], first_order_lag(np.ascontiguousarray(X[:, k]), t, 0.0137))
        assert np.array_equal(first_order_lag(X[:, k], t, 0.0137), Y[:, k])   # a strided column
