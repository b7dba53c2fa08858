"""The adopted calibration: one maximum-likelihood fit per campaign through the one forward
model.

Every reading of every run of the campaign enters one weighted Gauss–Newton fit of the
campaign model (:class:`accelcal.fitting.model.CampaignModel`): tumble and centrifuge
pooled, Koq and K3 shared by all mounts, the mount-angle errors, the turning-centre radius
and the mass-centre offset as parameters where the design sees them, temperature per
reading, the sinusoidal drive fitted to its logged rate.  The weights come from a noise
model fitted to the data of each run (white + rate-proportional, with regressor noise and
lag-1 autocorrelation; :mod:`accelcal.fitting.data`).

Uncertainty.  u = sqrt(diag((J^T W J)^-1)) at the solution, scaled by the lack-of-fit
factor sqrt(F) when the model is inadequate (F test of the cell means against the pure
error, Draper & Smith §2.1), with the lack-of-fit degrees of freedom then carried as the
coefficient's dof.  A fit with no spare degrees of freedom is *untestable*: it is flagged,
and its coefficients carry no uncertainty (NaN), because reading noise alone would pretend
to a precision the data cannot support.  The covariance of all coefficients is kept
(``extras['joint']['correlation']``).

The paper methods (eqs 4–7 radius, eq 9 per pair, eq 3 combination, 001 point LS, 002)
are computed beside it by :mod:`accelcal.estimators.campaign` and stored as cross-checks;
where one disagrees with the adopted value beyond their combined expanded uncertainty
(|En| > 1) a flag says so.

References: He & Yin 2017 (paper 000), Zhang et al. 2021 (001), Sun, Ren & Wang (002),
Zhan & Cai (003); JCGM 100:2008 §4.2, G.4; ISO 13528 §9.7 (En).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import replace
from typing import Any

import numpy as np

from ..constants import MOUNT_ANGLE_TOLERANCE_RAD
from ..effects import combination_formula, combination_name, si_unit
from ..fitting.core import birge_ratio, lstsq_svd, normalised_error
from ..fitting.data import (RunCells, block_note, drop_duplicate_cells, fit_noise, make_run,
                            pool_missing_noise, with_noise)
from ..fitting.identify import Combination, NearAlias, Why, dependence_text, display_name, near_aliases
from ..fitting.model import ACTING, CampaignModel, mount_runs, processing_effects
from ..fitting.procedure import ModelFit, fit_selected
from ..physics.axes import AXES
from ..results import AdequacyResult, BudgetTerm, CoefficientResult, RadiusResult
from .adequacy import runs_test, trend_test
from .records import TumbleCoefficient, run_columns
from ..fitting.distributions import chi2_sf, t_ppf

METHOD = "joint_ml"
#: Level of the extra-sum-of-squares test of the terms that only act on the runs, when the
#: designed model fails its lack-of-fit test: a campaign that fails that test by chance
#: (1 %) lets them in only 0.1 % of the time
ACTING_ALPHA = 1e-3
#: coefficients the adopted fit takes where a test is designed for them or acts on them
ACTING_TERMS = ("Kip", *sorted({k for ks in ACTING.values() for k in ks} - {"Kip"}))

#: Reported coefficients and what an aliased design leaves in them
NOTES = {
    "K0T": ("apparent bias TC: includes g c cos(gamma) of any fixture thermal tilt c "
            "(fixture_thermal_tilt), which the tilt-rotation design cannot separate (paper 001 §3.2)"),
}


def coverage_factor(dof: float, p: float = 0.95) -> float:
    """k for a coverage probability p from Student's t with ``dof`` degrees of freedom
    (JCGM 100 G.3); 2 for 30 or more dof (or an infinite/unknown dof)."""
    if not dof or not math.isfinite(dof) or dof >= 30:
        return 2.0
    return float(t_ppf(0.5 + p / 2, dof))


def fit_campaign_model(runs: Sequence[RunCells], effects: Sequence[str], *, shared: Sequence[str] = (),
                       per_run_bias: bool | None = None, per_run_scale: bool = False,
                       noise_passes: int = 1, keep: Sequence[str] = ()) -> ModelFit:
    """Fit a campaign model to runs whose cells are built (:func:`prepare`), through the one
    fit procedure (:func:`accelcal.fitting.procedure.fit_selected`): the design judged at
    the start and again after the first noise pass, a time constant bounded at 0.

    Parameters
    ----------
    runs : sequence of RunCells
    effects : sequence of str
        effects.md ids in the model.
    shared, per_run_bias, per_run_scale
        :class:`~accelcal.fitting.model.CampaignModel`.
    noise_passes : int
        Times the noise model of each run is refitted to the residuals of the fit.
    keep : sequence of str
        Parameters never held for being weakly determined.

    Returns
    -------
    ModelFit
    """
    # Kip is a designed coefficient of a tumble too (a head about OA turns IA through PA,
    # IEEE 1293), not only the centrifuge's cross_coupling effect; the terms that act on a
    # tumble or a tilted table come in there too (ACTING)
    def build(runs):
        return CampaignModel(runs, effects, shared=shared, per_run_bias=per_run_bias,
                             per_run_scale=per_run_scale, include=ACTING_TERMS, acting=ACTING)
    model = build(runs)
    # a term that only acts (a square term on a tilted table) is held while the designed
    # model fits: at 0.45 deg of tilt it is invisible, and would only dilute the others' u;
    # it is named in what the held terms leave in the rows (CampaignModel.combinations)
    hold = {n: "acts on these runs, held: the model fits without it" for n in model.acting_only}
    jf = fit_selected(model, keep=keep, noise_passes=noise_passes, effects=effects, hold=hold)
    if hold and jf.fit.lof.status == "inadequate":
        # ... and let in, as the design decides, where the designed model does not fit and
        # the terms let in explain it (extra sum of squares, Draper & Smith §6.1): a table
        # tilted by 10 deg or more shows its square terms; a campaign that fails the test by
        # chance keeps its model
        wider = fit_selected(build(jf.model.runs), keep=keep, noise_passes=noise_passes, effects=effects)
        t = wider.compare(jf, always_scaled=True)
        if wider.fit.rank > jf.fit.rank and t.p_value is not None and t.p_value < ACTING_ALPHA:
            wider.notes.append(
                f"the designed model did not fit (lack-of-fit F = {jf.fit.lof.statistic:.3g}); the terms "
                f"that act on these runs explain it (F = {t.statistic:.3g} on {t.q} terms, p = {t.p_value:.2g}) "
                f"and were let in: {', '.join(n for n in hold if n not in wider.held)}")
            jf = wider
    return jf


#: Within :func:`cells_kept`: id of a RunFile-like object -> [the object, its cells as
#: :func:`~accelcal.fitting.data.make_run` builds them, their first noise model or None]
_KEPT: ContextVar[dict | None] = ContextVar("accelcal_kept_cells", default=None)


@contextmanager
def cells_kept():
    """Inside it, :func:`prepare` builds each run's cells and fits their first noise model
    once, however many lists of the campaign's runs it is given (the joint fit, each
    tumble run alone, each head's runs); on leaving, what it kept is let go."""
    token = _KEPT.set({})
    try:
        yield
    finally:
        _KEPT.reset(token)


