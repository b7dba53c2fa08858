"""The fits a diagnosis compares: the campaign model (:class:`accelcal.fitting.model.
CampaignModel`, the one forward model) with the baseline effects and with candidates added,
all on the same cells and the same noise model, and the statistics on them (lack of fit,
likelihood ratio, held-out gap).

Conventions: every residual is whitened by the noise model of its run (fitted to the
within-cell scatter of the bare model's residuals, :func:`accelcal.fitting.data.fit_noise`),
so that fits with different effects are compared on the same weights (a likelihood ratio
needs them).  Gaps are rms excesses over the noise in units of a cell mean's sigma.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np
from scipy import stats

from ..effects import EFFECTS
from ..fitting.core import ParameterSet, column_space_basis, separable_columns, thin_svd
from ..fitting.data import RunCells
from ..fitting.identify import ALIAS_TOL, PRIORITY, Hold, Why
from ..fitting.model import CANDIDATE_SHARED, CampaignModel, effect_claim
from ..fitting.procedure import ModelFit, fit_model
from ..physics.rigs import INSTRUMENT_EFFECTS

#: Instrument coefficients that are not catalogue effects.  A candidate effect aliased with
#: one claims the direction where the joint fit's order puts it first
#: (:func:`accelcal.fitting.model.effect_claim`): the bare model holds the coefficient and the diagnosis names it
#: as the effect's coefficient alias (Kip and Kpp with only 0 and 45 deg mounts); where the
#: coefficient comes first (Kp before a mount angle), the bare model keeps it and the effect
#: is reported as absorbed by it.
NON_CATALOGUE = ("Kp", "Ko", "Kio", "Kpo", "Kpp", "Koo")
#: Catalogue instrument terms a test is designed to measure: part of the bare model where
#: that test is present (the tilt-rotation test measures K0T and K1T, paper 001).
DESIGNED_TERMS = ("K0T", "K1T")
#: Level of the lack-of-fit test that says whether a gap remains: a claim that the model is
#: inadequate is a strong one (one clean campaign in a thousand makes it by chance).
GAP_ALPHA = 0.001


class Fit(ModelFit):
    """A fitted model of the diagnosis: a :class:`~accelcal.fitting.procedure.ModelFit`,
    whose :class:`~accelcal.fitting.core.FitResult` ``fit`` holds the values, the whitened
    residual and Jacobian, chi-square, rank, lack of fit and the one covariance of every
    parameter; this class names parameters as the diagnosis asks for them (None, not an
    error, for a parameter the model lacks or does not determine)."""

    def index(self, name: str) -> int | None:
        """Position of a parameter in this fit's model.

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        int or None
            Its index in ``model.params``, :attr:`p` and the columns of :attr:`J`; None when
            the model has no such parameter.
        """
        return self.model.params.index.get(name)

    def value(self, name: str) -> float | None:
        """Estimate of one parameter, None when the model lacks it.

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float or None
            Estimate, or the held value when held [parameter unit]; None when the model has
            no such parameter.
        """
        return None if self.index(name) is None else self.fit.value(name)

    def std(self, name: str) -> float | None:
        """Standard uncertainty of one parameter: the fit result's
        (:meth:`accelcal.fitting.core.FitResult.std`, the lack-of-fit factor included).

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float or None
            [parameter unit]; None when the model has no such parameter, it is held or not
            determined, or its variance is not positive.
        """
        if self.index(name) is None:
            return None
        u = self.fit.std(name)
        return u if u > 0 else None

    def basis(self) -> np.ndarray:
        """Orthonormal basis of the span of the free columns (whitened).

        Returns
        -------
        (N, r) ndarray
            :func:`accelcal.fitting.core.column_space_basis` of the free, active columns of
            ``fit.J`` [1]; r is the rank.
        """
        return column_space_basis(self.fit.J[:, self.active])

    def effect_parameters(self, effect: str) -> list[str]:
        """Names of the free parameters of an effect in this model (theta0 per head, ...).

        Parameters
        ----------
        effect : str
            effects.md id; an instrument-term effect (``odd_quadratic``, ``cubic``,
            ``cross_coupling``, ``bias_temperature``, ``scale_temperature``) also names its
            coefficient (Koq, K3, Kip, K0T, K1T; one per campaign).

        Returns
        -------
        list of str
            Names of the parameters that are the effect and free and active in this fit
            (:attr:`active`), in model order; empty when there are none.
        """
        coef = INSTRUMENT_EFFECTS.get(effect)
        return [prm.name for prm, role, v in zip(self.model.params, self.model.roles, self.active)
                if v and ((role.kind == "effect" and role.key == effect) or (coef and role.kind == "coef"
                                                                              and role.key == coef))]

    def effect_parameter(self, effect: str) -> str | None:
        """Name of the (single) parameter of an effect in this model, if it has one.

        Parameters
        ----------
        effect : str
            effects.md id; an instrument-term effect without an effect parameter falls back
            on its coefficient (Koq, K3, Kip, K0T, K1T).

        Returns
        -------
        str or None
            The name when exactly one varying (not held) parameter is the effect's; None
            when there is none or several (one per head, mount or campaign).
        """
        names = [prm.name for prm, role in zip(self.model.params, self.model.roles)
                 if role.kind == "effect" and role.key == effect and prm.vary]
        if not names:
            coef = INSTRUMENT_EFFECTS.get(effect)
            names = [prm.name for prm, role in zip(self.model.params, self.model.roles)
                     if role.kind == "coef" and role.key == coef and prm.vary]
        return names[0] if len(names) == 1 else None


def project_out(U: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v minus its part in the span of U (orthonormal columns).

    Parameters
    ----------
    U : (n, r) ndarray
        Orthonormal columns, e.g. :meth:`Fit.basis` [1].
    v : (n,) or (n, k) ndarray
        Vector(s) to project [any unit].

    Returns
    -------
    ndarray
        ``v - U (U^T v)``, orthogonal to the columns of U [unit of v].
    """
    return v - U @ (U.T @ v)


