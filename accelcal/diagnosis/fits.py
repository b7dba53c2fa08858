"""The fits a diagnosis compares: the campaign model (:class:`accelcal.fitting.model.
CampaignModel`, the one forward model) with the baseline effects and with candidates added,
all on the same cells and the same noise model, and the statistics on them (lack of fit,
likelihood ratio, held-out gap).

Every fit is a :class:`accelcal.fitting.procedure.ModelFit` (values, covariance, whitened
residual and Jacobian, rank, lack of fit, holds).  Conventions: every residual is whitened by
the noise model of its run (fitted to the within-cell scatter of the bare model's residuals,
:func:`accelcal.fitting.data.fit_noise`), so that fits with different effects are compared
on the same weights (a likelihood ratio needs them).  Gaps are rms excesses over the noise in
units of a cell mean's sigma.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats

from ..effects import EFFECTS
from ..fitting.core import RCOND, column_space_basis, separable_columns, thin_svd
from ..fitting.data import RunCells
from ..fitting.identify import (ALIAS_TOL, PRIORITY, Hold, Why, aliased_with, nominal_point, seen_through_nuisances,
                                structural_point)
from ..fitting.model import CANDIDATE_SHARED, CampaignModel, Role, effect_claim
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


def basis(f: ModelFit) -> np.ndarray:
    """Orthonormal basis of the span of a fit's free, active columns (whitened).

    Parameters
    ----------
    f : ModelFit
        The fit.

    Returns
    -------
    (N, r) ndarray
        :func:`accelcal.fitting.core.column_space_basis` of ``fit.J[:, active]`` [1]; r is
        the rank.
    """
    return column_space_basis(f.fit.J[:, f.active])


def project_out(U: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v minus its part in the span of U (orthonormal columns).

    Parameters
    ----------
    U : (n, r) ndarray
        Orthonormal columns, e.g. :func:`basis` [1].
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
    """

    def __init__(self, cells: Sequence[RunCells], baseline: Sequence[str]):
        self.cells = list(cells)
        self.baseline = list(baseline)
        #: non-catalogue coefficients held in every model: name -> reason
        self.extra_held: dict[str, Hold] = {}
        #: instrument-term effects whose coefficient the runs determine only through the
        #: fitted nuisances (:meth:`bare`): effects.md id -> the coefficient's parameter name,
        #: in every model
        self.determined: dict[str, str] = {}

    def signature(self, f: ModelFit, effect: str) -> np.ndarray:
        """Whitened derivative of a fitted model with respect to a candidate effect
        (:meth:`CampaignModel.signature` at the fit's values).

        The difference step is the catalogue's (1e-3 of the effect's typical size), but for
        ``sensor_lag``, whose derivative vanishes at 0: half the median sample period of the
        runs it applies to [s] (1e-3 s when there are none).

        Parameters
        ----------
        f : ModelFit
            The fitted model (without the effect).
        effect : str
            effects.md id of the candidate.

        Returns
        -------
        (N,) ndarray
            [1 per effect unit].
        """
        h = None
        if effect == "sensor_lag":
            dts = [float(np.median(np.diff(r.cols["time_s"]))) if r.y_rows.size > 1 else 1.0
                   for r in self.cells if r.test in EFFECTS[effect].tests]
            h = 0.5 * float(np.median(dts)) if dts else 1e-3
        return f.model.signature(f.fit.values, effect, h)

    def fit(self, effects: Sequence[str], start: ModelFit | None = None, at: tuple[str, float] | None = None,
            noise_passes: int = 0) -> ModelFit:
        """Fit the model with ``effects``, starting from a previous fit's values (by name)
        and, for ``at = (effect, value)``, every parameter of that effect at ``value``.

        The model holds the earth rate at its physical size only when the baseline says it
        is there (as a candidate its scale is estimated); ``mount_angle_error`` is one
        shared angle unless the baseline has it; the designed terms
        (:data:`DESIGNED_TERMS`) are in wherever a test measures them.  The start is
        :meth:`CampaignModel.start` (the lag profiled unless ``start`` has a lag
        parameter).  The holds are :meth:`CampaignModel.select`'s, made nested in
        ``start``'s when it is given (so that the chi-squares compare), plus
        :attr:`extra_held` (:meth:`CampaignModel.with_holds`).  The fit is
        :func:`accelcal.fitting.procedure.fit_model` without bounds, with noise level
        ``'spread'`` and the lack of fit at :data:`GAP_ALPHA`; the bare model's first fit
        judges the design again at its estimate, as the joint fit does (a mass-centre
        offset turns the input of a 90 deg mount towards IA, and Kip is then seen).

        Parameters
        ----------
        effects : sequence of str
            effects.md ids in the model.
        start : ModelFit, optional
            The fit of a model this one extends.
        at : (str, float), optional
            An effect (effects.md id; an instrument-term effect sets its coefficient) and
            the start value of its parameters [effect unit].
        noise_passes : int
            Times the cells' noise model is refitted to the residuals and the model fitted
            again (0: the current noise model, the weights of the fits it is compared with);
            the refitted noise is then the Fitter's for the fits that follow.

        Returns
        -------
        ModelFit
        """
        m = self.model(effects)
        old = start.model.params if start is not None else {}
        p = m.start(profile_lag=not any(r.key == "sensor_lag" and prm.name in old
                                        for prm, r in zip(m.params, m.roles)))
        for i, prm in enumerate(m.params):
            if prm.name in old and old[prm.name].vary:
                p[i] = start.fit.value(prm.name)
            if at is not None and m.roles[i] == effect_role(at[0]):
                p[i] = at[1]
        held = m.select(p) if start is None else self._nested(m, p, m.select(p), start)
        held |= {k: v for k, v in self.extra_held.items() if k in m.params and k not in held}
        m = m.with_holds(held)
        p = np.where(m.params.free(), p, m.params.values())    # held ones at their held values
        mf = fit_model(m, p, held, noise_passes=noise_passes, reselect=start is None and not self.extra_held,
                       bounded=False, noise_level="spread", max_iter=30, alpha=GAP_ALPHA, effects=effects,
                       cautious=True)
        if noise_passes:
            self.cells = list(mf.model.runs)
        return mf

    def model(self, effects: Sequence[str], include: Sequence[str] = ()) -> CampaignModel:
        """The campaign model with ``effects`` as :meth:`fit` fits it: the designed terms
        (:data:`DESIGNED_TERMS`), the coefficients of :attr:`determined` and ``include``
        wherever a test measures them."""
        coefs = [INSTRUMENT_EFFECTS[e] for e in self.determined] + list(include)
        return CampaignModel(self.cells, list(effects), include=DESIGNED_TERMS + tuple(coefs),
                             fixed=[e for e in ("earth_rate",) if e in self.baseline],
                             shared=[e for e in CANDIDATE_SHARED if e not in self.baseline])

    @staticmethod
    def _nested(m: CampaignModel, p: np.ndarray, held: dict[str, Hold], start: ModelFit) -> dict[str, Hold]:
        """Holds of a model that extends ``start``: the parameters they share keep the status
        they had there (so that the two are nested and their chi-squares comparable); the new
        ones claim directions, in the model's priority order, among the free ones only (a
        new effect aliased with a free coefficient of higher priority is held; Ko gives its
        direction to theta0, which comes first); a new one ``select`` finds weakly
        determined stays held."""
        old = start.model.params
        new = [i for i, prm in enumerate(m.params) if prm.name not in old]
        cols = [i for i, prm in enumerate(m.params) if prm.name in old and old[prm.name].vary] + new
        out = {prm.name: start.held[prm.name] for prm in m.params if prm.name in start.held}
        J = m.jacobian(p, cols)
        kept = separable_columns(J, sorted(range(len(cols)), key=lambda c: (m.priority[cols[c]], cols[c])),
                                 ALIAS_TOL)
        for c, i in enumerate(cols):
            if c not in kept:
                with_ = tuple(m.params[cols[k]].name for k in aliased_with(J, c, kept))
                out[m.params[i].name] = Hold(Why.ALIASED, aliased_with=with_) if with_ else Hold(Why.NOT_EXCITED)
        for i in new:
            h = held.get(m.params[i].name)
            if h is not None and h.why is Why.WEAK:
                out[m.params[i].name] = h
        return out

    def bare(self, candidates: Sequence[str]) -> tuple[ModelFit, dict[str, np.ndarray]]:
        """The bare model (baseline effects) fitted, the noise model refitted to its residuals
        (twice), and the candidates' signatures at it.  A non-catalogue coefficient that a
        candidate would have to share its direction with is then held (:data:`NON_CATALOGUE`,
        kept in :attr:`extra_held` and held in every later fit) and the model refitted.

        Parameters
        ----------
        candidates : sequence of str
            effects.md ids of the candidate effects.

        Returns
        -------
        fit : ModelFit
            The bare model's fit.
        signatures : dict of str to ndarray
            Candidate -> its whitened signature at that fit, (N,) [1 per effect unit].
        """
        f = self.fit(self.baseline, noise_passes=2)
        self.determined = self._through_nuisances(f, candidates)
        if self.determined:
            f = self.fit(self.baseline, noise_passes=1)
        sigs = {c: self.signature(f, c) for c in candidates if c not in self.determined}
        self.extra_held = self._competing(f, sigs)
        if self.extra_held:
            f = self.fit(self.baseline, start=f)
            sigs = {c: self.signature(f, c) for c in sigs}
        return f, sigs

    def _through_nuisances(self, f: ModelFit, candidates: Sequence[str]) -> dict[str, str]:
        """Instrument-term candidates (Kip, Koq, K3, ...) whose coefficient the runs
        determine at the bare model's fitted nuisances but not at the nominal geometry
        (:func:`accelcal.fitting.identify.seen_through_nuisances`): the unit's own
        coefficient, which the bare model fits (Kip on mounts 0/90/180/270 with a
        mass-centre offset), not an effect the baseline left out.

        Returns
        -------
        dict of str to str
            effects.md id -> the coefficient's parameter name.
        """
        keys = {e: INSTRUMENT_EFFECTS[e] for e in candidates if e in INSTRUMENT_EFFECTS}
        if not keys:
            return {}
        m = self.model(self.baseline, include=list(keys.values()))
        p = m.params.values()
        for i, prm in enumerate(m.params):
            if prm.name in f.model.params:
                p[i] = f.fit.value(prm.name)
        cols = m.columns()
        J, Jn = m.jacobian(structural_point(p, cols)), m.jacobian(nominal_point(p, cols))
        which = [i for i, r in enumerate(m.roles) if r.kind == "coef" and r.key in keys.values()]
        seen = {m.roles[i].key: m.params[i].name for i in seen_through_nuisances(J, Jn, cols, which)}
        return {e: seen[k] for e, k in keys.items() if k in seen}

    @staticmethod
    def _competing(f: ModelFit, sigs: Mapping[str, np.ndarray]) -> dict[str, Hold]:
        """Non-catalogue coefficients (free in the fit) whose direction a candidate effect
        takes when the candidates claim directions before them, each at its own place in the
        model's priority order (initial_misalignment as theta0, before Ko; a mount angle or a
        tilt after Kp and Ko).  An instrument-term effect claims none: where the unit's own
        coefficient takes its direction (Kip a_I a_P = Kpp a_P^2 on 45/225 deg mounts, Kip g
        a_P = Kp a_P with IA up) the bare model keeps the coefficient, and the effect is
        reported aliased with it (:meth:`accelcal.diagnosis.core._Diagnosis.observability`)."""
        m = f.model
        free = np.flatnonzero(f.active)
        prio = [m.priority[i] for i in free]
        nc = [c for c, i in enumerate(free) if m.roles[i].kind == "coef" and m.roles[i].key in NON_CATALOGUE]
        if not nc:
            return {}
        J = f.fit.J[:, free]
        base = sorted((c for c in range(len(free)) if c not in nc), key=lambda c: (prio[c], c))
        ncs = sorted(nc, key=lambda c: (prio[c], c))
        kept0 = set(separable_columns(J, base + ncs, ALIAS_TOL))
        out: dict[str, list[str]] = {}
        n = len(free)
        for e, s in sigs.items():
            if not np.any(s) or e in INSTRUMENT_EFFECTS:
                continue
            pe = PRIORITY.index(effect_claim(e))
            order = base + [c for c in ncs if prio[c] <= pe] + [n] + [c for c in ncs if prio[c] > pe]
            kept = set(separable_columns(np.column_stack([J, s]), order, ALIAS_TOL))
            if n in kept:
                for c in ncs:
                    if c in kept0 and c not in kept:
                        out.setdefault(m.params[free[c]].name, []).append(e)
        return {k: Hold(Why.CLAIMED, aliased_with=tuple(v)) for k, v in out.items()}