def campaign_kept() -> dict:
    """What :func:`cells_kept` keeps for the campaign being computed, for the estimators
    that keep a run's derived arrays with it (keys tuples that name their method); outside
    it, a new empty dict, so that nothing is kept."""
    kept = _KEPT.get()
    return {} if kept is None else kept


def prepare(runs) -> tuple[list[RunCells], list[str]]:
    """RunFile-like objects (meta, data, sha256) -> cells with a first noise model.

    A run's cells and its own noise model depend on the run alone, except for its position
    in the list (its ``index``, and its ``run_id`` when the metadata has none) and the
    cells an earlier run of the list already holds (:func:`drop_duplicate_cells`); inside
    :func:`cells_kept` the rest is built once per run.
    """
    kept = campaign_kept()
    cells, own = [], []
    for j, r in enumerate(runs):
        k = kept.get(id(r))
        if k is None or k[0] is not r or (k[1].index != j and "run_id" not in r.meta):
            k = kept[id(r)] = [r, make_run(r.meta, run_columns(r), j, getattr(r, "sha256", "")), None]
        cells.append(replace(k[1], index=j, notes=list(k[1].notes)))
        own.append(k)
    notes = [n for n in map(block_note, cells) if n]
    notes += drop_duplicate_cells(cells)
    for c, k in zip(cells, own):
        if c.cid is k[1].cid and k[2] is None:
            k[2] = fit_noise(k[1])
    # a run that lost cells to an earlier one of this list: the scatter of those it kept
    noise = pool_missing_noise(cells, [k[2] if c.cid is k[1].cid else fit_noise(c) for c, k in zip(cells, own)])
    return [with_noise(c, m) for c, m in zip(cells, noise)], notes


# ----------------------------------------------------------------------------- results

def what_it_measures(comb: Combination | None, label: str) -> tuple[str, str]:
    """The row name and note of a free parameter: the combination the runs determine.

    Parameters
    ----------
    comb : Combination or None
        What the parameter measures (:meth:`accelcal.fitting.model.CampaignModel.combinations`);
        None when it takes nothing up.
    label : str
        Its row name when the runs determine it alone (``'K2'``, ``'theta0[PA]'``).

    Returns
    -------
    (str, str)
        Row name (:func:`accelcal.fitting.identify.display_name`, e.g. ``'K2(Koo)'``); note:
        what is aliased and which other held parameters it depends on, or ``''``.
    """
    notes = []
    if comb is not None and comb.terms:
        exact = combination_formula(label, comb.factors, 6)
        notes.append(f"aliased in this design: the runs determine {exact}, not {label} alone "
                     f"({', '.join(k for k, _ in comb.terms)} held at 0)")
    if comb is not None and comb.depends:
        notes.append("not determined alone by these runs: " + "; ".join(dependence_text(comb)))
    return display_name(label, comb), "; ".join(notes)


def nearly_aliased(jf: ModelFit) -> list[NearAlias]:
    """Pairs of free instrument coefficients the runs determine far better together than
    alone (:func:`accelcal.fitting.identify.near_aliases` of their estimates)."""
    model, fit = jf.model, jf.fit
    coef = [prm.name for i, prm in enumerate(model.params)
            if model.roles[i].kind == "coef" and prm.vary and fit.estimable[i]]
    if len(coef) < 2:
        return []
    names, R = fit.correlation(coef)
    return near_aliases(names, R, np.array([fit.std(n) for n in names]))


#: The flag of a pair the runs determine only together.  The run that would separate them
#: is advice a person reads on demand (:func:`accelcal.testdesign.separating_run_flag`:
#: the certificate's line is ``accelcal design``'s first proposal), not part of the science
ALIASED_PAIR_FLAG = ("{a}, {b}: the runs determine them only together; the run that would separate them: "
                     "accelcal design --separate {a},{b} --max-runs 1")