# ----------------------------------------------------------------------------- the fits
class Fitter:
    """Fits campaign models of one set of cells with a fixed noise model.

    Parameters
    ----------
    cells : list of RunCells
    baseline : list of str
        Effects the model is told about.
    include : sequence of str
        Designed catalogue terms to keep in the bare model (:data:`DESIGNED_TERMS`).
    """

    def __init__(self, cells: Sequence[RunCells], baseline: Sequence[str], include: Sequence[str] = DESIGNED_TERMS):
        self.cells = list(cells)
        self.baseline = list(baseline)
        self.include = tuple(include)
        #: non-catalogue coefficients held in every model: name -> reason
        self.extra_held: dict[str, Hold] = {}
        self.sample_period = {j: float(np.median(np.diff(r.cols["time_s"]))) if r.y_rows.size > 1 else 1.0
                              for j, r in enumerate(self.cells)}

    # ------------------------------------------------------------------ models
    def model(self, effects: Sequence[str]) -> CampaignModel:
        """The campaign model with ``effects``; the earth rate is held at its physical size
        only when the baseline says it is there (as a candidate its scale is estimated).

        ``mount_angle_error`` is one shared angle unless the baseline has it (then one per
        mount); the designed terms :attr:`include` are in wherever a test measures them.

        Parameters
        ----------
        effects : sequence of str
            effects.md ids in the model.

        Returns
        -------
        CampaignModel
            On the Fitter's cells, every candidate parameter free (nothing selected yet).
        """
        return CampaignModel(self.cells, list(effects), include=self.include,
                             fixed=[e for e in ("earth_rate",) if e in self.baseline],
                             shared=[e for e in CANDIDATE_SHARED if e not in self.baseline])

    def step(self, effect: str) -> float:
        """Difference step of an effect's signature: a sampled lag needs a finite one (a
        fraction of the sample period: its derivative vanishes at 0).

        Parameters
        ----------
        effect : str
            effects.md id.

        Returns
        -------
        float
            Step [effect unit]: for ``sensor_lag`` half the median sample period of the runs
            it applies to [s] (1e-3 s when there are none); else 1e-3 times the effect's
            typical size.
        """
        if effect == "sensor_lag":
            dts = [self.sample_period[j] for j, r in enumerate(self.cells) if r.test in EFFECTS[effect].tests]
            return 0.5 * float(np.median(dts)) if dts else 1e-3
        return 1e-3 * EFFECTS[effect].typical

    def signature(self, model: CampaignModel, p: np.ndarray, effect: str) -> np.ndarray:
        """Whitened derivative of the model with respect to a candidate effect.

        Parameters
        ----------
        model : CampaignModel
            The fitted model (without the effect).
        p : ndarray
            Its parameter vector [parameter units].
        effect : str
            effects.md id of the candidate.

        Returns
        -------
        (N,) ndarray
            :meth:`CampaignModel.signature` with the step :meth:`step` [1 per effect unit].
        """
        return model.signature(p, effect, self.step(effect))

    def fit(self, effects: Sequence[str], start: "Fit | None" = None, values: Mapping[str, float] | None = None,
            noise_passes: int = 0, max_iter: int = 30) -> Fit:
        """Fit the model with ``effects``; start from a previous fit's values (by name) and
        ``values`` (e.g. a candidate's linear estimate).

        The start is :meth:`CampaignModel.start` (the lag profiled unless ``start`` has a
        lag parameter), overwritten by the parameters free in ``start`` and then by
        ``values``.  The holds are :meth:`CampaignModel.select`'s, made nested in
        ``start``'s when it is given (so that the chi-squares compare), plus
        :attr:`extra_held`; held parameters sit at their held values.  The fit is
        :func:`accelcal.fitting.procedure.fit_model` without re-selection or bounds, with
        noise level ``'spread'`` and the lack of fit at :data:`GAP_ALPHA`.

        Parameters
        ----------
        effects : sequence of str
            effects.md ids in the model.
        start : Fit, optional
            Fit of a model this one extends.
        values : mapping of str to float, optional
            Parameter name -> start value [parameter unit]; names not in the model are
            ignored.
        noise_passes : int
            Times the cells' noise model is refitted to the residuals and the model fitted
            again (0: the current noise model, the weights of the fits it is compared with).
        max_iter : int
            Gauss–Newton iterations per pass.

        Returns
        -------
        Fit
            The fitted model.
        """
        m = self.model(effects)
        given = start is not None and any(start.index(prm.name) is not None for prm, role in
                                          zip(m.params, m.roles) if role.key == "sensor_lag")
        p = m.start(profile_lag=not given)
        if start is not None:
            for i, prm in enumerate(m.params):
                j = start.index(prm.name)
                if j is not None and start.model.params[j].vary:
                    p[i] = start.fit.values[j]
        for k, v in (values or {}).items():
            i = m.params.index.get(k)
            if i is not None:
                p[i] = v
        held = m.select(p)
        if start is not None:
            held = self._nested(m, p, held, start)
        for k, v in self.extra_held.items():
            if k in m.params.index:
                held.setdefault(k, v)
        m.params = ParameterSet(replace(prm, vary=prm.name not in held) for prm in m.params)
        for k in held:                           # at their held value, whatever a start said
            p[m.params.index[k]] = m.params[k].value
        # the first fit of the bare model judges the design again at its estimate, as the joint
        # fit does (a mass-centre offset turns the input of a 90 deg mount towards IA, and
        # Kip, weak at a zero offset, is then seen); later fits keep the holds they nest in
        mf = fit_model(m, p, held, noise_passes=noise_passes, reselect=start is None and not self.extra_held,
                       bounded=False, noise_level="spread", max_iter=max_iter, alpha=GAP_ALPHA, effects=effects,
                       cautious=True)
        if noise_passes:                         # the noise the next fits compare on
            self.cells = list(mf.model.runs)
        return Fit(**vars(mf))

    @staticmethod
    def _nested(m: CampaignModel, p: np.ndarray, held: dict[str, Hold], start: Fit) -> dict[str, Hold]:
        """Holds of a model that extends ``start``: the parameters they share keep the status
        they had there (so that the two are nested and their chi-squares comparable); the new
        ones claim directions, in the model's priority order, among the free ones only (a
        new effect aliased with a free coefficient of higher priority is held; Ko gives its
        direction to theta0, which comes first); a new one ``select`` finds weakly
        determined stays held."""
        new = [i for i, prm in enumerate(m.params) if start.index(prm.name) is None]
        old_free = [i for i, prm in enumerate(m.params) if i not in new
                    and start.model.params[start.index(prm.name)].vary]
        out = {prm.name: start.held[prm.name] for prm in m.params if prm.name in start.held}
        cols = old_free + new
        J = m.jacobian(p, cols)
        order = sorted(range(len(cols)), key=lambda c: (m.priority[cols[c]], cols[c]))
        kept = separable_columns(J, order, ALIAS_TOL)
        for c, i in enumerate(cols):
            if c not in kept:
                with_ = [m.params[cols[k]].name for k in kept
                         if abs(float(J[:, k] @ J[:, c])) > 1e-3 * np.linalg.norm(J[:, k]) * np.linalg.norm(J[:, c])]
                out[m.params[i].name] = (Hold(Why.ALIASED, aliased_with=tuple(with_[:4])) if with_
                                         else Hold(Why.NOT_EXCITED))
        for i in new:
            h = held.get(m.params[i].name)
            if h is not None and h.why is Why.WEAK:
                out[m.params[i].name] = h
        return out

    # ------------------------------------------------------------------ bare model
    def bare(self, candidates: Sequence[str]) -> tuple[Fit, dict[str, np.ndarray]]:
        """The bare model (baseline effects) fitted, the noise model refitted to its residuals
        (twice), and the candidates' signatures at it.  A non-catalogue coefficient that a
        candidate would have to share its direction with is then held (:data:`NON_CATALOGUE`)
        and the model refitted.

        The coefficients so held are kept in :attr:`extra_held` and held in every later fit.

        Parameters
        ----------
        candidates : sequence of str
            effects.md ids of the candidate effects.

        Returns
        -------
        fit : Fit
            The bare model's fit.
        signatures : dict of str to ndarray
            Candidate -> its whitened signature at that fit, (N,) [1 per effect unit].
        """
        f = self.fit(self.baseline, noise_passes=2)
        sigs = {c: self.signature(f.model, f.fit.values, c) for c in candidates}
        self.extra_held = self._competing(f, sigs)
        if self.extra_held:
            f = self.fit(self.baseline, start=f)
            sigs = {c: self.signature(f.model, f.fit.values, c) for c in candidates}
        return f, sigs

    def _competing(self, f: Fit, sigs: Mapping[str, np.ndarray]) -> dict[str, Hold]:
        """Non-catalogue coefficients (free in the fit) whose direction a candidate effect
        takes when the candidates claim directions before them."""
        m = f.model
        free = [i for i in np.flatnonzero(f.active)]
        nc = [c for c, i in enumerate(free) if m.roles[i].kind == "coef" and m.roles[i].key in NON_CATALOGUE]
        if not nc:
            return {}
        J = f.fit.J[:, free]

        def prio(c):
            i = free[c]
            key = m.roles[i].key
            k = "theta0" if key == "initial_misalignment" else (key if key in PRIORITY else (
                m.roles[i].kind if m.roles[i].kind in PRIORITY else "effect"))
            return (PRIORITY.index(k) if k in PRIORITY else len(PRIORITY), c)

        base = sorted([c for c in range(len(free)) if c not in nc], key=prio)
        ncs = sorted(nc, key=prio)
        kept0 = set(separable_columns(J, base + ncs, ALIAS_TOL))
        out: dict[str, list[str]] = {}
        n = len(free)
        for e, s in sigs.items():
            if not np.any(s):
                continue
            # the candidate claims at its own place in the joint fit's order: before Kpp as
            # cross_coupling (Kip), after Kp and Ko as a mount angle or a tilt
            pe = PRIORITY.index(effect_claim(e))
            order = base + [c for c in ncs if prio(c)[0] <= pe] + [n] + [c for c in ncs if prio(c)[0] > pe]
            kept = set(separable_columns(np.column_stack([J, s]), order, ALIAS_TOL))
            if n not in kept:
                continue
            for c in ncs:
                if c in kept0 and c not in kept:
                    out.setdefault(m.params[free[c]].name, []).append(e)
        return {k: Hold(Why.CLAIMED, aliased_with=tuple(v)) for k, v in out.items()}


