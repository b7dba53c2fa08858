"""Runs as the campaign model sees them: readings grouped into cells of replicates, a noise
model fitted to the data themselves, and the labels the diagnosis localises a gap along.

A *cell* is a group of readings that repeat the same nominal input: a centrifuge dwell
(``step``), a tumble head position, a tilt-rotation (set-point, angle) dwell, or, for the
sinusoidal centrifuge (which has no dwells), one phase of the drive across its periods.
The model is evaluated at every reading (its own logged rate, angle, temperature) and
averaged over the cell, so the cell mean of the model is exact; the fit runs on cell
means, weighted by the variance of each cell mean.

Noise model (per run, from the data; nothing is assumed from any simulator):

* the scatter of the *residuals* (output minus the model at each reading) inside each
  cell, so that noise in a logged regressor (rate, angle, temperature), which the output
  does not contain but the model input does, is counted where it acts;
* variance of one reading sigma^2(x) = a + b x^2, x the centripetal level omega_z^2 R of
  the reading [m/s^2] (0 for tumble and tilt-rotation runs): white noise plus noise that
  grows with rate, fitted by maximum likelihood to the cell variances ((n-1) s^2/sigma^2 ~
  chi^2_{n-1});
* lag-1 autocorrelation rho of the readings inside cells (AR(1)); the variance of a cell
  mean of n readings is sigma^2/n * [1 + 2 sum_k (1 - k/n) rho^k], and the cell variance
  s^2 is corrected for the bias autocorrelation gives it.

Duplicated readings (the same time and output sequence in two runs, e.g. one recording
filed under two head assignments) are counted once; the runs say so.
"""
from __future__ import annotations

import hashlib
import math
from functools import lru_cache
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import minimize_scalar

from ..physics.geometry import CentrifugeMount, geometry_of
from ..physics.rigs import centripetal_level, sine_drive
from .core import nested_test

#: a logged head/table angle that moves less than this within one position [deg] is reading
#: noise: the dwell stays one cell (the model still reads each reading's logged angle, so that
#: the noise of the log shows in the residual scatter and is counted in the weights)
ANGLE_TOL_DEG = 0.2
#: a reading further than this many robust sigmas from its cell's median is a spike
SPIKE_SIGMAS = 7.0
#: Readings a long run's reading-by-reading work takes at a time (its columns read into
#: block means, :func:`block_bounds`): the forward model's temporaries are a dozen arrays of
#: the length it is given, 0.6 GB at the 4.5 M readings of a 200 MB run.
ROW_SLICE = 1 << 20
#: smallest and largest lag-1 autocorrelation the noise model accepts
RHO_BOUNDS = (-0.5, 0.95)
#: |rho| sqrt(pairs) below which the lag-1 autocorrelation is not distinguished from 0
RHO_SIGNIFICANCE = 3.0
#: standard errors of the lag-1 ratio to the upper end of rho's interval: the lack-of-fit
#: test calls a model inadequate only if it is at that end too (a rho read low from short
#: cells would put a cell mean's noise too low and call clean data inadequate)
RHO_INTERVAL_Z = 2.0


@dataclass
class NoiseModel:
    """Noise of one run's readings: variance sigma^2(x) = a + b x^2 and AR(1) correlation.

    Attributes
    ----------
    a : float
        White-noise variance of one reading [output_unit^2]; nan when not estimable.
    b : float
        Rate-dependent part [output_unit^2 / (m/s^2)^2], x the centripetal level [m/s^2].
    rho : float
        Lag-1 autocorrelation of the readings inside a cell [1].
    rho_hi : float
        Upper end of rho's sampling interval [1] (:meth:`RunCells.cell_scatter`).
    dof : int
        Pure-error degrees of freedom it rests on [1].
    source : str
        What it was estimated from: 'residuals', 'outputs', 'pooled', 'fit residuals'
        ('none' when nothing could be).
    n_params : int
        Parameters of the variance function fitted to the scatter [1]: 1 (a) or 2 (a and
        b); the lack of fit counts them against the ``dof`` it rests on
        (:func:`accelcal.fitting.model.lack_of_fit_reference`).
    """
    a: float
    b: float = 0.0
    rho: float = 0.0
    rho_hi: float = 0.0
    dof: int = 0
    source: str = "outputs"
    n_params: int = 1

    def reading_variance(self, x: np.ndarray) -> np.ndarray:
        """Variance of one reading at centripetal level x.

        Parameters
        ----------
        x : array_like
            Centripetal level omega_z^2 R [m/s^2] (0 off centrifuges).

        Returns
        -------
        ndarray
            a + b x^2 [output_unit^2], shape of x.
        """
        return self.a + self.b * np.asarray(x, float) ** 2


def _per_cell_size(n: np.ndarray, value, out: np.ndarray) -> np.ndarray:
    """``out`` with each cell's entry set to ``value(size)``, worked out once per distinct
    cell size (the AR(1) factors depend on n alone); a size whose value is None keeps
    ``out``'s entry."""
    for val in np.unique(n):
        v = value(val)
        if v is not None:
            out[n == val] = v
    return out


def ar1_mean_factor(n: np.ndarray, rho: float) -> np.ndarray:
    """Variance inflation of the mean of n AR(1) readings.

    Parameters
    ----------
    n : array_like
        Readings per cell [1].
    rho : float
        Lag-1 autocorrelation [1].

    Returns
    -------
    ndarray
        Var(mean) / (sigma^2 / n) = 1 + 2 sum_{k=1}^{n-1} (1 - k/n) rho^k [1], shape of n
        (1 where rho = 0 or n <= 1).
    """
    n = np.asarray(n, float)
    if rho == 0.0:
        return np.ones_like(n)

    def factor(val):
        k = np.arange(1, int(val))
        return 1.0 + 2.0 * np.sum((1.0 - k / val) * rho ** k) if k.size else 1.0
    return _per_cell_size(n, factor, np.empty_like(n))


def ar1_variance_factor(n: np.ndarray, rho: float) -> np.ndarray:
    """Bias of the sample variance of n AR(1) readings.

    Parameters
    ----------
    n : array_like
        Readings per cell [1].
    rho : float
        Lag-1 autocorrelation [1].

    Returns
    -------
    ndarray
        E[s^2] / sigma^2 = 1 - 2/(n(n-1)) sum_{k=1}^{n-1} (n-k) rho^k [1], shape of n;
        1 where rho = 0 or n < 2, and at least 0.05.
    """
    n = np.asarray(n, float)
    if rho == 0.0:
        return np.ones_like(n)

    def factor(val):
        if val < 2:
            return None
        k = np.arange(1, int(val))
        return 1.0 - 2.0 / (val * (val - 1.0)) * np.sum((val - k) * rho ** k)
    return np.maximum(_per_cell_size(n, factor, np.ones_like(n)), 0.05)


def ar1_scatter_dof(n: np.ndarray, rho: float) -> np.ndarray:
    """Degrees of freedom of the within-cell sum of squares of n AR(1) readings
    (Satterthwaite: Q = e^T C e with C = I - 11^T/n and e ~ N(0, sigma^2 R), so
    E[Q] = sigma^2 tr(CR), Var[Q] = 2 sigma^4 tr((CR)^2) and nu = tr(CR)^2 / tr((CR)^2)).
    Correlated readings carry less information on the variance than n - 1 independent
    ones: at rho = 0.9, 8 readings give about 2.8 dof, not 7.

    Parameters
    ----------
    n : array_like
        Readings per cell [1].
    rho : float
        Lag-1 autocorrelation [1].

    Returns
    -------
    ndarray
        nu [1], shape of n: n - 1 where rho = 0; 0 for n < 2.
    """
    n = np.asarray(n, float)
    out = np.maximum(n - 1.0, 0.0)
    if rho == 0.0:
        return out

    def dof(val):
        m = int(val)
        if m < 2:
            return None
        if m > 400:                       # the long-cell limit, (n - 1)(1 - rho^2)/(1 + rho^2)
            return (m - 1) * (1 - rho * rho) / (1 + rho * rho)
        i = np.arange(m)
        CR = rho ** np.abs(i[:, None] - i[None, :])
        CR = CR - CR.mean(axis=0, keepdims=True)
        return np.trace(CR) ** 2 / float(np.sum(CR * CR.T))
    return _per_cell_size(n, dof, out)