def stored_aliased_pairs(extras: Mapping[str, Any] | None) -> list[tuple[str, str]]:
    """The instrument-coefficient pairs a stored joint fit determined only together, each
    flagged as :data:`ALIASED_PAIR_FLAG` (read where :func:`_records` writes them; [] for a
    result without them).

    Parameters
    ----------
    extras : mapping or None
        The stored result's extras.

    Returns
    -------
    list of (str, str)
    """
    return [(a, b) for a, b in ((extras or {}).get("joint") or {}).get("aliased_pairs") or []]


def run_consistency(runs, effects: Sequence[str], alpha: float = 0.01) -> tuple[list[dict], list[str]]:
    """Do runs of one test kind that measure the same coefficients agree?

    Each tumble run is fitted alone (its own K0, K1, K2, theta0) and the K0 and K1 of the
    runs are compared by their Birge ratio against the reading-noise uncertainty of each
    run (chi-square with N - 1 dof).  Runs that disagree are flagged, not silently averaged:
    the joint fit's lack-of-fit test and its sqrt(F) scaling carry the disagreement into
    the adopted uncertainty.

    Returns
    -------
    rows, flags
        One row per (test, coefficient) compared: values, u, Birge ratio, p, agree.
    """
    rows, flags = [], []
    tumble = [r for r in runs if str(r.meta["test"]) == "tumble"]
    if len(tumble) < 2:
        return rows, flags
    fits = {}
    for r in tumble:
        try:
            cells, _ = prepare([r])
            fits[str(r.meta["run_id"])] = fit_campaign_model(cells, [e for e in effects
                                                                       if e == "initial_misalignment"])
        except Exception as exc:  # one run that cannot be fitted alone is a flag, not a crash
            flags.append(f"run {r.meta.get('run_id')} cannot be fitted alone: {type(exc).__name__}: {exc}")
    for name in ("K0", "K1"):
        vals, us, ids = [], [], []
        for rid, jf in fits.items():
            if name in jf.model.params.index and jf.fit.estimable[jf.model.params.index[name]]:
                vals.append(jf.value(name))
                us.append(jf.fit.std_noise(name))
                ids.append(rid)
        if len(vals) < 2 or not all(u > 0 for u in us):
            continue
        m, um, birge, dof = birge_ratio(vals, us)
        p = float(chi2_sf(birge ** 2 * dof, dof))
        agree = p >= alpha
        rows.append({"test": "tumble", "coefficient": name, "runs": ids, "values": vals, "u_readings": us,
                     "birge_ratio": birge, "p": p, "agree": agree})
        if not agree:
            flags.append(f"tumble runs disagree on {name}: " + ", ".join(f"{i} {v:.6g}" for i, v in zip(ids, vals))
                         + f" (Birge ratio {birge:.3g} against their reading noise, p = {p:.2g}); not averaged "
                           "silently: the adopted value's uncertainty carries the scatter (lack-of-fit scaling)")
    return rows, flags


def campaign_results(runs, rig_ids: Sequence[str] | None = None, effects: Sequence[str] | None = None,
                     rig_uncertainty: Mapping[str, Mapping[str, float]] | None = None) -> dict[str, Any]:
    """The joint fit of one campaign and its results in the pipeline's record types.

    Parameters
    ----------
    runs : sequence of RunFile-like (meta, data, sha256)
        The runs of one campaign (newest revision of each run_id).
    effects : sequence of str, optional
        Effects in the model (default :func:`processing_effects` of the tests present).
    rig_uncertainty : mapping, optional
        Rig id -> :data:`~accelcal.effects.RIG_INPUTS` id -> the lab's stated standard
        uncertainty [the input's unit] (accelcal.toml ``[rigs."ID"]``): type-B terms of
        every budget (:func:`rig_input_terms`); an input that enters but is not stated is a
        flag and ``extras['rig_inputs']['missing']``.

    Returns
    -------
    dict
        coefficients (list of CoefficientResult, method 'joint_ml', adopted), radii,
        adequacy, budget, alignment (list of dict), flags (list of str), extras (dict),
        fit (ModelFit).
    """
    cells, notes = prepare(runs)
    tests = sorted({c.test for c in cells})
    eff = processing_effects(tests) if effects is None else list(effects)
    jf = fit_campaign_model(cells, eff)
    jf.notes += notes
    cells = jf.model.runs                          # with the noise models the fit refitted
    out = _records(jf, cells, rig_uncertainty or {})
    out["flags"] += [ALIASED_PAIR_FLAG.format(a=a, b=b) for a, b in out.pop("aliased_pairs")]
    rows, flags = run_consistency(runs, eff)
    out["flags"] += flags
    if rows:
        out["extras"]["run_consistency"] = rows
    return out