# ----------------------------------------------------------------------------- statistics
def gap_rms(f: Fit) -> float:
    """rms excess of the whitened cell residuals over the noise: sqrt(max(0, (chi2 - dof) / N)).

    Parameters
    ----------
    f : Fit
        The fit.

    Returns
    -------
    float
        The gap [1, sigma of a cell mean]; 0 without cells.
    """
    return float(math.sqrt(max(f.fit.chi2 - f.fit.dof, 0.0) / f.fit.n_obs)) if f.fit.n_obs else 0.0


def variance_factor(f: Fit) -> float:
    """Factor by which a gap the model leaves inflates the residual variance: max(1, chi2/dof)
    (inf without dof); a nested test against that residual (:func:`lr_test`).

    Parameters
    ----------
    f : Fit
        The fit.

    Returns
    -------
    float
        [1].
    """
    return max(1.0, f.fit.chi2 / f.fit.dof) if f.fit.dof > 0 else math.inf


def shrink(before: float | None, after: float | None) -> float | None:
    """1 - after / before (None when there was no gap to shrink).

    Parameters
    ----------
    before, after : float or None
        Gap without and with the change (:func:`gap_rms`, :func:`heldout_gap`) [1].

    Returns
    -------
    float or None
        Fraction of the gap removed [1]; None when either is None or ``before`` <= 0.
    """
    if before is None or after is None or before <= 0:
        return None
    return float(1.0 - after / before)