def effect_role(effect: str) -> Role:
    """The :class:`accelcal.fitting.model.Role` of an effect's parameters: its coefficient's
    for an instrument-term effect (Koq, K3, Kip, K0T, K1T), else the effect's own."""
    return Role("coef", INSTRUMENT_EFFECTS[effect]) if effect in INSTRUMENT_EFFECTS else Role("effect", effect)


def effect_parameters(f: ModelFit, effect: str, free: np.ndarray | None = None) -> list[str]:
    """Names of an effect's parameters in a fit (theta0 per head, ...), in model order.

    Parameters
    ----------
    f : ModelFit
        The fit.
    effect : str
        effects.md id (:func:`effect_role`).
    free : (p,) ndarray of bool, optional
        Which parameters count; default the fit's active ones (free, acting on the data).

    Returns
    -------
    list of str
    """
    role = effect_role(effect)
    mask = f.active if free is None else free
    return [prm.name for prm, r, v in zip(f.model.params, f.model.roles, mask) if v and r == role]


def effect_parameter(f: ModelFit, effect: str) -> str | None:
    """The name of an effect's one varying parameter; None when it has none or several (one
    per head, mount or campaign)."""
    names = effect_parameters(f, effect, f.model.params.free())
    return names[0] if len(names) == 1 else None


