"""scipy.stats' sf and ppf of the distributions the fits test with, without its overhead.

``scipy.stats.<dist>.sf`` / ``.ppf`` check and broadcast their arguments (~60 µs a call);
the science calls them a few hundred times per campaign on scalars.  For a scalar inside
the support with valid parameters scipy's answer is the special function below (scipy
1.x ``_sf`` / ``_ppf`` of the distribution, loc 0 and scale 1 applied the same way), so the
functions here return the very same float; anything else (edges, NaN, bad parameters)
is left to scipy.stats itself.
"""
from __future__ import annotations

import math

from scipy import special, stats


def _finite(*xs) -> bool:
    return all(isinstance(x, (int, float)) and math.isfinite(x) for x in xs)


def norm_sf(x):
    """Survival function of the standard normal, ``stats.norm.sf(x)``.

    Parameters
    ----------
    x : float or array_like
        Standardised value (z-score) [1].

    Returns
    -------
    float or ndarray
        Upper-tail probability P(Z > x) [1].
    """
    if _finite(x):
        return special.ndtr(-((x - 0) / 1))
    return stats.norm.sf(x)


def norm_ppf(q):
    """Quantile (inverse CDF) of the standard normal, ``stats.norm.ppf(q)``.

    Parameters
    ----------
    q : float or array_like
        Lower-tail probability [1].

    Returns
    -------
    float or ndarray
        z such that P(Z <= z) = q [1].
    """
    if _finite(q) and 0 < q < 1:
        return special.ndtri(q) * 1 + 0
    return stats.norm.ppf(q)


def chi2_sf(x, df):
    """Survival function of the chi-squared distribution, ``stats.chi2.sf(x, df)``.

    Parameters
    ----------
    x : float or array_like
        Chi-squared statistic [1].
    df : float or array_like
        Degrees of freedom [1].

    Returns
    -------
    float or ndarray
        Upper-tail probability P(X > x) [1].
    """
    if _finite(x, df) and df > 0 and x > 0:
        return special.chdtrc(df, (x - 0) / 1)
    return stats.chi2.sf(x, df)


def f_sf(x, dfn, dfd):
    """Survival function of the F distribution, ``stats.f.sf(x, dfn, dfd)``.

    Parameters
    ----------
    x : float or array_like
        F statistic [1].
    dfn : float or array_like
        Numerator degrees of freedom [1].
    dfd : float or array_like
        Denominator degrees of freedom [1].

    Returns
    -------
    float or ndarray
        Upper-tail probability P(F > x) [1].
    """
    if _finite(x, dfn, dfd) and dfn > 0 and dfd > 0 and x > 0:
        return special.fdtrc(dfn, dfd, (x - 0) / 1)
    return stats.f.sf(x, dfn, dfd)


def t_ppf(q, df):
    """Quantile (inverse CDF) of Student's t distribution, ``stats.t.ppf(q, df)``.

    Parameters
    ----------
    q : float or array_like
        Lower-tail probability [1].
    df : float or array_like
        Degrees of freedom [1].

    Returns
    -------
    float or ndarray
        t such that P(T <= t) = q [1].
    """
    if _finite(q, df) and df > 0 and 0 < q < 1:
        return special.stdtrit(df, q) * 1 + 0
    return stats.t.ppf(q, df)