def folds(cells: Sequence[RunCells]) -> np.ndarray:
    """Held-out fold (0/1) of every cell: alternate cells of each run, in the order of the
    run's cells (dwells in time, head positions, phases of the drive).

    Parameters
    ----------
    cells : sequence of RunCells
        The runs, in model order.

    Returns
    -------
    (N,) ndarray of int
        0 or 1 per cell, runs stacked in order (the rows of the model); each run starts at 0.
    """
    return np.concatenate([np.arange(r.ncell) % 2 for r in cells]) if cells else np.zeros(0, int)


def heldout_parts(f: Fit, fold: np.ndarray, tol: float = 1e-6) -> tuple:
    """Both folds of the held-out prediction of a fit (:func:`_heldout_fold` for fold 0 and
    1), computed once for :func:`heldout_gap` and :func:`heldout_test` alike.

    Parameters
    ----------
    f : Fit
        The fit (its whitened residual and the free columns of its Jacobian).
    fold : (N,) ndarray of int
        Fold (0 or 1) of each cell (:func:`folds`).
    tol : float
        Relative residual of a held-out cell's Jacobian row outside the training fold's
        row space below which the fold determines the cell [1].

    Returns
    -------
    tuple
        :func:`_heldout_fold`'s result for fold 0 and for fold 1: the mask of the cells it
        predicts, their whitened prediction residuals [1] and the rows A with A A^T the
        covariance of those predictions [1]; None for a fold that predicts no cell.
    """
    return tuple(_heldout_fold(f, fold, k, tol) for k in (0, 1))