def ar1_deviation_lag1(n: int, rho: float, powers: np.ndarray | None = None) -> tuple[float, float]:
    """Expected lag-1 sum and sum of squares of the deviations of n AR(1) readings from
    their own mean, per unit reading variance (derived in the body; no short-cell
    approximation).

    With R_ij = rho^|i-j|, row means m_t = (1/n) sum_j R_tj and M = 1^T R 1 / n^2, the
    deviation d_t = e_t - mean(e) has Cov(d_t, d_s) = R_ts - m_t - m_s + M, so
    E[sum_t d_t^2] = n - n M and E[sum_t d_t d_{t+1}] = (n-1) rho - (n+1) M + 2 m_1
    (sum_t m_t = n M, m_1 = m_n).  At rho = 0 their ratio is -1/n, the +1/n correction.

    Parameters
    ----------
    n : int
        Readings in the cell [1], at least 2.
    rho : float
        Lag-1 autocorrelation of the readings [1].
    powers : ndarray, optional
        rho ** arange(m) for some m >= n [1]: the powers cells of several sizes share (the
        same floats, each power computed alone).

    Returns
    -------
    (float, float)
        E[sum d_t d_{t+1}] / sigma^2 and E[sum d_t^2] / sigma^2 [1].
    """
    p = rho ** np.arange(n) if powers is None else powers[:n]
    k = np.arange(1, n)
    M = (n + 2.0 * float(np.sum((n - k) * p[1:]))) / (n * n)
    m1 = float(np.sum(p)) / n
    return (n - 1) * rho - (n + 1) * M + 2.0 * m1, n - n * M


def _ar1_lag1_ratio_bounded(n: int, rho: float) -> tuple[float, float]:
    """g(n, rho) = E[lag-1 sum] / E[sum of squares] of :func:`ar1_deviation_lag1` from the
    closed forms of its two geometric sums, with a bound on the rounding error of this value
    and of :func:`ar1_deviation_lag1`'s, which sums the series term by term.

    S = sum_{k<n} rho^k = (1 - rho^n) / (1 - rho) and T = sum_{k=1}^{n-1} (n - k) rho^k =
    rho (n (1 - rho) - (1 - rho^n)) / (1 - rho)^2.  The bound is the first-order (Higham,
    *Accuracy and Stability of Numerical Algorithms*, 2nd ed., sec. 3-4) error of each,
    u = 2^-53, a library power within 16 ulp: the series summed in any order
    is off by at most (n + 17) u sum |term|, the closed forms by their few
    roundings, amplified where 1 - rho^n and n (1 - rho) nearly cancel (short cells,
    rho -> 1); the rest of the formula is common to both and |g| <= 1 (Cauchy-Schwarz).

    Parameters
    ----------
    n : int
        Readings in the cell [1], at least 3.
    rho : float
        Lag-1 autocorrelation [1], |rho| < 1.

    Returns
    -------
    (float, float)
        g [1] and the bound on |g - exact g| of both evaluations [1] (inf where the sum of
        squares is not told from 0).
    """
    u, c = 2.0 ** -53, 16                          # the unit roundoff; ulp of a library power
    a, q = 1.0 - rho, rho ** n
    b = 1.0 - q
    s1, t = b / a, rho * (n * a - b) / (a * a)
    ra = abs(rho)                                  # bounds on the sums of |term|
    A1, AT = min(n, 1.0 / (1.0 - ra)), min(n * (n - 1) / 2, n * ra / (1.0 - ra))
    eb = c * u * abs(q) + u * abs(b)
    err_s = max(eb / a + 2 * u * A1, (n + c) * u * A1)
    err_t = max(ra * (eb + 3 * u * (n * a + abs(b))) / (a * a) + 5 * u * AT, (n + c + 1) * u * AT)
    M, M_abs = (n + 2.0 * t) / (n * n), (n + 2.0 * AT) / (n * n)
    err_m = 2 * (err_t + u * (n + 2.0 * AT)) / (n * n)
    err_lag1 = (n + 1) * err_m + 2 * (err_s + u * A1) / n + 3 * u * ((n - 1) * ra + (n + 1) * M_abs + 2 * A1 / n)
    err_sq = n * err_m + 2 * u * n * (1.0 + M_abs)
    squares = n - n * M
    g = ((n - 1) * rho - (n + 1) * M + 2.0 * (s1 / n)) / squares
    return g, (err_lag1 + err_sq) / (squares - 2 * err_sq) + 2 * u if squares > 4 * err_sq else math.inf


