"""Measurement uncertainty: GUM law of propagation (JCGM 100:2008), the JCGM 101:2008
check of a linear budget by propagation of distributions, and paper 000's u(Kip) (§3.2,
eq 10).

A budget is linear in its inputs (every coefficient of the paper methods is, to first
order, JCGM 100 eq 10): one line per input with its sensitivity, in the input's own unit.

Distributions (by their standard uncertainty u, JCGM 101 §6.4):
  'normal'      N(x, u^2)
  'uniform'     rectangular, half-width a = sqrt(3) u            (JCGM 100 4.3.7)
  'triangular'  symmetric triangular, half-width a = sqrt(6) u   (JCGM 100 4.3.9)
  'arcsine'     U-shaped, half-width a = sqrt(2) u               (JCGM 101 6.4.6)
  't'           x + u * t_nu (JCGM 101 6.4.9, Type A with nu = n - 1 degrees of
                freedom; its standard deviation is u sqrt(nu / (nu - 2)))
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..effects import split_combination
from ..results import BudgetTerm
from ..fitting.distributions import norm_ppf

#: half-width / standard uncertainty of the bounded distributions.
HALF_WIDTH_PER_U = {"uniform": math.sqrt(3.0), "triangular": math.sqrt(6.0), "arcsine": math.sqrt(2.0)}
DISTRIBUTIONS = ("normal", "uniform", "triangular", "arcsine", "t")


def uniform_u(half_width: float) -> float:
    """Type B standard uncertainty of a rectangular distribution (JCGM 100 4.3.7, eq 7).

    Parameters
    ----------
    half_width : float
        a [any unit].

    Returns
    -------
    float
        u = |a| / sqrt(3) [unit of a].
    """
    return abs(float(half_width)) / math.sqrt(3.0)


@dataclass
class GumBudget:
    """Result of :func:`linear_budget`.  Unpacks as ``value, u_c, terms = linear_budget(...)``.

    value: y (output unit); u_c: combined standard uncertainty (JCGM 100 eq 10);
    terms: one :class:`BudgetTerm` per input (contribution = |c_i| u_i).
    """
    value: float
    u_c: float
    terms: list[BudgetTerm]

    def __iter__(self):
        return iter((self.value, self.u_c, self.terms))


def welch_satterthwaite(contributions: Sequence[float], dofs: Sequence[float]) -> float:
    """Welch–Satterthwaite effective degrees of freedom (JCGM 100 eq G.2b).

    .. math::

        \\nu_{eff} = \\frac{u_c^4}{\\sum_i u_i^4(y) / \\nu_i}, \\quad u_i(y) = |c_i| u(x_i)

    Parameters
    ----------
    contributions : sequence of float
        u_i(y) [unit of y].
    dofs : sequence of float
        nu_i; infinite ones (Type B taken as exactly known) contribute nothing.

    Returns
    -------
    float
        nu_eff (inf when every finite-dof contribution is zero).
    """
    ui = np.asarray(contributions, float)
    nu = np.asarray(dofs, float)
    uc4 = float((ui**2).sum()) ** 2
    fin = np.isfinite(nu) & (ui > 0)
    denom = float((ui[fin] ** 4 / nu[fin]).sum())
    return math.inf if denom == 0 else uc4 / denom


def linear_budget(coefficient: str, terms: Sequence[tuple], *, method: str = "", rig_id: str = "",
                  value: float | None = None) -> GumBudget:
    """GUM budget (JCGM 100 eq 10) of a coefficient that depends linearly on its inputs.

    Parameters
    ----------
    coefficient : str
        Its name (effects.md), e.g. ``'K2'``.
    terms : sequence of tuple
        (quantity, value, standard uncertainty, sensitivity c_i, type 'A'/'B', distribution)
        per input [input units; c_i in coefficient unit per input unit].  Inputs with zero
        uncertainty are kept (they document a correction).
    method, rig_id : str
        Written into every :class:`~accelcal.results.BudgetTerm`.
    value : float, optional
        The coefficient's value (default: the sum of c_i x_i).

    Returns
    -------
    GumBudget
        u_c = sqrt(sum (c_i u_i)^2) (uncorrelated inputs); terms carry ``method`` and ``rig_id``.
    """
    for t in terms:
        if t[5] not in DISTRIBUTIONS:
            raise ValueError(f"unknown distribution {t[5]!r}; known: {DISTRIBUTIONS}")
    vals = np.array([float(t[1]) for t in terms])
    us = np.array([float(t[2]) for t in terms])
    cs = np.array([float(t[3]) for t in terms])
    lines = [BudgetTerm(coefficient, str(t[0]), float(x), float(u), float(c), float(abs(c * u)), str(t[4]),
                        str(t[5]), method, rig_id) for t, x, u, c in zip(terms, vals, us, cs)]
    y = float(np.dot(cs, vals)) if value is None else float(value)
    return GumBudget(y, math.sqrt(max(float(((cs * us) ** 2).sum()), 0.0)), lines)


def numerical_tolerance(u: float, ndig: int = 2) -> float:
    """JCGM 101 7.9.2: write u with ndig significant digits as c x 10^l (c an ndig-digit
    integer); delta = 10^l / 2.  E.g. u = 0.0123, ndig = 2 -> c = 12, l = -3, delta = 0.0005."""
    u = abs(float(u))
    if u == 0 or not math.isfinite(u):
        return 0.0
    l = math.floor(math.log10(u)) - (ndig - 1)
    c = round(u / 10.0**l)
    if c >= 10**ndig:          # rounding carried into a new digit, e.g. 0.0999 -> 0.10
        l += 1
    return 0.5 * 10.0**l


def linear_output_interval(sensitivities: Sequence[float], std_uncertainties: Sequence[float],
                           distributions: Sequence[str], p: float = 0.95, points: int = 1 << 12
                           ) -> tuple[float, float, float]:
    """The probabilistically symmetric 100p % interval and the standard deviation of
    y = sum c_i x_i for independent inputs, by numerical convolution of their densities
    (propagation of distributions without sampling noise; JCGM 101 §5.4, valid for a linear
    model).  Inputs 'normal' or 'uniform' (or 'triangular'); returns (low, high, sd) of y - y0."""
    c = np.asarray(sensitivities, float)
    u = np.asarray(std_uncertainties, float)
    s = np.abs(c) * u
    dist = list(distributions)
    var_normal = float(sum(si * si for si, d in zip(s, dist) if d not in HALF_WIDTH_PER_U))
    sd = float(np.sqrt(np.sum(s * s)))
    if sd == 0:
        return 0.0, 0.0, 0.0
    half = 9.0 * sd + sum(HALF_WIDTH_PER_U[d] * si for si, d in zip(s, dist) if d in HALF_WIDTH_PER_U)
    h = 2.0 * half / points
    x = -half + h * np.arange(points)
    freq = np.fft.rfftfreq(points, h)
    w = 2 * np.pi * freq
    phi = np.exp(-0.5 * var_normal * w * w)            # characteristic function of the sum
    for si, d in zip(s, dist):
        if d == "uniform":
            phi = phi * np.sinc(HALF_WIDTH_PER_U["uniform"] * si * w / np.pi)
        elif d == "triangular":
            phi = phi * np.sinc(HALF_WIDTH_PER_U["triangular"] * si * w / (2 * np.pi)) ** 2
        elif d not in ("normal", "t"):
            raise ValueError(f"linear_output_interval: distribution {d!r} not supported")
    # density on the grid: inverse transform, centred
    dens = np.fft.irfft(phi * np.exp(1j * w * half), n=points) / h
    dens = np.clip(dens, 0, None)
    cdf = np.cumsum(dens) * h
    cdf /= cdf[-1]
    edge = x + h / 2                                   # the CDF of a bin is reached at its right edge
    lo = float(np.interp((1 - p) / 2, cdf, edge))
    hi = float(np.interp((1 + p) / 2, cdf, edge))
    return lo, hi, sd


def validate_gum_linear(sensitivities: Sequence[float], std_uncertainties: Sequence[float],
                        distributions: Sequence[str], p: float = 0.95, ndig: int = 2) -> dict:
    """JCGM 101 §8 validation of the GUM interval of a linear budget, against the interval
    of the propagated distribution (:func:`linear_output_interval`, no sampling noise, so a
    FAIL means the normal approximation itself is off, not the Monte Carlo).

    Returns dict: gum_u, gum_low/high (k = the normal quantile of p), low, high, delta,
    d_low, d_high, validated."""
    lo, hi, sd = linear_output_interval(sensitivities, std_uncertainties, distributions, p)
    k = float(norm_ppf((1 + p) / 2))
    delta = numerical_tolerance(sd, ndig)
    d_low, d_high = abs(-k * sd - lo), abs(k * sd - hi)
    return {"gum_u": sd, "gum_low": -k * sd, "gum_high": k * sd, "low": lo, "high": hi, "delta": delta,
            "d_low": d_low, "d_high": d_high, "validated": bool(d_low <= delta and d_high <= delta)}


def budget_check(method: str, rig_id: str, coefficient: str, value: float, terms: Sequence[BudgetTerm]) -> dict | None:
    """JCGM 101 §8 check of a linear budget, keyed and shaped as ``extras['mc_check']`` holds it.

    Parameters
    ----------
    method, rig_id, coefficient : str
        Which coefficient.
    value : float
        Its value [its unit].
    terms : sequence of BudgetTerm
        Its budget lines (sensitivity, standard uncertainty, distribution; those with u = 0
        are left out).

    Returns
    -------
    dict or None
        gum_u, mc_u, mc_low, mc_high (absolute), validated, delta, procedure: the GUM
        interval against the propagated distribution of the linear model, by numerical
        convolution (:func:`validate_gum_linear`; no sampling noise, so a FAIL is the normal
        approximation's, not the Monte Carlo's); None without an uncertain input.
    """
    use = [b for b in terms if b.std_uncertainty > 0]
    if not use or not math.isfinite(value):
        return None
    chk = validate_gum_linear([b.sensitivity for b in use], [b.std_uncertainty for b in use],
                              [b.distribution for b in use])
    return {"method": method, "rig_id": rig_id, "coefficient": coefficient, "gum_u": chk["gum_u"],
            "mc_u": chk["gum_u"], "mc_low": value + chk["low"], "mc_high": value + chk["high"],
            "validated": chk["validated"], "delta": chk["delta"],
            "procedure": "propagation of distributions by numerical convolution (linear budget, JCGM 101 5.4)"}


def kip_uncertainty(u_c2: float, u_dc2: float, u_K2: float, u_Kpp: float, u_dKpp: float, *,
                    rtol: float = 1e-9) -> dict:
    """u(Kip), paper 000 §3.2, all in s^2/m ((m/s^2)/(m/s^2)^2); inputs are standard
    uncertainties (Type B uniform ones already divided by sqrt(3), see :func:`uniform_u`).

    printed (paper 000 eq 10):  u = sqrt(2 (u^2(c2) + u^2(dc2)) + u^2(K2) + u^2(Kpp) + u^2(dKpp))
    GUM (JCGM 100 eq 10) on Kip = 2 (c2 + dc2) - (K2 + Kpp + dKpp) (paper 000 eq 3 with the
    corrections dc2 of eq 8 and dKpp): sensitivities 2, 2, -1, -1, -1, so
                                u = sqrt(4 (u^2(c2) + u^2(dc2)) + u^2(K2) + u^2(Kpp) + u^2(dKpp)).

    Returns dict: printed, gum, differ (True when they differ by more than rtol relative),
    ratio = gum / printed, budget (list of BudgetTerm, from :func:`linear_budget`), note.
    """
    us = np.array([u_c2, u_dc2, u_K2, u_Kpp, u_dKpp], float)
    printed = math.sqrt(2 * (us[0]**2 + us[1]**2) + us[2]**2 + us[3]**2 + us[4]**2)
    gb = linear_budget("Kip", [(name, 0.0, u, c, t, d) for name, u, c, t, d in zip(
        ("c2", "dc2", "K2", "Kpp", "dKpp"), us, (2.0, 2.0, -1.0, -1.0, -1.0), "ABAAB",
        ("normal", "uniform", "normal", "normal", "uniform"))])
    gum = gb.u_c
    differ = bool(abs(gum - printed) > rtol * max(gum, printed))
    return {"printed": printed, "gum": gum, "differ": differ,
            "ratio": gum / printed if printed > 0 else math.nan, "budget": gb.terms,
            "note": ("paper 000 eq 10 weights u(c2), u(dc2) by 2; the GUM sensitivity of Kip to c2 "
                     "is 2, so the factor is 4" if differ else "")}



#: Step of local gravity for a paper method's derivative [m/s²] (1e-4 relative: far above
#: the fits' convergence tolerance, far below any curvature of C(g)).
G_LOCAL_STEP = 1e-3


def _with_g(runs: Sequence, key: str, dg: float) -> list:
    """Copies of the runs (data shared) with local gravity moved by ``dg``."""
    import copy
    out = []
    for r in runs:
        r2 = copy.copy(r)
        object.__setattr__(r2, "meta", {**r.meta, key: float(r.meta[key]) + dg})
        out.append(r2)
    return out


def _key(c) -> tuple[str, str, str, float]:
    """(method, rig, what the row estimates, value) of a coefficient record: a tumble row by
    its fitted parameter (:attr:`.records.TumbleCoefficient.key`); any other row by the
    quantity its name stands for (``K0`` of ``K0(Koo)``)."""
    return c.method, c.rig_id, getattr(c, "key", None) or split_combination(c.name)[0], c.value


def add_stated_g_local(est, runs: Sequence, steps, records: list, stated) -> None:
    """Give a paper method's coefficients that have no local-gravity line the type-B line of
    its stated standard uncertainty (JCGM 100 §5.1.3), with the sensitivity dC/dg of the
    method itself: the method run again on the same readings with g ± :data:`G_LOCAL_STEP`
    (a central difference; the other methods' outcomes it reads held), and the combined u
    and effective degrees of freedom (JCGM 100 eq G.2b) with it; the JCGM 101 check is made
    again.

    Parameters
    ----------
    est : accelcal.estimators.registry.Estimator
        The paper method.
    runs : sequence
        Its runs (``meta["g_local_m_s2"]``, ``meta["rig_id"]``).
    steps : mapping
        The campaign's first passes (``est.prepare`` outcomes by method).
    records : list of accelcal.estimators.records.Records
        Its records, changed in place.
    stated : mapping
        Rig id -> rig-input id -> stated standard uncertainty (``g_local`` [m/s²]).
    """
    from ..effects import RIG_INPUTS
    g_in = RIG_INPUTS["g_local"]
    g_of = {str(r.meta.get("rig_id", "")): float(r.meta[g_in.meta_key]) for r in runs
            if r.meta.get(g_in.meta_key) is not None}

    def lacks(rec, c) -> bool:
        return ((stated.get(c.rig_id) or {}).get("g_local") is not None and c.rig_id in g_of
                and not any(b.coefficient == c.name and b.method == c.method and b.rig_id == c.rig_id
                            and b.quantity.startswith(g_in.what) for b in rec.budget))
    if not any(lacks(rec, c) for rec in records for c in rec.coefficients):
        return
    moved = {}
    try:
        for sign in (1, -1):
            rs = _with_g(runs, g_in.meta_key, sign * G_LOCAL_STEP)
            st = dict(steps)
            if est.prepare is not None:
                st[est.method] = est.prepare(rs, st)
            moved[sign] = [_key(c) for rec in est.records(rs, st) for c in rec.coefficients]
    except Exception as exc:        # the values stand; the missing line is a flag
        records[-1].flags.append(f"{est.method}: the local-gravity line of its budgets could not "
                                 f"be evaluated ({type(exc).__name__}: {exc})")
        return
    # matched in order: a combination's name carries g (K0 + g²·Koo), its place does not
    here = [_key(c) for rec in records for c in rec.coefficients]
    if [k[:3] for k in moved[1]] != [k[:3] for k in here] or [k[:3] for k in moved[-1]] != [k[:3] for k in here]:
        records[-1].flags.append(f"{est.method}: the local-gravity line of its budgets could not "
                                 f"be evaluated (other coefficients with g moved)")
        return
    i = -1
    for rec in records:
        checks = rec.extras.get("mc_check") or {}
        for c in rec.coefficients:
            i += 1
            if not lacks(rec, c):
                continue
            u_g = stated[c.rig_id]["g_local"]
            sens = (moved[1][i][3] - moved[-1][i][3]) / (2 * G_LOCAL_STEP)
            rec.budget.append(BudgetTerm(c.name, f"{g_in.what} of {c.rig_id} (type B, normal; u "
                                         f"stated in accelcal.toml)", g_of[c.rig_id], u_g, sens,
                                         abs(sens) * u_g, "B", "normal", c.method, c.rig_id))
            u_old = c.std_uncertainty
            c.std_uncertainty = math.hypot(u_old, sens * u_g)
            if c.dof is not None and math.isfinite(c.dof):
                c.dof = welch_satterthwaite([u_old, abs(sens) * u_g], [c.dof, math.inf])
            checks.pop(f"{c.method}:{c.rig_id}:{c.name}", None)
        rec.checked()