def heldout_gap(f: Fit, fold: np.ndarray, tol: float = 1e-6, parts: tuple | None = None) -> float | None:
    """rms excess over the noise of the residuals of each fold predicted by the model fitted
    to the other fold (linearised at the solution), with the exact expectation of a model
    that is right: 1 + j (J_T^T J_T)^+ j^T per held-out cell.  Cells the training fold does
    not determine (outside its row space, or predicted to a variance above
    :data:`PREDICTION_VARIANCE_MAX`) are not predicted; None when no cell is.

    Parameters
    ----------
    f : Fit
        The fit (its whitened residual and the free columns of its Jacobian).
    fold : (N,) ndarray of int
        Fold of each cell, 0 or 1 (:func:`folds`).
    tol : float
        Relative distance of a held-out row from the training fold's row space (and norm of
        its inactive columns) up to which the cell counts as determined [1].
    parts : tuple, optional
        :func:`heldout_parts` of the fit, when already made.

    Returns
    -------
    float or None
        sqrt(max(0, sum of squared held-out residuals - their expectation) / n) over the n
        predicted cells of both folds [1, sigma of a cell mean]; None when no cell is
        predicted.
    """
    ss = ex = 0.0
    n = 0
    for got in (heldout_parts(f, fold, tol) if parts is None else parts):
        if got is None:
            continue
        _, zh, A = got
        ss += float(zh @ zh)
        ex += float(zh.size + np.sum(A * A))
        n += int(zh.size)
    if n == 0:
        return None
    return float(math.sqrt(max(ss - ex, 0.0) / n))