def held_type_b_directions(model: CampaignModel, p: np.ndarray, held: Mapping[str, Any],
                           tolerance: float = MOUNT_ANGLE_TOLERANCE_RAD
                           ) -> list[tuple[str, np.ndarray, float, frozenset[str]]]:
    """The type-B inputs of parameters the design cannot determine but that are physically
    there, as the directions they move the model: the one list the budget
    (:func:`type_b_terms`) and the test-design advice (:mod:`accelcal.testdesign`) read.

    A mount angle of a mount whose IA is radial (phi0 = 0/180 deg) changes the fit only at
    second order, exactly as K2 does (eq 8 at phi0 = 0: dc2 = Kip dphi); a tilt of IA out
    of the table plane (effects.md ``ia_tilt``) is a constant g sin(lambda) at first order
    (the run biases take it) and a cross-coupling term at second order (Kip lambda a_i^2
    where the vertical axis is PA, -Kio lambda a_i^2 where it is OA); a cross-axis
    sensitivity the design aliases with the mount angles or theta0 is absorbed at first
    order and leaks at second order.  Each is uniform within the fixture tolerance
    (JCGM 100 4.3.7: u = a / sqrt(3)).

    Parameters
    ----------
    model : CampaignModel
    p : ndarray
        Parameter vector [parameter units].
    held : mapping of str to Hold
        Parameter name -> its hold (:func:`accelcal.fitting.identify.holds`).
    tolerance : float
        Fixture angle tolerance [rad].

    Returns
    -------
    list of (str, ndarray, float, frozenset of str)
        (budget quantity, whitened direction (N,) [1 per input unit], u_B [rad],
        parameters that report it as part of their value).
    """
    uB = tolerance / math.sqrt(3.0)
    out = []
    for label, runs in model.unseparable_angles.items():
        out.append((f"mount angle of {label} (type B, uniform ±{tolerance:.3g} rad: not separable, eq 8)",
                    model.signature(p, "mount_angle_error", runs=runs), uB, frozenset()))
    cen = [j for j, r in enumerate(model.runs) if r.test == "centrifuge"]
    if cen and "ia_tilt" not in model.effects:
        by_rig: dict[str, list[int]] = {}
        for j in cen:
            by_rig.setdefault(model.runs[j].rig_id, []).append(j)
        for rig, runs in by_rig.items():
            out.append((f"IA tilt out of the table plane on {rig} (type B, uniform ±{tolerance:.3g} rad: "
                        "not separable)", model.signature(p, "ia_tilt", runs=runs), uB, frozenset()))
    for name, i, absorbers in absorbed_cross_axis(model, held):
        out.append((f"{name} (type B, uniform ±{tolerance:.3g} rad: aliased, absorbed at first order)",
                    model.jacobian(p, [i])[:, 0], uB, absorbers))
    return out


#: Cross-axis sensitivities a design may alias with the mount angles or theta0 (absorbed at
#: first order, leaking at second: :func:`absorbed_cross_axis`).
CROSS_AXIS_ABSORBED = ("Kp", "Ko")


def absorbed_cross_axis(model: CampaignModel, held: Mapping[str, Any]) -> list[tuple[str, int, frozenset[str]]]:
    """The cross-axis sensitivities (Kp, Ko) the design aliases with the mount angles or
    theta0: (name, parameter index, the parameters that report it as part of their value).
    What those take of it is their definition (their note says so), not an error; what
    leaks to the others is a type-B term (:func:`held_type_b_directions`)."""
    index = model.params.index
    return [(name, index[name], frozenset(h.aliased_with)) for name, h in held.items()
            if model.roles[index[name]].key in CROSS_AXIS_ABSORBED and h.why is Why.ALIASED and h.aliased_with]


def type_b_terms(jf: ModelFit, tolerance: float = MOUNT_ANGLE_TOLERANCE_RAD) -> dict[str, list[tuple[str, float, float]]]:
    """Type-B terms of parameters the design cannot determine but that are physically there
    (:func:`held_type_b_directions`): the bias each would transfer to every fitted
    parameter, dtheta = (J^T W J)^-1 J^T W j dphi (j its direction).

    Returns
    -------
    dict
        parameter name -> [(quantity, sensitivity, u_B)].
    """
    model, fit = jf.model, jf.fit
    free = np.flatnonzero(model.params.free() & fit.estimable)
    out: dict[str, list[tuple[str, float, float]]] = {}
    for quantity, col, uB, absorbers in held_type_b_directions(model, fit.values, jf.held, tolerance=tolerance):
        sol = lstsq_svd(fit.J[:, free], col)
        for c, i in enumerate(free):
            name = model.params[i].name
            if name in absorbers:
                continue
            out.setdefault(name, []).append((quantity, float(sol.x[c]), uB))
    return out


def rig_input_directions(model: CampaignModel, p: np.ndarray, stated: Mapping[str, Mapping[str, float]]
                         ) -> tuple[list[tuple[str, Any, list[np.ndarray], float, list[int]]], list[dict[str, str]]]:
    """The rig inputs the drop gives as known (local gravity, the thermal table's tilt, the
    temperature reading) that enter the model, as the directions they move it: the one
    list the budget (:func:`rig_input_terms`) and the test-design advice read.

    Parameters
    ----------
    model : CampaignModel
    p : ndarray
        Parameter vector [parameter units].
    stated : mapping
        Rig id -> input id -> standard uncertainty [the input's unit: m/s2, deg, degC].

    Returns
    -------
    directions : list of (rig, RigInput, list of ndarray, float, list of int)
        Rig, the input's spec, its whitened directions (one per set point for a per-point
        input) [1 per input unit], its stated u [input unit], the runs it acts on.
    missing : list of dict
        ``{"rig", "input", "key"}`` of each input that enters the fit but has no stated
        uncertainty (``key``: the accelcal.toml key that states it).
    """
    from ..effects import RIG_INPUTS
    out = []
    missing: list[dict[str, str]] = []
    by_rig: dict[str, list[int]] = {}
    for j, r in enumerate(model.runs):
        by_rig.setdefault(r.rig_id, []).append(j)
    for rig, runs in sorted(by_rig.items()):
        for spec in RIG_INPUTS.values():
            js = [j for j in runs if model.runs[j].test in spec.tests]
            if not js or not _enters(model, spec, js):
                continue
            u = (stated.get(rig) or {}).get(spec.id)
            if u is None:
                missing.append({"rig": rig, "input": spec.id, "key": spec.config_key})
                continue
            if spec.per_point:      # one direction per set point of the rig's runs
                sets = {j: model.runs[j].cols.get("temp_set_c") for j in js}
                sets = {j: v for j, v in sets.items() if v is not None}
                levels = np.unique(np.concatenate([v[np.isfinite(v)] for v in sets.values()] or [[]]))
                dirs = [model.input_direction(p, spec.id, list(sets), {j: v == t for j, v in sets.items()})
                        for t in levels]
            else:
                dirs = [model.input_direction(p, spec.id, js)]
            dirs = [d for d in dirs if np.any(d != 0.0)]
            if dirs:
                out.append((rig, spec, dirs, float(u), js))
    return out, missing