def ar1_from_lag1(r: float, n: np.ndarray, weight: np.ndarray) -> float:
    """The AR(1) correlation whose expected pooled lag-1 ratio of within-cell deviations is
    the observed one: solves sum_c w_c g(n_c, rho) = r, g = E[lag-1 sum] / E[sum of
    squares] (:func:`ar1_deviation_lag1`), by bisection within :data:`RHO_BOUNDS`.  Short
    cells bias the plain ratio low (-(1 + 3 rho)/n and more: at rho = 0.9 in 10-reading
    cells it reads about 0.5); this does not.

    Each step needs only the sign of sum_c w_c g - r: the closed form of g
    (:func:`_ar1_lag1_ratio_bounded`) gives it where it is further from 0 than the two
    evaluations' error bound, :func:`ar1_deviation_lag1` in the last steps next to the root,
    so that rho is the float the term-by-term series gives.

    Parameters
    ----------
    r : float
        Pooled sum d_t d_{t+1} over pooled sum d_t^2 [1].
    n : (ncell,) ndarray
        Readings per cell [1] (cells of fewer than 3 readings carry no information on rho
        and are left out).
    weight : (ncell,) ndarray
        Each cell's within-cell sum of squares (its share of the pooled denominator) [any].

    Returns
    -------
    float
        rho [1].
    """
    ok = (n >= 3) & (weight > 0)
    if not np.any(ok):
        return 0.0
    vals, inv = np.unique(n[ok].astype(int), return_inverse=True)
    w = np.bincount(inv, weights=weight[ok]) / float(np.sum(weight[ok]))
    vals, w, u = vals.tolist(), w.tolist(), 2.0 ** -53       # u: the unit roundoff

    def h(rho):                   # sum_c w_c g - r, or a value of its sign
        ge = [_ar1_lag1_ratio_bounded(v, rho) for v in vals]
        cheap = sum(wi * g for wi, (g, _) in zip(w, ge)) - r
        if abs(cheap) > 4 * (sum(wi * e for wi, (_, e) in zip(w, ge)) + (len(w) + 2) * u * (sum(w) + abs(r))):
            return cheap
        total, p = 0.0, rho ** np.arange(vals[-1])
        for v, wi in zip(vals, w):
            lag1, squares = ar1_deviation_lag1(v, rho, p)
            total += wi * (lag1 / squares)
        return total - r

    lo, hi = RHO_BOUNDS
    if h(lo) >= 0:
        return lo
    if h(hi) <= 0:
        return hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if h(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass
class RunCells:
    """One run reduced to cells (see the module docstring).

    Attributes
    ----------
    index : int
        Position of the run in its campaign list.
    meta : dict
        Typed metadata (drop format).
    geometry : CentrifugeMount | TumbleHead | TiltTable
        Mounting of the instrument on the rig (:func:`accelcal.physics.geometry.geometry_of`).
    cols : dict of ndarray
        The columns the forward model reads, one value per reading (for a sine run the
        logged rate is replaced by the drive fitted to it, see :func:`fitted_drive`).
    rate_derivative : ndarray or None
        d(omega)/dt per reading for sine runs (from the fitted drive), else None.
    cid : ndarray of int
        Cell of each reading; readings of dropped (duplicate) cells have cid -1.
    n : ndarray
        Readings per cell.
    y_rows, y : ndarray
        Output per reading and per cell (mean) [output_unit].
    x_rows, x : ndarray
        Centripetal level per reading and per cell [m/s^2] (0 off centrifuges).
    lines : ndarray
        File line of each cell's first reading (0 when unknown).
    attrs : dict of ndarray
        Labels per cell for localisation: time, time_frac, position, g_level, polarity,
        sweep, temperature, mount.
    noise : NoiseModel or None
        Set by :func:`with_noise` (a copy of the run).
    var_mean : ndarray or None
        Variance of each cell mean [output_unit^2].
    sha256 : str
        Hash of the source file ('' when unknown).
    notes : list of str
        What was done to the run (drive model, spikes, duplicates), for reports.
    """
    index: int
    meta: dict
    geometry: object
    cols: dict
    rate_derivative: np.ndarray | None
    cid: np.ndarray
    n: np.ndarray
    y_rows: np.ndarray
    y: np.ndarray
    x_rows: np.ndarray
    x: np.ndarray
    lines: np.ndarray
    attrs: dict = field(default_factory=dict)
    noise: NoiseModel | None = None
    var_mean: np.ndarray | None = None
    sha256: str = ""
    notes: list[str] = field(default_factory=list)

    @property
    def test(self) -> str:
        """Test kind: 'centrifuge', 'sine_centrifuge', 'tumble' or 'tilt_rotation'."""
        return str(self.meta["test"])

    @property
    def run_id(self) -> str:
        """The run's ``run_id`` (``'run<index>'`` when the metadata has none)."""
        return str(self.meta.get("run_id", f"run{self.index}"))

    @property
    def campaign(self) -> str:
        """The run's campaign id ('' when none)."""
        return str(self.meta.get("campaign", ""))

    @property
    def rig_id(self) -> str:
        """The rig's id ('' when none)."""
        return str(self.meta.get("rig_id", ""))

    @property
    def ncell(self) -> int:
        """Number of cells kept [1]."""
        return int(self.n.size)

    def _kept_mask(self) -> np.ndarray | None:
        """``cid >= 0`` (the readings kept), None when every reading is: worked out once per
        ``cid`` array (the model takes thousands of cell means per campaign; ``cid`` is only
        ever replaced, never changed in place)."""
        memo = self.__dict__.get("_keep_memo")
        if memo is None or memo[0] is not self.cid:
            keep = self.cid >= 0
            memo = self.__dict__["_keep_memo"] = (self.cid, None if keep.all() else keep)
        return memo[1]

    def cell_mean(self, rows: np.ndarray) -> np.ndarray:
        """Mean over each cell of a per-reading quantity.

        Parameters
        ----------
        rows : (nrow,) array_like
            One value per reading [any unit]; readings with cid -1 are ignored.

        Returns
        -------
        (ncell,) ndarray
            Cell means [unit of rows].
        """
        keep = self._kept_mask()
        if keep is None:              # every reading: the same sums without indexing
            return np.bincount(self.cid, weights=np.asarray(rows, float), minlength=self.ncell) / self.n
        return np.bincount(self.cid[keep], weights=np.asarray(rows, float)[keep],
                           minlength=self.ncell) / self.n

    def cell_means(self, columns: np.ndarray) -> np.ndarray:
        """:meth:`cell_mean` of each column of a block, at once.

        Parameters
        ----------
        columns : (nrow, k) array_like
            k values per reading [any unit].

        Returns
        -------
        (ncell, k) ndarray
            Column q is ``cell_mean(columns[:, q])``, bit for bit: one ``bincount`` over
            (cell, column) pairs adds each pair's readings in reading order, as the
            column's own ``bincount`` does.
        """
        X = np.asarray(columns, float)
        k = X.shape[1]
        keep = self._kept_mask()
        cid = self.cid if keep is None else self.cid[keep]
        if keep is not None:
            X = X[keep]
        pair = (cid[:, None] * k + np.arange(k)).ravel()
        sums = np.bincount(pair, weights=X.ravel(), minlength=self.ncell * k)
        return sums.reshape(self.ncell, k) / self.n[:, None]

    def _deviations(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(keep, deviation from its cell's mean per reading, sum of squares per cell, sample
        variance per cell) of a per-reading quantity."""
        keep = self.cid >= 0
        r = np.asarray(rows, float)
        if self._kept_mask() is None:
            # every reading kept: the same numbers without the masked copies
            dev = r - self.cell_mean(r)[self.cid]
            ss = np.bincount(self.cid, weights=dev * dev, minlength=self.ncell)
        else:
            dev = np.zeros_like(r)
            dev[keep] = r[keep] - self.cell_mean(r)[self.cid[keep]]
            ss = np.bincount(self.cid[keep], weights=dev[keep] ** 2, minlength=self.ncell)
        s2 = np.where(self.n >= 2, ss / np.maximum(self.n - 1, 1), np.nan)
        return keep, dev, ss, s2

    def cell_variance(self, rows: np.ndarray) -> np.ndarray:
        """Within-cell sample variance of a per-reading quantity (:meth:`cell_scatter`
        without the lag-1 correlation).

        Parameters
        ----------
        rows : (nrow,) array_like
            One value per reading [any unit]; readings with cid -1 are ignored.

        Returns
        -------
        (ncell,) ndarray
            Sample variance in each cell [unit of rows ^2]; nan for 1-reading cells.
        """
        return self._deviations(rows)[3]

    def cell_scatter(self, rows: np.ndarray, estimate_when_white: bool = False) -> tuple[np.ndarray, float, float]:
        """Within-cell sample variance of a per-reading quantity and the pooled lag-1
        autocorrelation of its deviations inside cells.

        Parameters
        ----------
        rows : (nrow,) array_like
            One value per reading [any unit]; readings with cid -1 are ignored.
        estimate_when_white : bool
            Give a rho within its sampling noise as its estimate (floored at 0, as
            ``rho`` and ``rho_hi``) instead of 0: in 8-reading cells a rho of 0.3, which
            puts a cell mean's variance 1.9 times above what white readings of the same
            scatter give, is within its sampling noise about one time in three.

        Returns
        -------
        s2 : (ncell,) ndarray
            Sample variance in each cell [unit of rows ^2]; nan for 1-reading cells.
        rho : float
            Lag-1 autocorrelation of consecutive readings of one cell [1], 0 when within
            its sampling noise (:data:`RHO_SIGNIFICANCE`, judged on the ratio less what
            white readings give in these cells) unless ``estimate_when_white``; else the
            AR(1) correlation whose expected ratio in cells of these sizes is the one
            observed (:func:`ar1_from_lag1`), clipped to :data:`RHO_BOUNDS`.
        rho_hi : float
            Upper end of rho's sampling interval (:data:`RHO_INTERVAL_Z`) [1]; rho when
            it is within its sampling noise.
        """
        keep, dev, ss, s2 = self._deviations(rows)
        same = keep[1:] & keep[:-1] & (self.cid[1:] == self.cid[:-1])
        lag = dev[1:] * dev[:-1]          # the products of the pairs, then the same-cell ones:
        num = float(np.sum(lag[same]))    # the same numbers as masking both factors first
        del lag
        dk = dev if self._kept_mask() is None else dev[keep]
        den = float(np.sum(dk * dk))
        if self._kept_mask() is None:     # counts as float sums of ones: exact, no copy of cid
            pc = np.bincount(self.cid[1:], weights=same, minlength=self.ncell)
        else:
            pc = np.bincount(self.cid[1:][same], minlength=self.ncell).astype(float)
        r = num / den if den > 0 else 0.0
        # the deviations from a cell mean are negatively correlated by -1/n: white readings
        # give the ratio r0 = -sum_c ss_c / n_c / sum_c ss_c (cells weighted as the pooled
        # ratio weights them: noise growing with rate in cells shorter than the rest would
        # otherwise read as a negative rho)
        ok2 = self.n >= 2
        r0 = -float(np.sum(ss[ok2] / self.n[ok2]) / np.sum(ss[ok2])) if np.any(ok2) and np.sum(ss[ok2]) > 0 else 0.0
        # an autocorrelation within its sampling noise is taken as 0: a noisy rho would
        # scale the weights of white-noise data by chance.  The ratio's sd is 1/sqrt(pairs)
        # when the cells' scatter is alike; where it grows with rate, the few loud cells
        # carry the ratio: var r ~ sum_c ss_c^2 / p_c / (sum_c ss_c)^2, p_c = n_c - 1 pairs
        # (the scatter each cell is expected to have: a + b x^2 through the cells' own)
        use = (pc > 0) & np.isfinite(s2)
        pairs = 0.0
        if np.any(use):
            X = np.column_stack([np.ones(int(use.sum())), self.x[use] ** 2])
            ab = np.linalg.lstsq(X, s2[use], rcond=None)[0] if np.ptp(self.x[use]) > 0 else \
                np.array([float(np.mean(s2[use])), 0.0])
            v = np.maximum(X @ ab, 0.05 * float(np.mean(s2[use])))
            w = v * (self.n[use] - 1.0)
            pairs = float(np.sum(w) ** 2 / np.sum(w * w / pc[use])) if np.sum(w) > 0 else 0.0
        white = pairs == 0 or abs(r - r0) * math.sqrt(pairs) < RHO_SIGNIFICANCE
        if white and (pairs == 0 or not estimate_when_white):
            return s2, 0.0, 0.0
        # read without the short cells' bias; one that is there with the upper end of
        # its sampling interval (Bartlett: var r ~ (1 - rho^2) / pairs)
        rho = float(np.clip(ar1_from_lag1(r, self.n, ss), *RHO_BOUNDS))
        if white:
            return s2, max(rho, 0.0), max(rho, 0.0)
        r_hi = r + RHO_INTERVAL_Z * math.sqrt(max(1.0 - rho * rho, 0.0) / pairs)
        return s2, rho, float(np.clip(max(ar1_from_lag1(r_hi, self.n, ss), rho), *RHO_BOUNDS))


# ----------------------------------------------------------------------------- building

def unique_small_ints(key: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(key, return_index=True, return_inverse=True)`` of non-negative integer
    keys of a small range (cells, a thermal run's point and position), found by counting
    instead of sorting the readings: the same three arrays, without the sort's copies of a
    long run.

    Parameters
    ----------
    key : (n,) ndarray of int
        Keys [1]; any other (negative, or a range over 4 n + 65536) goes to np.unique.

    Returns
    -------
    uniq, first, inverse : ndarray
        The sorted distinct keys, the index of each one's first reading, and each
        reading's index into ``uniq``.
    """
    if key.size == 0 or key.min() < 0 or key.max() > 4 * key.size + (1 << 16):
        return np.unique(key, return_index=True, return_inverse=True)
    present = np.bincount(key) > 0
    uniq = np.flatnonzero(present)
    rank = np.cumsum(present) - 1
    # a key's first reading starts one of the blocks of equal consecutive keys
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    first_of = np.full(present.size, key.size, np.int64)
    np.minimum.at(first_of, key[starts], starts)
    return uniq, first_of[uniq], rank[key]


class Groups:
    """Rows grouped by a key, the groups in sorted key order, with their reductions.

    Each reduction is taken in a fixed order: segment sums by ``np.add.reduceat`` where the
    rows of each group are consecutive and the column is complete, else a compensated
    (Kahan) sequential sum over each group's finite values in row order; standard
    deviations by Welford's sequential update.  These are the orders of pandas' groupby,
    so the values are its, bit for bit.

    Parameters
    ----------
    key : (n,) array_like
        Group key of each row; a missing (nan) key leaves its row out of every group.
    """

    def __init__(self, key):
        key = np.asarray(key)
        if key.dtype.kind in "iu":
            self.keys, _, ids = unique_small_ints(key)
        else:
            ok = ~np.isnan(key) if key.dtype.kind == "f" else np.ones(key.size, bool)
            self.keys, inv = np.unique(key[ok], return_inverse=True)
            ids = np.full(key.size, -1, np.intp)
            ids[ok] = inv.reshape(-1)
        self.ids = ids.reshape(-1).astype(np.intp, copy=False)
        self.ngroups = len(self.keys)
        self.counts = np.bincount(self.ids[self.ids >= 0], minlength=self.ngroups).astype(np.int64)
        #: the rows of each group are consecutive (missing keys, if any, first)
        self.monotonic = bool(np.all(self.ids[1:] >= self.ids[:-1]))

    def _segments(self, v: np.ndarray, skip_nan: bool = True):
        """The values of the rows in groups (nan values left out), ordered by group and within
        it by row, with each group's first index and size."""
        keep = self.ids >= 0
        if skip_nan and v.dtype.kind == "f":
            keep &= ~np.isnan(v)
        rows = np.flatnonzero(keep)
        if not self.monotonic:
            rows = rows[np.argsort(self.ids[rows], kind="stable")]
        sizes = np.bincount(self.ids[rows], minlength=self.ngroups)
        return v[rows], np.cumsum(sizes) - sizes, sizes

    def _reduceat(self, v: np.ndarray) -> np.ndarray | None:
        """Segment sums of a complete column whose groups are consecutive, else None."""
        if not self.monotonic or (v.dtype.kind == "f" and np.isnan(v).any()):
            return None
        vs, starts, _ = self._segments(v, skip_nan=False)
        return np.add.reduceat(vs, starts) if vs.size else np.zeros(self.ngroups, vs.dtype)

    def _sequential(self, v: np.ndarray, welford: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(sum or mean, compensation or M2, count) of each group's finite values taken one at
        a time in row order: the Kahan-compensated sum, or Welford's mean and sum of squared
        deviations, in Python floats (IEEE doubles: the operations of the array form, without
        an array call per value)."""
        vs, starts, sizes = self._segments(v)
        a, b = np.zeros(self.ngroups), np.zeros(self.ngroups)
        for g in range(self.ngroups):
            ag = bg = 0.0
            for i, x in enumerate(vs[starts[g]:starts[g] + sizes[g]].tolist(), start=1):
                if welford:
                    old = ag
                    ag += (x - old) / i
                    bg += (x - ag) * (x - old)
                else:
                    y = x - bg
                    t = ag + y
                    bg = (t - ag) - y
                    bg = 0.0 if bg != bg else bg        # an infinite value: no compensation
                    ag = t
            a[g], b[g] = ag, bg
        return a, b, sizes

    def sum(self, v) -> np.ndarray:
        """Sum of each group's finite values (0 where none)."""
        v = np.asarray(v, np.float64)
        r = self._reduceat(v)
        return r if r is not None else self._sequential(v, welford=False)[0]

    def mean(self, v) -> np.ndarray:
        """Mean of each group's finite values (nan where none)."""
        v = np.asarray(v, np.float64)
        r = self._reduceat(v)
        if r is not None:
            return r / self.counts.astype(np.float64)
        s, _, n = self._sequential(v, welford=False)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > 0, s / n, np.nan)

    def std(self, v, ddof: int = 1) -> np.ndarray:
        """Sample standard deviation of each group's finite values (nan where <= ddof)."""
        _, m2, n = self._sequential(np.asarray(v, np.float64), welford=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(n > ddof, np.sqrt(m2 / (n - ddof).astype(np.float64)), np.nan)

    def min(self, v) -> np.ndarray:
        """Least of each group's values, nan skipped (nan where none)."""
        v = np.asarray(v)
        vs, starts, sizes = self._segments(v)
        out = np.fmin.reduceat(vs, np.minimum(starts, max(vs.size - 1, 0))) if vs.size else vs
        return np.where(sizes > 0, out, np.nan) if (sizes == 0).any() else out


def fitted_drive(t: np.ndarray, logged: np.ndarray, f: float, harmonics: int = 3
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The table rate of a sinusoidal drive as the logged rate measures it, and its derivative.

    The logged ``table_rate_rad_s`` of a disc centrifuge is a measurement with its own
    noise (an encoder-derived rate).  Squared into omega^2 R that noise would enter the
    model's input (errors in variables); the drive itself is periodic, so a least-squares
    fit of a constant and ``harmonics`` harmonics of f to the logged rate recovers it
    with the noise averaged over the whole run.

    Parameters
    ----------
    t : (n,) ndarray
        Reading times [s].
    logged : (n,) ndarray
        Logged table rate [rad/s].
    f : float
        Drive frequency [Hz].
    harmonics : int
        Number of harmonics of f fitted besides the constant [1].

    Returns
    -------
    rate, rate_derivative : ndarray
        [rad/s], [rad/s^2] at the times t.

    References
    ----------
    Sun, Ren & Wang, sinusoidal-rate disc centrifuge (paper 002,
    ../shared/docs/methods.md).
    """
    t = np.asarray(t, float)
    cols, dcols = [np.ones_like(t)], [np.zeros_like(t)]
    for k in range(1, harmonics + 1):
        w = 2 * np.pi * k * f
        cols += [np.sin(w * t), np.cos(w * t)]
        dcols += [w * np.cos(w * t), -w * np.sin(w * t)]
    X, D = np.column_stack(cols), np.column_stack(dcols)
    b, *_ = np.linalg.lstsq(X, np.asarray(logged, float), rcond=None)
    return X @ b, D @ b


#: A stepped run of more readings than this is taken as means of blocks of consecutive
#: readings of one dwell (:func:`block_bounds`): the science then holds arrays of
#: about this length (a block more per dwell at most) whatever the run's, and the
#: campaign model evaluates the forward model over them whole.
BLOCK_READINGS = ROW_SLICE
#: The keys of a stepped run's cells (its dwells), by test: (column, largest step within
#: a dwell [its unit]); consecutive readings whose keys stay within these are one cell of
#: :func:`make_run`, and a block of :func:`block_bounds` never straddles two.  Sine runs
#: have no dwells and are never taken as blocks.
CELL_KEYS = {"centrifuge": (("step", 0.0),),
             "tumble": (("position", 0.0), ("angle_deg", ANGLE_TOL_DEG)),
             "tilt_rotation": (("temp_set_c", 0.0), ("rotation_deg", ANGLE_TOL_DEG))}
#: The drop format's angle columns [deg]: a block whose readings straddle the wrap of
#: the circle (0/360, or +-180) is averaged on the circle (:func:`block_means`).
ANGLE_COLUMNS = frozenset({"table_angle_deg", "angle_deg", "rotation_deg"})
#: Key of a run's metadata that says it was taken as block means: (readings, blocks,
#: most readings in a block).
BLOCK_META_KEY = "block_means"


def dwell_starts(test: str, cols, n: int) -> np.ndarray:
    """The first reading of each dwell of a run: the one segmentation of a run into dwells,
    for the science's cells (:func:`make_run`), its blocks (:func:`block_bounds`) and the
    validation's within-dwell checks (:mod:`accelcal.schemas.derived`).

    A dwell is a run of consecutive readings whose keys (:data:`CELL_KEYS`) each stay
    within their tolerance of the reading before's (a missing key equals a missing key);
    a run without dwells (a sine run) is one dwell.

    Parameters
    ----------
    test : str
        The run's test kind.
    cols : mapping
        The run's key columns, ``cols[c]`` an array of its readings.
    n : int
        Readings in the run [1].

    Returns
    -------
    (ndwell,) ndarray of int
        Row of each dwell's first reading, ascending (0 first; empty when n is 0).
    """
    change = np.zeros(n, bool)
    change[:1] = True
    for c, tol in CELL_KEYS.get(test, ()):
        k = np.asarray(cols[c], float)
        k = np.where(np.isfinite(k), k, -1e300)
        change[1:] |= (np.abs(k[1:] - k[:-1]) > tol) if tol > 0 else (k[1:] != k[:-1])
    return np.flatnonzero(change)


def block_bounds(rows_of, test: str, n: int, most: int, rows_at_once: int = ROW_SLICE) -> np.ndarray:
    """Blocks of consecutive readings that a long stepped run is taken as.

    Each dwell (:func:`dwell_starts`: a cell of :func:`make_run`) of m readings is cut into
    q = ceil(m / most) blocks of near-equal length (floor or ceil of m / q readings): the
    mean of a block is a reading of the run with its noise divided by about the block's
    length, so a dwell's blocks are alike (the noise model's cell scatter stays that of one
    kind of reading) and their mean is the dwell's mean to within the unequal lengths.  The dwells are found ``rows_at_once``
    readings at a time (each slice with the reading before it): the same dwells as the
    whole run's keys give.

    Parameters
    ----------
    rows_of : callable
        ``rows_of(c, lo, hi)`` gives readings ``lo`` to ``hi`` of column ``c``.
    test : str
        The run's test kind (its dwell keys, :data:`CELL_KEYS`).
    n : int
        Readings in the run [1].
    most : int
        Most readings in a block [1].
    rows_at_once : int
        Readings read at a time [1].

    Returns
    -------
    (nblock + 1,) ndarray of int
        Row of each block's first reading, then n: block i is rows
        ``bounds[i]:bounds[i + 1]``.
    """
    if n == 0:
        return np.zeros(1, np.int64)
    parts = []
    for lo in range(0, n, rows_at_once):
        hi = min(lo + rows_at_once, n)
        a = max(lo - 1, 0)
        starts = dwell_starts(test, {c: rows_of(c, a, hi) for c, _ in CELL_KEYS[test]}, hi - a)
        parts.append(starts if lo == 0 else starts[1:] + a)
    first = np.concatenate(parts)
    m = np.diff(np.r_[first, n])
    q = -(-m // max(int(most), 1))
    dwell = np.repeat(np.arange(first.size), q)
    i = np.arange(int(q.sum())) - np.repeat(np.cumsum(q) - q, q)
    return np.r_[first[dwell] + (i * m[dwell]) // q[dwell], n].astype(np.int64)


def block_means(rows_of, names: Sequence[str], bounds: np.ndarray, first: Sequence[str],
                rows_at_once: int = ROW_SLICE) -> dict[str, np.ndarray]:
    """The columns of a run as block means (:func:`block_bounds`), one column and about
    ``rows_at_once`` readings at a time.

    Parameters
    ----------
    rows_of : callable
        ``rows_of(c, lo, hi)`` gives readings ``lo`` to ``hi`` of column ``c``.
    names : sequence of str
        The columns to make.
    bounds : (nblock + 1,) ndarray of int
        From :func:`block_bounds`.
    first : sequence of str
        Columns constant in a block (the dwell keys) or naming where it starts (``line``):
        their first reading's value, in its own type.
    rows_at_once : int
        Readings read at a time [1].

    Returns
    -------
    dict of str to (nblock,) ndarray
        Per block: the mean of each other column over its finite readings (nan where it
        has none: an empty cell of a nullable column) [the column's unit]; the first
        reading's value of the ``first`` columns.
    """
    nb = int(bounds.size) - 1
    # ranges of whole blocks of about rows_at_once readings each
    cuts = [0]
    while cuts[-1] < nb:
        lo = bounds[cuts[-1]]
        cuts.append(max(int(np.searchsorted(bounds, lo + rows_at_once, side="right")) - 1,
                        cuts[-1] + 1))
        cuts[-1] = min(cuts[-1], nb)
    out: dict[str, np.ndarray] = {}
    for c in names:
        col = None
        for a, b in zip(cuts[:-1], cuts[1:]):
            lo, hi = int(bounds[a]), int(bounds[b])
            v = rows_of(c, lo, hi)
            at = bounds[a:b] - lo
            if c in first:
                part = v[at]
            else:
                ok = np.isfinite(v)
                total = np.add.reduceat(np.where(ok, v, 0.0), at)
                count = np.add.reduceat(ok.astype(np.int64), at)
                with np.errstate(invalid="ignore", divide="ignore"):
                    part = np.where(count > 0, total / np.maximum(count, 1), np.nan)
                if c in ANGLE_COLUMNS:
                    part = _circular_means(v, ok, at, count, part)
            if col is None:
                col = np.empty(nb, part.dtype)
            col[a:b] = part
        out[c] = col if col is not None else np.zeros(0)
    return out


def _circular_means(v: np.ndarray, ok: np.ndarray, at: np.ndarray, count: np.ndarray,
                    part: np.ndarray) -> np.ndarray:
    """Block means of an angle column [deg] (:func:`block_means`' ``part``) with each block
    whose readings straddle the circle's wrap -- spread over more than 180 deg, as an
    azimuth logged about 0 as 359.99 and 0.01 is -- averaged on the circle instead: its
    readings below the middle of their range turned once round (+360 deg), then the mean
    taken back into [0, 360).  Every other block keeps its plain mean, bit for bit."""
    lo = np.fmin.reduceat(np.where(ok, v, np.inf), at)
    hi = np.fmax.reduceat(np.where(ok, v, -np.inf), at)
    wrap = (count > 0) & (hi - lo > 180.0)
    if not wrap.any():
        return part
    mid = np.repeat(0.5 * (lo + hi), np.diff(np.r_[at, v.size]))
    turned = np.add.reduceat(np.where(ok, np.where(v < mid, v + 360.0, v), 0.0), at)
    return np.where(wrap, np.mod(turned / np.maximum(count, 1), 360.0), part)


def long_run_blocks(test: str, n_rows: int, cols: Mapping) -> tuple[dict, dict] | None:
    """How the science takes a run: a stepped run of more than :data:`BLOCK_READINGS`
    readings as the means of blocks of consecutive readings of one dwell, else
    whole.

    Parameters
    ----------
    test : str
        The run's test kind.
    n_rows : int
        Its readings [1].
    cols : mapping
        Its columns (the test's and ``line``), read a slice of readings at a time by
        ``cols.rows(c, lo, hi)`` (a run in its Parquet file,
        :class:`accelcal.schemas.tables.ParquetColumns`).

    Returns
    -------
    (dict of ndarray, dict) or None
        The block means of every column (:func:`block_bounds`, at most
        ceil(n_rows / BLOCK_READINGS) readings a block; :func:`block_means`, the exact
        cell keys and ``line`` from a block's first reading) and what to add to the run's
        metadata (:data:`BLOCK_META_KEY`: readings, blocks, most readings in a block);
        None for a run to be read whole (a sine run, or one of at most BLOCK_READINGS).
    """
    if n_rows <= BLOCK_READINGS or test not in CELL_KEYS:
        return None
    most = -(-n_rows // BLOCK_READINGS)
    bounds = block_bounds(cols.rows, test, n_rows, most)
    exact = tuple(c for c, tol in CELL_KEYS[test] if tol == 0)      # the same in every reading of a block
    data = block_means(cols.rows, list(cols), bounds, first=(*exact, "line"))
    return data, {BLOCK_META_KEY: [int(n_rows), int(bounds.size - 1), int(most)]}


def _float_columns(data, names: Sequence[str]) -> dict[str, np.ndarray]:
    """``{c: np.asarray(data[c], float)}`` of every column but ``line``: a float64 column of
    a DataFrame is used as it is (a big run is in memory once), any other converted."""
    return {c: np.asarray(data[c], float) for c in names if c != "line"}


def make_run(meta: Mapping, data, index: int = 0, sha256: str = "", sine_segments: int = 1) -> RunCells:
    """Cells, levels and labels of one run (typed meta and its columns).

    Parameters
    ----------
    meta : mapping
        Typed metadata of the drop format.
    data : DataFrame or mapping of arrays
        The run's columns (drop format), optionally with ``line`` (file line numbers).
    index : int
        Position of the run in its campaign list [1].
    sha256 : str
        Hash of the source file, kept on the run.
    sine_segments : int
        A sine run's cells are the phases of the drive within each of this many equal
        stretches of time (default 1: across the whole run).  With one, whatever changes
        slowly in time (a bias drift) lands inside the cells, in the noise; the diagnosis
        uses several, keeping at least five periods per cell.

    Returns
    -------
    RunCells
        Cells of the run: centrifuge dwells by ``step``; tumble positions by
        (``position``, ``angle_deg`` within :data:`ANGLE_TOL_DEG`); tilt-rotation dwells
        by (``temp_set_c``, ``rotation_deg``); sine runs by drive phase, with the table
        rate replaced by :func:`drive_rate` (the logged one kept as
        ``logged_rate_rad_s``).  No noise model yet (see :func:`fit_noise`).

    Raises
    ------
    ValueError
        When ``meta['test']`` is not a known test kind.
    """
    meta = dict(meta)
    test = str(meta["test"])
    geo = geometry_of(meta)
    all_names = list(data.columns if hasattr(data, "columns") else data.keys())
    cols = _float_columns(data, all_names)
    nrow = len(cols["output"])
    t = cols.get("time_s", np.arange(nrow, dtype=float))
    lines = np.asarray(data["line"], float) if "line" in all_names else np.zeros(nrow)
    wdot = None
    if test in CELL_KEYS:
        starts = dwell_starts(test, cols, nrow)
        cid = np.repeat(np.arange(starts.size), np.diff(np.r_[starts, nrow]))
    elif test == "sine_centrifuge":
        f = float(meta["rate_frequency_hz"])
        rate, wdot, drive_note = drive_rate(meta, t, cols["table_rate_rad_s"])
        cols["logged_rate_rad_s"] = cols["table_rate_rad_s"]
        cols["table_rate_rad_s"] = rate
        cols["table_angle_deg"] = np.nan_to_num(cols.get("table_angle_deg", np.zeros(nrow)))
        dt = float(np.median(np.diff(t))) if nrow > 1 else 1.0
        nb = max(int(round(1.0 / (f * dt))), 1)
        cid = np.floor(((t - t[0]) * f % 1.0) * nb + 0.5).astype(int) % nb
        periods = float(np.ptp(t)) * f if nrow > 1 else 0.0
        seg = int(max(1, min(sine_segments, periods // 5)))
        if seg > 1:
            cid = cid + nb * np.minimum(((t - t[0]) / (np.ptp(t) + dt) * seg).astype(int), seg - 1)
    else:
        raise ValueError(f"unknown test kind {test!r}")
    cid = unique_small_ints(cid)[2]
    k = int(cid.max()) + 1 if cid.size else 0
    n = np.bincount(cid, minlength=k).astype(float)
    y_rows = cols["output"]
    y = np.bincount(cid, weights=y_rows, minlength=k) / n
    first_line = np.full(k, np.inf)
    np.minimum.at(first_line, cid, lines)
    x_rows = np.zeros(nrow)
    if isinstance(geo, CentrifugeMount):
        x_rows = centripetal_level(meta, cols["table_rate_rad_s"], geo.arm_radius_m)
    run = RunCells(index=index, meta=meta, geometry=geo, cols=cols, rate_derivative=wdot, cid=cid, n=n,
                   y_rows=y_rows, y=y, x_rows=x_rows, x=np.bincount(cid, weights=x_rows, minlength=k) / n,
                   lines=np.where(np.isfinite(first_line), first_line, 0).astype(int), sha256=sha256)
    run.attrs = _labels(run, t)
    if test == "sine_centrifuge":
        run.notes.append(drive_note)
    if BLOCK_META_KEY in meta:
        run.notes.append(block_note(run))
    return run


def block_note(run: RunCells) -> str | None:
    """What a run taken as block means (:func:`long_run_blocks`) says of it, for its notes
    and the joint fit's; None for a run taken reading by reading.

    Parameters
    ----------
    run : RunCells
        The run (its ``meta`` holds :data:`BLOCK_META_KEY` when it was taken so).

    Returns
    -------
    str or None
    """
    if BLOCK_META_KEY not in run.meta:
        return None
    readings, blocks, most = run.meta[BLOCK_META_KEY]
    return (f"{run.run_id}: its {readings:,} readings are taken as the means of {blocks:,} "
            f"blocks of at most {most} consecutive readings of one dwell (a long run)")


def drive_rate(meta: Mapping, t: np.ndarray, logged: np.ndarray, alpha: float = 1e-6,
               harmonics: int = 3) -> tuple[np.ndarray, np.ndarray | None, str]:
    """The table rate a sine run's model uses, and its derivative (None = the drive's own).

    The logged rate is a measurement of the drive omega = Omega sin(2 pi f t) (paper 002)
    with its own noise.  The nominal drive is used unless the logged rate departs from it
    beyond that noise (F test of a fit of a constant and ``harmonics`` harmonics of f
    against the nominal drive, at ``alpha``); then the fitted drive is used, since the
    table did not follow its command.  Using the logged rate itself would square its noise
    into the centripetal input (errors in variables).  alpha is small (1e-6) because the
    fitted drive carries its own estimation noise into every cell of the run, and the
    rate noise of a real table is often proportional to the rate, which the F test's
    constant variance does not know; a table that does not follow its command by the paper's
    5e-5 rad/s gives F in the thousands.

    Parameters
    ----------
    meta : mapping
        Typed metadata with ``rate_amplitude_rad_s`` (Omega) [rad/s] and
        ``rate_frequency_hz`` (f) [Hz].
    t : (n,) ndarray
        Reading times [s].
    logged : (n,) ndarray
        Logged table rate [rad/s].
    alpha : float
        Significance level of the F test [1].
    harmonics : int
        Number of harmonics of f in the fitted drive [1].

    Returns
    -------
    rate : (n,) ndarray
        Table rate for the model [rad/s].
    rate_derivative : (n,) ndarray or None
        Its time derivative [rad/s^2]; None when the nominal drive is used (the model
        differentiates the nominal drive itself).
    note : str
        Which drive was chosen, with F and p, for the run's notes.

    References
    ----------
    Sun, Ren & Wang, sinusoidal-rate disc centrifuge (paper 002,
    ../shared/docs/methods.md).
    """
    f = float(meta["rate_frequency_hz"])
    nominal = sine_drive(meta, t)
    fit, dfit = fitted_drive(t, logged, f, harmonics)
    q = 2 * harmonics + 1
    rss1 = float(np.sum((logged - fit) ** 2))
    rss0 = float(np.sum((logged - nominal) ** 2))
    dof = max(len(t) - q, 1)
    t = nested_test(rss0, rss1, q, dof, always_scaled=True)
    F, p = (t.statistic, t.p_value) if rss1 > 0 else (float("inf"), 0.0)
    if p >= alpha:
        return nominal, None, (f"logged rate follows the nominal drive within its noise ({math.sqrt(rss1 / dof):.2g} "
                               f"rad/s, F = {F:.3g}, p = {p:.2g}): the nominal drive is the model's rate")
    return fit, dfit, (f"logged rate departs from the nominal drive (F = {F:.3g}, p = {p:.2g}): the drive "
                       f"fitted to it ({harmonics} harmonics) is the model's rate")


def _labels(run: RunCells, t: np.ndarray) -> dict:
    """Per-cell labels: where along which dimension each cell lies (diagnosis localisation)."""
    meta, geo, k = run.meta, run.geometry, run.ncell
    attrs: dict[str, np.ndarray] = {}
    tm = run.cell_mean(t)
    attrs["time"] = tm
    attrs["time_frac"] = (tm - tm.min()) / max(float(np.ptp(tm)), 1e-12) if k else tm
    if "temp_c" in run.cols:
        T = run.cols["temp_c"]
        if np.isfinite(T).any():            # a copy only where there are gaps to fill
            attrs["temperature"] = run.cell_mean(np.nan_to_num(T, nan=float(np.nanmean(T)))
                                                 if np.isnan(T).any() else T)
    if run.test == "tilt_rotation":
        attrs["temperature"] = run.cell_mean(run.cols["temp_set_c"])
        attrs["position"] = run.cell_mean(run.cols["rotation_deg"]) % 360.0
    elif run.test == "tumble":
        attrs["position"] = run.cell_mean(run.cols["angle_deg"]) % 360.0
        attrs["mount"] = np.array([geo.label] * k, object)
    else:
        g = float(meta["g_local_m_s2"])
        attrs["g_level"] = run.x / g
        pol = "+" if math.cos(geo.phi_rad) > 1e-6 else ("-" if math.cos(geo.phi_rad) < -1e-6 else "0")
        attrs["polarity"] = np.array([pol] * k, object)
        attrs["mount"] = np.array([f"{geo.plane}@{geo.phi_deg:g}"] * k, object)
        if run.test == "centrifuge":
            rate = run.cell_mean(run.cols["table_rate_rad_s"])
            imax = int(np.argmax(rate)) if k else 0
            order = np.argsort(tm)
            rank = np.empty(k, int)
            rank[order] = np.arange(k)
            attrs["sweep"] = np.where(rate <= 0, "rest", np.where(rank <= rank[imax], "up", "down")).astype(object)
        else:
            f = float(meta["rate_frequency_hz"])
            attrs["position"] = run.cell_mean(((t - t[0]) * f % 1.0) * 360.0)
    return attrs


def reject_spikes(run: RunCells, k: float = SPIKE_SIGMAS) -> int:
    """Drop the readings further than ``k`` robust sigmas from their cell's median (rare
    spikes of a DAQ), in place, with a note on the run.

    The robust sigma of a cell is 1.4826 times its median absolute deviation, but at least
    half the median of the run's cells (a cell of a few equal readings has none) and twice
    the output's count size when the output is quantised.  Cells of fewer than four readings
    are left alone.  Dropped readings get cid -1 and ``n``, ``y``, ``x`` are recomputed.

    Parameters
    ----------
    run : RunCells
        The run, changed in place.
    k : float
        Threshold in robust sigmas [1].

    Returns
    -------
    int
        Number of readings dropped [1].
    """
    keep = run.cid >= 0
    y = run.y_rows
    k_cells = run.ncell
    med = np.full(k_cells, np.nan)
    mad = np.full(k_cells, np.nan)
    order = np.argsort(run.cid, kind="stable")
    cid_s = run.cid[order]
    for c in range(k_cells):
        a, b = np.searchsorted(cid_s, c), np.searchsorted(cid_s, c, side="right")
        if b - a >= 4:
            v = y[order[a:b]]
            med[c] = np.median(v)
            mad[c] = 1.4826 * np.median(np.abs(v - med[c]))
    ok = np.isfinite(mad)
    if not ok.any():
        return 0
    u = np.unique(y[keep])
    quantum = float(np.min(np.diff(u))) if u.size > 1 else 0.0
    floor = max(0.5 * float(np.median(mad[ok])), 2.0 * quantum)
    scale = np.maximum(np.where(ok, mad, np.inf), floor)
    c = np.where(keep, run.cid, 0)
    bad = keep & ok[c] & (np.abs(y - med[c]) > k * scale[c])
    nbad = int(bad.sum())
    if nbad:
        run.cid = np.where(bad, -1, run.cid)
        n = np.bincount(run.cid[run.cid >= 0], minlength=k_cells).astype(float)
        run.n = n
        run.y = run.cell_mean(y)
        run.x = run.cell_mean(run.x_rows)
        run.notes.append(f"{nbad} reading(s) more than {k:g} robust sigmas from their cell's median dropped "
                         "as spikes")
    return nbad


def drop_duplicate_cells(runs: Sequence[RunCells]) -> list[str]:
    """Cells whose readings (time and output, to the last digit) already appear in an
    earlier run are dropped from the later one: the same recording counted twice would
    halve its uncertainty.

    Parameters
    ----------
    runs : sequence of RunCells
        Runs in campaign order; later runs lose their duplicate cells, in place (cells
        renumbered, their readings given cid -1, a note added to the run).

    Returns
    -------
    list of str
        One note per run affected.
    """
    seen: dict[str, tuple[str, int]] = {}
    notes = []
    for run in runs:
        t = run.cols.get("time_s", np.arange(run.y_rows.size, dtype=float))
        dup = []
        # rows of cell c in row order: a stable sort by cell, split at the cell boundaries
        # (the same rows, and bytes, as np.flatnonzero(run.cid == c) taken cell by cell)
        order = np.argsort(run.cid, kind="stable")
        bounds = np.searchsorted(run.cid[order], np.arange(run.ncell + 1))
        for c in range(run.ncell):
            rows = order[bounds[c]:bounds[c + 1]]
            ty = np.column_stack((t[rows], run.y_rows[rows]))
            h = hashlib.sha1(ty.tobytes()).hexdigest()
            if h in seen and seen[h][0] != run.run_id:
                dup.append((c, seen[h]))
            else:
                seen.setdefault(h, (run.run_id, c))
        if dup:
            drop = np.array([c for c, _ in dup])
            keep = np.setdiff1d(np.arange(run.ncell), drop)
            _restrict(run, keep)
            others = sorted({o for _, (o, _) in dup})
            note = (f"{run.run_id}: {len(dup)} of its cells hold readings already in {', '.join(others)} "
                    "(the same recording); counted once")
            run.notes.append(note)
            notes.append(note)
    return notes


def _restrict(run: RunCells, keep: np.ndarray) -> None:
    """Keep only the cells ``keep`` (renumbered); readings of the others get cid -1."""
    remap = np.full(run.ncell, -1)
    remap[keep] = np.arange(keep.size)
    run.cid = np.where(run.cid >= 0, remap[np.maximum(run.cid, 0)], -1)
    run.n, run.y, run.x, run.lines = run.n[keep], run.y[keep], run.x[keep], run.lines[keep]
    run.attrs = {k: v[keep] for k, v in run.attrs.items()}
    if run.var_mean is not None:
        run.var_mean = run.var_mean[keep]


# ----------------------------------------------------------------------------- noise

def fit_noise(run: RunCells, residual_rows: np.ndarray | None = None, *, use_level: bool | None = None,
              cautious: bool = False) -> NoiseModel:
    """The run's :class:`NoiseModel`, fitted to the within-cell scatter of ``residual_rows``
    (output minus model per reading; default the outputs themselves); the run is not
    changed (:func:`with_noise` makes the run that carries it).

    The within-cell variances are corrected for the AR(1) bias
    (:func:`ar1_variance_factor`) and a + b x^2 is fitted to them by the Gamma (chi-square)
    likelihood.

    Parameters
    ----------
    run : RunCells
        The run.
    residual_rows : (nrow,) ndarray, optional
        Output minus model per reading [output_unit]; None uses the outputs.
    use_level : bool, optional
        Fit the b x^2 term (default: for centrifuge runs whose level x varies, as their
        noise grows with rate).
    cautious : bool
        Take rho at the upper end of its sampling interval (``rho_hi``) for everything,
        and one within its sampling noise at its estimate, not 0: a cell mean's noise is
        then not put too low where short cells read rho low (the diagnosis, which must
        not call coloured noise a gap).

    Returns
    -------
    NoiseModel
        a [output_unit^2], b [output_unit^2/(m/s^2)^2], rho [1]; a = nan and source
        'none' when no cell has two readings.
    """
    rows = run.y_rows if residual_rows is None else residual_rows
    s2, rho, rho_hi = run.cell_scatter(rows, estimate_when_white=cautious)
    if cautious:
        rho = rho_hi
    ok = (run.n >= 2) & np.isfinite(s2)
    if use_level is None:
        use_level = isinstance(run.geometry, CentrifugeMount) and float(np.ptp(run.x)) > 0
    if not ok.any():
        model = NoiseModel(a=float("nan"), source="none")
    else:
        cs = ar1_variance_factor(run.n[ok], rho)
        S = s2[ok] / cs
        nu = run.n[ok] - 1.0
        X = run.x[ok]
        model = _fit_variance_function(S, nu, X, use_level)
        model.rho = rho
        model.rho_hi = rho_hi
        model.dof = int(nu.sum())
        model.source = "outputs" if residual_rows is None else "residuals"
    return model


def with_noise(run: RunCells, model: NoiseModel) -> RunCells:
    """A copy of the run (its arrays shared) that carries a noise model and the variance of
    each cell mean under it (``var_mean``, :func:`mean_variance`)."""
    return replace(run, noise=model, var_mean=mean_variance(run, model))


@lru_cache(maxsize=1)
def _profile_grid() -> np.ndarray:
    """The t grid of :func:`_fit_variance_function` (a constant: built once, read only)."""
    ts = np.concatenate([[0.0], np.geomspace(1e-9, 1.0, 46)[:-1], [1.0 - 1e-12]])
    ts.setflags(write=False)
    return ts


def _fit_variance_function(S: np.ndarray, nu: np.ndarray, X: np.ndarray, use_level: bool) -> NoiseModel:
    """a + b x^2 by the Gamma likelihood of cell variances S with nu dof each.

    Written v = c ((1 - t) + t u), u = (x / max|x|)^2, t in [0, 1]: for each t the scale c
    has a closed form, c = sum(nu S / w) / sum(nu), so the likelihood is profiled on t alone
    (a grid, then Brent's method on the best bracket): the same maximum as a 2-D search,
    some 50 times faster (the diagnosis refits noise models many times)."""
    pooled = float(np.sum(nu * S) / np.sum(nu))
    if not use_level or S.size < 3 or float(np.ptp(X)) == 0.0:
        return NoiseModel(a=max(pooled, 1e-300))
    sx = max(float(np.max(np.abs(X))), 1e-30)
    u = (np.asarray(X, float) / sx) ** 2
    sn = float(np.sum(nu))

    add = np.add.reduce          # np.sum's own reduction, without its wrapper (called ~30 times per fit)

    def profile(t: float) -> tuple[float, float]:
        w = np.maximum((1.0 - t) + t * u, 1e-300)
        c = max(float(add(nu * S / w, axis=None)) / sn, 1e-300)
        return sn * math.log(c) + float(add(nu * np.log(w), axis=None)), c

    ts = _profile_grid()
    # the grid at once: row k is profile(ts[k]) element for element (the same operations on
    # the same values; each row summed on its own as the 1-d sums do)
    W = np.maximum((1.0 - ts[:, None]) + ts[:, None] * u, 1e-300)
    cs = np.sum(nu * S / W, axis=1)
    ls = np.sum(nu * np.log(W), axis=1)
    vals = [sn * math.log(max(float(ck) / sn, 1e-300)) + float(lk) for ck, lk in zip(cs, ls)]
    k = int(np.argmin(vals))
    t = float(ts[k])
    lo, hi = float(ts[max(k - 1, 0)]), float(ts[min(k + 1, ts.size - 1)])
    r = minimize_scalar(lambda q: profile(q)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
    if r.fun < vals[k]:
        t = float(r.x)
    c = profile(t)[1]
    return NoiseModel(a=float(c * (1.0 - t)), b=float(c * t / sx ** 2), n_params=2)


def pooled_noise(runs: Sequence[RunCells]) -> NoiseModel | None:
    """One noise model for several runs of the same kind: a, b and rho averaged with their
    pure-error degrees of freedom as weights (a run's own estimate rests on few replicates
    per cell; what a run not yet made will show is better told by all of them).

    Parameters
    ----------
    runs : sequence of RunCells
        Runs with noise models (those without a finite estimate are left out).

    Returns
    -------
    NoiseModel or None
        a [output_unit^2], b [output_unit^2 / (m/s^2)^2], rho [1], source 'pooled'; None
        when no run has an estimate.
    """
    ok = [r.noise for r in runs if r.noise is not None and math.isfinite(r.noise.a)]
    if not ok:
        return None
    w = np.array([max(m.dof, 1) for m in ok], float)
    avg = lambda v: float(np.sum(w * np.array(v, float)) / np.sum(w))  # noqa: E731
    return NoiseModel(a=avg([m.a for m in ok]), b=avg([m.b for m in ok]), rho=avg([m.rho for m in ok]),
                      rho_hi=avg([m.rho_hi for m in ok]), dof=int(w.sum()), source="pooled")


def mean_variance(run: RunCells, model: NoiseModel) -> np.ndarray:
    """Variance of each cell mean of ``run`` under a noise model: sigma^2(x) times
    :func:`ar1_mean_factor` over n (``var_mean`` of :func:`with_noise`).

    Parameters
    ----------
    run : RunCells
    model : NoiseModel

    Returns
    -------
    ndarray
        [output_unit^2], one per cell.
    """
    return model.reading_variance(run.x) * ar1_mean_factor(run.n, model.rho) / run.n


def pool_missing_noise(runs: Sequence[RunCells], noise: Sequence[NoiseModel]) -> list[NoiseModel]:
    """The noise models of runs with those without replicates (no estimate) replaced by the
    median reading variance of the runs of the same test kind that have one (a run pooled
    so counts for the runs after it).

    Without such peers the variance of the run's outputs is used (1 if that is 0).  The
    pooled model is white (b = 0, rho = 0), source 'pooled'.

    Parameters
    ----------
    runs : sequence of RunCells
    noise : sequence of NoiseModel
        Each run's own estimate (:func:`fit_noise`).

    Returns
    -------
    list of NoiseModel
        One per run.
    """
    out = list(noise)
    for j, run in enumerate(runs):
        if math.isfinite(out[j].a):
            continue
        peers = [m.a for r, m in zip(runs, out) if r.test == run.test and math.isfinite(m.a)]
        a = float(np.median(peers)) if peers else float(np.var(run.y_rows)) or 1.0
        out[j] = NoiseModel(a=a, source="pooled")
    return out
