"""Model adequacy of a regression on replicated readings (IEEE 836 practice, quoted by
paper 000 §2.1.3: "every fit must pass a model adequacy test").

The regressions of the centrifuge (radius eq 7, cross-coupling eq 9) are fitted to
dwell means with weights n_j / sigma_j^2, sigma_j^2 from the reading-noise model.
The readings within a dwell are replicates, so the residual sum of squares splits
into *pure error* (scatter inside dwells) and *lack of fit* (dwell means off the
model):

    SS_PE  = sum_j sum_i (y_ij - ybar_j)^2 / sigma_j^2            dof N - m
    SS_LOF = sum_j n_j (ybar_j - yhat_j)^2 / sigma_j^2            dof m - p
    F      = (SS_LOF / (m - p)) / (SS_PE / (N - m))  ~  F(m - p, N - m) under H0

(the F test is the fitting core's one lack-of-fit test,
:func:`accelcal.fitting.core.lack_of_fit`), plus three residual checks on the standardised
dwell residuals in time order: a trend in time (t test of the slope), an up-versus-down sweep difference
(paired t test at matched levels) and the Wald–Wolfowitz run of signs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import special

from ..fitting.core import ALPHA, FitResult, LackOfFit, linear_fit
from ..fitting.core import lack_of_fit as core_lack_of_fit
from ..fitting.distributions import norm_sf, t_ppf

__all__ = ["ALPHA", "DwellFit", "choose_order", "pure_error_test", "runs_test", "sweep_test", "trend_test",
           "weighted_dwell_fit"]


@dataclass
class DwellFit:
    """Weighted least-squares fit to dwell means, with its adequacy statistics.

    Attributes
    ----------
    names : list
        Parameters, read from ``result`` (estimates [y unit per regressor unit]: :meth:`value`).
    cov : ndarray
        The core's noise covariance scaled by s2 (the method's covariance).
    s2 : float
        (SS_LOF + SS_PE) / (N - p); about 1 for an adequate model.
    yhat, std_resid : ndarray
        Fitted dwell means and standardised residuals (ybar - yhat) sqrt(W).
    ss_lof, ss_pe, dof_lof, dof_pe, f_statistic, p_value
        The lack-of-fit test (F and p NaN when untestable).
    trend_p, sweep_p, runs_p : float
        The residual checks (Bonferroni-adjusted over groups).
    """
    #: the fitting core's result of the solve (design, whitened residual, noise covariance):
    #: the names and estimates are read from it
    result: FitResult
    cov: np.ndarray                 # the core's noise covariance scaled by the residual mean square s2
    s2: float                       # (SS_LOF + SS_PE) / (N - p); ~1 for an adequate model
    yhat: np.ndarray
    std_resid: np.ndarray           # (ybar - yhat) sqrt(W)
    ss_lof: float
    ss_pe: float
    dof_lof: int
    dof_pe: int
    f_statistic: float
    p_value: float
    trend_p: float = 1.0
    sweep_p: float = 1.0
    runs_p: float = 1.0
    extra: dict = field(default_factory=dict)

    @property
    def names(self) -> list[str]:
        """Parameter names, in the design's column order."""
        return self.result.names

    @property
    def adequate(self) -> bool:
        return bool(self.p_value >= ALPHA and min(self.trend_p, self.sweep_p, self.runs_p) >= ALPHA / 3)

    def std_error(self, name: str) -> float:
        i = self.names.index(name)
        return float(np.sqrt(self.cov[i, i]))

    def value(self, name: str) -> float:
        return self.result.value(name)


def pure_error_test(ss_lof: float, dof_lof: int, ss_pe: float, dof_pe: int) -> LackOfFit:
    """The core's lack-of-fit test (:func:`accelcal.fitting.core.lack_of_fit`) against the
    pure error of replicated readings, at :data:`ALPHA`.

    Parameters
    ----------
    ss_lof, ss_pe : float
        Lack-of-fit and pure-error sums of squares (same weighting).
    dof_lof, dof_pe : int
        Their degrees of freedom.

    Returns
    -------
    LackOfFit
        'untestable' when either has no degrees of freedom: without replicates there is no
        independent estimate of the noise to test against.
    """
    if dof_pe <= 0:
        return LackOfFit("untestable", None, None, int(dof_lof), 0, 1.0,
                         "no replicated readings: no pure error to test the model against")
    return core_lack_of_fit(ss_lof, dof_lof, ss_pe, dof_pe, ALPHA)