def rig_input_terms(jf: ModelFit, stated: Mapping[str, Mapping[str, float]]
                    ) -> tuple[dict[str, list[tuple[str, float, float, str, float]]], list[dict[str, str]]]:
    """Type-B terms of the rig inputs the drop gives as known (:func:`rig_input_directions`).

    Parameters
    ----------
    jf : ModelFit
        The campaign's joint fit.
    stated : mapping
        Rig id -> input id -> standard uncertainty [the input's unit: m/s2, deg, degC].

    Returns
    -------
    terms : dict
        Parameter name -> [(quantity, sensitivity [parameter unit per input unit], u,
        'normal', the input's value)] for the stated inputs, in SI units (an angle in rad;
        a temperature reading's value is its error, 0).
    missing : list of dict
        As :func:`rig_input_directions`.
    """
    model, fit = jf.model, jf.fit
    free = np.flatnonzero(model.params.free() & fit.estimable)
    terms: dict[str, list[tuple[str, float, float, str, float]]] = {}
    directions, missing = rig_input_directions(model, fit.values, stated)
    for rig, spec, dirs, u, js in directions:
        # the estimate moves opposite to the model: theta(x + dx) - theta(x) = -J^+ j dx
        sens = -np.array([lstsq_svd(fit.J[:, free], d).x for d in dirs])    # (points, free)
        c = np.sqrt((sens ** 2).sum(axis=0)) if spec.per_point else sens[0]
        x = 0.0 if spec.meta_key is None else float(model.runs[js[0]].meta[spec.meta_key])
        if spec.unit == "deg":      # budgets state inputs in SI units: the angle in rad
            c, u, x = c * (180.0 / math.pi), u * (math.pi / 180.0), math.radians(x)
        q = (f"{spec.what} of {rig} (type B, normal; u stated in accelcal.toml"
             + (f"; {len(dirs)} set points, sensitivities root-sum-square)" if spec.per_point else ")"))
        for k, i in enumerate(free):
            if c[k] != 0.0:
                terms.setdefault(model.params[i].name, []).append((q, float(c[k]), float(u), "normal", x))
    return terms, missing


def _enters(model: CampaignModel, spec, js: Sequence[int]) -> bool:
    """Whether a rig input enters the model of runs ``js``: a metadata value (g_local, the
    table's tilt) always does; a logged column (the temperature) where the run has it and
    a free coefficient of the model reads it (:attr:`accelcal.effects.RigInput.read_through`:
    :func:`accelcal.physics.rigs.rig_output` reads the temperature only through K0T, K1T)."""
    if spec.column is None:
        return True
    return (any(spec.column in model.runs[j].cols for j in js)
            and any(role.key in spec.read_through and prm.vary
                    for prm, role in zip(model.params, model.roles)))


def _type_a_lines(name: str, value: float, u_noise: float, factor: float) -> list[BudgetTerm]:
    """The type-A lines of an adopted row's budget: the readings through the forward model
    [its unit], and the lack-of-fit scaling u sqrt(F^2 - 1) where the model is inadequate
    (``factor`` = sqrt(F) > 1)."""
    out = [BudgetTerm(name, "readings: joint fit through the forward model (noise model per run, "
                            "autocorrelation included)", value, u_noise, 1.0, u_noise, "A", "normal", METHOD)]
    if factor > 1:
        extra = u_noise * math.sqrt(factor ** 2 - 1.0)
        out.append(BudgetTerm(name, f"model inadequacy: lack-of-fit scaling sqrt(F) = {factor:.3g}",
                              0.0, extra, 1.0, extra, "A", "normal", METHOD))
    return out