def uncertainty(f: ModelFit, name: str) -> float | None:
    """A fit's standard uncertainty of one parameter (lack-of-fit factor included) [its
    unit]; None where the fit gives none (held, not determined, not positive)."""
    u = f.std(name)
    return u if u > 0 else None


# ----------------------------------------------------------------------------- statistics
def gap_rms(f: ModelFit) -> float:
    """rms excess of the whitened cell residuals over the noise: sqrt(max(0, (chi2 - dof) / N)).

    Parameters
    ----------
    f : ModelFit
        The fit.

    Returns
    -------
    float
        The gap [1, sigma of a cell mean]; 0 without cells.
    """
    return float(math.sqrt(max(f.fit.chi2 - f.fit.dof, 0.0) / f.fit.n_obs)) if f.fit.n_obs else 0.0


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


def heldout_parts(f: ModelFit, fold: np.ndarray, tol: float = 1e-6) -> tuple:
    """Both folds of the held-out prediction of a fit (:func:`_heldout_fold` for fold 0 and
    1), computed once for :func:`heldout_gap` and :func:`heldout_test` alike.

    Parameters
    ----------
    f : ModelFit
        The fit (its whitened residual and the free columns of its Jacobian).
    fold : (N,) ndarray of int
        Fold (0 or 1) of each cell (:func:`folds`).
    tol : float
        Relative distance of a held-out row from the training fold's row space (and norm of
        its inactive columns) up to which the cell counts as determined [1].

    Returns
    -------
    tuple
        :func:`_heldout_fold`'s result for fold 0 and for fold 1: the mask of the cells it
        predicts, their whitened prediction residuals [1] and the rows A with A A^T the
        covariance of those predictions [1]; None for a fold that predicts no cell.
    """
    return tuple(_heldout_fold(f, fold, k, tol) for k in (0, 1))


