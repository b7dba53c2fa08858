"""The instrument model, IEEE 1293 form in SI units (effects.md, "Instrument model").

    A = K0 + a_i + K2 a_i^2 + K3 a_i^3 + Koq a_i|a_i| + Kp a_p + Ko a_o
          + Kip a_i a_p + Kio a_i a_o + Kpo a_p a_o + Kpp a_p^2 + Koo a_o^2
    E = K1 * A

with temperature K0(T) = K0 + K0T (T - T_ref), K1(T) = K1 (1 + K1T (T - T_ref))
and bias drift K0 + d t (effect ``bias_drift``).  a_* in m/s^2, E in output_unit.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..constants import T_REF_C

#: Coefficient names of the model with their default (ideal instrument) values.
DEFAULTS = {"K0": 0.0, "K1": 1.0, "K2": 0.0, "K3": 0.0, "Koq": 0.0, "Kp": 0.0, "Ko": 0.0,
            "Kip": 0.0, "Kio": 0.0, "Kpo": 0.0, "Kpp": 0.0, "Koo": 0.0, "K0T": 0.0, "K1T": 0.0}


#: |specific force| [m/s^2] below which a term of A whose coefficient is 0 is exactly +-0:
#: a product of up to three such factors stays finite (< 1e300), and 0 times it is +-0
_SKIP_BELOW = 1e100


#: The terms of A after K0 + a_i, in the order of effects.md's sum, each as its
#: coefficient times its factors, multiplied left to right as written there (K a_i a_p is
#: (K a_i) a_p: :data:`COEFFICIENT_TERMS` gives the factors alone, rounded otherwise).
_TERMS = (
    ("K2", lambda K, ai, ap, ao: K * ai**2),
    ("K3", lambda K, ai, ap, ao: K * ai**3),
    ("Koq", lambda K, ai, ap, ao: K * ai * np.abs(ai)),
    ("Kp", lambda K, ai, ap, ao: K * ap),
    ("Ko", lambda K, ai, ap, ao: K * ao),
    ("Kip", lambda K, ai, ap, ao: K * ai * ap),
    ("Kio", lambda K, ai, ap, ao: K * ai * ao),
    ("Kpo", lambda K, ai, ap, ao: K * ap * ao),
    ("Kpp", lambda K, ai, ap, ao: K * ap**2),
    ("Koo", lambda K, ai, ap, ao: K * ao**2),
)


def _sum_terms(c: Mapping[str, float], ai: np.ndarray, ap: np.ndarray, ao: np.ndarray,
               skip_zero: bool) -> np.ndarray:
    """A of :func:`indicated_acceleration` without the K0T and drift terms: the terms added
    one by one, left to right (the same operations, in the same order, as the written-out
    sum of effects.md).  With ``skip_zero``, a term whose coefficient is 0 is left out (the
    fits evaluate the model thousands of times per campaign, mostly at coefficients that
    are 0).

    Leaving them out is exact when every factor is finite and below :data:`_SKIP_BELOW`
    (the caller checks) and K0 is not -0: a term of coefficient +-0 is then +-0, and adding
    +-0 to a partial sum s leaves s unchanged unless s is -0; K0 + a_i is not -0 unless K0
    is, and a sum s + t with s not -0 is not -0 either (IEEE 754, rounding to nearest), so
    no partial sum ever is."""
    A = c["K0"] + ai
    for name, term in _TERMS:
        K = c[name]
        if skip_zero and K == 0.0:
            continue
        A = A + term(K, ai, ap, ao)
    return A


def indicated_acceleration(coeffs: Mapping[str, float], f: np.ndarray,
                           temp_c: np.ndarray | None = None,
                           time_s: np.ndarray | None = None,
                           bias_drift: float = 0.0) -> np.ndarray:
    """Indicated acceleration of the instrument model (effects.md, IEEE 1293 form).

    .. math::

        A = K_0 + K_{0T}(T - T_{ref}) + d\\,t + a_i + K_2 a_i^2 + K_3 a_i^3 + K_{oq} a_i |a_i|
            + K_p a_p + K_o a_o + K_{ip} a_i a_p + K_{io} a_i a_o + K_{po} a_p a_o
            + K_{pp} a_p^2 + K_{oo} a_o^2

    (He & Yin 2017, paper 000 eq 1, with the odd quadratic and cubic of effects.md).

    Parameters
    ----------
    coeffs : mapping
        Coefficients [SI, effects.md units]; absent ones are 0 (K1 is not used here).
    f : (..., 3) ndarray
        Specific force on (IA, PA, OA) [m/s2].
    temp_c : ndarray, optional
        Temperature T [degC] (K0T only; the scale-factor TC belongs to K1(T), :func:`output`).
    time_s : ndarray, optional
        Time t [s] (``bias_drift``).
    bias_drift : float
        d [m/s2/s].

    Returns
    -------
    ndarray
        A [m/s2].
    """
    c = dict(DEFAULTS)
    for k, v in coeffs.items():
        if k in DEFAULTS:
            c[k] = float(v)
    ai, ap, ao = f[..., 0], f[..., 1], f[..., 2]
    skip_zero = bool(any(c[name] == 0.0 for name, _ in _TERMS)
                     and (c["K0"] != 0.0 or math.copysign(1.0, c["K0"]) > 0.0)
                     and f.size and np.maximum.reduce(np.abs(f), axis=None) < _SKIP_BELOW)
    A = _sum_terms(c, ai, ap, ao, skip_zero)
    if temp_c is not None and c["K0T"] != 0.0:
        A = A + c["K0T"] * (np.asarray(temp_c, float) - T_REF_C)
    if time_s is not None and bias_drift != 0.0:
        A = A + bias_drift * np.asarray(time_s, float)
    return A


#: The term each additive coefficient multiplies in A (effects.md instrument model), as a
#: function of the specific force columns (a_i, a_p, a_o) [m/s^2]: dA/dK, the term of
#: :data:`_TERMS` at K = 1 (exact: a product with 1.0 rounds nothing).
COEFFICIENT_TERMS = {"K0": lambda ai, ap, ao: np.ones_like(ai),
                     **{name: (lambda ai, ap, ao, term=term: term(1.0, ai, ap, ao)) for name, term in _TERMS}}


def output_derivative(name: str, coeffs: Mapping[str, float], f: np.ndarray,
                      temp_c: np.ndarray | None = None, time_s: np.ndarray | None = None,
                      bias_drift: float = 0.0) -> np.ndarray:
    """dE/dK of :func:`output` for one instrument coefficient, exactly.

    Parameters
    ----------
    name : str
        K0, K1, K2, K3, Koq, Kp, Ko, Kip, Kio, Kpo, Kpp, Koo, K0T or K1T (effects.md).
    coeffs : mapping
        The coefficients at which to differentiate [SI].
    f : (n, 3) ndarray
        Specific force on (IA, PA, OA) [m/s^2].
    temp_c, time_s : ndarray, optional
        As for :func:`output`.

    Returns
    -------
    ndarray
        [output_unit per unit of the coefficient].  E = K1(T) A is linear in every additive
        coefficient (dE/dK = K1(T) dA/dK), in K0T (K1(T) (T - T_ref)) and bilinear in K1 and
        K1T; no term of this derivative is approximate.
    """
    ai, ap, ao = f[..., 0], f[..., 1], f[..., 2]
    K1T_ = scale_factor(coeffs, temp_c)
    if name in COEFFICIENT_TERMS:
        return K1T_ * COEFFICIENT_TERMS[name](ai, ap, ao)
    if name in ("K0T", "K1T") and temp_c is None:      # no temperature: no temperature term
        return np.zeros_like(ai)
    if name == "K0T":
        return K1T_ * (np.asarray(temp_c, float) - T_REF_C)
    A = indicated_acceleration(coeffs, f, temp_c, time_s, bias_drift)
    if name == "K1":
        K1 = float(coeffs.get("K1", 1.0))
        return (K1T_ / K1) * A if K1 != 0 else A * 0.0
    if name == "K1T":
        return float(coeffs.get("K1", 1.0)) * (np.asarray(temp_c, float) - T_REF_C) * A
    raise KeyError(f"{name!r} is not an instrument coefficient")


def scale_factor(coeffs: Mapping[str, float], temp_c: np.ndarray | None = None) -> np.ndarray | float:
    """Scale factor at temperature (effects.md temperature model).

    .. math::

        K_1(T) = K_1 (1 + K_{1T} (T - T_{ref})), \\quad T_{ref} = 20\\,^\\circ C

    Parameters
    ----------
    coeffs : mapping
        K1 [output_unit/(m/s2)], K1T [1/degC].
    temp_c : ndarray, optional
        T [degC].

    Returns
    -------
    ndarray or float
        K1(T) [output_unit/(m/s2)] (Zhang et al. 2021, paper 001, temperature model).
    """
    K1 = float(coeffs.get("K1", 1.0))
    K1T = float(coeffs.get("K1T", 0.0))
    if temp_c is None or K1T == 0.0:
        return K1
    return K1 * (1.0 + K1T * (np.asarray(temp_c, float) - T_REF_C))


def output(coeffs: Mapping[str, float], f: np.ndarray, temp_c=None, time_s=None,
           bias_drift: float = 0.0) -> np.ndarray:
    """Instrument output E = K1(T) A (effects.md).

    Parameters
    ----------
    coeffs : mapping
        Coefficients [SI].
    f : (..., 3) ndarray
        Specific force on (IA, PA, OA) [m/s2].
    temp_c, time_s, bias_drift
        As for :func:`indicated_acceleration`.

    Returns
    -------
    ndarray
        E [output_unit].
    """
    return scale_factor(coeffs, temp_c) * indicated_acceleration(coeffs, f, temp_c, time_s, bias_drift)


def first_order_lag(x: np.ndarray, time_s: np.ndarray, tau: float) -> np.ndarray:
    """The recorded output of a first-order lag with time constant tau (effect ``sensor_lag``).

    A DAQ record of a lagged output is the digital first-order lag at its own sample times:

        y[n] = a_n y[n-1] + (1 - a_n) x[n],   a_n = exp(-(t_n - t_{n-1}) / tau),   y[0] = x[0]

    (exponential smoothing; the exact response of tau y' = x - y to an input that takes the
    value x[n] over (t_{n-1}, t_n]).  For slow inputs it delays them by
    D = dt a / (1 - a), i.e. tau - dt/2 for tau >> dt and almost nothing for tau << dt, and it
    attenuates them by a further omega^2 D dt / 2 that a continuous lag of the same delay
    does not: the data tell the two forms apart.  Data of an independent reference
    simulator (``../shared/diagnosis-dev``, ``sine-lag-*``) follow this form to the noise,
    and reject the continuous one.

    ``x`` may be (n,) or (n, k): k series filtered at once along the time axis.

    Parameters
    ----------
    x : ndarray
        Input series [any unit], (n,) or (n, k).
    time_s : ndarray
        Sample times [s].
    tau : float
        Time constant [s]; tau <= 0 returns a copy of x.

    Returns
    -------
    ndarray
        y [unit of x].
    """
    x = np.asarray(x, float)
    if tau <= 0.0 or x.size == 0:
        return x.copy()
    t = np.asarray(time_s, float)
    dts = np.diff(t)
    if x.shape[0] > 2 and dts.size and np.all(dts > 0) and np.ptp(dts) <= 1e-9 * dts[0]:
        from scipy.signal import lfilter
        a = math.exp(-float(dts.mean()) / tau)
        y, _ = lfilter([1.0 - a], [1.0, -a], x[1:], axis=0, zi=(a * x[:1]))
        return np.concatenate([x[:1], y])
    y = np.empty_like(x)
    y[0] = x[0]
    for n in range(1, x.shape[0]):
        a = math.exp(-max(t[n] - t[n - 1], 0.0) / tau)
        y[n] = a * y[n - 1] + (1.0 - a) * x[n]
    return y