def _records(jf: ModelFit, cells: list[RunCells], stated: Mapping[str, Mapping[str, float]]) -> dict[str, Any]:
    model, fit = jf.model, jf.fit
    lof = fit.lof
    tb = {n: [(q, c, u, "uniform", 0.0) for q, c, u in v] for n, v in type_b_terms(jf).items()}
    inputs, missing = rig_input_terms(jf, stated)
    for n, v in inputs.items():
        tb.setdefault(n, []).extend(v)
    flags: list[str] = []
    coefficients: list[CoefficientResult] = []
    budget: list[BudgetTerm] = []
    out_unit = str(cells[0].meta.get("output_unit", "out"))
    rigs = sorted({c.rig_id for c in cells})
    rig_label = rigs[0] if len(rigs) == 1 else "+".join(rigs)
    untestable = lof.status == "untestable"
    dof = lof.dof_lof if lof.status == "inadequate" else (fit.dof if not untestable else 0)
    k = coverage_factor(dof) if lof.status == "inadequate" else 2.0
    if untestable:
        flags.append("joint fit: untestable: the runs leave no degrees of freedom to test the model "
                     "(as many parameters as distinct inputs); its coefficients carry no uncertainty")
    elif lof.status == "inadequate":
        flags.append(f"joint fit: model inadequate (lack-of-fit F = {lof.statistic:.3g}, p = {lof.p_value:.2g}, "
                     f"{lof.dof_lof}/{lof.dof_pe} dof): uncertainties scaled by sqrt(F) = {lof.factor:.3g}")
    if not fit.converged:
        flags.append(f"joint fit did not converge: {fit.message}")
    flags += [f"joint fit: {n}" for n in jf.notes]
    if missing:
        flags.append("budgets leave out rig inputs with no stated uncertainty: "
                     + "; ".join(f"{m['input']} of {m['rig']} ([rigs.\"{m['rig']}\"] {m['key']})" for m in missing)
                     + " (accelcal.toml)")
    rig_of = _dominant_rigs(jf)
    measures = model.combinations(fit.values, {prm.name: fit.std(prm.name) for prm in model.params if prm.vary})
    # each nearly aliased pair with its coefficients and the combination's factor t to two
    # digits, so that every campaign of a design names the same row
    near = [(a, b, *(model.roles[model.params.index[n]].key for n in (a, b)), float(f"{t:.2g}"), r)
            for a, b, t, r in nearly_aliased(jf)]
    pairs: list[tuple[str, str]] = [(ka, kb) for _, _, ka, kb, _, _ in near]
    near_note: dict[str, str] = {}
    for a, b, ka, kb, t, r in near:
        comb = combination_formula(ka, {kb: float(f"{t:.2g}")}, 2)
        row = (f" (its own row, {combination_name(ka, {kb: t})})"
               if si_unit(ka) == si_unit(kb) and fit.converged else "")
        for n, other in ((a, kb), (b, ka)):
            near_note[n] = "; ".join(x for x in (near_note.get(n, ""), (
                f"nearly aliased with {other} (correlation {r:+.4f}): the runs determine {comb}{row} "
                "far better than either alone")) if x)
    # instrument coefficients
    for i, prm in enumerate(model.params):
        role = model.roles[i]
        if role.kind != "coef" or not prm.vary or not fit.estimable[i]:
            continue
        name, alias = what_it_measures(measures.get(prm.name), role.key)
        pairs += [(role.key, k) for k, _ in getattr(measures.get(prm.name), "terms", ())]
        if prm.name in near_note:
            alias = "; ".join(x for x in (alias, near_note[prm.name]) if x)
        if alias:
            flags.append(f"{name}: {alias}")
        u = fit.std(prm.name)
        terms_b = tb.get(prm.name, [])
        u = float("nan") if untestable else math.sqrt(u * u + sum((c * ub) ** 2 for _, c, ub, _, _ in terms_b))
        note = "; ".join(x for x in ("joint ML fit of every reading through the forward model",
                                     NOTES.get(role.key, ""), alias) if x)
        coefficients.append(CoefficientResult(name, float(fit.values[i]), float(u), si_unit(name, out_unit),
                                              METHOD, rig_of.get(prm.name, rig_label), float(dof), note,
                                              adopted=True, coverage_factor=k,
                                              factors=getattr(measures.get(prm.name), "factors", {})))
        budget += _type_a_lines(name, float(fit.values[i]), fit.std_noise(prm.name), lof.factor)
        for q, c, ub, dist, x in terms_b:
            budget.append(BudgetTerm(name, q, x, ub, c, abs(c) * ub, "B", dist, METHOD))
    for a, b, ka, kb, t, r in near:
        # the combination the runs do determine, as a row of its own where it is a
        # coefficient of the same unit (Kip+Kpp; its u is that of the rounded combination);
        # a fit that stopped before converging is not at its optimum along the weak
        # direction, which a combination with a rounded factor would take up
        if si_unit(ka) != si_unit(kb) or not fit.converged:
            continue
        name = display_name(ka, Combination(ka, ((kb, t),)))
        c = np.zeros(len(model.params))
        c[model.params.index[a]], c[model.params.index[b]] = 1.0, t
        value = float(c @ fit.values)
        u = float(np.sqrt(max(c @ fit.cov @ c, 0.0))) if not untestable else float("nan")
        u_noise = float(np.sqrt(max(c @ fit.cov_noise @ c, 0.0)))
        coefficients.append(CoefficientResult(
            name, value, u, si_unit(ka, out_unit), METHOD, rig_of.get(a, rig_label), float(dof),
            f"joint ML fit; {ka} and {kb} are nearly aliased in this design (correlation {r:+.4f}): "
            f"the runs determine this combination, not each alone", adopted=True, coverage_factor=k,
            factors={kb: t}))
        budget += _type_a_lines(name, value, u_noise, lof.factor)
    mc_check = _mc_checks(coefficients, budget)
    # theta0 per head
    for i, prm in enumerate(model.params):
        role = model.roles[i]
        if role.key != "initial_misalignment" or not prm.vary or not fit.estimable[i]:
            continue
        runs_h = [model.runs[j] for j in prm.runs or ()]
        head = runs_h[0].geometry if runs_h else None
        heads = sum(r.key == "initial_misalignment" for r in model.roles)
        label = f"theta0[{AXES[head.head_axis]}]" if head is not None and heads > 1 else "theta0"
        u = float("nan") if untestable else fit.std(prm.name)
        label, alias = what_it_measures(measures.get(prm.name), label)
        if alias:
            flags.append(f"{label}: {alias}")
        coefficients.append(CoefficientResult(
            label, float(fit.values[i]), u, "rad", METHOD, runs_h[0].rig_id if runs_h else rig_label, float(dof),
            "; ".join(x for x in ("initial misalignment of this dividing head (never pooled across heads)", alias)
                      if x), adopted=True, coverage_factor=k, factors=getattr(measures.get(prm.name), "factors", {})))
        budget.append(BudgetTerm(label, "readings: joint fit through the forward model", float(fit.values[i]),
                                 fit.std_noise(prm.name), 1.0, fit.std_noise(prm.name), "A", "normal", METHOD))
    # geometry: radii, mass-centre offset, mount angles, tool errors
    radii, alignment = _geometry_records(jf)
    # adequacy record
    tr, rn = _residual_checks(jf)
    adequacy = [AdequacyResult(rig_label, "joint campaign fit", 0, None,
                               float(lof.statistic) if lof.statistic is not None else float("nan"),
                               float(lof.p_value) if lof.p_value is not None else float("nan"),
                               int(lof.dof_lof), int(lof.dof_pe), tr, 1.0, rn,
                               lof.status == "adequate", True,
                               f"status {lof.status}; {len(model.runs)} runs, {model.N} cells, "
                               f"{int(model.params.free().sum())} free parameters")]
    names, R = fit.correlation([model.params[i].name for i in range(len(model.params))
                                if model.params[i].vary and fit.estimable[i]])
    extras = {
        "method": METHOD,
        "effects": model.effects,
        "parameters": [{"name": prm.name, "key": prm.key, "unit": prm.unit, "group": prm.group,
                        "value": float(fit.values[i]),
                        "u": (fit.std(prm.name) if prm.vary and fit.estimable[i] else None),
                        "held": jf.reason(prm.name)} for i, prm in enumerate(model.params)],
        "correlation": {"names": names, "matrix": np.round(R, 4).tolist()},
        "lack_of_fit": {"status": lof.status, "F": lof.statistic, "p": lof.p_value, "dof_lof": lof.dof_lof,
                        "dof_pe": lof.dof_pe, "factor": lof.factor, "note": lof.note},
        "chi2": fit.chi2, "cells": model.N, "rank": fit.rank, "iterations": jf.iterations,
        "converged": fit.converged,
        "noise": {r.run_id: {"a": r.noise.a, "b": r.noise.b, "rho": r.noise.rho, "dof": r.noise.dof,
                             "source": r.noise.source} for r in model.runs},
        "notes": jf.notes,
        "aliased_pairs": [list(ab) for ab in dict.fromkeys(pairs)],
        "rig_inputs": {"stated": {rig: dict(stated[rig]) for rig in sorted({r.rig_id for r in model.runs})
                                  if rig in stated},
                       "missing": missing},
    }
    return {"mc_check": mc_check, "coefficients": coefficients, "radii": radii, "adequacy": adequacy, "budget": budget,
            "alignment": alignment, "flags": flags, "extras": extras, "fit": jf,
            "aliased_pairs": list(dict.fromkeys(pairs))}