def heldout_gap(parts: tuple) -> float | None:
    """rms excess over the noise of the residuals of each fold predicted by the model fitted
    to the other fold (linearised at the solution), with the exact expectation of a model
    that is right: 1 + j (J_T^T J_T)^+ j^T per held-out cell.  Cells the training fold does
    not determine (outside its row space, or predicted to a variance above
    :data:`PREDICTION_VARIANCE_MAX`) are not predicted.

    Parameters
    ----------
    parts : tuple
        :func:`heldout_parts` of the fit.

    Returns
    -------
    float or None
        sqrt(max(0, sum of squared held-out residuals - their expectation) / n) over the n
        predicted cells of both folds [1, sigma of a cell mean]; None when no cell is
        predicted.
    """
    ss = ex = 0.0
    n = 0
    for got in parts:
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


def _heldout_fold(f: ModelFit, fold: np.ndarray, k: int, tol: float):
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
    keep = S > S[0] * RCOND
    V = Vt[keep].T
    JH = J[H][:, act] / norm[act]
    inact = np.linalg.norm(J[H][:, ~act], axis=1)
    resid = np.linalg.norm(JH - (JH @ V) @ V.T, axis=1)
    scale = np.maximum(np.linalg.norm(JH, axis=1), 1e-300)
    ok = (resid <= tol * scale) & (inact <= tol * np.maximum(scale, 1.0))
    # a cell whose prediction the training half knows only to far worse than its own noise
    # (a parameter that half barely determines) tests nothing: its expected square alone
    # would outweigh any misfit of the other cells
    A = (JH @ V) / S[keep]
    ok &= np.sum(A * A, axis=1) <= PREDICTION_VARIANCE_MAX
    if not ok.any():
        return None
    d = V @ ((U[:, keep].T @ z[T]) / S[keep])
    return ok, z[H][ok] - JH[ok] @ d, A[ok]


