"""Rig kinematics: the specific force each instrument axis senses on each rig,
nominal (drop-format.md) and with the rig effects of effects.md.

This is *the* forward model of accelcal: the simulator, the estimators and the
diagnosis all call it.  Inputs are a run's typed metadata (``meta``, as parsed
from the drop) and its columns (``data``: a DataFrame or mapping of arrays named
as in drop-format.md).  ``effects`` maps effect ids (effects.md) to their
parameter; an effect that is absent is not there.  The drop format's nominal
input includes the earth rate: pass ``NOMINAL`` (``{"earth_rate": 1.0}``) for it.

Frames. For the centrifuges, (e1, e2) are the first and second plane axes, "up"
the vertical axis direction, u the unit vector from the instrument towards the
spindle (angle phi from e1 towards e2).  A point at p (from the spindle, in the
table plane) on a table turning at omega_z about the vertical has acceleration
omega_z' z x p - omega_z^2 p; the specific force is that minus gravity, i.e.
plus g on "up".
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from functools import lru_cache

import numpy as np

from ..constants import M2_PERIOD_S, OMEGA_EARTH, T_REF_C
from ..effects import EFFECTS
from .geometry import CentrifugeMount, geometry_of, rotation_sign
from .instrument import first_order_lag, output

#: The drop format's nominal input: everything nominal, earth rate included.
NOMINAL: dict[str, float] = {"earth_rate": 1.0}

#: Effects that are instrument coefficients (the catalogue's ``Effect.coefficient``):
#: effect id -> coefficient name.
INSTRUMENT_EFFECTS = {e.id: e.coefficient for e in EFFECTS.values() if e.coefficient}


def _col(data, name, n=None, default=0.0) -> np.ndarray:
    try:
        v = data[name]
    except (KeyError, IndexError):
        return np.full(n if n is not None else 0, default, float)
    return np.asarray(v, dtype=float)


def _n(data) -> int:
    """Number of rows of a DataFrame or of a mapping of equal-length arrays."""
    if hasattr(data, "shape") and hasattr(data, "columns"):
        return int(data.shape[0])
    for k in ("time_s", "output"):
        try:
            return len(data[k])
        except (KeyError, TypeError):
            pass
    return len(next(iter(data.values())))


def omega_z(meta: Mapping, rate: np.ndarray, effects: Mapping[str, float] | None = None) -> np.ndarray:
    """Inertial rate of the table about the vertical.

    .. math::

        \\omega_z = s (1 + \\varepsilon) \\omega + k \\Omega_e \\sin \\Phi

    Parameters
    ----------
    meta : mapping
        ``rotation_sense`` (s), ``site_latitude_deg`` (Phi [deg]).
    rate : ndarray
        Logged table rate omega [rad/s].
    effects : mapping, optional
        ``rate_scale_error`` epsilon [1] and ``earth_rate`` k [1] (effects.md; absent = 0).

    Returns
    -------
    ndarray
        omega_z [rad/s], Omega_e = 7.292115e-5 rad/s (drop-format.md; He & Yin 2017, paper 000
        eq 6 carries the same earth-rate term).
    """
    effects = effects or {}
    eps = float(effects.get("rate_scale_error", 0.0))
    scale = float(effects.get("earth_rate", 0.0))
    return (rotation_sign(meta) * (1.0 + eps) * np.asarray(rate, float)
            + scale * OMEGA_EARTH * _sin_latitude(float(meta["site_latitude_deg"])))


def _sin_latitude(lat_deg: float) -> np.float64:
    """sin(Phi) of a site latitude Phi [deg], as :func:`omega_z` computes it (a few sites,
    many calls); 0 and -0 (equal keys, different sines) are not memoised."""
    if lat_deg == 0.0:
        return np.sin(np.radians(lat_deg))
    return _sin_latitude_memo(lat_deg)


@lru_cache(maxsize=256)
def _sin_latitude_memo(lat_deg: float) -> np.float64:
    return np.sin(np.radians(lat_deg))


def sine_drive(meta: Mapping, time_s: np.ndarray) -> np.ndarray:
    """Commanded rate of the sinusoidal drive (Sun, Ren & Wang, paper 002).

    .. math::

        \\omega(t) = \\Omega \\sin(2 \\pi f t)

    Parameters
    ----------
    meta : mapping
        ``rate_amplitude_rad_s`` (Omega [rad/s]), ``rate_frequency_hz`` (f [Hz]).
    time_s : ndarray
        Time [s].

    Returns
    -------
    ndarray
        Table rate [rad/s], unsigned (the rotation sense is applied by :func:`omega_z`).
    """
    Om, f = float(meta["rate_amplitude_rad_s"]), float(meta["rate_frequency_hz"])
    return Om * np.sin(2 * np.pi * f * np.asarray(time_s, float))


def sine_drive_angle(meta: Mapping, time_s: np.ndarray) -> np.ndarray:
    """Table angle of the sinusoidal drive, the integral of :func:`sine_drive` from 0.

    .. math::

        \\theta(t) = \\frac{\\Omega}{2 \\pi f} (1 - \\cos(2 \\pi f t))

    Parameters
    ----------
    meta : mapping
        ``rate_amplitude_rad_s`` [rad/s], ``rate_frequency_hz`` [Hz].
    time_s : ndarray
        Time [s].

    Returns
    -------
    ndarray
        Table angle [deg].
    """
    Om, f = float(meta["rate_amplitude_rad_s"]), float(meta["rate_frequency_hz"])
    t = np.asarray(time_s, float)
    return np.degrees(Om / (2 * np.pi * f) * (1.0 - np.cos(2 * np.pi * f * t)))


def centripetal_level(meta: Mapping, rate: np.ndarray, radius_m: float) -> np.ndarray:
    """Centripetal acceleration at the arm radius, omega_z^2 R, with the earth rate in
    omega_z (paper 000 §2.1: the g level of a centrifuge dwell).

    Parameters
    ----------
    meta : mapping
        Run metadata (``rotation_sense``, ``latitude_deg``: :func:`omega_z`).
    rate : ndarray
        Table rate [rad/s].
    radius_m : float
        Arm radius [m].

    Returns
    -------
    ndarray
        [m/s2].
    """
    return omega_z(meta, rate, {"earth_rate": 1.0}) ** 2 * radius_m


def sine_rate_derivative(meta: Mapping, time_s: np.ndarray, effects: Mapping[str, float] | None = None) -> np.ndarray:
    """Angular acceleration of the sinusoidal drive.

    .. math::

        \\dot\\omega_z = s (1 + \\varepsilon) \\Omega \\, 2 \\pi f \\cos(2 \\pi f t)

    Parameters
    ----------
    meta : mapping
        ``rate_amplitude_rad_s`` (Omega [rad/s]), ``rate_frequency_hz`` (f [Hz]),
        ``rotation_sense``.
    time_s : ndarray
        Time [s].
    effects : mapping, optional
        ``rate_scale_error`` epsilon [1].

    Returns
    -------
    ndarray
        [rad/s2], signed like omega_z (Sun, Ren & Wang, paper 002: drive
        omega = Omega sin(2 pi f t)).
    """
    effects = effects or {}
    eps = float(effects.get("rate_scale_error", 0.0))
    Om, f = float(meta["rate_amplitude_rad_s"]), float(meta["rate_frequency_hz"])
    return rotation_sign(meta) * (1.0 + eps) * Om * 2 * np.pi * f * np.cos(2 * np.pi * f * np.asarray(time_s, float))


def centrifuge_specific_force(meta: Mapping, data, effects: Mapping[str, float] | None = None, *,
                              radius_m: float | None = None,
                              rate_derivative: np.ndarray | None = None,
                              geometry: CentrifugeMount | None = None) -> np.ndarray:
    """Specific force on the instrument axes of a centrifuge run.

    .. math::

        \\mathbf f = -\\omega_z^2 \\mathbf p + h \\dot\\omega_z \\, \\hat z \\times \\mathbf p + g \\, \\widehat{up},
        \\quad \\mathbf p = -R(1 + \\kappa \\omega_z^2) \\mathbf u(\\varphi + \\Delta\\varphi) + r \\mathbf e_1

    (u the unit vector towards the spindle at the mount angle, e1 the first plane axis;
    centripetal, tangential and gravity terms of drop-format.md; He & Yin 2017, paper 000
    §2.2 for the mass-centre geometry; Sun, Ren & Wang, paper 002 for the tangential term).

    Parameters
    ----------
    meta : mapping
        Typed run metadata (``g_local_m_s2`` [m/s2], mount geometry, ``arm_radius_m`` [m],
        ``rotation_sense``, ``site_latitude_deg`` [deg]; sine: ``rate_amplitude_rad_s``,
        ``rate_frequency_hz``).
    data : DataFrame or mapping
        ``table_rate_rad_s`` [rad/s], ``time_s`` [s], ``table_angle_deg`` [deg] (spindle tilt).
    effects : mapping, optional
        earth_rate [1], rate_scale_error [1], mount_angle_error [rad], mass_centre_offset [m],
        arm_stretch [s2], ia_tilt [rad], spindle_tilt [rad] (effects.md definitions and signs;
        spindle_tilt with both its radial and its tangential part).
    radius_m : float or (m, 1) ndarray, optional
        Spindle to fixture turning centre [m] (default ``arm_radius_m``).  An (m, 1) column,
        like ``mount_angle_error`` and ``mass_centre_offset`` in ``effects``
        (:data:`POINT_COLUMNS`), evaluates m parameter points at once: row k of the
        result is, element for element, the result at the k-th values (the same operations;
        a fit's finite differences ask for many points of one run).
    rate_derivative : ndarray, optional
        d(omega_z)/dt per row [rad/s2]; default 0 for ``centrifuge`` and
        :func:`sine_rate_derivative` for ``sine_centrifuge``.
    geometry : CentrifugeMount, optional
        ``geometry_of(meta)``, where the caller holds it (a fit evaluates the model
        thousands of times per campaign).

    Returns
    -------
    (n, 3) or (m, n, 3) ndarray
        Specific force on (IA, PA, OA) [m/s2]; (m, n, 3) for m parameter points.
    """
    effects = effects or {}
    n = _n(data)
    g = float(meta["g_local_m_s2"])
    geo = geometry_of(meta) if geometry is None else geometry
    e1, e2, v, vs, h = geo.e1, geo.e2, geo.vertical, geo.vertical_sign, geo.handedness
    R0 = geo.arm_radius_m if radius_m is None else _point_value(radius_m)
    phi = geo.phi_rad + _point_value(effects.get("mount_angle_error", 0.0))
    r = _point_value(effects.get("mass_centre_offset", 0.0))
    kappa = float(effects.get("arm_stretch", 0.0))
    lam = float(effects.get("ia_tilt", 0.0))
    beta = float(effects.get("spindle_tilt", 0.0))

    wz = omega_z(meta, _col(data, "table_rate_rad_s", n), effects)
    if rate_derivative is None and str(meta.get("test")) == "sine_centrifuge" and "rate_amplitude_rad_s" in meta:
        rate_derivative = sine_rate_derivative(meta, _col(data, "time_s", n), effects)
    # none: 0 on every row, where a scalar 0 makes every product and sum below the same,
    # element for element, as a column of zeros would (the fits evaluate this model
    # thousands of times per campaign)
    wdot = 0.0 if rate_derivative is None else np.asarray(rate_derivative, float)

    w2 = wz**2
    # without arm stretch, R0 (1 + 0 w_z^2) is R0 on every row where w_z^2 is finite (then the
    # sum of the w_z^2 >= 0 is finite too)
    R = R0 if kappa == 0.0 and math.isfinite(np.add.reduce(w2)) else R0 * (1.0 + kappa * w2)
    ux, uy = np.cos(phi), np.sin(phi)
    # position of the effective mass centre from the spindle, in (e1, e2) coordinates
    p1 = -R * ux + r
    p2 = -R * uy
    nw2 = -w2
    f1 = nw2 * p1 + wdot * h * (-p2)
    f2 = nw2 * p2 + wdot * h * p1
    fup = g * np.cos(beta)          # the same value on every row
    if beta != 0.0:
        # effects.md spindle_tilt: g sin(beta) cos(alpha) along the inward radial u and
        # g sin(beta) sin(alpha) along the ccw direction of motion h (sin phi e1 - cos phi e2)
        alpha = np.radians(np.nan_to_num(_col(data, "table_angle_deg", n)))
        gr = g * np.sin(beta) * np.cos(alpha)
        gt = g * np.sin(beta) * np.sin(alpha)
        f1 = f1 + gr * ux + gt * h * uy
        f2 = f2 + gr * uy - gt * h * ux
    if lam != 0.0:
        f1, fup = f1 * np.cos(lam) + fup * np.sin(lam), fup * np.cos(lam) - f1 * np.sin(lam)
    F = np.zeros(np.broadcast_shapes(np.shape(f1), np.shape(f2)) + (3,))
    F[..., e1] = f1
    F[..., e2] = f2
    F[..., v] = vs * fup
    return F


#: Test kind -> the effects (and ``radius``, the ``radius_m`` keyword) whose value its
#: specific force takes as an (m, 1) column of m parameter points: each enters by
#: elementwise operations alone, so row k of the result is computed as the k-th scalar
#: would be (:func:`centrifuge_specific_force`, :func:`tumble_specific_force`).
POINT_COLUMNS = {"centrifuge": frozenset({"radius", "mount_angle_error", "mass_centre_offset"}),
                 "sine_centrifuge": frozenset({"radius", "mount_angle_error", "mass_centre_offset"}),
                 "tumble": frozenset({"initial_misalignment"})}


def _point_value(v) -> float | np.ndarray:
    """A parameter value as the specific forces compute with it: a float, or an (m, 1)
    float array of m parameter points (:data:`POINT_COLUMNS`)."""
    return np.asarray(v, float) if isinstance(v, np.ndarray) and v.ndim else float(v)


def tumble_specific_force(meta: Mapping, data, effects: Mapping[str, float] | None = None) -> np.ndarray:
    """Specific force on the instrument axes of a dividing-head tumble.

    .. math::

        f_{cos} = g \\cos(\\theta + \\theta_0), \\quad f_{sin} = g \\sin(\\theta + \\theta_0), \\quad f_{head} = 0

    (drop-format.md; Zhan & Cai, paper 003).

    Parameters
    ----------
    meta : mapping
        ``g_local_m_s2`` [m/s2], ``head_axis``, ``cos_axis``, ``sin_axis`` (signed axes).
    data : DataFrame or mapping
        ``angle_deg``: head angle theta [deg].
    effects : mapping, optional
        ``initial_misalignment`` theta0 [rad]; an (m, 1) column evaluates m values at once
        (:data:`POINT_COLUMNS`).

    Returns
    -------
    (n, 3) or (m, n, 3) ndarray
        Specific force on (IA, PA, OA) [m/s2]; (m, n, 3) for m parameter points.
    """
    effects = effects or {}
    n = _n(data)
    g = float(meta["g_local_m_s2"])
    th = np.radians(_col(data, "angle_deg", n)) + _point_value(effects.get("initial_misalignment", 0.0))
    head = geometry_of(meta)
    F = np.zeros(th.shape + (3,))
    F[..., head.cos_axis] = head.cos_sign * g * np.cos(th)
    F[..., head.sin_axis] = head.sin_sign * g * np.sin(th)
    return F


def tilt_rotation_specific_force(meta: Mapping, data, effects: Mapping[str, float] | None = None) -> np.ndarray:
    """Specific force on the instrument axes of a tilted rotary table.

    .. math::

        f_{sin} = g \\sin\\gamma \\sin\\theta, \\quad f_{cos} = g \\sin\\gamma \\cos\\theta,
        \\quad f_{normal} = g \\cos\\gamma

    (drop-format.md; Zhang et al. 2021, paper 001).

    Parameters
    ----------
    meta : mapping
        ``g_local_m_s2`` [m/s2], ``tilt_deg`` (gamma [deg]), ``sin_axis``, ``cos_axis``,
        ``normal_axis``.
    data : DataFrame or mapping
        ``rotation_deg`` (theta [deg]), ``time_s`` [s], ``temp_c`` [degC].
    effects : mapping, optional
        base_tilt_drift [rad/s] (gamma += dgamma/dt t), tilt_tide [rad]
        (gamma += A sin(2 pi t / M2)), fixture_thermal_tilt [rad/degC] (IA tilts towards the
        normal axis by c (T - T_ref)).

    Returns
    -------
    (n, 3) ndarray
        Specific force on (IA, PA, OA) [m/s2].
    """
    effects = effects or {}
    n = _n(data)
    g = float(meta["g_local_m_s2"])
    t = _col(data, "time_s", n)
    tab = geometry_of(meta)
    gamma = (tab.gamma_rad + float(effects.get("base_tilt_drift", 0.0)) * t
             + float(effects.get("tilt_tide", 0.0)) * np.sin(2 * np.pi * t / M2_PERIOD_S))
    th = np.radians(_col(data, "rotation_deg", n))
    si, ss, ci, cs = tab.sin_axis, tab.sin_sign, tab.cos_axis, tab.cos_sign
    ni, ns = tab.normal_axis, tab.normal_sign
    F = np.zeros((n, 3))
    F[:, si] = ss * g * np.sin(gamma) * np.sin(th)
    F[:, ci] = cs * g * np.sin(gamma) * np.cos(th)
    F[:, ni] = ns * g * np.cos(gamma)
    c = float(effects.get("fixture_thermal_tilt", 0.0))
    if c != 0.0 and ni != 0:
        delta = np.nan_to_num(c * (_col(data, "temp_c", n, np.nan) - T_REF_C))
        a_ia = F[:, 0].copy()
        a_n = ns * F[:, ni]                       # along the signed normal direction
        F[:, 0] = a_ia * np.cos(delta) + a_n * np.sin(delta)
        F[:, ni] = ns * (a_n * np.cos(delta) - a_ia * np.sin(delta))
    return F


def specific_force(test: str, meta: Mapping, data, effects: Mapping[str, float] | None = None,
                   **kw) -> np.ndarray:
    """Specific force of any run: dispatch on the test kind.

    Parameters
    ----------
    test : str
        'centrifuge', 'sine_centrifuge', 'tumble' or 'tilt_rotation'.
    meta, data, effects, **kw
        As for :func:`centrifuge_specific_force`, :func:`tumble_specific_force`,
        :func:`tilt_rotation_specific_force` (``kw`` for the centrifuges only: a tumble's or a
        tilt table's geometry is looked up from ``meta``).

    Returns
    -------
    (n, 3) ndarray
        Specific force on (IA, PA, OA) [m/s2].
    """
    if test in ("centrifuge", "sine_centrifuge"):
        return centrifuge_specific_force(meta, data, effects, **kw)
    if test == "tumble":
        return tumble_specific_force(meta, data, effects)
    if test == "tilt_rotation":
        return tilt_rotation_specific_force(meta, data, effects)
    raise ValueError(f"unknown test kind {test!r}")


def instrument_coefficients(coeffs: Mapping[str, float], effects: Mapping[str, float]) -> dict[str, float]:
    """The instrument coefficients with the instrument-term effects added to theirs.

    Parameters
    ----------
    coeffs : mapping
        Instrument coefficients [SI, effects.md units].
    effects : mapping
        effects.md id -> parameter; odd_quadratic, cubic, cross_coupling, bias_temperature
        and scale_temperature add to Koq, K3, Kip, K0T, K1T (:data:`INSTRUMENT_EFFECTS`).

    Returns
    -------
    dict
        The coefficients the instrument model (effects.md) sees.
    """
    c = dict(coeffs)
    for eid, name in INSTRUMENT_EFFECTS.items():
        if eid in effects:
            c[name] = float(c.get(name, 0.0)) + float(effects[eid])
    return c


def rig_output(test: str, meta: Mapping, data, coeffs: Mapping[str, float],
               effects: Mapping[str, float] | None = None, **kw) -> np.ndarray:
    """Noise-free instrument output of a run: the one forward model.

    .. math::

        E = K_1(T) \\, A(\\mathbf f), \\quad \\mathbf f = \\text{specific force of the rig}

    with A the effects.md instrument model (:func:`accelcal.physics.instrument.output`)
    and f from :func:`specific_force`.

    Parameters
    ----------
    test : str
        Test kind.
    meta : mapping
        Typed run metadata.
    data : DataFrame or mapping
        The run's columns (drop-format.md); ``temp_c`` [degC] feeds K0T, K1T.
    coeffs : mapping
        Instrument coefficients [SI, effects.md units].
    effects : mapping, optional
        effects.md id -> parameter; instrument-term effects (odd_quadratic, cubic,
        cross_coupling, bias_temperature, scale_temperature) add to their coefficient;
        ``sensor_lag`` [s] lags the output, ``bias_drift`` [m/s2/s] drifts K0.
    **kw
        Passed to :func:`specific_force` (``radius_m``, ``rate_derivative``, ``geometry``).

    Returns
    -------
    (n,) or (m, n) ndarray
        E [output_unit]; (m, n) for m parameter points given as (m, 1) columns
        (:data:`POINT_COLUMNS`), each row lagged on its own.
    """
    effects = dict(effects or {})
    c = instrument_coefficients(coeffs, effects)
    F = specific_force(test, meta, data, effects, **kw)
    n = F.shape[-2]
    # the temperature only enters through K0T and K1T (instrument.output): not read without them
    temp = None
    if ((float(c.get("K0T", 0.0)) != 0.0 or float(c.get("K1T", 0.0)) != 0.0)
            and "temp_c" in getattr(data, "keys", lambda: [])()):
        temp = _col(data, "temp_c", n, np.nan)
    if temp is not None:
        temp = np.where(np.isfinite(temp), temp, T_REF_C)
    t = _col(data, "time_s", n)
    E = output(c, F, temp, t, float(effects.get("bias_drift", 0.0)))
    tau = float(effects.get("sensor_lag", 0.0))
    if tau > 0.0:
        E = first_order_lag(E, t, tau) if E.ndim == 1 else first_order_lag(E.T, t, tau).T
    return E
