"""diagnose(): where the real data depart from the rig model, which catalogue effect causes
it, how far the gap shrinks once that effect is added, checked on held-out data.

Method (docs/diagnosis.md says it for a lab engineer):

1. *Cells and noise.*  Readings are grouped in cells of replicates and a noise model is
   fitted to the within-cell scatter of the residuals, per run, heteroscedastic in the
   centripetal level, with lag-1 autocorrelation (:mod:`accelcal.fitting.data`).
2. *Bare model.*  The one forward model with the baseline effects
   (:class:`accelcal.fitting.model.CampaignModel`): the instrument coefficients the tests are
   designed to determine shared by the campaign as eq 2 mixes them, a bias per centrifuge
   run, a turning-centre radius per rig; no free term per mount.  A non-catalogue
   coefficient that a candidate effect would have to share its direction with is held, and
   named as the effect's alias.
3. *Candidates.*  Catalogue effects that apply to the tests and are not in the baseline.
   Each one's signature (the derivative of the forward model) projected off the bare
   model's columns says whether the runs can see it at all (observable fraction) and how
   small an effect they could detect.
4. *Forward selection.*  The best candidates by score are refitted (nonlinear, all
   parameters); the likelihood ratio, scaled by chi2/dof of the larger model when that
   exceeds 1, is tested at alpha / (m k) (Bonferroni over the m candidates of step k and the
   steps), and an effect is
   taken only if it also shrinks the gap on held-out cells (alternate cells of each run
   predicted by a fit to the others).  After each step an earlier member is exchanged for
   a candidate when the data prefer the new subset (sequential replacement,
   :func:`best_swap`): the best subset of each size is compared, not only the path.
5. *Verdict.*  A selected effect that passes the held-out gate: it removes half the gap on
   the held-out cells (shrink >= HELDOUT_GATE), or the held-out cells confirm it at five
   sigma (:func:`.fits.heldout_test`, z >= HELDOUT_Z: a standard normal when the effect
   buys nothing, whatever the design's size); of several, the processing model's first
   among those with a five-sigma part of their own; null when none passes both gates.  ``explained`` is the lack-of-fit
   test of the final model against the pure error: false when a significant gap remains,
   null when the runs leave no degrees of freedom to test it.
6. *Where and what shape* the gap has (before, and what remains after): segments of the
   cells by run, mount, g level, position, IA input, temperature, time; simple forms.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np
from scipy import stats

from ..effects import EFFECTS
from ..rounding import round_gum_sci
from ..fitting.core import pure_error_lack_of_fit
from ..fitting.data import (RunCells, drop_duplicate_cells, fit_noise, make_run, pool_missing_noise,
                            reject_spikes, with_noise)
from ..fitting.blas import single_thread
from ..fitting.identify import (ALIAS_COS, BASE, NEAR_ALIAS_R, TAKEN_SHARE, UNOBSERVABLE_FRACTION, added_correlations,
                                alias_cos, near_aliases, taken_up)
from ..fitting.model import processing_effects
from ..fitting.procedure import ModelFit
from ..physics.rigs import specific_force
from .fits import (GAP_ALPHA, NON_CATALOGUE, Fitter, basis, effect_parameter, effect_parameters, folds, gap_rms,
                   gap_test, heldout_gap, heldout_parts, heldout_test, lr_test, project_out, shrink, uncertainty)
from .localise import input_scale, localise, residual_si, shape, shape_tests, summary, where

#: held-out shrink that names an effect (it removes half the gap on cells it was not fitted to)
HELDOUT_GATE = 0.5
#: held-out z that names an effect whatever the shrink (:func:`.fits.heldout_test`: the
#: held-out cells move the way the training cells said, at five sigma).  The shrink, a ratio
#: of gaps floored at zero, falls with the number of cells (0.3-0.5 for an effect at z 9-13
#: in 480 cells); the held-out z is a standard normal when the effect buys
#: nothing, whatever the design's size
HELDOUT_Z = 5.0
#: lack-of-fit level at which the bare model shows a gap worth naming an effect for (below
#: it, only an effect of five sigma on its own is named)
GAP_SEEN = 0.05
#: drop-one statistic (delta chi2 per parameter, divided by chi2/dof when that exceeds 1) of
#: an effect the verdict may name when several are found: a five-sigma part of the
#: chi-square; if none has it, the largest is named
VERDICT_STATISTIC = 25.0
#: An effect whose estimate exceeds this many times its catalogue plausible size is not a
#: verdict (:meth:`_Diagnosis.implausible`) [1].
IMPLAUSIBLE = 10.0
#: chi-square by which the data prefer one model to another of the same size (a sigma):
#: within it two aliased candidates are a tie (:meth:`_Diagnosis.tie_break`), and a subset
#: is not replaced by another (:func:`best_swap`)
TIE_CHI2 = 1.0
#: a sine run's cells: the drive's phases in this many stretches of time (a slow change in
#: time, a bias drift, then shows between cells instead of inside them)
SINE_SEGMENTS = 4


#: candidates whose signature is the logged temperature's (through K0T, K1T, a fixture tilt)
TEMPERATURE_EFFECTS = ("bias_temperature", "scale_temperature", "fixture_thermal_tilt")
#: level of the test that the logged temperature moves beyond its reading noise
TEMPERATURE_HELD_P = 0.01


def _temperature_held(cells: Sequence[RunCells]) -> tuple[float, float] | None:
    """(F, p) when the temperature the runs log does not move beyond its own reading noise,
    else None (no effect enters on a signature that is only a regressor's
    measurement noise).

    One-way analysis of variance of ``temp_c`` over the cells of every run, pooled: the
    between-cell mean square (around each run's mean) over the within-cell one, F with
    (sum (k_j - 1), sum (n_j - k_j)) degrees of freedom
    (:func:`accelcal.fitting.core.pure_error_lack_of_fit`).  Held when p >
    TEMPERATURE_HELD_P.
    """
    z, cell, n = [], [], 0
    for r in cells:
        T = np.asarray(r.cols.get("temp_c", np.full(r.cid.size, np.nan)), float)
        ok = (r.cid >= 0) & np.isfinite(T)
        if ok.sum() >= 3:                   # around the run's mean: one parameter per run
            z.append(T[ok] - T[ok].mean())
            cell.append(r.cid[ok] + n)
            n += r.ncell
    t = pure_error_lack_of_fit(np.concatenate(z), np.concatenate(cell), len(z)) if z else None
    if t is None or t.p_value is None or t.dof_pe == 0:
        return None
    return (t.statistic, t.p_value) if t.p_value > TEMPERATURE_HELD_P else None


def resolve_baseline(baseline, tests: Sequence[str]) -> tuple[list[str], str]:
    """The effects the diagnosis' forward model includes from the start.

    Parameters
    ----------
    baseline : None, str or sequence of str
        None: the pipeline's processing model for the tests
        (:func:`accelcal.fitting.model.processing_effects`); 'none' (any case): the bare
        model; otherwise effects.md ids, as a list or comma-separated.
    tests : sequence of str
        Test kinds present ('centrifuge', 'sine_centrifuge', 'tumble', 'tilt_rotation').

    Returns
    -------
    effects : list of str
        Effect ids, duplicates dropped, order kept.
    label : str
        'default' for None, else the ids joined by commas, or 'none'.

    Raises
    ------
    ValueError
        When an id is not in the effects catalogue.
    """
    if baseline is None:
        return processing_effects(tests), "default"
    if isinstance(baseline, str):
        baseline = [] if baseline.strip().lower() == "none" else [b.strip() for b in baseline.split(",") if b.strip()]
    out = list(dict.fromkeys(baseline))
    for b in out:
        if b not in EFFECTS:
            raise ValueError(f"unknown effect id {b!r} in the baseline (effects.md ids: {sorted(EFFECTS)})")
    return out, (",".join(out) or "none")


def candidates_for(tests: Sequence[str], baseline: Sequence[str]) -> list[str]:
    """Catalogue effects that apply to the tests present and are not in the baseline.

    Parameters
    ----------
    tests : sequence of str
        Test kinds present.
    baseline : sequence of str
        Effect ids already in the model.

    Returns
    -------
    list of str
        Effect ids (effects.md) in catalogue order.
    """
    return [e for e, d in EFFECTS.items() if e not in baseline and any(t in d.tests for t in tests)]


def prepare_cells(runs) -> tuple[list[RunCells], list[str]]:
    """RunFile-like objects (meta, data) -> cells as :func:`accelcal.estimators.joint.prepare`
    makes them, but with sine cells per stretch of time (:data:`SINE_SEGMENTS`) and rare
    spikes dropped before the noise model is fitted
    (:func:`accelcal.fitting.data.reject_spikes`).

    Per run, in order: cells (:func:`~accelcal.fitting.data.make_run`), duplicate cells
    across runs dropped, spikes rejected, the noise level variable of gravity tests set
    (:func:`angle_level`), the noise model fitted to the outputs' within-cell scatter; then
    runs without replicates take a pooled noise model.

    Parameters
    ----------
    runs : iterable of RunFile-like or of RunCells
        Parsed runs (``meta``, ``data``, optionally ``sha256``); a list made only of
        RunCells is returned as it is.

    Returns
    -------
    cells : list of RunCells
        With noise models and ``var_mean`` [output_unit^2].
    notes : list of str
        Duplicate-cell and spike notes for the report.
    """
    runs = list(runs)
    if runs and all(isinstance(r, RunCells) for r in runs):
        return runs, []
    cells = [make_run(r.meta, r.data, j, getattr(r, "sha256", ""), sine_segments=SINE_SEGMENTS)
             for j, r in enumerate(runs)]
    notes = drop_duplicate_cells(cells)
    for c in cells:
        if reject_spikes(c):
            notes.append(c.notes[-1])
        angle_level(c)
    # the level term wherever the level varies between cells
    noise = pool_missing_noise(cells, [fit_noise(c, use_level=bool(c.x.size and np.ptp(c.x) > 0), cautious=True)
                                       for c in cells])
    return [with_noise(c, m) for c, m in zip(cells, noise)], notes


def angle_level(run: RunCells) -> None:
    """On a gravity test the noise level variable x of the noise model (a + b x^2) becomes the
    sensitivity of the IA input to the logged angle, |d a_i / d theta| [m/s^2 per rad]: the
    reading noise of a logged head or table angle enters the residuals as much as the input
    moves with the angle (none at IA up or down, most at IA horizontal), as the logged rate's
    noise grows with the centripetal level on a centrifuge.

    The derivative is a central difference of the specific force along IA over +-1e-3 deg of
    ``angle_deg`` (tumble) or ``rotation_deg`` (tilt-rotation); other test kinds are left
    alone.

    Parameters
    ----------
    run : RunCells
        The run; ``x_rows`` and ``x`` [m/s^2 per rad] are replaced in place.
    """
    col = {"tumble": "angle_deg", "tilt_rotation": "rotation_deg"}.get(run.test)
    if col is None:
        return
    h = 1e-3
    up, dn = dict(run.cols), dict(run.cols)
    up[col] = run.cols[col] + h
    dn[col] = run.cols[col] - h
    da = (specific_force(run.test, run.meta, up)[:, 0] - specific_force(run.test, run.meta, dn)[:, 0])
    run.x_rows = np.abs(da) / (2 * math.radians(h))
    run.x = run.cell_mean(run.x_rows)


def diagnose(runs, baseline=None, alpha: float = 0.05, *, max_effects: int = 8, refit_top: int = 3) -> dict:
    """Diagnose the gap between the forward model with ``baseline`` and the runs.

    Parameters
    ----------
    runs : sequence of RunFile-like (meta, data) or RunCells
        One or more campaigns (every run is fitted in one model; coefficients per campaign).
    baseline : None, 'none', str or list of str
        Effects the model already includes: None = the pipeline's processing model for the
        tests present, 'none' = the bare model, or effects.md ids.
    alpha : float
        Family-wise significance of the selection [1] (Bonferroni over the candidates and
        steps).
    max_effects : int
        Most effects the forward selection takes [1].
    refit_top : int
        Candidates refitted (nonlinear) per selection step, best scores first; the others
        are ranked by their linear estimate [1].

    Returns
    -------
    dict
        The JSON contract (:func:`public` drops the private ``_fits``): verdict, explained,
        ranking, gap (with significant_before/after), where, unexplained, ...

    Raises
    ------
    ValueError
        When there are no runs, or the baseline names an unknown effect.

    References
    ----------
    Draper & Smith, *Applied Regression Analysis*, 3rd ed., §2.1 (lack of fit with pure
    error, the ``explained`` test).
    """
    with single_thread():
        return _Diagnosis(runs, baseline, alpha, max_effects, refit_top).run()


def best_swap(members: Sequence[str], movable: Sequence[str], pool: Sequence[str], drop, gains, add, chi2,
              chi2_now: float, refit_top: int, margin: float = TIE_CHI2):
    """One pass of sequential replacement: the best exchange of one member of a subset for a
    candidate outside it.

    Forward selection takes, at each step, the effect that best explains what the effects
    already taken leave; an early choice that a later pair explains better (one effect that
    mimics the sum of two) is never revisited.  For each movable member i, the model without
    it is fitted (``drop``), every candidate outside the subset is scored against it
    (``gains``: the linear chi-square it would remove), and those whose score exceeds
    member i's own by more than ``margin`` (the best ``refit_top`` of them) are fitted in
    its place (``add``).  The exchange that lowers the chi-square most, by more than
    ``margin``, is returned.

    Parameters
    ----------
    members : sequence of str
        The subset (effects.md ids).
    movable : sequence of str
        The members that may be exchanged.
    pool : sequence of str
        Every candidate the selection may take.
    drop : callable
        ``drop(i) -> fit`` of the subset without member i.
    gains : callable
        ``gains(fit, cands) -> {c: (score, estimate)}``: the chi-square adding c to the fit
        would remove (linearised) [1] and c's linear estimate [effect unit].
    add : callable
        ``add(fit, c, estimate) -> fit`` with c added, started at its estimate.
    chi2 : callable
        ``chi2(fit) -> float`` [1].
    chi2_now : float
        The subset's chi-square [1].
    refit_top : int
        Most exchanges fitted per member.
    margin : float
        Chi-square by which an exchange must be better [1].

    Returns
    -------
    best : (str, str, fit, float) or None
        (member out, candidate in, the fit with the exchange, its fall in chi-square).
    tried : list of dict
        Every exchange fitted: ``out``, ``in``, ``score`` and ``delta_chi2`` (the fall in
        chi-square against the subset, negative when it fits worse) [1].

    References
    ----------
    Miller, A. J., *Subset Selection in Regression*, 2nd ed., Chapman & Hall 2002, §3.5
    (sequential replacement).
    """
    best, tried = None, []
    for i in movable:
        d = drop(i)
        g = gains(d, [c for c in pool if c not in members or c == i])
        better = sorted((c for c in g if c != i and g[c][0] > g[i][0] + margin), key=lambda c: -g[c][0])
        for c in better[:refit_top]:
            t = add(d, c, g[c][1])
            fall = chi2_now - chi2(t)
            tried.append({"out": i, "in": c, "score": g[c][0], "delta_chi2": fall})
            if fall > margin and (best is None or fall > best[3]):
                best = (i, c, t, fall)
    return best, tried


class _Diagnosis:
    def __init__(self, runs, baseline, alpha, max_effects, refit_top):
        self.t0 = time.perf_counter()
        self.cells, self.notes = prepare_cells(runs)
        if not self.cells:
            raise ValueError("no runs to diagnose")
        self.tests = sorted({c.test for c in self.cells})
        self.baseline, self.label = resolve_baseline(baseline, self.tests)
        self.cands = candidates_for(self.tests, self.baseline)
        self.alpha, self.max_effects, self.refit_top = alpha, max_effects, refit_top
        self.F = Fitter(self.cells, self.baseline)
        self.fold = folds(self.cells)
        # the held-out predictions of each fit, keyed by id() with the fit kept alive beside
        # them: an id alone is reused by a new fit once the old one is collected
        self._parts: dict[int, tuple[ModelFit, tuple]] = {}

    # ------------------------------------------------------------------ helpers
    def parts(self, f: ModelFit) -> tuple:
        """:func:`.fits.heldout_parts` of a fit, made once."""
        hit = self._parts.get(id(f))
        if hit is None or hit[0] is not f:
            hit = self._parts[id(f)] = (f, heldout_parts(f, self.fold))
        return hit[1]

    def ho(self, f: ModelFit) -> float | None:
        """:func:`.fits.heldout_gap` of a fit."""
        return heldout_gap(self.parts(f))

    def score(self, f: ModelFit, effect: str, U: np.ndarray) -> tuple[float, float, float, np.ndarray]:
        """(score, linear estimate, its standard uncertainty, projected signature) of a
        candidate against a fit whose column space U spans (:func:`.fits.basis`)."""
        sp = project_out(U, self.F.signature(f, effect))
        n2 = float(sp @ sp)
        if n2 <= 0:
            return 0.0, 0.0, math.inf, sp
        est = float(sp @ f.fit.z) / n2
        return est * est * n2, est, 1.0 / math.sqrt(n2), sp

    def trial(self, f: ModelFit, effect: str, est: float) -> ModelFit:
        """The fit with a candidate added, started at its linear estimate (clipped to its
        plausible size; a lag from its profile)."""
        lim = EFFECTS[effect].plausible
        at = None if effect == "sensor_lag" else (effect, float(np.clip(est, -lim, lim)))
        return self.F.fit(f.effects + [effect], start=f, at=at)

    @staticmethod
    def implausible(e: dict) -> bool:
        """Whether a ranked effect's estimate lies beyond :data:`IMPLAUSIBLE` times its
        catalogue plausible size; if so its note says so.  Such an estimate is no verdict:
        it is evidence that the gap is something the catalogue does not hold (an effect
        that size would be a broken instrument, not an unmodelled one)."""
        est, lim = e.get("estimate"), EFFECTS[e["effect"]].plausible
        if est is None or not lim or abs(est) <= IMPLAUSIBLE * lim:
            return False
        e["note"] = "; ".join(x for x in (e.get("note"), (
            f"estimate {est:.2g} {EFFECTS[e['effect']].unit} is {abs(est) / lim:.0f} x its largest plausible "
            f"size ({lim:.2g}): not a verdict; the gap is likely something the catalogue does not hold")) if x)
        return True

    # ------------------------------------------------------------------ steps
    def observability(self, bare: ModelFit, sigs: dict[str, np.ndarray]) -> dict[str, dict]:
        """Per candidate: whether the runs can see its signature off the bare model, and how
        small an effect they could detect."""
        U = basis(bare)
        zthr = float(stats.norm.isf(self.alpha / (2 * max(len(self.cands), 1))))
        # one test of the logged temperature for every candidate that would read it
        temp = _temperature_held(self.cells) if set(self.cands) & set(TEMPERATURE_EFFECTS) else None
        obs = {}
        for c in self.cands:
            s = sigs[c]
            ns = float(np.linalg.norm(s))
            o = obs[c] = {"observable": False, "observable_fraction": 0.0, "absorbed_fraction": None,
                          "min_detectable": None}
            if ns == 0:
                o["note"] = ("no signature in these runs: nothing they vary acts on it"
                             + (" (no temperature logged)" if c in ("bias_temperature", "scale_temperature") else ""))
                continue
            if c in TEMPERATURE_EFFECTS and temp is not None:
                o["note"] = (f"not observable in these runs: the temperature they log is held within its "
                             f"sensor noise (between-cell F = {temp[0]:.2g}, p = {temp[1]:.2g}); its signature "
                             "would be that noise")
                continue
            sp = project_out(U, s)
            fr = float(np.linalg.norm(sp) / ns)
            o["observable_fraction"] = fr
            o["absorbed_fraction"] = float(max(0.0, 1.0 - fr * fr))
            near = self.near_coefficients(bare, sp, s)
            # what is left of an absorbed one is rounding; of a nearly aliased one, a sliver the
            # design did not plan: the bare model's parameters that take it up, share of |s|^2
            # [1] and how far one effect unit moves each [parameter unit / effect unit]
            if fr < UNOBSERVABLE_FRACTION or near:
                idx = np.flatnonzero(bare.active)
                ab = o["absorbed_by"] = [{"parameter": bare.model.params[idx[k]].name, "share": sh, "per_unit": x}
                                         for k, sh, x in taken_up(bare.fit.J[:, idx], s)]
                o["note"] = (f"not observable in these runs: {100 * o['absorbed_fraction']:.4g} % of its signature "
                             f"lies in the bare model's columns ({', '.join(a['parameter'] for a in ab[:3])}); "
                             "whatever its size, those parameters take it up")
                if near:
                    o["near_alias"] = near
                    o["note"] += ("; aliased with " + ", ".join(f"{k} (nearly, r = {_corr_text(r)})"
                                                                for k, r in near.items())
                                  + f", the run that separates them: the advice 'separate {c} from {next(iter(near))}'")
                continue
            o["projected"] = sp
            # against the noise, not the gap: the gap is what a candidate may explain
            md = o["min_detectable"] = zthr / float(np.linalg.norm(sp))
            o["observable"] = bool(md <= EFFECTS[c].plausible)
            if not o["observable"]:
                o["note"] = (f"weakly observable: the smallest size these runs could detect ({md:.3g} "
                             f"{EFFECTS[c].unit}) exceeds its largest plausible size ({EFFECTS[c].plausible:.3g})")
        return obs

    @staticmethod
    def near_coefficients(bare: ModelFit, sp: np.ndarray, s: np.ndarray) -> dict[str, float]:
        """The bare model's instrument coefficients a candidate's estimate would correlate
        with at |r| >= :data:`~accelcal.fitting.identify.NEAR_ALIAS_R` were it added
        (:func:`~accelcal.fitting.identify.near_aliases`): the runs determine only their
        combination (Kip and Kpp on mounts 0/180/45/225, where a_I a_P = a_P^2 but for the
        mass-centre offset's r / R).  Name -> r [1], largest |r| first; {} when none.

        Parameters
        ----------
        bare : ModelFit
            The bare model.
        sp, s : (N,) ndarray
            The candidate's signature projected off the bare model, and whole [1 per
            effect unit].
        """
        # 1 - r^2 >= (|sp| / |s|)^2: only a direction the bare model nearly absorbs can have one
        if float(sp @ sp) > (1.0 - NEAR_ALIAS_R ** 2) * float(s @ s):
            return {}
        idx = np.flatnonzero(bare.active)
        names = [bare.model.params[i].name for i in idx] + ["effect"]
        R, u = added_correlations(bare.fit.J[:, idx], s)
        coef = {names[k] for k, i in enumerate(idx) if bare.model.roles[i].kind == "coef"}
        pairs = [a for a in near_aliases(names, R, u) if a.b == "effect" and a.a in coef]
        return {a.a: a.r for a in sorted(pairs, key=lambda a: -abs(a.r))}

    def select(self, bare: ModelFit, obs: dict) -> tuple[ModelFit, list[str], list[dict], dict]:
        """Forward selection: score, refit the best, likelihood ratio and held-out gates."""
        cur, sel, steps = bare, [], []
        fits = {(): bare}
        pool = [c for c in self.cands if obs[c]["observable"]]
        while len(sel) < self.max_effects:
            rem = [c for c in pool if c not in sel]
            if not rem or cur.fit.dof <= 0:
                break
            U = basis(cur)
            sc = {c: self.score(cur, c, U) for c in rem}
            top = sorted(rem, key=lambda c: -sc[c][0])[: self.refit_top]
            rows, best = [], None
            for c in top:
                t = self.trial(cur, c, sc[c][1])
                # Bonferroni over every test the selection has made: m candidates at step k
                r = {"effect": c, "score": sc[c][0], **self.gates(cur, t, len(rem) * (len(sel) + 1))}
                rows.append(r)
                fits[tuple(sel + [c])] = t
                if r["passes"] and (best is None or r["delta_chi2"] > best[1]["delta_chi2"]):
                    best = (c, r, t)
            best = self.tie_break(best, rows, fits, sel, sc)
            steps.append({"step": len(sel) + 1, "candidates": len(rem), "tried": rows,
                          "taken": best[0] if best else None})
            if best is None:
                break
            sel.append(best[0])
            # the noise model is refitted to the residuals of the model that takes the effect
            # (a gap that varies inside cells, a K1T with the temperature moving during a
            # dwell, inflates the bare model's), and the next step compares on it
            cur = self.F.fit(best[2].effects, start=best[2], noise_passes=1)
            fits = {tuple(sel): cur}
            cur, sel, fits = self.replace(cur, sel, fits, pool, steps[-1], len(rem) * len(sel))
        return cur, sel, steps, fits

    def gates(self, smaller: ModelFit, larger: ModelFit, m: int) -> dict:
        """What a larger model must pass against a smaller one to be taken: its likelihood
        ratio (:func:`.fits.lr_test`) significant at alpha / m, and a held-out gap it does
        not widen (``shrink_heldout`` None or above 0): ``passes``."""
        lr = lr_test(smaller, larger, m, self.alpha)
        sh = shrink(self.ho(smaller), self.ho(larger))
        return {**{k: lr[k] for k in ("delta_chi2", "p_value", "threshold_p", "significant")}, "shrink_heldout": sh,
                "passes": lr["significant"] and (sh is None or sh > 0)}

    def gains(self, f: ModelFit, cands: Sequence[str]) -> dict[str, tuple[float, float]]:
        """Candidate -> (score, linear estimate) against a fit (:meth:`score`)."""
        U = basis(f)
        return {c: self.score(f, c, U)[:2] for c in cands}

    def replace(self, cur: ModelFit, sel: list[str], fits: dict, pool: list[str], step: dict,
                m: int) -> tuple[ModelFit, list[str], dict]:
        """The best subset of the size the selection has reached, by sequential replacement
        (:func:`best_swap`; Miller 2002, §3.5): each member but the one just added is
        dropped in turn and the candidates that would gain more than it are fitted in its
        place.  An exchange the data prefer by more than :data:`TIE_CHI2` is made when the
        new subset passes the step's gates (:meth:`gates`, Bonferroni over m) against the
        best model one smaller seen; then the noise model is refitted and the search
        repeated.  Each exchange lowers the chi-square, so the search ends.

        The fits without each member stay in ``fits`` (keyed by the others, in order): the
        ranking's drop-one fits when this is the final size.  ``step`` records the
        exchanges fitted (``swaps``), those made (``replaced``, with their gates) and the
        subset kept (``best_subset``).
        """
        step["swaps"], step["replaced"] = [], []
        drops: dict[str, ModelFit] = {}

        def drop(i: str) -> ModelFit:
            others = tuple(x for x in sel if x != i)
            drops[i] = fits[others] = self.F.fit(self.baseline + list(others), start=cur)
            return drops[i]

        for _ in pool:
            drops.clear()
            got, tried = best_swap(sel, sel[:-1], pool, drop, self.gains, self.trial, lambda f: f.fit.chi2,
                                   cur.fit.chi2, self.refit_top)
            step["swaps"] += tried
            if got is None:
                break
            out, new, t, _ = got
            smaller = min([drops.get(sel[-1]) or drop(sel[-1]), *drops.values()], key=lambda f: f.fit.chi2)
            g = self.gates(smaller, t, m)
            step["replaced"].append({"out": out, "in": new, **g,
                                     "against": [e for e in smaller.effects if e not in self.baseline]})
            if not g["passes"]:
                break
            sel = [x for x in sel if x != out] + [new]
            cur = self.F.fit(t.effects, start=t, noise_passes=1)
            fits = {tuple(sel): cur}
        step["best_subset"] = list(sel)
        return cur, sel, fits

    def tie_break(self, best, rows, fits, sel, sc):
        """Two aliased candidates (|cos| of their projected signatures > ALIAS_COS) that the
        data do not tell apart (their chi-squares within :data:`TIE_CHI2` of each other:
        neither preferred by a sigma) are a tie: the one of higher precedence
        (:meth:`precedence`) is taken and the other is reported as its alias."""
        if best is None:
            return None
        c0, lr0, _ = best
        a = sc[c0][3]
        for r in rows:
            c = r["effect"]
            if c == c0 or not r["passes"]:
                continue
            b = sc[c][3]
            tie = abs(r["delta_chi2"] - lr0["delta_chi2"]) <= TIE_CHI2
            if abs(alias_cos(a, b)) > ALIAS_COS and tie and self.precedence(c) < self.precedence(best[0]):
                best = (c, r, fits[tuple(sel + [c])])
        return best

    def precedence(self, effect: str) -> int:
        """Order in which effects are named when the data cannot choose: first those the
        lab's processing model carries for these tests (in its order: the term it would have
        to add), then the catalogue's order (effects.md)."""
        order = processing_effects(self.tests) + [e for e in EFFECTS if e not in processing_effects(self.tests)]
        return order.index(effect)

    def row(self, c: str, obs: dict, **kw) -> dict:
        """Ranking row of a candidate: what ``obs`` says of it, nothing estimated unless
        ``kw`` says so."""
        o = obs[c]
        return {"effect": c, "estimate": None, "std_uncertainty": None, "unit": EFFECTS[c].unit, "z": None,
                "delta_chi2": None, "p_value": None, "significant": False, "selected": False,
                "shrink_in_sample": None, "shrink_heldout": None, "observable": o["observable"],
                "observable_fraction": o["observable_fraction"], "absorbed_fraction": o["absorbed_fraction"],
                "min_detectable": o["min_detectable"], "aliases": [], **kw}

    def entry(self, c: str, final: ModelFit, without: ModelFit, obs: dict, selected: bool, m: int) -> dict:
        """Ranking row of an effect from a fit with it (final or add-one) and one without."""
        name = effect_parameter(final, c)
        lr = lr_test(without, final, m, self.alpha)
        est = final.value(name) if name else None
        u = uncertainty(final, name) if name else None
        many = effect_parameters(final, c)
        extra = {"estimates": {n: {"value": final.value(n), "std_uncertainty": uncertainty(final, n)}
                               for n in many}} if len(many) > 1 else {}
        held_out = heldout_test(without, final, self.fold, parts=(self.parts(without), self.parts(final)))
        return self.row(c, obs, estimate=est, std_uncertainty=u, **extra, z=(est / u) if (est is not None and u)
                        else None, delta_chi2=lr["delta_chi2"], p_value=lr["p_value"], statistic=lr["statistic"],
                        significant=bool(selected and lr["significant"]), selected=selected,
                        shrink_in_sample=shrink(gap_rms(without), gap_rms(final)),
                        shrink_heldout=shrink(self.ho(without), self.ho(final)),
                        **{f"heldout_{k}": v for k, v in held_out.items() if k != "cells"})

    # ------------------------------------------------------------------ main
    def run(self) -> dict:
        bare, sigs = self.F.bare(self.cands)
        self.cands = [c for c in self.cands if c not in self.F.determined]
        obs = self.observability(bare, sigs)
        final, sel, steps, fits = self.select(bare, obs)
        if sel:          # the bare model on the final noise model: gaps compared on one scale
            fits[()] = self.F.fit(self.baseline, start=bare)
        m = max(sum(o["observable"] for o in obs.values()), 1)
        ranking = []
        for c in sel:
            others = [e for e in sel if e != c]
            wo = fits.get(tuple(others)) or self.F.fit(self.baseline + others, start=final)
            ranking.append(self.entry(c, final, wo, obs, True, m))
        U = basis(final)
        rest = [c for c in self.cands if c not in sel and obs[c]["observable"]]
        sc = {c: self.score(final, c, U) for c in rest}
        s2 = max(final.fit.chi2 / final.fit.dof, 1.0) if final.fit.dof > 0 else 1.0
        for k, c in enumerate(sorted(rest, key=lambda c: -sc[c][0])):
            if k < self.refit_top and final.fit.dof > 0:
                ranking.append(self.entry(c, self.trial(final, c, sc[c][1]), final, obs, False, m))
            else:
                s, est, se, _ = sc[c]
                ranking.append(self.row(c, obs, estimate=est, std_uncertainty=se * math.sqrt(s2),
                                        z=est / se if se and math.isfinite(se) else None, delta_chi2=s,
                                        note="linear estimate (projected signature), not refitted"))
        unobservable = []
        for c in self.cands:
            if obs[c]["observable"]:
                continue
            o = obs[c]
            e = self.row(c, obs, note=o.get("note", ""))
            if "absorbed_by" in o:
                e["absorbed_by"] = o["absorbed_by"]
                if "near_alias" in o:
                    e["near_alias"] = o["near_alias"]
                self.instrument_aliases(e, bare)
            ranking.append(e)
            unobservable.append({k: e[k] for k in ("effect", "observable_fraction", "absorbed_fraction", "note")}
                                | {k: o[k] for k in ("absorbed_by", "near_alias") if k in o})
        ranking += [self.determined_row(c, final) for c in self.F.determined]
        self.aliases(ranking, obs, bare)
        # verdict: a selected effect that passes significance and the held-out gate
        # a gap worth naming: the bare model's lack of fit at 5 %, or a five-sigma effect of
        # its own (a two-sigma effect in a model that fits is not a diagnosis)
        gap = bare.fit.lof.p_value is not None and bare.fit.lof.p_value < GAP_SEEN
        implausible = {e["effect"] for e in ranking if self.implausible(e)}
        ok = [e for e in ranking if e["selected"] and e["significant"] and e["effect"] not in implausible
              and ((e["shrink_heldout"] or -math.inf) >= HELDOUT_GATE or (e.get("heldout_z") or 0.0) >= HELDOUT_Z)
              and (gap or (e.get("statistic") or 0.0) >= VERDICT_STATISTIC)]
        # of several, the one the processing model carries first among those that carry a
        # five-sigma part of the chi-square on their own (all are listed significant)
        strong = ([e for e in ok if (e.get("statistic") or 0.0) >= VERDICT_STATISTIC]
                  or sorted(ok, key=lambda e: -e["delta_chi2"])[:1])
        verdict = min(strong, key=lambda e: self.precedence(e["effect"]))["effect"] if strong else None
        sel_rank = sorted([e for e in ranking if e["selected"]], key=lambda e: -(e["delta_chi2"] or 0))
        ranking = sel_rank + [e for e in ranking if not e["selected"]]
        if verdict:
            ranking.sort(key=lambda e: e["effect"] != verdict)
            self.alias_estimates(ranking[0], final, sel, obs)
        return self.report(bare, fits[()], final, sel, steps, ranking, unobservable, verdict)

    def instrument_aliases(self, e: dict, bare: ModelFit) -> None:
        """An effect the bare model's instrument coefficients take up whole (a mount angle
        error in one mount plane is the unit's Kp, Kp = -dphi; a rate scale error on a
        centrifuge without a gravity reference is K1): those coefficients are its
        ``aliases``, and ``alias_estimates`` says what the effect would be were the whole
        of each coefficient's estimate the effect.  The bare model keeps the coefficient:
        the calibration exists to measure it.

        Parameters
        ----------
        e : dict
            Ranking row of an unobservable effect with ``absorbed_by``; changed in place.
        bare : ModelFit
            The bare model's fit.
        """
        m = bare.model
        near = e.get("near_alias", {})
        for a in e["absorbed_by"]:
            k = a["parameter"]
            i = m.params.index.get(k)
            if (i is None or m.roles[i].kind != "coef" or not a["per_unit"]
                    or (abs(a["share"]) < TAKEN_SHARE and k not in near)):
                continue
            e["aliases"].append(k)
            if m.roles[i].key not in BASE:   # a cross term's whole estimate could be the effect; K1's not
                e.setdefault("alias_estimates", {})[k] = bare.value(k) / a["per_unit"]
            how = f" nearly (r = {_corr_text(near[k])})" if k in near else ""
            e.setdefault("coefficient_aliases", []).append(
                {"coefficient": k, "value": bare.value(k), "std_uncertainty": uncertainty(bare, k),
                 "unit": m.params[k].unit, **({"r": near[k]} if k in near else {}),
                 "note": f"instrument coefficient the bare model determines, aliased with the effect{how}; these runs cannot tell "
                         f"{e['effect']} from it, and the calibration keeps {k}"})

    def determined_row(self, c: str, final: ModelFit) -> dict:
        """Ranking row of an instrument-term candidate whose coefficient the runs determine
        through the fitted nuisances (:attr:`.fits.Fitter.determined`): the unit's own
        coefficient, fitted by every model here, reported with its value; never a verdict.

        Parameters
        ----------
        c : str
            effects.md id (cross_coupling for Kip).
        final : ModelFit
            The final model (the coefficient's estimate and uncertainty).
        """
        k = self.F.determined[c]
        v, u = final.value(k), uncertainty(final, k)
        vt, ut = round_gum_sci(v, u)
        through = [e for e in self.baseline if effect_parameters(final, e, final.model.params.free())]
        seen = {c: {"observable": True, "observable_fraction": None, "absorbed_fraction": None, "min_detectable": None}}
        return self.row(c, seen, estimate=v, std_uncertainty=u, z=v / u if u else None,
                        determined={"coefficient": k, "value": v, "std_uncertainty": u,
                                    "unit": final.model.params[k].unit},
                        note=(f"{k} determined after all: {vt} ± {ut} {EFFECTS[c].unit} (standard uncertainty); "
                              f"these runs determine the unit's {k} only through the fitted "
                              f"{', '.join(through) or 'rig geometry'}, so the bare model fits it: the instrument's "
                              "own coefficient, not an unmodelled effect"))

    def alias_estimates(self, e: dict, final: ModelFit, sel: list[str], obs: dict) -> None:
        """What each alias of the verdict would be if it were the cause: the final model with
        the alias in place of the verdict, refitted (its estimate and how much worse it fits)."""
        out = {}
        for d in e["aliases"]:
            if d in sel or not obs.get(d, {}).get("observable"):
                continue
            alt = self.F.fit([x for x in final.effects if x != e["effect"]] + [d], start=final)
            name = effect_parameter(alt, d)
            if name is not None:
                out[d] = alt.value(name)
                e.setdefault("alias_fit", {})[d] = {"delta_chi2_worse": alt.fit.chi2 - final.fit.chi2,
                                                    "std_uncertainty": uncertainty(alt, name)}
        if out:
            e["alias_estimates"] = out

    def aliases(self, ranking: list[dict], obs: dict, bare: ModelFit) -> None:
        """What the runs cannot tell each ranked effect from, both projected off the bare
        model (|cos| above :data:`~accelcal.fitting.identify.ALIAS_COS`,
        :func:`~accelcal.fitting.identify.alias_cos`): the other effects' signatures, and the
        columns of the non-catalogue coefficients the bare model holds because the runs
        cannot determine them (:meth:`CampaignModel.select`: the effect's estimate then
        includes the coefficient; one 45 deg mount with Kip withheld: cross_coupling is
        Kip + Kpp); and the coefficients held so that the effect can be seen
        (:attr:`.fits.Fitter.extra_held`).

        Parameters
        ----------
        ranking : list of dict
            Ranking rows, changed in place (``aliases``, ``alias_cos``,
            ``coefficient_aliases``).
        obs : dict
            :meth:`observability` (``projected`` signatures [1]).
        bare : ModelFit
            The bare model (its Jacobian has every column, held ones included).
        """
        m = bare.model
        dirs = {c: o["projected"] for c, o in obs.items() if "projected" in o and np.any(o["projected"])}
        why = {}
        held = [(k, h) for k, h in bare.held.items() if k in m.params
                and m.roles[m.params.index[k]].kind == "coef" and m.roles[m.params.index[k]].key in NON_CATALOGUE]
        U = basis(bare) if held else None
        for k, h in held:
            col = bare.fit.J[:, m.params.index[k]]
            v = project_out(U, col)
            # a column the bare model takes up (a mount angle takes Kp) is not what an
            # effect's signature shows: only what is left of it counts
            if np.linalg.norm(col) > 0 and np.linalg.norm(v) > UNOBSERVABLE_FRACTION * np.linalg.norm(col):
                dirs[k], why[k] = v, h.reason
        for e in ranking:
            c = e["effect"]
            co = [k for k, h in self.F.extra_held.items() if c in h.aliased_with]
            if co:
                e["coefficient_aliases"] = [{"coefficient": k, "note": "instrument coefficient, not a catalogue "
                                             "effect: held in the bare model so that the effect can be seen; the "
                                             "runs cannot tell them apart"} for k in co]
            if c not in dirs:
                continue
            for d, b in dirs.items():
                cs = alias_cos(dirs[c], b)
                if d == c or abs(cs) <= ALIAS_COS or d in e["aliases"]:
                    continue
                e["aliases"].append(d)
                e.setdefault("alias_cos", {})[d] = cs
                if d in why and not any(x["coefficient"] == d for x in e.get("coefficient_aliases", [])):
                    e.setdefault("coefficient_aliases", []).append(
                        {"coefficient": d, "note": f"instrument coefficient the runs cannot determine ({why[d]}; held "
                                                   "at 0 in the bare model): the effect's estimate includes it"})

    def report(self, bare0: ModelFit, bare: ModelFit, final: ModelFit, sel, steps, ranking, unobservable, verdict) -> dict:
        """bare0: the bare model on its own noise model (its lack of fit is 'before'); bare:
        on the final noise model (gaps and shrinks are compared with the final fit on it)."""
        before, after = gap_test(bare0), gap_test(final)
        explained = None if after["significant"] is None else not after["significant"]
        if before["significant"] is False and after["significant"] is None:
            explained = True
        # the omnibus test dilutes a shaped gap over every cell: the targeted test of a
        # sweep hysteresis (rising vs falling steps) can say on its own that a gap remains
        shaped = shape_tests(final) if final.fit.dof > 0 else []
        if explained is not False and any(t["significant"] for t in shaped):
            explained = False
            after = {**after, "significant": True, "status": "shaped gap",
                     "shape_test": next(t for t in shaped if t["significant"])}
        rows_b = localise(bare0, self.alpha)
        rows_a = localise(final, self.alpha) if sel else rows_b
        ho_b, ho_a = self.ho(bare), self.ho(final)
        g = {"rms_before": float(np.sqrt(np.mean(bare.fit.z ** 2))),
             "rms_after": float(np.sqrt(np.mean(final.fit.z ** 2))),
             "noise_rms": float(np.sqrt(final.fit.dof / final.fit.n_obs)) if final.fit.n_obs else None,
             "gap_rms_before": gap_rms(bare), "gap_rms_after": gap_rms(final),
             "shrink_in_sample": shrink(gap_rms(bare), gap_rms(final)),
             "heldout_gap_rms_before": ho_b, "heldout_gap_rms_after": ho_a, "shrink_heldout": shrink(ho_b, ho_a),
             "significant_before": before, "significant_after": after,
             "units": "rms_* and gap_* in units of the noise sigma of a cell mean (whitened); gap_rms = "
                      "sqrt(max(0, (chi2 - dof) / N)); held-out: alternate cells of each run predicted by a fit to "
                      "the others",
             "si": {"rms_before_m_s2": float(np.sqrt(np.mean(residual_si(bare) ** 2))),
                    "rms_after_m_s2": float(np.sqrt(np.mean(residual_si(final) ** 2))),
                    "noise_rms_m_s2": _noise_si(final)},
             "chi2_before": bare.fit.chi2, "dof_before": bare.fit.dof,
             "chi2_after": final.fit.chi2, "dof_after": final.fit.dof}
        forms = shape(final) if explained is False else None
        unexplained = {"where": where(rows_a), "shape": forms, "text": "a significant gap remains that no catalogue "
                       "effect explains: " + summary(rows_a, forms)} if explained is False else None
        out = {
            "verdict": verdict,
            "verdict_aliases": next((e["aliases"] for e in ranking if e["effect"] == verdict), []) if verdict else [],
            "explained": explained,
            "status": self.status(before, after, verdict, sel),
            "selected": sel,
            "baseline": {"label": self.label, "effects": self.baseline, "bare_model": _bare_text(bare0)},
            "ranking": ranking,
            "unobservable": unobservable,
            "where": where(rows_b),
            "where_after": where(rows_a) if sel else None,
            "unexplained": unexplained,
            "shape_before": shape(bare0),
            "shape_tests": shaped,
            "gap": g,
            "selection_steps": steps,
            "alpha": self.alpha, "gap_alpha": GAP_ALPHA, "heldout_gate": HELDOUT_GATE, "heldout_z": HELDOUT_Z,
            "held": {k: h.reason for k, h in bare0.held.items()},
            "determined": [{"effect": e["effect"], **e["determined"], "note": e["note"]}
                           for e in ranking if "determined" in e],
            "notes": self.notes,
            "runs": [{"run_id": r.run_id, "test": r.test, "campaign": r.campaign, "cells": r.ncell,
                      "noise": {"a": r.noise.a, "b": r.noise.b, "rho": r.noise.rho, "dof": r.noise.dof,
                                "source": r.noise.source}, "notes": r.notes} for r in self.F.cells],
            "K1": {c: final.value(n) for c in final.model.campaigns if (n := final.model.name(c, "K1")) is not None},
            "where_all": rows_b,
            "_fits": {"before": bare0, "after": final},
        }
        out["elapsed_s"] = time.perf_counter() - self.t0
        return out

    @staticmethod
    def status(before, after, verdict, sel) -> str:
        if before["significant"] is None:
            return "untestable: no degrees of freedom (the bare model has as many parameters as distinct inputs)"
        if after.get("status") == "shaped gap":
            t = after["shape_test"]
            return (f"a shaped gap remains unexplained{' after ' + ', '.join(sel) if sel else ''}: {t['test']} "
                    f"(z = {t['z']:.1f}) that no catalogue effect explains")
        if not before["significant"] and not sel:
            return "no significant gap"
        if verdict and after["significant"] is False:
            return f"gap explained by {', '.join(sel)}"
        if after["significant"] is None:
            return f"{', '.join(sel)} found; what remains is untestable (no degrees of freedom left)"
        if after["significant"]:
            return ("a significant gap remains unexplained" + (f" after {', '.join(sel)}" if sel else "")
                    + ("" if verdict else ": no catalogue effect passes the significance and held-out gates"))
        return (f"{', '.join(sel)} significant, but none is named: none removes {HELDOUT_GATE:g} of the gap "
                f"on held-out cells or is confirmed there at z >= {HELDOUT_Z:g}, or a "
                "gap too small to name an effect for (the bare model fits at 5 % and no effect has five sigma)")