def stored_adequacy(extras: Mapping[str, Any] | None) -> str | None:
    """The joint fit's lack-of-fit status in a stored result ('adequate', 'inadequate',
    'untestable'), or None when the result has no joint fit: what the certificate's
    method section states, read where the joint fit writes it (:func:`_records`).

    Parameters
    ----------
    extras : mapping or None
        The stored result's extras.

    Returns
    -------
    str or None
    """
    return (((extras or {}).get("joint") or {}).get("lack_of_fit") or {}).get("status")


def stored_missing_rig_inputs(extras: Mapping[str, Any] | None) -> list[dict] | None:
    """The rig inputs a stored joint fit found entering its budgets without a stated
    uncertainty (``{'input', 'rig', 'key'}`` each); [] without a joint fit, None
    for a joint fit stored before the rig inputs entered the budgets.

    Parameters
    ----------
    extras : mapping or None
        The stored result's extras.

    Returns
    -------
    list of dict or None
    """
    jx = (extras or {}).get("joint")
    if not jx:
        return []
    if "rig_inputs" not in jx:
        return None
    return list(jx["rig_inputs"].get("missing") or [])


def _mc_checks(coefficients: Sequence[CoefficientResult], budget: Sequence[BudgetTerm]) -> dict[str, dict]:
    """JCGM 101 check of each adopted coefficient's budget (:func:`.uncertainty.budget_check`:
    the linear budget's distributions propagated by exact convolution, no sampling noise)."""
    from .uncertainty import budget_check
    out = {}
    for c in coefficients:
        terms = [b for b in budget if b.coefficient == c.name and b.method == METHOD]
        chk = budget_check(METHOD, c.rig_id, c.name, c.value, terms) if math.isfinite(c.std_uncertainty) else None
        if chk is not None:
            out[f"{METHOD}:{c.rig_id}:{c.name}"] = chk
    return out


def _dominant_rigs(jf: ModelFit) -> dict[str, str]:
    """The rig whose runs carry most of the information on each parameter (the sum of the
    squared whitened Jacobian column over its rows): the rig a coefficient is calibrated on,
    for rig comparisons (K1 on the dividing head, the second-order terms on the centrifuge)."""
    model, J = jf.model, jf.fit.J
    out = {}
    rigs = sorted({r.rig_id for r in model.runs})
    for i, prm in enumerate(model.params):
        info = {rig: 0.0 for rig in rigs}
        for j, r in enumerate(model.runs):
            col = J[model.rows(j), i]
            info[r.rig_id] += float(col @ col)
        out[prm.name] = max(info, key=info.get)
    return out