def heldout_test(without: ModelFit, with_: ModelFit, fold: np.ndarray, tol: float = 1e-6,
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
    without, with_ : ModelFit
        The fits without and with the change (the same cells).
    fold : (N,) ndarray of int
        :func:`folds`.
    tol : float
        As :func:`heldout_parts`.
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


def lr_test(before: ModelFit, after: ModelFit, m: int, alpha: float) -> dict:
    """The nested test of a model with a candidate added (:meth:`ModelFit.compare`: the
    likelihood ratio, scaled by the larger model's chi2/dof when that exceeds 1, an F test
    against the residual the gap leaves), Bonferroni over m candidates.

    Parameters
    ----------
    before : ModelFit
        The smaller model.
    after : ModelFit
        The model with the candidate added (nested: it extends ``before``).
    m : int
        Number of candidates tested (Bonferroni).
    alpha : float
        Family-wise significance level [1].

    Returns
    -------
    dict
        ``delta_chi2`` [1], ``statistic`` and ``p_value``
        (:class:`accelcal.fitting.core.NestedTest`; None without degrees of freedom),
        ``threshold_p`` = alpha / m, ``significant`` (delta chi2 > 0 and p below the
        threshold).
    """
    t = after.compare(before)
    return {"delta_chi2": t.delta_chi2, "statistic": t.statistic, "p_value": t.p_value, "threshold_p": alpha / m,
            "significant": bool(t.p_value is not None and t.delta_chi2 > 0 and t.p_value < alpha / m)}


def gap_test(f: ModelFit) -> dict:
    """The lack-of-fit test of a model against the pure error (the tests behind 'explained').

    Parameters
    ----------
    f : ModelFit
        The fit (its lack of fit ``fit.lof``, tested at :data:`GAP_ALPHA`).

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