def trend_test(t: np.ndarray, r: np.ndarray) -> float:
    """Residual check: a linear trend in time.

    Parameters
    ----------
    t : ndarray
        Time of each residual [s].
    r : ndarray
        Standardised residuals [1].

    Returns
    -------
    float
        Two-sided p of the slope (t test); 1.0 with fewer than 4 residuals.
    """
    if len(r) < 4 or np.ptp(t) == 0:
        return 1.0
    # the t test of the least-squares slope (as scipy.stats.linregress, without its overhead,
    # which was a tenth of the centrifuge method's time)
    tc = np.asarray(t, float) - np.mean(t)
    rc = np.asarray(r, float) - np.mean(r)
    sxx, syy, sxy = float(tc @ tc), float(rc @ rc), float(tc @ rc)
    if syy == 0.0:
        return 1.0
    rho = min(max(sxy / np.sqrt(sxx * syy), -1.0), 1.0)
    df = len(r) - 2
    if abs(rho) >= 1.0:
        return 0.0
    return _two_sided_t(rho * np.sqrt(df / ((1.0 - rho) * (1.0 + rho))), df)


def _two_sided_t(t: float, df: int) -> float:
    """P(|T| > |t|) for Student's t with df degrees of freedom."""
    return float(2.0 * special.stdtr(df, -abs(t)))


def sweep_test(level: np.ndarray, sweep: np.ndarray, r: np.ndarray) -> float:
    """Residual check: up- versus down-sweep residuals at matched levels (hysteresis).

    Parameters
    ----------
    level : ndarray
        Input level of each residual [m/s2]; levels within 2 % are matched.
    sweep : ndarray
        'up', 'down' or 'rest'.
    r : ndarray
        Standardised residuals [1].

    Returns
    -------
    float
        Two-sided p of the mean up-minus-down difference (paired t test); 1.0 with fewer
        than 3 matched levels.
    """
    # python floats (tolist) carry the same values as the numpy scalars, at a fraction of the cost
    level, sweep, r = (np.asarray(v).tolist() for v in (level, sweep, r))
    up = {round(float(a), 3): x for a, s, x in zip(level, sweep, r) if s == "up"}
    down = {round(float(a), 3): x for a, s, x in zip(level, sweep, r) if s == "down"}
    # match each down level to the nearest up level within 2 %
    d = []
    ups = np.array(sorted(up))
    for a, x in down.items():
        if ups.size == 0:
            break
        k = int(np.argmin(np.abs(ups - a)))
        if abs(ups[k] - a) <= 0.02 * max(abs(a), 1e-12):
            d.append(up[float(ups[k])] - x)
    d = np.asarray(d)
    if d.size < 3 or np.std(d, ddof=1) == 0:
        return 1.0
    return _two_sided_t(float(np.mean(d) / (np.std(d, ddof=1) / np.sqrt(d.size))), d.size - 1)


def runs_test(r: np.ndarray) -> float:
    """Residual check: Wald–Wolfowitz runs test on the signs of residuals in time order.

    Parameters
    ----------
    r : ndarray
        Residuals in time order.

    Returns
    -------
    float
        Two-sided p (normal approximation); too few runs means structure left in the
        residuals.  1.0 with fewer than 6 non-zero residuals or one sign only.
    """
    s = np.sign(r[r != 0])
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    if n1 == 0 or n2 == 0 or n1 + n2 < 6:
        return 1.0
    runs = 1 + int(np.sum(s[1:] != s[:-1]))
    n = n1 + n2
    mu = 2.0 * n1 * n2 / n + 1.0
    var = 2.0 * n1 * n2 * (2.0 * n1 * n2 - n) / (n**2 * (n - 1))
    if var <= 0:
        return 1.0
    z = (runs - mu) / np.sqrt(var)
    return float(2 * norm_sf(abs(z)))


