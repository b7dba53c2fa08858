"""Drift of a unit's coefficients between calibrations, and when it must come back.

Plain functions on arrays (no warehouse, no Prefect): the ``due`` and ``history`` commands
and the ``recalibration_forecast`` table wrap them (:mod:`accelcal.ops.due`).

Model (per unit and coefficient, one *series* = the complete, real, non-excluded
calibrations in time order since the last adjustment or flagged step)::

    x_i = a + b (t_i - t_ref) + e_i,      e_i ~ N(0, u_i^2 + tau^2)            (1)

``u_i`` is the campaign's standard uncertainty, ``tau^2`` the between-campaign scatter
(what moves the unit between campaigns beyond a straight line, plus rig reproducibility
the campaign's budget does not hold).  This is the weighted straight line of the
variables method (NCSLI RP-1 Variables Method V1; ILAC-G24/OIML D10 section "control
chart" and "in-use time"), with the weights of a random-effects regression:

* ``tau^2`` is the moment estimate of DerSimonian & Laird (1986) extended to a weighted
  regression: with ``w_i = 1/u_i^2``, ``Q = sum w_i r_i^2`` has expectation
  ``(n - p) + tau^2 c``, ``c = sum w_i - tr((X'WX)^-1 X'W^2X)``                  (2)
* with few campaigns it is shrunk towards the fleet's value for the same unit model and
  coefficient, each weighted by its degrees of freedom (``PRIOR_DOF`` for the fleet)::

      tau^2 = max(0, (nu_0 tau_fleet^2 + nu_j tau_j^2) / (nu_0 + nu_j))          (3)

* predictions are Student-t with the Welch-Satterthwaite degrees of freedom of the part
  of the variance that scales with ``tau^2`` (GUM G.4.1).

"Out of tolerance" (the issue's definition) is the true coefficient having moved from the
value in use ``v`` (the last calibration's value) by more than the tolerance ``T``::

    P_out(t) = P(|X(t) - v| > T),  X(t) ~ t_nu(mu(t), s(t)),  s^2 = var(line(t)) + tau^2   (4)

and the due date is the first day on which ``P_out`` reaches the lab's risk (a
reliability target of 1 - risk, RP-1 V1).  A unit with too little history gets a
stated basis instead of a date; a prior from the fleet is used and said so.

A step the line cannot explain (a shock, a repair) is tested by adding an offset at each
campaign (``x_i += delta [i >= k]``): the step is flagged when its normalised error
``En = delta / U(delta)`` (U = 2 u) exceeds ``STEP_EN``, or its t test survives a
Bonferroni correction over the candidate places (``STEP_ALPHA``).  A flagged step, like an adjustment,
starts a new series: it is never smoothed over.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy import stats

from .fitting.core import FitResult, linear_fit
from .fitting.identify import design_rank

#: Two step positions whose p values agree to this relative tolerance are a tie (the data
#: cannot place the step); the later one is taken.
STEP_TIE_RTOL = 1e-9
#: Days of a year of the drift rates [d/a] (Julian year).
YEAR_DAYS = 365.25
#: Degrees of freedom the fleet's between-campaign scatter counts for in eq (3).
PRIOR_DOF = 4.0
#: En of a step above which (with the t test below) a step is flagged.
STEP_EN = 2.0
#: Family-wise false-alarm probability of the step test over a series' candidate places
#: (a missed shock costs wrong due dates, a false flag a look at the unit's history).
STEP_ALPHA = 0.05
#: Significance of a new series' own drift rate differing from the unit's earlier rate.
SLOPE_CHANGE_ALPHA = 0.01
#: How far ahead a due date is looked for [a].
HORIZON_YEARS = 10.0
#: A unit's own drift rate gives way to the fleet's spread of rates when its standard
#: uncertainty is more than this many times that spread (two campaigns a day apart).
OWN_RATE_FACTOR = 2.0
#: Fewest units with a drift fit that make a fleet prior for the drift rate.
MIN_FLEET_UNITS = 3

#: P_out at the ends of the 95 % interval of the day the coefficient leaves its tolerance:
#: the days on which eq (4) passes 2.5 % and 97.5 % (the prediction band inverted).
EXIT_LEVEL = (0.025, 0.975)

BASIS_FIT = "drift fit"
BASIS_FLEET = "fleet prior"
BASIS_NO_TOL = "no tolerance"


# --------------------------------------------------------------------- time ----

def to_years(t: Any) -> np.ndarray:
    """Times as decimal years since 1970-01-01 [a]: datetime64, datetime/date or floats
    (taken as years already)."""
    a = np.asarray(t)
    if a.dtype.kind == "M":
        return a.astype("datetime64[s]").astype(float) / (86400.0 * YEAR_DAYS)
    if a.dtype.kind == "O":
        return np.array([np.datetime64(x, "s").astype(float) / (86400.0 * YEAR_DAYS)
                         if not isinstance(x, (int, float)) else float(x) for x in a.ravel()]
                        ).reshape(a.shape)
    return a.astype(float)


# ------------------------------------------------------------- the line fit ----

def _wls_fit(X: np.ndarray, x: np.ndarray, var: np.ndarray) -> FitResult:
    """The weighted straight line (plus segment offsets) through the fitting core
    (:func:`accelcal.fitting.core.linear_fit`, sigma^2 = ``var``, known: the between-
    campaign scatter is in ``var`` as tau^2, eq 2): coefficients ``a``, ``b``, then the
    earlier segments' offsets, covariance (X'WX)^-1 in ``cov_noise``, the chi-square test
    of the line in ``lack_of_fit``.  A design the data cannot determine (rank below its
    columns: a step position or segment with no calibration of its own) raises
    ``LinAlgError``."""
    names = ["a", "b"] + [f"offset{k}" for k in range(X.shape[1] - 2)]
    fit = linear_fit(X, x, np.sqrt(var), names, residual_scale=False)
    if fit.rank < X.shape[1]:
        raise np.linalg.LinAlgError("singular design: a parameter of the drift line is not determined")
    return fit


def _wls(X: np.ndarray, x: np.ndarray, var: np.ndarray):
    """:func:`_wls_fit` as (coefficients, covariance (X'WX)^-1, residuals [unit])."""
    fit = _wls_fit(X, x, var)
    return fit.values, fit.cov_noise, x - X @ fit.values


def scatter_moments(X: np.ndarray, x: np.ndarray, u: np.ndarray) -> tuple[float, float, float]:
    """(Q, n - p, c) of eq (2): the weighted residual sum of squares with w = 1/u^2, its
    degrees of freedom and the coefficient of tau^2 in its expectation.

    DerSimonian & Laird (1986), Controlled Clinical Trials 7:177, eq for Q, extended to a
    regression (Thompson & Sharp 1999, Stat. Med. 18:2693): E[Q] = (n-p) + tau^2 c."""
    w = 1.0 / u ** 2
    beta, cov, r = _wls(X, x, u ** 2)
    Q = float(np.sum(w * r ** 2))
    c = float(np.sum(w) - np.trace(cov @ (X.T @ (X * (w ** 2)[:, None]))))
    return Q, float(len(x) - X.shape[1]), c


def _design(t: np.ndarray, t_ref: float, step_at: int | None = None,
            segments: Sequence[int] = ()) -> np.ndarray:
    """Columns: the level of the last segment, the drift rate, then one offset per
    earlier segment (``segments``: the first index of each later segment) and the step
    test's offset."""
    idx = np.arange(len(t))
    cols = [np.ones_like(t), t - t_ref]
    for j, s in enumerate(segments):        # earlier segment j: indices before segments[j]
        lo = segments[j - 1] if j else 0
        cols.append(((idx >= lo) & (idx < s)).astype(float))
    if step_at is not None:
        cols.append((idx >= step_at).astype(float))
    return np.column_stack(cols)


@dataclass(frozen=True)
class FleetPrior:
    """What the fleet of one unit model says about one coefficient.

    tau2 : pooled between-campaign variance [unit^2], eq (2) over the fleet's series
    dof : its degrees of freedom (sum of n - 2 over the series)
    slope_mean, slope_sd : mean and spread of the units' fitted drift rates [unit/a]
        (the spread never below the root-mean-square uncertainty of one unit's rate)
    n_units : units with a drift fit behind slope_mean / slope_sd
    """
    tau2: float | None = None
    dof: float = 0.0
    slope_mean: float | None = None
    slope_sd: float | None = None
    n_units: int = 0


def fleet_prior(series: Sequence[tuple[Any, Any, Any]]) -> FleetPrior:
    """Pool a fleet's series ``[(t, x, u), ...]`` (one per unit; the current series of
    each) into a :class:`FleetPrior`.  Series with fewer than three campaigns add nothing
    to tau^2; with two they add a drift rate."""
    Qs = dofs = cs = 0.0
    slopes, u_b2, pairs = [], [], []
    for t, x, u in series:
        t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
        if len(t) < 2 or np.ptp(t) <= 0:
            continue
        X = _design(t, float(np.mean(t)))
        if len(t) >= 3:
            Q, dof, c = scatter_moments(X, x, u)
            Qs, dofs, cs = Qs + Q, dofs + dof, cs + c
        else:
            pairs.append((t[1] - t[0], x[1] - x[0], math.hypot(u[0], u[1])))
        beta, cov, _ = _wls(X, x, u ** 2)
        slopes.append(float(beta[1]))
        u_b2.append(float(cov[1, 1]))
    if dofs == 0 and len(pairs) >= 2:
        # no series of three: the variables method's residuals (NCSLI RP-1 V1), the
        # fleet's pairs of calibrations about one common rate; a pair's difference holds
        # the scatter twice (E[Q] = (n - 1) + 2 tau^2 c); the units' spread of rates
        # stays in it, so tau^2 is an upper estimate
        dt_, dx_, ud = (np.array(v) for v in zip(*pairs))
        Q, dofs, c = scatter_moments(dt_[:, None], dx_, ud)
        Qs, cs = Q, 2.0 * c
    tau2 = max(0.0, (Qs - dofs) / cs) if dofs > 0 and cs > 0 else None
    if len(slopes) >= MIN_FLEET_UNITS:
        # spread of the units' rates, never below the typical uncertainty of one rate
        sd = math.sqrt(max(float(np.var(slopes, ddof=1)), float(np.mean(u_b2))))
        return FleetPrior(tau2, dofs, float(np.mean(slopes)), sd, len(slopes))
    return FleetPrior(tau2, dofs, n_units=len(slopes))


@dataclass
class DriftFit:
    """Eq (1) fitted to one series: two weighted fits of the same line, which it wraps.

    result : the fit with tau2 in the weights (``a``, ``b``, ``beta``, ``cov``)
    result0 : the same with tau2 = 0 (its ``cov_noise``, for the degrees of freedom)
    t_ref : the time ``a`` is the line's value at [a]
    tau2 : between-campaign variance [unit^2]; dof : its degrees of freedom
    t, x, u : the series [a, unit, unit]
    """
    t_ref: float
    result: FitResult
    result0: FitResult
    tau2: float
    dof: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    tau2_own: float | None = None      # the series' own eq (2) estimate (untruncated)

    @property
    def a(self) -> float:
        """Value of the line at t_ref [unit] (the last segment's level)."""
        return float(self.result.values[0])

    @property
    def b(self) -> float:
        """Drift rate [unit/a]."""
        return float(self.result.values[1])

    @property
    def cov(self) -> np.ndarray:
        """Covariance of the coefficients (a, b, then the earlier segments' offsets) with tau2
        in the weights [unit^2, ...]."""
        return self.result.cov_noise

    @property
    def u_b(self) -> float:
        return float(math.sqrt(self.cov[1, 1]))

    def line(self, t) -> np.ndarray:
        return self.a + self.b * (np.asarray(t, float) - self.t_ref)

    def _var_line(self, cov, t) -> np.ndarray:
        d = np.asarray(t, float) - self.t_ref
        return cov[0, 0] + 2 * d * cov[0, 1] + d ** 2 * cov[1, 1]

    def predictive(self, t, u_new=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean [unit], standard deviation [unit] and degrees of freedom of the value at
        t [a]: of the coefficient itself (u_new = 0) or of a new campaign's result with
        standard uncertainty u_new."""
        v = self._var_line(self.cov, t) + self.tau2 + np.asarray(u_new, float) ** 2
        v0 = self._var_line(self.result0.cov_noise, t) + np.asarray(u_new, float) ** 2
        vt = np.maximum(v - v0, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            nu = np.where(vt > 0, v ** 2 / (vt ** 2 / max(self.dof, 1e-9)), np.inf)
        return self.line(t), np.sqrt(v), np.minimum(nu, 1e6)


def fit_drift(t, x, u, prior: FleetPrior | None = None, prior_dof: float = PRIOR_DOF,
              step_at: int | None = None, segments: Sequence[int] = ()) -> DriftFit:
    """Eq (1) with tau^2 from eqs (2)-(3).

    Parameters
    ----------
    t : times [a] (or datetime64); x : values [unit]; u : standard uncertainties [unit]
    prior : the fleet's tau^2 to shrink towards (None: the series alone)
    step_at : fit an offset from this campaign on (the step test's alternative)
    segments : first index of each later segment (after an adjustment or a flagged
        step): every segment has its own level, the drift rate is common; ``a`` is the
        last segment's level

    Raises
    ------
    ValueError
        No drift rate can be estimated (no segment with two campaigns at different
        times), or no degrees of freedom for tau^2 (and no fleet prior).
    """
    t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
    bounds = [0, *segments, len(t)]
    if not any(np.ptp(t[a:b]) > 0 for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= 2):
        raise ValueError("a drift line needs two campaigns at different times in one series")
    if not np.all(np.isfinite(u)) or np.any(u <= 0):
        raise ValueError("every campaign needs a positive standard uncertainty")
    t_ref = float(np.mean(t))
    X = _design(t, t_ref, step_at, segments)
    if design_rank(X) < X.shape[1]:
        raise ValueError("the series does not determine a level and a drift rate")
    Q, nu_j, c = scatter_moments(X, x, u)
    own = (Q - nu_j) / c if nu_j > 0 and c > 0 else None
    nu_0 = min(prior_dof, prior.dof) if prior is not None and prior.tau2 is not None else 0.0
    num = (nu_0 * prior.tau2 if nu_0 > 0 else 0.0) + (nu_j * own if own is not None else 0.0)
    dof = nu_0 + (nu_j if own is not None else 0.0)
    if dof <= 0:
        raise ValueError("no degrees of freedom for the between-campaign scatter "
                         "(too few campaigns and no fleet of the same model)")
    tau2 = max(0.0, num / dof)
    return DriftFit(t_ref, _wls_fit(X, x, u ** 2 + tau2), _wls_fit(X, x, u ** 2), tau2, dof, t, x, u,
                    tau2_own=own)


def slope_change_p(t, x, u, start: int, prior: FleetPrior | None = None,
                   segments: Sequence[int] = ()) -> float | None:
    """p value (two-sided t) of a different drift rate from campaign ``start`` on, in the
    model of :func:`fit_drift` with ``segments``; None when it cannot be tested (fewer
    than three campaigns from ``start``)."""
    t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
    if len(t) - start < 3 or start < 2:
        return None
    try:
        f = fit_drift(t, x, u, prior, segments=segments)
    except (ValueError, np.linalg.LinAlgError):
        return None
    X = _design(t, f.t_ref, None, segments)
    X = np.column_stack([X, (t - f.t_ref) * (np.arange(len(t)) >= start)])
    return _last_term(X, x, u, f)[2] if design_rank(X) == X.shape[1] else None


def _last_term(X: np.ndarray, x: np.ndarray, u: np.ndarray, f: DriftFit) -> tuple[float, float, float]:
    """Value, standard uncertainty and two-sided t p value (``f.dof``) of the coefficient of
    X's last column (a step, a change of rate) in the weighted line with ``f``'s tau^2."""
    beta, cov, _ = _wls(X, x, u ** 2 + f.tau2)
    sd = math.sqrt(cov[-1, -1])
    return float(beta[-1]), sd, float(2 * stats.t.sf(abs(float(beta[-1])) / sd, f.dof))


# ----------------------------------------------------------------- steps ----

@dataclass(frozen=True)
class Step:
    """A step the line cannot explain, between campaigns ``at - 1`` and ``at`` of the
    series: size [unit], its standard uncertainty [unit], En = size / (2 u), p value of
    the t test (before the Bonferroni correction)."""
    at: int
    size: float
    u_size: float
    en: float
    p: float


def find_steps(t, x, u, prior: FleetPrior | None = None, en_limit: float = STEP_EN,
               alpha: float = STEP_ALPHA, offset: int = 0) -> list[Step]:
    """Steps a straight line cannot explain, in time order (recursively: a flagged step
    splits the series and both parts are tested again).

    At each candidate place k = 1 .. n-1 the line gets an offset from campaign k on
    (eq 1 plus ``delta [i >= k]``, tau^2 re-estimated under that model and shrunk to the
    fleet's).  The most significant place is flagged when ``|En| > en_limit`` (En =
    delta / U(delta), U = 2u, the ISO 13528 form) or its two-sided t test is below
    ``alpha / (n - 1)`` (Bonferroni over the places).  Needs three campaigns.  ``offset``:
    the index of ``t[0]`` in the whole series (the steps' ``at`` count from there).
    """
    t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
    n = len(t)
    if n < 3:
        return []
    best = None
    for k in range(1, n):
        try:
            f = fit_drift(t, x, u, prior, step_at=k)
        except (ValueError, np.linalg.LinAlgError):
            continue
        delta, sd, p = _last_term(_design(t, f.t_ref, k), x, u, f)
        # positions the data cannot tell apart (three calibrations: a step after the first
        # or after the second fits them equally, to the last digit) go to the later one:
        # the current series then holds only calibrations certainly after the step
        if best is None or p <= best.p * (1 + STEP_TIE_RTOL):
            best = Step(offset + k, delta, sd, delta / (2 * sd), p)
    if best is None or (abs(best.en) <= en_limit and best.p >= alpha / (n - 1)):
        return []
    k = best.at - offset
    return (find_steps(t[:k], x[:k], u[:k], prior, en_limit, alpha, offset) + [best]
            + find_steps(t[k:], x[k:], u[k:], prior, en_limit, alpha, offset + k))


def en_consecutive(x, U) -> np.ndarray:
    """En between consecutive campaigns, (x_i - x_{i-1}) / sqrt(U_i^2 + U_{i-1}^2)
    (ISO 13528; the warehouse's ``coefficient_changes.en``); len(x) - 1 values."""
    x, U = np.asarray(x, float), np.asarray(U, float)
    return np.diff(x) / np.sqrt(U[1:] ** 2 + U[:-1] ** 2)


# ----------------------------------------------------------- out of tolerance ----

def p_out(mean, sd, dof, value_in_use: float, tol: float) -> np.ndarray:
    """Eq (4): probability that the coefficient lies further than tol [unit] from the
    value in use, for a Student-t prediction (mean, sd [unit], dof)."""
    lo = stats.t.cdf((value_in_use - tol - np.asarray(mean)) / sd, dof)
    hi = stats.t.sf((value_in_use + tol - np.asarray(mean)) / sd, dof)
    return lo + hi


def due_from(predict, t_last: float, value_in_use: float, tol: float, risk: float,
             horizon: float = HORIZON_YEARS) -> tuple[float | None, float | None]:
    """First day after t_last [a] on which eq (4) reaches ``risk``, searched day by day
    up to ``horizon`` years; (t_due [a], P_out there) or (None, None).  ``predict(t)``
    returns (mean, sd, dof) of the coefficient at t."""
    days = np.arange(0, int(horizon * YEAR_DAYS) + 1)
    t = t_last + days / YEAR_DAYS
    m, s, nu = predict(t)
    p = p_out(m, s, nu, value_in_use, tol)
    hit = np.nonzero(p >= risk)[0]
    if not len(hit):
        return None, None
    return float(t[hit[0]]), float(p[hit[0]])


def tolerance_of(spec: dict[str, float] | None, value_in_use: float) -> float | None:
    """Tolerance [unit] from a config entry ``{relative = r}`` (times |value in use|) or
    ``{absolute = T}``; None without one."""
    if not spec:
        return None
    if "absolute" in spec:
        return float(spec["absolute"])
    if "relative" in spec:
        return float(spec["relative"]) * abs(value_in_use)
    return None


# ------------------------------------------------------------------ forecast ----

@dataclass
class Forecast:
    """The answer for one series: what the ``due`` command and the view show.

    drift_per_year, u_drift_per_year [unit/a]; due [a] or None; basis says where the
    date comes from or why there is none."""
    n_campaigns: int                 # in the current series
    n_total: int                     # every calibration of the coefficient
    t_last: float
    value_in_use: float
    u_in_use: float
    tolerance: float | None
    drift_per_year: float | None
    u_drift_per_year: float | None
    due: float | None
    p_out_at_due: float | None
    basis: str
    steps: list[Step] = field(default_factory=list)
    series_start: int = 0            # index of the current series' first campaign
    fit: DriftFit | None = None
    predict: Any = None              # t -> (mean, sd, dof) of the coefficient
    due_interval: tuple[float | None, float | None] = (None, None)   # 95 % of the exit [a]

    def interval(self, t, u_new=0.0, level=0.95):
        """Prediction interval [unit] at t [a]: of the coefficient (u_new = 0) or of a new
        campaign's value with standard uncertainty u_new."""
        if self.fit is not None and self.predict == self.fit.predictive:
            m, s, nu = self.fit.predictive(np.asarray(t, float), u_new)
        else:
            m, s, nu = self.predict(np.asarray(t, float))
            s = np.sqrt(s ** 2 + np.asarray(u_new, float) ** 2)
        k = stats.t.ppf(0.5 + level / 2, nu)
        return m - k * s, m + k * s


def series_bounds(n: int, adjusted: Sequence[bool] | None, steps: Sequence[Step]) -> list[int]:
    """First index of every series after the first: each adjustment campaign and each
    flagged step starts one."""
    out = {i for i, a in enumerate([] if adjusted is None else adjusted) if a and 0 < i < n}
    out |= {s.at for s in steps if 0 < s.at < n}
    return sorted(out)


def current_series_start(n: int, adjusted: Sequence[bool] | None, steps: Sequence[Step]) -> int:
    """Index where the current series begins (0 when no adjustment or step)."""
    b = series_bounds(n, adjusted, steps)
    return b[-1] if b else 0


def forecast(t, x, u, tol_spec: dict[str, float] | None, risk: float,
             adjusted: Sequence[bool] | None = None, prior: FleetPrior | None = None,
             horizon: float = HORIZON_YEARS) -> Forecast:
    """Drift, prediction and due date of one unit's coefficient.

    Parameters
    ----------
    t : calibration times [a] or datetime64, in time order; x, u : value and standard
        uncertainty [unit]; adjusted : campaigns marked as adjustments (each starts a
        new series); tol_spec : ``{relative = r}`` or ``{absolute = T}``, None when the
        config has none; risk : the acceptable probability of being out of tolerance;
        prior : the fleet's (same model and coefficient).

    Every adjustment and every flagged step starts a new series: a new level, never a
    line drawn through the jump.  The drift rate is the unit's own, common to its series
    (a shock or an adjustment moves the coefficient, not the mechanism that drifts it),
    unless the current series has three campaigns or more and its own rate differs
    significantly (t test, p < ``SLOPE_CHANGE_ALPHA``): then the current series alone is used.
    Basis:

    * "drift fit": eq (1) (with tau^2 of eq 3);
    * "fleet prior": no drift rate in the unit's history (one campaign, or one per
      series), or one over ``OWN_RATE_FACTOR`` times less certain than the spread of
      the fleet's rates (two campaigns a day apart): the fleet's drift-rate spread and scatter, from the value in use;
    * no date, and the basis says why: no tolerance in the config, too little history
      and no fleet of the model.
    """
    t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
    n = len(t)
    if n == 0:
        raise ValueError("no calibrations")
    adj = [bool(a) for a in adjusted] if adjusted is not None else [False] * n
    parts = [0, *series_bounds(n, adj, []), n]
    steps: list[Step] = []
    for lo, hi in zip(parts[:-1], parts[1:]):
        steps += find_steps(t[lo:hi], x[lo:hi], u[lo:hi], prior, offset=lo)
    bounds = series_bounds(n, adj, steps)
    start = bounds[-1] if bounds else 0
    v, t_last = float(x[-1]), float(t[-1])
    tol = tolerance_of(tol_spec, v)
    out = Forecast(n - start, n, t_last, v, float(u[-1]), tol, None, None, None, None, "",
                   steps, start)
    why = []
    if start > 0:
        why.append("series since " + ("adjustment" if adj[start] else "flagged step")
                   + f" at calibration {start + 1}")
    p_change = slope_change_p(t, x, u, start, prior, bounds) if bounds else None
    own_only = p_change is not None and p_change < SLOPE_CHANGE_ALPHA
    if own_only:
        why.append("drift rate changed at the new series: fitted to it alone")
    try:
        fit = fit_drift(t[start:], x[start:], u[start:], prior) if own_only else fit_drift(t, x, u, prior, segments=bounds)
    except (ValueError, np.linalg.LinAlgError):
        fit = None
    if (fit is not None and prior is not None and prior.slope_sd is not None
            and fit.u_b > OWN_RATE_FACTOR * prior.slope_sd):
        why.append(f"its own drift rate is over {OWN_RATE_FACTOR:g} times less certain than "
                   "the spread of the fleet's")
        fit = None
    if fit is not None:
        out.fit, out.drift_per_year, out.u_drift_per_year = fit, fit.b, fit.u_b
        out.predict = fit.predictive
        nfit = len(fit.t)
        shrunk = (prior is not None and prior.tau2 is not None and prior.dof > 0)
        basis = (BASIS_FIT + f" ({nfit} calibration{'s' if nfit > 1 else ''}"
                 + (f" in {len(bounds) + 1} series" if bounds and not own_only else "")
                 + (", scatter shrunk to the fleet's" if shrunk else "") + ")")
    elif prior is not None and prior.slope_sd is not None:
        bm, bs, nu_b = prior.slope_mean, prior.slope_sd, prior.n_units - 1
        tau2 = prior.tau2 or 0.0
        u_last = float(u[-1])

        def pred(tt, bm=bm, bs=bs, nu_b=nu_b, tau2=tau2, u_last=u_last):
            d = np.asarray(tt, float) - t_last
            return (v + bm * d, np.sqrt(u_last ** 2 + tau2 + (bs * d) ** 2),
                    np.full_like(d, float(nu_b)))
        out.predict = pred
        out.drift_per_year, out.u_drift_per_year = bm, bs
        basis = (f"{BASIS_FLEET} ({n} calibration{'s' if n > 1 else ''}, no drift rate of "
                 f"its own; drift rates of {prior.n_units} units of the model)")
    else:
        basis = (f"{n} calibration{'s' if n > 1 else ''}, no drift rate of its own and no "
                 "fleet of the model to take one from: no due date")
    if tol is None:
        basis = (BASIS_NO_TOL + ": none for this model and coefficient in the config, "
                 "no due date; " + basis.split(": no due date")[0])
    elif out.predict is not None:
        out.due, out.p_out_at_due = due_from(out.predict, t_last, v, tol, risk, horizon)
        out.due_interval = (due_from(out.predict, t_last, v, tol, EXIT_LEVEL[0], horizon)[0],
                            due_from(out.predict, t_last, v, tol, EXIT_LEVEL[1], horizon)[0])
        if out.due is None:
            why.append(f"not due within {horizon:g} years")
    out.basis = "; ".join([basis] + why)
    return out


def holdout_covers(t, x, u, prior: FleetPrior | None = None, level: float = 0.95,
                   adjusted: Sequence[bool] | None = None) -> bool | None:
    """Back-test: does the prediction interval of the series without its last campaign
    cover that campaign's value (with its u)?  None when no prediction can be made."""
    t, x, u = to_years(t), np.asarray(x, float), np.asarray(u, float)
    f = forecast(t[:-1], x[:-1], u[:-1], None, 0.05,
                 None if adjusted is None else list(adjusted)[:-1], prior, horizon=0.0)
    if f.predict is None or (adjusted is not None and list(adjusted)[-1]):
        return None
    lo, hi = f.interval(np.array([t[-1]]), u_new=u[-1], level=level)
    return bool(lo[0] <= x[-1] <= hi[0])


def due_date_statement(due_date: str | None, basis: str, risk: float,
                       state_due_date: bool) -> str | None:
    """The certificate's sentence on the recalibration date, or None.

    ISO/IEC 17025:2017 7.8.6 / 7.8.4.3: a calibration certificate states a
    recalibration date only when agreed with the customer (``[certificate]
    state_due_date = true``).  Without a date the sentence gives the basis instead."""
    if not state_due_date:
        return None
    if due_date:
        return (f"Recommended recalibration by {due_date}: the date on which the predicted "
                f"probability of this unit being outside its tolerance reaches "
                f"{risk * 100:g} %. Basis: {basis}.")
    return f"No recalibration date is stated: {basis}."