#: largest variance of a held-out cell's prediction by the other half [sigma^2 of the cell
#: mean] for the cell to count as predicted (:func:`heldout_gap`, :func:`heldout_test`)
PREDICTION_VARIANCE_MAX = 100.0


def _heldout_fold(f: Fit, fold: np.ndarray, k: int, tol: float):
    """Fold k of :func:`heldout_gap`: the held-out cells the other fold determines (a
    boolean mask over the cells of fold k), their whitened prediction residuals, and the
    rows A with A A^T the covariance of those predictions (the training fit's) [1]; None
    when no cell is predicted."""
    J = f.fit.J[:, f.active]
    z = f.fit.z
    T, H = fold != k, fold == k
    if not T.any() or not H.any():
        return None
    norm = np.linalg.norm(J[T], axis=0)
    act = norm > 0
    if not act.any():
        return None
    Js = J[T][:, act] / norm[act]
    U, S, Vt = thin_svd(Js)
    keep = S > S[0] * 1e-10
    V = Vt[keep].T
    JH = J[H][:, act] / norm[act]
    inact = np.linalg.norm(J[H][:, ~act], axis=1)
    resid = np.linalg.norm(JH - (JH @ V) @ V.T, axis=1)
    scale = np.maximum(np.linalg.norm(JH, axis=1), 1e-300)
    ok = (resid <= tol * scale) & (inact <= tol * np.maximum(scale, 1.0))
    # a cell whose prediction the training half knows only to far worse than its own noise
    # (a parameter that half barely determines) tests nothing: one such cell's expected
    # square, 1e9 beside a misfit of 3e4, floored a whole campaign's held-out gap at 0
    A = (JH @ V) / S[keep]
    ok &= np.sum(A * A, axis=1) <= PREDICTION_VARIANCE_MAX
    if not ok.any():
        return None
    d = V @ ((U[:, keep].T @ z[T]) / S[keep])
    return ok, z[H][ok] - JH[ok] @ d, A[ok]


def heldout_test(without: Fit, with_: Fit, fold: np.ndarray, tol: float = 1e-6,
                 parts: tuple | None = None) -> dict:
    """Held-out test of what a change of model buys (a naming rule that does not
    depend on the design's size).

    Each fold's cells are predicted by both models fitted to the other fold (linearised at
    their solutions, as :func:`heldout_gap`).  With r the held-out residuals of the model
    without the change and d the change of prediction (r minus the residuals with it), the
    statistic is sum d.r over both folds, divided by its standard deviation when the change
    buys nothing, sqrt(sum |d|^2 + |A^T d|^2) (A A^T: the covariance of the training fit's
    prediction, which r also carries): a standard normal then in the linear model, whatever
    the number of cells; large when the held-out cells move the way the training cells
    said.  One-sided p.

    Parameters
    ----------
    without, with_ : Fit
        The fits without and with the change (the same cells).
    fold : (N,) ndarray of int
        :func:`folds`.
    tol : float
        As :func:`heldout_gap`.
    parts : (tuple, tuple), optional
        :func:`heldout_parts` of ``without`` and ``with_``, when already made.

    Returns
    -------
    dict
        ``z`` [1] and ``p`` (one-sided), None when no held-out cell is predicted by both
        or the change moves no prediction; ``cells``: the cells compared; ``share``: the
        share of the held-out excess (sum of squares over its expectation, not floored)
        the change removes, 1 - excess_with / excess_without [1] (None without an excess).
    """
    num = var = 0.0
    cells = 0
    excess = np.zeros(2)                # held-out sum of squares over its expectation: without, with
    pb, pa = parts if parts is not None else (heldout_parts(without, fold, tol), heldout_parts(with_, fold, tol))
    for k, gb, ga in zip((0, 1), pb, pa):
        if gb is None or ga is None:
            continue
        nh = int((fold == k).sum())
        rb, ra = np.full(nh, np.nan), np.full(nh, np.nan)
        Ab, Aa = np.zeros((nh, gb[2].shape[1])), np.zeros((nh, ga[2].shape[1]))
        rb[gb[0]], ra[ga[0]], Ab[gb[0]], Aa[ga[0]] = gb[1], ga[1], gb[2], ga[2]
        both = gb[0] & ga[0]
        if not both.any():
            continue
        d = rb[both] - ra[both]
        num += float(d @ rb[both])
        var += float(d @ d) + float(np.sum((Ab[both].T @ d) ** 2))
        cells += int(both.sum())
        for i, (r, A) in enumerate(((rb, Ab), (ra, Aa))):
            excess[i] += float(r[both] @ r[both]) - float(both.sum() + np.sum(A[both] ** 2))
    if var <= 0.0:
        return {"z": None, "p": None, "cells": cells, "share": None}
    z = num / math.sqrt(var)
    share = float(1.0 - excess[1] / excess[0]) if excess[0] > 0 else None
    return {"z": float(z), "p": float(stats.norm.sf(z)), "cells": cells, "share": share}