def weighted_dwell_fit(X: np.ndarray, names: list[str], ybar: np.ndarray, n: np.ndarray,
                       ss_within: np.ndarray, sigma2: np.ndarray, *, time: np.ndarray | None = None,
                       level: np.ndarray | None = None, sweep: np.ndarray | None = None,
                       moving: np.ndarray | None = None, group: np.ndarray | None = None,
                       dof_pe_rows: np.ndarray | None = None) -> DwellFit:
    """Weighted least squares of dwell means on regressors, with the lack-of-fit test and the
    residual checks (module docstring).

    The solve is :func:`accelcal.fitting.core.linear_fit` (scaled SVD) with the standard
    deviation of each dwell mean sqrt(sigma2 / n); the covariance is that fit's noise-model
    covariance times the residual mean square over the readings,
    s2 = (SS_LOF + SS_PE) / (N - p).

    Parameters
    ----------
    X : (m, p) ndarray
        Regressors, one row per dwell [y unit per parameter unit].
    names : list of str
        Parameter names.
    ybar : (m,) ndarray
        Dwell means [y unit].
    n, ss_within, sigma2 : (m,) ndarray
        Readings, sum of squares about the mean [y unit squared] and reading variance of the
        noise model [y unit squared] of each dwell.
    time, level, sweep, moving : ndarray, optional
        Per dwell: time [s], level (|a| [m/s2]), 'up'/'down'/'rest', moving flag; the
        residual checks run when ``time`` is given.
    group : ndarray, optional
        Id per row; the residual checks run per group (e.g. per polarity) and the smallest p
        is kept (Bonferroni-adjusted by the number of groups).
    dof_pe_rows : ndarray, optional
        Pure-error dof of each row when a row merges several dwells.

    Returns
    -------
    DwellFit
        With the core's :class:`~accelcal.fitting.core.FitResult` in ``result``.
    """
    X = np.asarray(X, float)
    W = n / sigma2
    sw = np.sqrt(W)
    res = linear_fit(X, ybar, 1.0 / sw, list(names), residual_scale=False)
    beta = res.values
    yhat = X @ beta
    ss_lof, ss_pe = float(np.sum(W * (ybar - yhat) ** 2)), float(np.sum(ss_within / sigma2))
    dof_lof = int(len(ybar) - X.shape[1])
    dof_pe = int(np.sum(n - 1)) if dof_pe_rows is None else int(np.sum(dof_pe_rows))
    lof = pure_error_test(ss_lof, dof_lof, ss_pe, dof_pe)
    F, p = ((float("nan"), float("nan")) if lof.status == "untestable" or lof.statistic is None
            else (float(lof.statistic), float(lof.p_value)))
    N = int(np.sum(n))
    s2 = (ss_lof + ss_pe) / max(N - X.shape[1], 1)
    cov = res.cov_noise * s2
    r = (ybar - yhat) * sw
    fit = DwellFit(result=res, cov=cov, s2=float(s2), yhat=yhat, std_resid=r,
                   ss_lof=ss_lof, ss_pe=ss_pe, dof_lof=dof_lof, dof_pe=dof_pe, f_statistic=F, p_value=p)
    if time is not None:
        mv = np.ones(len(r), bool) if moving is None else np.asarray(moving, bool)
        grp = np.zeros(len(r), int) if group is None else np.asarray(group)
        tp, sp, rp = [], [], []
        for gid in np.unique(grp):
            k = mv & (grp == gid)
            order = np.argsort(np.asarray(time)[k])
            rr = r[k][order]
            tp.append(trend_test(np.asarray(time)[k][order], rr))
            rp.append(runs_test(rr))
            if level is not None and sweep is not None:
                sp.append(sweep_test(np.asarray(level)[k], np.asarray(sweep)[k], r[k]))
        m = len(tp)
        fit.trend_p = min(1.0, min(tp) * m) if tp else 1.0
        fit.runs_p = min(1.0, min(rp) * m) if rp else 1.0
        fit.sweep_p = min(1.0, min(sp) * m) if sp else 1.0
    return fit


def choose_order(fits: dict[int, DwellFit], added: dict[int, list[str]]) -> tuple[int, bool]:
    """The lowest adequate model order whose next order adds nothing significant.

    An order is chosen when its fit is adequate (lack of fit and residual checks,
    :attr:`DwellFit.adequate`) *and* no parameter added by the next order differs from zero
    at ALPHA (two-sided t test with the next fit's residual dof).  The second condition is
    the direct test of the missing term: a 6-sigma cubic must not be left out because the
    lack-of-fit test, which spreads its power over all dwells, happened to pass (paper 000
    §2.1.3: "use 2nd or 3rd order, and every fit must pass a model adequacy test").

    Parameters
    ----------
    fits : dict
        Order -> DwellFit.
    added : dict
        Order -> names of the parameters that order adds to the one below.

    Returns
    -------
    (int, bool)
        The order and whether it is adequate; when no order qualifies, the highest order and
        its adequacy.
    """
    orders = sorted(fits)
    for i, o in enumerate(orders):
        if not fits[o].adequate:
            continue
        if i + 1 < len(orders):
            nxt = fits[orders[i + 1]]
            dof = max(nxt.dof_lof + nxt.dof_pe, 1)
            tcrit = t_ppf(1 - ALPHA / 2, dof)
            if any(abs(nxt.value(n)) > tcrit * nxt.std_error(n) for n in added.get(orders[i + 1], [])):
                continue
        return o, True
    return orders[-1], bool(fits[orders[-1]].adequate)