def _corr_text(r: float) -> str:
    """A correlation near +-1 with one digit beyond the first that departs from 9
    (0.999983, not 1.0)."""
    d = max(2, int(math.ceil(-math.log10(max(1.0 - abs(r), 1e-15)))) + 1)
    return f"{r:.{d}f}"


def _noise_si(f: ModelFit) -> float:
    """rms noise sigma of a cell mean, referred to the input [m/s^2]."""
    return float(np.sqrt(np.mean((f.model.sig / input_scale(f)) ** 2))) if f.fit.n_obs else 0.0


def _bare_text(f: ModelFit) -> str:
    free = [p.name for p, v in zip(f.model.params, f.active) if v]
    held = [f"{k} ({h.reason})" for k, h in f.held.items()]
    return ("the forward model with the baseline effects; free: " + ", ".join(free)
            + ("; held: " + "; ".join(held) if held else ""))


def public(result: dict) -> dict:
    """The JSON-able part of a diagnosis.

    Parameters
    ----------
    result : dict
        Result of :func:`diagnose`.

    Returns
    -------
    dict
        A shallow copy without the private keys (those starting with ``_``, e.g. ``_fits``).
    """
    return {k: v for k, v in result.items() if not k.startswith("_")}


__all__ = ["diagnose", "public", "resolve_baseline", "candidates_for", "NON_CATALOGUE"]