def _residual_checks(jf: ModelFit) -> tuple[float, float]:
    """Trend in time and run of signs of the whitened cell residuals, per run (Bonferroni)."""
    tp, rp = [], []
    for j, r in enumerate(jf.model.runs):
        z = jf.fit.z[jf.model.rows(j)]
        t = r.attrs.get("time", np.arange(z.size, dtype=float))
        o = np.argsort(t)
        tp.append(trend_test(t[o], z[o]))
        rp.append(runs_test(z[o]))
    m = max(len(tp), 1)
    return (min(1.0, min(tp) * m) if tp else 1.0), (min(1.0, min(rp) * m) if rp else 1.0)


def _geometry_records(jf: ModelFit) -> tuple[list[RadiusResult], list[dict]]:
    """Polarity radii of the IA mounts (delta method through the model), the turning-centre
    radius, the mass-centre offset, mount-angle errors and tool errors."""
    model, fit = jf.model, jf.fit
    p = fit.values
    radii: list[RadiusResult] = []
    alignment: list[dict] = []
    for (rig, plane, phi), idx in mount_runs(model).items():
        for j in idx:
            g = model.runs[j].geometry
            pol = g.ia_polarity
            if pol is None or plane.split("-")[0] != "IA":
                continue
            rho = model.polarity_radius(p, j)
            grad = np.zeros(len(p))
            for i in model.run_params[j]:
                if not (model.params[i].vary and fit.estimable[i]) or model.roles[i].kind == "coef":
                    continue
                h = 1e-3 * model.params[i].scale
                pp, pm = p.copy(), p.copy()
                pp[i] += h
                pm[i] -= h
                grad[i] = (model.polarity_radius(pp, j) - model.polarity_radius(pm, j)) / (2 * h)
            u = float(math.sqrt(max(grad @ fit.cov @ grad, 0.0)))
            radii.append(RadiusResult(rig, "+" if pol > 0 else "-", METHOD, None, None, rho, u,
                                      note="distance of the effective mass centre from the spindle: turning-centre "
                                           "radius and mass-centre offset of the joint fit"))
    geo = {}
    for i, prm in enumerate(model.params):
        role = model.roles[i]
        if role.kind in ("radius",) or (role.kind == "effect" and role.key != "initial_misalignment"):
            geo[prm.name] = {"value": float(p[i]), "u": fit.std(prm.name) if prm.vary and fit.estimable[i] else None,
                             "unit": prm.unit, "held": jf.reason(prm.name)}
    if geo:
        alignment.append({"kind": "joint", "method": METHOD, "parameters": geo})
    return radii, alignment


def method_quantity(c: CoefficientResult, adopted: dict[str, CoefficientResult], runs) -> tuple[float, float, str]:
    """The adopted value of the quantity a paper method's coefficient estimates, its u and
    how it was formed.  A single tumble measures K0 + K_ss g^2, K_ss the square term of the
    head's other turning axis (paper 003 model with effects.md terms); everything else the
    methods report is the instrument coefficient itself."""
    a = adopted[c.name]
    if isinstance(c, TumbleCoefficient) and c.name in ("K0", "K2"):
        from ..physics.geometry import geometry_of
        tumble = next((r for r in runs if str(r.meta["test"]) == "tumble"), None)
        other = geometry_of(tumble.meta).other_axis if tumble is not None else None
        sq = {1: "Kpp", 2: "Koo"}.get(other)
        if sq in adopted:
            k = adopted[sq]
            if c.name == "K0":
                g2 = float(tumble.meta["g_local_m_s2"]) ** 2
                return (a.value + k.value * g2, math.hypot(a.std_uncertainty, k.std_uncertainty * g2),
                        f"K0 + {sq} g^2")
            if isinstance(c, TumbleCoefficient) and c.less:
                return a.value - k.value, math.hypot(a.std_uncertainty, k.std_uncertainty), f"K2 - {sq}"
    return a.value, a.std_uncertainty, c.name


def compare_with_methods(adopted: Sequence[CoefficientResult], others: Sequence[CoefficientResult],
                         runs=()) -> tuple[list[dict], list[str]]:
    """En of every paper-method value against the adopted value of the same quantity
    (:func:`method_quantity`; expanded uncertainties, k = 2); |En| > 1 is flagged."""
    rows, flags = [], []
    by = {c.name: c for c in adopted}
    for c in others:
        a = by.get(c.name)
        if a is None or c is a or not all(map(math.isfinite, (a.std_uncertainty, c.std_uncertainty))):
            continue
        av, au, what = method_quantity(c, by, runs)
        en = normalised_error(c.value, 2 * c.std_uncertainty, av, 2 * au)
        rows.append({"coefficient": c.name, "method": c.method, "value": c.value, "u": c.std_uncertainty,
                     "adopted": av, "adopted_u": au, "quantity": what, "En": en, "differ": abs(en) > 1})
        if abs(en) > 1:
            flags.append(f"{c.name}: {c.method} gives {c.value:.6g} {c.unit}, the adopted joint fit "
                         f"{av:.6g} for {what} (En = {en:+.2f}, beyond their combined expanded uncertainty)")
    return rows, flags