def lr_test(before: Fit, after: Fit, m: int, alpha: float) -> dict:
    """Likelihood ratio of a nested model with q more parameters, the chi-square scaled by
    the larger model's chi2/dof when that exceeds 1 (F test against the residual that the gap
    leaves), Bonferroni over m candidates.  Untestable without degrees of freedom.
    ``statistic`` is delta chi2 / q, divided by that chi2/dof when it exceeds 1.

    Parameters
    ----------
    before : Fit
        The smaller model.
    after : Fit
        The model with the candidate added (nested: it extends ``before``).
    m : int
        Number of candidates tested (Bonferroni).
    alpha : float
        Family-wise significance level [1].

    Returns
    -------
    dict
        ``delta_chi2`` [1]; ``scale`` (the larger model's :func:`variance_factor`); ``statistic``;
        ``p_value`` (F(q, dof) when scaled, else chi-square with q dof); ``threshold_p`` =
        alpha / m; ``significant`` (delta chi2 > 0 and p below the threshold).  Without
        degrees of freedom: ``scale``, ``statistic`` and ``p_value`` None, not significant,
        and a ``note``.  q is the rank gained, at least 1.
    """
    q = max(after.fit.rank - before.fit.rank, 1)
    dchi = float(before.fit.chi2 - after.fit.chi2)
    if after.fit.dof <= 0:
        return {"delta_chi2": dchi, "scale": None, "statistic": None, "p_value": None, "threshold_p": alpha / m,
                "significant": False, "note": "untestable: no degrees of freedom left"}
    s2 = variance_factor(after)
    if s2 > 1.0:
        F = dchi / q / s2
        p = float(stats.f.sf(F, q, after.fit.dof))
    else:
        F = dchi / q
        p = float(stats.chi2.sf(dchi, q))
    return {"delta_chi2": dchi, "scale": s2, "statistic": float(F), "p_value": p, "threshold_p": alpha / m,
            "significant": bool(dchi > 0 and p < alpha / m)}


def gap_test(f: Fit) -> dict:
    """The lack-of-fit test of a model against the pure error (the tests behind 'explained').

    Parameters
    ----------
    f : Fit
        The fit (its :attr:`Fit.lof`, tested at :data:`GAP_ALPHA`).

    Returns
    -------
    dict
        ``status`` ('significant gap', 'no significant gap' or 'untestable'),
        ``significant`` (bool, None when untestable), ``p_value``, ``F`` (the F statistic
        against the pure error, or chi2/dof against the noise model when there is no pure
        error), ``dof_lof``, ``dof_pe``, ``alpha``; ``test`` naming the test, or ``note``
        saying why it is untestable.

    References
    ----------
    Draper & Smith, *Applied Regression Analysis*, 3rd ed., §2.1 (lack of fit with pure
    error).
    """
    lof = f.fit.lof
    if lof.status == "untestable":
        return {"status": "untestable", "significant": None, "p_value": None, "F": None,
                "dof_lof": lof.dof_lof, "dof_pe": lof.dof_pe, "alpha": GAP_ALPHA,
                "note": "untestable: no degrees of freedom" if lof.dof_lof <= 0 else f"untestable: {lof.note}"}
    sig = lof.status == "inadequate"
    return {"status": "significant gap" if sig else "no significant gap", "significant": sig,
            "p_value": lof.p_value, "F": lof.statistic, "dof_lof": lof.dof_lof, "dof_pe": lof.dof_pe,
            "alpha": GAP_ALPHA,
            "test": "lack of fit of the cell means against the pure error (F)" if lof.dof_pe else
                    "chi-square of the cell means against the noise model"}
