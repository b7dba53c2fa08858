"""Sinusoidal-rate disc centrifuge: joint three-attitude identification (paper 002).

Paper 002 (Sun, Ren & Wang, HIT; ``shared/docs/methods.md``) drives a disc
centrifuge at ω(t) = Ω·sin(2πft) (Ω = 4π rad/s, f = 1 Hz, R = 1 m).  The
instrument then senses a centripetal input ω_z²R (≥ 0) and a tangential input
R·dω/dt that changes sign, plus gravity on the vertical axis.  Three mounting
attitudes are used:

* (a) IA to the spindle, PA tangential, OA vertical  (``mount_plane: IA-PA``)
* (b) OA to the spindle, IA tangential, PA vertical  (``mount_plane: OA-IA``)
* (c) PA to the spindle, OA tangential, IA vertical  (``mount_plane: PA-OA``)

Each attitude alone leaves some coefficient combinations aliased (e.g. in (a)
a_I ≥ 0, so K2·a_I² and Koq·a_I·|a_I| are the same regressor); together they
identify every second-order term, K3 and some rig ("tool") errors.

Paper 002 is a configuration of the one fit (all SI, effects.md names and units):

* Model: the forward model of :mod:`accelcal.physics.rigs`
  (:func:`~accelcal.physics.rigs.rig_output` with the drop format's NOMINAL effects,
  earth rate, plus the tool errors being identified) and paper 002's KPPP·a_P³ +
  KOOO·a_O³.  Coefficient columns of the Jacobian are exact
  (:func:`~accelcal.physics.instrument.output_derivative`); tool-error columns are
  central differences of the forward model (tests/test_design_columns.py).
* Parameters: the core's :class:`~accelcal.fitting.core.ParameterSet`; K1 shared (in
  attitude (c) IA only sees +g, so a per-run K1 there is inseparable from its K0) and K0
  shared by default (a repeatable bias makes K1 absolute through gravity; this is also
  what separates ``mass_centre_offset`` from ``rate_scale_error``); ``per_run_bias=True``
  frees K0 per run, and an F test compares the two.
* Fit: the core's solves (:func:`~accelcal.fitting.core.lstsq_svd` for the linear
  start and the covariance, :func:`~accelcal.fitting.core.gauss_newton` when tool errors
  are fitted), with paper 002's reweighting: one weight per run from its residual RMS
  (a second pass, weights of geometric mean one).
* Reporting: the residual-scaled covariance s²·(JᵀWJ)⁺ of paper 002's least squares;
  rank, condition number and Roy–Vetterli effective rank of the column-scaled design;
  optional parameters (tool errors, KPPP, KOOO) the joint design does not determine are
  held at zero and named (:func:`accelcal.fitting.identify.holds` with its thresholds;
  paper 002 states none of its own).  The lack of fit is tested against the pure
  error of the drive's phases (:func:`~accelcal.fitting.core.pure_error_lack_of_fit`).
* :func:`aliasing_report` analyses each attitude's columns alone;
  :func:`compare_compensation` is paper 002's identify-then-compensate comparison.

Rate source.  The logged ``table_rate_rad_s`` of the 2026-11-19 sample is the drive
Ω·sin 2πft plus white measurement noise (σ ≈ 9e-6 rad/s) that is *not* in the table's
motion: squaring it for the centripetal input puts that noise into the regressors (errors
in variables; attitude (a) residual 2.6e-5 mA instead of 1.36e-6 mA), and differentiating
it numerically amplifies it (5-point stencil: ≈ 6e-4 rad/s²).  ``rate_source`` selects
``'drive'`` (default; Ω·sin 2πft from ``rate_amplitude_rad_s`` and ``rate_frequency_hz``
with its analytic derivative), ``'fitted'`` (the logged rate fitted by a constant and
``n_harmonics`` harmonics of f, for a rig whose motion departs from the command) or
``'logged'``; ``rate_derivative`` may be forced to ``'drive'``, ``'fitted'`` or
``'numeric'`` (:func:`rate_source_comparison`).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.sparse.csgraph import connected_components

from ..effects import si_unit, typical_size
from ..fitting.core import (ALPHA, RCOND, FitResult, Parameter, ParameterSet, gauss_newton, lstsq_svd, lstsq_svd_x,
                            nested_test, pure_error_lack_of_fit)
from ..fitting.data import RunCells, fitted_drive, make_run
from ..fitting.identify import ALIAS_SHARE, ALIAS_TOL, PRIORITY, Column, Hold, holds
from ..physics import instrument, rigs
from ..results import (BudgetTerm, CoefficientResult, FitCheck, ResidualFigure, ResidualPanel, ResidualSeries,
                       display_number)
from . import uncertainty as unc
from .joint import campaign_kept
from .records import Records, jsonable
from .registry import Estimator, register

#: Method id of paper 002's records.
METHOD = "sine_ls"

TEST = "sine_centrifuge"

#: Instrument coefficients of the effects.md model fitted here (K1 multiplies everything).
COEFFS = ("K0", "K1", "Kp", "Ko", "K2", "K3", "Koq", "Kip", "Kio", "Kpo", "Kpp", "Koo")
#: Paper 002's extra third-order terms (KPPP·a_P³, KOOO·a_O³), not in the effects.md model.
EXTRA_TERMS = ("Kppp", "Kooo")
#: Tool errors visible to the design (effects.md ids) and their default scope.
DEFAULT_TOOL_ERRORS: dict[str, str] = {"spindle_tilt": "shared", "mass_centre_offset": "shared",
                                        "rate_scale_error": "shared", "sensor_lag": "shared"}
#: Parameters bounded below by 0 (effects.md: a lag time constant is not negative).
NON_NEGATIVE = ("sensor_lag",)
#: The three attitudes of paper 002.
ATTITUDES = ("a", "b", "c")


# --------------------------------------------------------------------------- inputs

def _attitude(g) -> str:
    """'a' / 'b' / 'c' of paper 002 from the axis pointing to the spindle (a run's typed mount,
    :attr:`~accelcal.physics.geometry.CentrifugeMount.radial_axis`: IA, OA, PA), else the
    mount description."""
    return {0: "a", 2: "b", 1: "c"}[g.radial_axis[0]] if g.radial_axis is not None else f"{g.plane}@{g.phi_deg:g}"


def _five_point(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Numerical derivative of the logged rate [rad/s2]: 5-point (4th-order) stencils,
    central inside and one-sided at the two first and last samples (uniform sampling)."""
    h = float(np.median(np.diff(t)))
    if w.size < 5:
        return np.gradient(w, t)
    edge = [(-25, 48, -36, 16, -3), (-3, -10, 18, -6, 1)]       # one-sided stencils [1/(12 h)]
    first = [sum(c * v for c, v in zip(e, w[:5])) for e in edge]
    last = [-sum(c * v for c, v in zip(e, w[::-1][:5])) for e in edge]
    return np.r_[first, w[:-4] - 8 * w[1:-3] + 8 * w[3:-1] - w[4:], last[::-1]] / (12 * h)


def prepare_runs(runs: Sequence, rate_source: str = "drive", rate_derivative: str | None = None,
                 n_harmonics: int = 3) -> list[RunCells]:
    """Turn runs into fit inputs (paper 002).

    Parameters
    ----------
    runs : sequence
        ``(meta, data)`` pairs or RunFile-like objects with .meta/.data (time_s [s],
        table_rate_rad_s [rad/s], table_angle_deg [deg], output [output_unit]).
    rate_source : str
        Centripetal rate: 'drive' (Omega sin(2 pi f t)), 'fitted' (harmonic fit of the
        logged rate) or 'logged' (module doc).
    rate_derivative : str, optional
        None (the source's own: the fit's analytic derivative for 'fitted', the drive's
        otherwise), 'drive', 'fitted' or 'numeric' (5-point stencil).
    n_harmonics : int
        Harmonics of f in the fitted rate.

    Returns
    -------
    list of RunCells
        One run each (:func:`accelcal.fitting.data.make_run`: drive-phase cells) whose ``cols``
        hold the rate of ``rate_source`` and whose ``rate_derivative`` is the unsigned
        d(omega)/dt of the chosen derivative [rad/s2] (None: the drive's own); ``run_id``
        defaults to ``run<i>``.
    """
    out, kept = [], campaign_kept()
    for i, r in enumerate(runs):
        meta0, data = (r.meta, r.data) if hasattr(r, "meta") else r
        k = kept.get(("sine_ls", id(data), i, n_harmonics), {})
        if k.get("data") is not data or k["meta0"] is not meta0:     # the rates of a run, once per campaign
            meta = dict(meta0)
            if str(meta.get("test", TEST)) != TEST:
                raise ValueError(f"run {meta.get('run_id', i)} is a {meta.get('test')!r} run, not {TEST}")
            meta["test"] = TEST
            meta.setdefault("run_id", f"run{i}")
            cols = {c: np.asarray(data[c], float) for c in ("time_s", "table_rate_rad_s", "table_angle_deg", "output")}
            t, w = cols["time_s"], cols["table_rate_rad_s"]
            fit_w, fit_d = fitted_drive(t, w, float(meta["rate_frequency_hz"]), n_harmonics)
            cols["table_angle_deg"] = np.nan_to_num(cols["table_angle_deg"])
            k = kept[("sine_ls", id(data), i, n_harmonics)] = {
                "data": data, "meta0": meta0, "meta": meta, "cols": cols,
                "rates": {"fitted": fit_w, "drive": rigs.sine_drive(meta, t), "logged": w},
                "wdots": {"drive": None, "fitted": fit_d, "numeric": _five_point(t, w)}}
        if rate_source not in k["rates"]:
            raise ValueError(f"rate_source {rate_source!r}")
        cols = {**k["cols"], "table_rate_rad_s": k["rates"][rate_source]}
        deriv = rate_derivative or ("fitted" if rate_source == "fitted" else "drive")
        if deriv not in k["wdots"]:
            raise ValueError(f"rate_derivative {rate_derivative!r}")
        if rate_source not in k:
            k[rate_source] = make_run(k["meta"], cols, i)
        out.append(replace(k[rate_source], cols=cols, rate_derivative=k["wdots"][deriv]))
    return out


# --------------------------------------------------------------------------- the model

def _build_params(prep: list[RunCells], per_run_bias: bool, extra_terms: Sequence[str],
                  tool_errors: Mapping[str, str], K1_scale: float) -> ParameterSet:
    """The parameters of the fit in the core's terms: ``group`` is the kind ('coef' an
    effects.md coefficient, 'extra' paper 002's KPPP/KOOO, 'tool' an effects.md rig effect),
    ``runs`` the one run a per-run parameter belongs to (None: shared by every run), the
    unit the catalogue's in the runs' output unit, the scale the catalogue's typical size
    (K1: ``K1_scale``)."""
    out_unit = str(prep[0].meta.get("output_unit", "")) or "<output_unit>"

    def scoped(key: str, kind: str, scope: str) -> list[Parameter]:
        scale, unit = K1_scale if key == "K1" else typical_size(key), si_unit(key, out_unit)
        if scope not in ("shared", "per_run"):
            raise ValueError(f"tool-error scope {scope!r} (use 'shared' or 'per_run')")
        return [Parameter(key, key, unit, scale, None, kind)] if scope == "shared" else \
            [Parameter(f"{key}[{r.meta['run_id']}]", key, unit, scale, (i,), kind) for i, r in enumerate(prep)]
    return ParameterSet([q for c in COEFFS for q in scoped(c, "coef", "per_run" if c == "K0" and per_run_bias
                                                             else "shared")]
                        + [q for e in extra_terms for q in scoped(e, "extra", "shared")]
                        + [q for e, scope in tool_errors.items() for q in scoped(e, "tool", scope)])


def _run_values(params: ParameterSet, x: np.ndarray, i: int) -> tuple[dict, dict, dict]:
    """(coefficients, extra terms, effects) of run i for the parameter vector x."""
    coeffs, extra, eff = {}, {}, dict(rigs.NOMINAL)
    for p, v in zip(params, x):
        if p.acts_on(i):
            {"coef": coeffs, "extra": extra, "tool": eff}[p.group][p.key] = float(v)
    return coeffs, extra, eff


def _kw(run: RunCells, eff: Mapping) -> dict:
    """The forward model's keywords of a run: its mount geometry, and the rate derivative of a run
    whose source is not the drive's own [rad/s2]."""
    return {"geometry": run.geometry, **({} if run.rate_derivative is None else {"rate_derivative": rigs.rotation_sign(
        run.meta) * (1.0 + float(eff.get("rate_scale_error", 0.0))) * run.rate_derivative})}


def _force(run: RunCells, eff: Mapping) -> np.ndarray:
    """Specific force of a run under the effects ``eff`` (:func:`accelcal.physics.rigs.specific_force`)
    [m/s2]; inside a campaign, at the nominal rig (every tool error zero) once per run and
    rate source, which each fit of paper 002 asks for again."""
    nominal = all(v == 0.0 for k, v in eff.items() if k not in rigs.NOMINAL)
    kept = campaign_kept() if nominal else {}
    key = ("sine_force", id(run.meta), id(run.cols["table_rate_rad_s"]), id(run.rate_derivative), *eff.items())
    if key not in kept:             # the value holds what the key's ids name
        kept[key] = (rigs.specific_force(TEST, run.meta, run.cols, eff, **_kw(run, eff)), run.meta,
                     run.cols["table_rate_rad_s"], run.rate_derivative)
    return kept[key][0]


def _extra_accel(extra: Mapping, F: np.ndarray) -> np.ndarray:
    """Paper 002's KPPP·a_P³ + KOOO·a_O³ (m/s²), added to the effects.md indicated acceleration."""
    return extra.get("Kppp", 0.0) * F[:, 1] ** 3 + extra.get("Kooo", 0.0) * F[:, 2] ** 3


def model_output(run: RunCells, coeffs: Mapping, extra: Mapping, eff: Mapping) -> np.ndarray:
    """Output of one run: the forward model.

    Parameters
    ----------
    run : prepared run (:func:`prepare_runs`)
    coeffs : mapping
        Instrument coefficients [SI].
    extra : mapping
        Paper 002's Kppp, Kooo [s4/m2].
    eff : mapping
        Effects (earth rate and tool errors, effects.md ids).

    Returns
    -------
    ndarray
        E [output_unit]: :func:`accelcal.physics.rigs.rig_output` plus K1 (Kppp a_P^3 +
        Kooo a_O^3), passed through the same sensor lag.
    """
    kw = _kw(run, eff)
    E = rigs.rig_output(TEST, run.meta, run.cols, coeffs, eff, **kw)
    if any(extra.values()):
        x = float(coeffs.get("K1", 1.0)) * _extra_accel(extra, _force(run, eff))
        E = E + instrument.first_order_lag(x, run.cols["time_s"], float(eff.get("sensor_lag", 0.0)))
    return E


def _jacobian_run(params: ParameterSet, x: np.ndarray, run: RunCells, i: int,
                  cols: Sequence[int] | None = None) -> np.ndarray:
    """d E_run / d x (n, p) of the forward model.

    Parameters
    ----------
    params, x : the parameters and their values [SI].
    run, i : the run and its index.
    cols : sequence of int, optional
        Only these columns (the others are left 0).

    Returns
    -------
    (n, p) ndarray
        [output_unit per parameter unit]: exact columns for the instrument coefficients
        (:func:`accelcal.physics.instrument.output_derivative`, lagged like the output),
        K1 times a_P^3, a_O^3 for paper 002's extra terms, and central differences of the
        forward model (:func:`model_output`) with step 1e-2 of the parameter's scale for
        tool errors (one-sided at the tau >= 0 bound of the sensor lag).
    """
    coeffs, extra, eff = _run_values(params, x, i)
    F = _force(run, eff)
    J = np.zeros((run.y_rows.size, len(params)))
    lin = []
    for j in (range(len(params)) if cols is None else cols):
        p = params[j]
        if not p.acts_on(i):
            continue
        if p.group == "coef":
            J[:, j] = instrument.output_derivative(p.key, coeffs, F) + (_extra_accel(extra, F) if p.key == "K1" else 0)
        elif p.group == "extra":
            J[:, j] = float(coeffs.get("K1", 1.0)) * _extra_accel({p.key: 1.0}, F)
        else:
            h = np.eye(len(x))[j] * (1e-2 * p.scale)
            lo = p.key == "sensor_lag" and x[j] < h[j]           # one-sided at the tau >= 0 bound
            J[:, j] = (model_output(run, *_run_values(params, x + h, i))
                       - model_output(run, *_run_values(params, x - h * (not lo), i))) / (h[j] * (1 if lo else 2))
            continue
        lin.append(j)
    tau = float(eff.get("sensor_lag", 0.0))
    if tau > 0 and lin:                   # the lag is linear: lagged columns of the lagged model
        J[:, lin] = instrument.first_order_lag(J[:, lin], run.cols["time_s"], tau)
    return J


def _residual(params: ParameterSet, prep: list[RunCells], x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted residual y - E of every run [output_unit times the run weight]."""
    return np.concatenate([w[i] * (r.y_rows - model_output(r, *_run_values(params, x, i))) for i, r in enumerate(prep)])


def _split(v: np.ndarray, prep: list[RunCells]) -> list[np.ndarray]:
    """A stacked per-reading vector (or the rows of a matrix) cut into its runs."""
    return np.split(v, np.cumsum([r.y_rows.size for r in prep])[:-1])


def _jacobian(params: ParameterSet, prep: list[RunCells], x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted design of every run [output_unit per parameter unit times the run weight]."""
    return np.vstack([w[i] * _jacobian_run(params, x, r, i) for i, r in enumerate(prep)])


#: Points whose residual and Jacobian :func:`_once` keeps per fit (the most recent): what is
#: asked again is the last point of a step (the selection's start, then the first
#: Gauss–Newton point; the last point, then the reweighting and the reporting), and a long
#: run's Jacobian at every point of a fit would grow with its readings times the iterations
ONCE_POINTS = 3


def _once(kept: dict, f, params: ParameterSet, prep: list[RunCells], x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``f(params, prep, x, w)`` (:func:`_residual`, :func:`_jacobian`) evaluated once per fit
    however often its selection, passes and reporting ask at the same parameters, x and w
    (:data:`ONCE_POINTS` of each kept)."""
    key = (f.__name__, tuple(params.names), x.tobytes(), w.tobytes())
    if key not in kept:
        kept[key] = f(params, prep, x, w)
        same = [k for k in kept if k[0] == f.__name__]
        for k in same[:-ONCE_POINTS]:
            del kept[k]
    return kept[key]


# --------------------------------------------------------------------------- diagnostics

def design_diagnostics(J: np.ndarray, names: Sequence[str]) -> dict:
    """Rank / conditioning of a design (Jacobian) after scaling every column to unit norm.

    Parameters
    ----------
    J : (n, p) ndarray
        Design [output_unit per parameter unit].
    names : sequence of str

    Returns
    -------
    dict
        n_params, rank (relative singular value above the one alias threshold
        :data:`accelcal.fitting.identify.ALIAS_TOL`, by
        :func:`accelcal.fitting.core.lstsq_svd`; an identically zero column counts as one zero
        singular value with its unit vector as a null direction), condition_number (inf when a
        relative singular value is below the core's rank rule :data:`~accelcal.fitting.core.RCOND`),
        effective_rank_roy_vetterli exp(H(sigma / sum sigma)), relative_singular_values, and
        the aliased groups (:func:`_alias_groups`).
    """
    sol = lstsq_svd(J, np.zeros(J.shape[0]), ALIAS_TOL)
    S, zero = sol.singular_values, np.flatnonzero(sol.column_norm <= 0)      # a zero column: a zero value
    rel = np.r_[S / S[0] if S.size and S[0] > 0 else S, np.zeros(zero.size)]
    null = np.vstack([sol.null_space.T.reshape(-1, J.shape[1]), np.eye(J.shape[1])[zero]])
    p = rel[rel > 0] / rel.sum()
    return {"n_params": len(names), "rank": int(sol.rank),
            "condition_number": float(rel[0] / rel[-1]) if rel[-1] > RCOND else float("inf"),
            "effective_rank_roy_vetterli": float(np.exp(-np.sum(p * np.log(p)))),
            "relative_singular_values": [float(v) for v in rel],
            **_alias_groups(null, rel[rel <= ALIAS_TOL], names)}


def _alias_groups(null: np.ndarray, rel_null: np.ndarray, names: Sequence[str]) -> dict:
    """Groups of parameters coupled through the (near-)null space of the column-scaled design.

    P = V_null V_nullᵀ is the projector onto the directions the data cannot see; it does not
    depend on the choice of null basis.  Two parameters are aliased when |P_jk| exceeds
    :data:`~accelcal.fitting.identify.ALIAS_TOL`; groups are the connected components.  Each
    null direction is also returned as a combination {name: weight} (weights of unit-norm
    scaled columns, those above :data:`~accelcal.fitting.identify.ALIAS_SHARE`)."""
    P = null.T @ null
    involved = np.flatnonzero(np.diag(P) > ALIAS_TOL)
    label = connected_components(np.abs(P[np.ix_(involved, involved)]) > ALIAS_TOL, directed=False)[1]
    return {"aliased_groups": [[names[involved[k]] for k in np.flatnonzero(label == g)]
                               for g in dict.fromkeys(label)],
            "null_combinations": [{"relative_singular_value": float(sv),
                                   "weights": {names[k]: round(float(v[k]), 4)
                                               for k in np.argsort(-np.abs(v)) if abs(v[k]) > ALIAS_SHARE}}
                                  for v, sv in zip(null, rel_null)]}


# --------------------------------------------------------------------------- the fit

@dataclass
class SineFit:
    """Result of :func:`identify_sine_campaign` (Sun, Ren & Wang, paper 002: joint
    three-attitude least squares).

    Attributes
    ----------
    result : FitResult
        The fitting core's result: values, residual-scaled covariance s^2 (J^T W J)^+, the
        weighted design and residual, and the pure-error lack-of-fit test.
    sigma : float
        Weighted pooled residual standard deviation [output_unit].
    residual_rms : dict
        Per run label: RMS residual [output_unit].
    diagnostics : dict
        Rank, condition and aliasing of the joint design (:func:`design_diagnostics`).
    dropped : dict of str to Hold
        Optional parameters held as not determined (:class:`~accelcal.fitting.identify.Hold`).
    options : dict
        The configuration of the fit.
    runs : list
        The prepared runs (:func:`prepare_runs`), in the order of the design's rows.
    """
    result: FitResult
    sigma: float
    residual_rms: dict[str, float]
    diagnostics: dict[str, Any]
    dropped: dict[str, Hold]
    options: dict[str, Any]
    runs: list[RunCells]

    @property
    def attitudes(self) -> dict[str, str]:
        """Attitude 'a' | 'b' | 'c' by run label."""
        return {str(r.meta["run_id"]): _attitude(r.geometry) for r in self.runs}

    @property
    def names(self) -> list[str]:
        """Parameter names, in the fit's order."""
        return self.result.names

    @property
    def units(self) -> dict[str, str]:
        """SI unit by parameter name."""
        return {p.name: p.unit for p in self.result.params}

    @property
    def values(self) -> dict[str, float]:
        """Estimates by name [SI, per ``units``]."""
        return {n: float(v) for n, v in zip(self.result.names, self.result.values)}

    @property
    def std(self) -> dict[str, float]:
        """Standard uncertainties by name [SI], from the residual-scaled covariance."""
        return {n: float(v) for n, v in zip(self.names, np.sqrt(np.clip(np.diag(self.result.cov), 0.0, None)))}

    @property
    def tool_errors(self) -> dict[str, float]:
        """Identified tool errors by effects.md id [SI]."""
        return {p.name: p.value for p in self.result.params if p.group == "tool"}

    @property
    def dof(self) -> int:
        """Readings minus parameters [1]."""
        return int(self.result.dof)


def _linear_start(params: ParameterSet, prep: list[RunCells], w: np.ndarray, tau: float = 0.0,
                  rss: list | None = None) -> np.ndarray:
    """Weighted LS optimum of the model with every tool error at zero (``sensor_lag`` at
    ``tau``): E is linear in (K1, K1*Kj) (one-to-one with (K1, Kj) for K1 != 0), solved by
    :func:`accelcal.fitting.core.lstsq_svd_x`.  The residual sum of squares is appended to
    ``rss`` when given."""
    x1 = np.array([1.0 if p.key == "K1" else (tau if p.key == "sensor_lag" else 0.0) for p in params])
    lin = [j for j, p in enumerate(params) if p.group != "tool"]
    J1 = np.vstack([w[i] * _jacobian_run(params, x1, r, i, lin) for i, r in enumerate(prep)])[:, lin]
    y = np.concatenate([w[i] * r.y_rows for i, r in enumerate(prep)])
    b = lstsq_svd_x(J1, y)
    if rss is not None:
        rss.append(float(np.sum((y - J1 @ b) ** 2)))
    k1 = next(j for j, p in enumerate(params) if p.key == "K1")
    K1 = float(b[lin.index(k1)]) if np.isfinite(b[lin.index(k1)]) and b[lin.index(k1)] != 0.0 else 1.0
    x = np.zeros(len(params))
    x[lin] = b / K1
    x[k1] = K1
    return x


def _lag_start(params: ParameterSet, prep: list[RunCells], x0: np.ndarray) -> np.ndarray:
    """Start of ``sensor_lag``: a sampled first-order lag shows nothing of a tau far below
    the sample period (its derivative vanishes at 0, physics.instrument.first_order_lag), so
    the start is the best of a few multiples of the period (0 included) by the residual of
    the coefficient-only fit."""
    j = next((k for k, p in enumerate(params) if p.key == "sensor_lag"), None)
    if j is None:
        return x0
    dt = float(np.median(np.concatenate([np.diff(r.cols["time_s"]) for r in prep])))
    taus = [0.0] + [k * dt for k in (0.2, 0.5, 1.0, 2.0, 5.0)]
    rss: list[float] = []
    starts = [_linear_start(params, prep, np.ones(len(prep)), tau, rss) for tau in taus]
    x = starts[int(np.argmin(rss))]
    x[j] = taus[int(np.argmin(rss))]
    return x


def _select(params: ParameterSet, prep: list[RunCells], x0: np.ndarray, kept: dict
            ) -> tuple[dict[str, Hold], ParameterSet, np.ndarray]:
    """Hold the optional parameters (tool errors, KPPP, KOOO) the joint design does not
    determine at the start x0 (:func:`accelcal.fitting.identify.holds`): (name -> hold, the
    parameters kept, their start).

    The design is whitened by the residual standard deviation of one linearised step with
    every parameter free (so that a large tool error is not taken for noise).  The
    instrument coefficients are never held: a rank deficiency among them is reported
    (:func:`design_diagnostics`).
    """
    J0 = _once(kept, _jacobian, params, prep, x0, np.ones(len(prep)))
    r0 = _once(kept, _residual, params, prep, x0, np.ones(len(prep)))
    r0 = r0 - J0 @ lstsq_svd_x(J0, r0)
    s0 = float(np.sqrt(r0 @ r0 / max(r0.size - len(params), 1)))
    rank = {k: i for i, k in enumerate(PRIORITY)}
    columns = [Column(p.name, "coef" if p.group == "coef" else "effect", p.key, p.unit,
                      rank.get(p.key, len(PRIORITY))) for p in params]
    coefs = [p.name for p in params if p.group == "coef"]
    held = {k: h for k, h in holds(J0 / (s0 if s0 > 0 else 1.0), columns, keep=coefs, scale_rule=False).items()
            if k not in coefs}
    kept = [j for j, p in enumerate(params) if p.name not in held]
    return held, params.subset(params.names[j] for j in kept), x0[kept]


def identify_sine_campaign(runs: Sequence | None, *, tool_errors: Mapping[str, str] | None = None,
                           per_run_bias: bool = False, extra_terms: Sequence[str] = (),
                           rate_source: str = "drive", rate_derivative: str | None = None,
                           n_harmonics: int = 3, reweight: bool = True,
                           prepared: list[RunCells] | None = None) -> SineFit:
    """Joint least squares over the attitudes of a sinusoidal-rate campaign (paper 002).

    .. math::

        E = K_1 (K_0 + a_I + K_2 a_I^2 + K_3 a_I^3 + K_{oq} a_I |a_I| + K_p a_P + K_o a_O
            + K_{ip} a_I a_P + K_{io} a_I a_O + K_{po} a_P a_O + K_{pp} a_P^2 + K_{oo} a_O^2)

    with (a_I, a_P, a_O) [m/s2] from :func:`accelcal.physics.rigs.specific_force` of each
    attitude (centripetal, tangential, gravity, earth rate and the tool errors fitted), E in
    output_unit (Sun, Ren & Wang, paper 002; effects.md instrument model).

    Parameters
    ----------
    runs : sequence
        ``(meta, data)`` pairs (typed metadata; time_s [s], table_rate_rad_s [rad/s],
        table_angle_deg [deg], output [output_unit]) or RunFile-like objects.
    tool_errors : mapping, optional
        effects.md id -> 'shared' | 'per_run' (spindle_tilt, mass_centre_offset,
        rate_scale_error, sensor_lag, ia_tilt, arm_stretch); ``{}`` (default) fits the nominal
        rig (earth rate only); :data:`DEFAULT_TOOL_ERRORS` is the compensated fit.
    per_run_bias : bool
        K0 per run instead of shared.
    extra_terms : sequence of str
        Subset of ('Kppp', 'Kooo') [s4/m2].
    rate_source, rate_derivative, n_harmonics
        How the rate and its derivative are formed (:func:`prepare_runs`).
    reweight : bool
        Paper 002's reweighting: one weight per run from its residual RMS (a second pass).
    prepared : list, optional
        Output of :func:`prepare_runs` (then ``runs`` and the rate options are ignored).

    Returns
    -------
    SineFit
        Values [SI], residual-scaled covariance s^2 (J^T W J)^+, design diagnostics and the
        lack-of-fit test against the pure error of the drive's phases.

    Notes
    -----
    With the tool errors at zero the model is linear in (K1, K1 Kj): the start (and the fit
    when no tool error is identified) is one linear solve; with tool errors the fit is the
    core's :func:`accelcal.fitting.core.gauss_newton` (``sensor_lag`` >= 0).

    References
    ----------
    Sun, Ren & Wang, sinusoidal-rate disc centrifuge calibration (paper 002;
    ``shared/docs/methods.md``).
    """
    tool_errors = dict(tool_errors or {})
    prep = prepared if prepared is not None else prepare_runs(runs, rate_source, rate_derivative, n_harmonics)
    params = _build_params(prep, per_run_bias, extra_terms, tool_errors, 1.0)
    ones = np.ones(len(prep))
    x0 = _linear_start(params, prep, ones)
    params = ParameterSet(replace(p, scale=abs(x0[j])) if p.key == "K1" else p for j, p in enumerate(params))
    kept: dict = {}
    dropped, params, x0 = _select(params, prep, _lag_start(params, prep, x0), kept)
    nonlinear = any(p.group == "tool" for p in params)
    w, x = ones, x0
    success, message = True, "linear least squares (no tool-error parameter)"
    rw_runs = reweight and len(prep) > 1
    for k in range(2 if rw_runs else 1):
        if nonlinear:
            gn = gauss_newton(lambda p: _once(kept, _residual, params, prep, p, w),
                              lambda p: _once(kept, _jacobian, params, prep, p, w), x,
                              max_iter=50, lower=np.array([0.0 if p.key in NON_NEGATIVE else -np.inf for p in params]))
            x, success, message = gn.p, gn.converged, gn.message
        elif k > 0 or dropped:   # no tool error: (K1, K1*Kj) reparametrise a linear model
            x = _linear_start(params, prep, w)
        if rw_runs:           # the weights of the next pass, and of the covariance after the last
            sig = np.array([np.sqrt(np.mean(e ** 2)) for e in _split(_once(kept, _residual, params, prep, x, ones), prep)])
            w = 1.0 / np.where(sig > 0, sig, 1.0)
            w = w / np.exp(np.mean(np.log(w)))      # geometric-mean-one weights
    derivative = rate_derivative or ("fitted" if rate_source == "fitted" else "drive")
    options = {"tool_errors": tool_errors, "per_run_bias": per_run_bias, "extra_terms": list(extra_terms),
               "rate_source": rate_source, "rate_derivative": derivative, "n_harmonics": n_harmonics,
               "reweight": reweight}
    return _finish(params, prep, x, w, dropped, success, message, options, kept)


def _finish(params: ParameterSet, prep: list[RunCells], x: np.ndarray, w: np.ndarray, dropped: dict[str, Hold],
            success: bool, message: str, options: dict, kept: dict) -> SineFit:
    """Paper 002's reporting of a fit at x with run weights w as the core's
    :class:`~accelcal.fitting.core.FitResult`: the residual-scaled covariance s^2 (J^T W J)^+
    (:func:`~accelcal.fitting.core.lstsq_svd`, s^2 the weighted residual variance on n - p
    dof) and the pure-error lack-of-fit test of the drive's phases."""
    Jw = _once(kept, _jacobian, params, prep, x, w)
    raw = _split(_once(kept, _residual, params, prep, x, np.ones(len(prep))), prep)
    rw = np.concatenate([wi * e for wi, e in zip(w, raw)])
    dof = rw.size - len(params)
    s2 = float(rw @ rw / dof)
    sol = lstsq_svd(Jw, np.zeros(rw.size))
    cells = np.concatenate([i + len(prep) * r.cid for i, r in enumerate(prep)])      # unique across runs
    lof = replace(pure_error_lack_of_fit(rw, cells, len(params)), factor=float(np.sqrt(s2)),
                  note="covariance scaled by the residual variance (paper 002's least squares)")
    result = FitResult(ParameterSet(replace(p, value=float(v)) for p, v in zip(params, x)), x, sol.cov,
                       sol.cov * s2, sol.estimable, float(rw @ rw), dof, rw.size, sol.rank, lof, rw, Jw,
                       bool(success), str(message))
    return SineFit(
        result=result, sigma=float(np.sqrt(s2) / np.exp(np.mean(np.log(w)))),
        residual_rms={str(r.meta["run_id"]): float(np.sqrt(np.mean(e ** 2))) for r, e in zip(prep, raw)},
        diagnostics=design_diagnostics(Jw, [p.name for p in params]), dropped=dropped,
        options=options, runs=prep)


# --------------------------------------------------------------------------- aliasing, comparisons

def aliasing_report(fit: SineFit) -> list[dict[str, Any]]:
    """Per attitude: which parameter combinations that attitude alone cannot separate.

    Computed from the design, not asserted: the rows of the fit's Jacobian that belong to
    one run, restricted to the parameters that act on that run, columns scaled to unit
    norm, SVD; directions with relative singular value at most
    :data:`~accelcal.fitting.identify.ALIAS_TOL` are the aliased (unseen)
    combinations and the groups are the connected components of the projector onto them
    (:func:`design_diagnostics`).  E.g. in attitude (a) (IA to the spindle) a_I ≥ 0, so
    a_I² ≡ a_I·|a_I| and K2 and Koq fall in one group; in (b) the tangential a_I changes
    sign and Koq separates from K2.
    """
    out = []
    for r, Jr in zip(fit.runs, _split(fit.result.J, fit.runs)):
        act = [j for j in range(Jr.shape[1]) if np.any(Jr[:, j] != 0.0)]
        names = [fit.names[j] for j in act]
        d = design_diagnostics(Jr[:, act], names)
        grouped = {n for g in d["aliased_groups"] for n in g}
        mount = f"{r.meta['mount_plane']}@{float(r.meta['mount_angle_deg']):g} {r.meta['vertical_axis']}"
        d.update({"run": str(r.meta["run_id"]), "attitude": _attitude(r.geometry), "mount": mount,
                  "parameters": names, "separable": [n for n in names if n not in grouped],
                  "not_excited": [fit.names[j] for j in range(Jr.shape[1]) if j not in act]})
        out.append(d)
    return out


def aliased_together(report: Mapping[str, Any], *names: str) -> bool:
    """Whether parameters fall in one aliased group of an attitude's report.

    Parameters
    ----------
    report : mapping
        One entry of :func:`aliasing_report`.
    *names : str

    Returns
    -------
    bool
    """
    return any(all(n in g for n in names) for g in report["aliased_groups"])


def _summary(fit: SineFit) -> dict[str, Any]:
    return {n: {"value": fit.values[n], "std": fit.std[n], "unit": fit.units[n]} for n in fit.names}


def _f_test(f_small: SineFit, f_big: SineFit) -> dict[str, Any]:
    """F test of the nested fits (the terms f_big adds), on paper 002's residual variances
    (:func:`accelcal.fitting.core.nested_test`)."""
    t = nested_test(f_small.sigma ** 2 * f_small.dof, f_big.sigma ** 2 * f_big.dof, f_small.dof - f_big.dof,
                    f_big.dof, always_scaled=True)
    return {"F": t.statistic, "df1": int(t.q), "df2": int(t.dof), "p_value": t.p_value}


def compare_compensation(runs: Sequence | None, tool_errors: Mapping[str, str] | None = None, *,
                         prepared: list[RunCells] | None = None, uncompensated: SineFit | None = None,
                         **kw) -> tuple[SineFit, SineFit, dict[str, Any]]:
    """Paper 002's identify-then-compensate comparison (Sun, Ren & Wang).

    Parameters
    ----------
    runs : sequence
        As for :func:`prepare_runs` (or ``prepared=`` prepared runs).
    tool_errors : mapping, optional
        effects.md ids to identify (default :data:`DEFAULT_TOOL_ERRORS`).
    prepared : list, optional
        Output of :func:`prepare_runs`.
    uncompensated : SineFit, optional
        Fit 1 when it is already made.
    **kw
        Passed to :func:`identify_sine_campaign`.

    Returns
    -------
    (fit1, fit2, comparison)
        Fit 1: the nominal input (earth rate only, tool errors ignored); fit 2: the tool
        errors identified jointly through the forward model (the input compensated); the
        JSON-able comparison: coefficient shifts (fit2 - fit1, also in units of fit 2's u),
        the identified tool errors and an F test of the tool-error terms.
    """
    tool_errors = dict(DEFAULT_TOOL_ERRORS if tool_errors is None else tool_errors)
    rate = {k: kw.pop(k) for k in ("rate_source", "rate_derivative", "n_harmonics") if k in kw}
    prep = prepared or prepare_runs(runs, **rate)
    f1 = uncompensated or identify_sine_campaign(None, tool_errors={}, prepared=prep, **kw)
    f2 = identify_sine_campaign(None, tool_errors=tool_errors, prepared=prep, **kw)
    coef = [n for n in f1.names if n in f2.values]
    return f1, f2, {
        "uncompensated": _summary(f1), "compensated": _summary(f2),
        "shift": {n: f2.values[n] - f1.values[n] for n in coef},
        "shift_in_sigma": {n: (f2.values[n] - f1.values[n]) / f2.std[n] if f2.std[n] > 0 else None for n in coef},
        "tool_errors": {n: v for n, v in _summary(f2).items() if n in f2.tool_errors},
        "dropped_as_unidentifiable": {k: h.reason for k, h in f2.dropped.items()},
        "residual_rms": {"uncompensated": f1.residual_rms, "compensated": f2.residual_rms},
        "f_test_tool_errors": _f_test(f1, f2)}


def rate_source_comparison(runs: Sequence, **kw) -> dict[str, Any]:
    """Which way of forming the rate and its derivative reproduces the data (module doc).

    Parameters
    ----------
    runs : sequence
        As for :func:`prepare_runs`.
    **kw
        Passed to :func:`identify_sine_campaign`.

    Returns
    -------
    dict
        'rate=<source>,derivative=<source>' -> residual RMS per run and sigma [output_unit]
        of the coefficient-only fit (five linear fits).
    """
    out = {}
    for rs, rd in (("drive", "drive"), ("fitted", "fitted"), ("logged", "drive"), ("drive", "numeric"),
                   ("logged", "numeric")):
        f = identify_sine_campaign(runs, tool_errors={}, rate_source=rs, rate_derivative=rd, reweight=False, **kw)
        out[f"rate={rs},derivative={rd}"] = {"residual_rms": f.residual_rms, "sigma": f.sigma}
    return out


def _no_values_flag(missing: Sequence[str]) -> str:
    """The flag of a campaign whose attitudes do not separate paper 002's coefficients."""
    return (f"sine_ls: no values: attitude(s) {', '.join(missing)} missing, and paper 002's "
            "least squares needs a, b and c to separate its coefficients; the joint fit "
            "says what these runs determine")


def process_sine_campaign(runs: Sequence, rig_id: str = "", *, tool_errors: Mapping[str, str] | None = None,
                          rate_source: str = "drive", rate_derivative: str | None = None,
                          compare_rate_sources: bool = True) -> tuple[list[CoefficientResult], dict[str, Any]]:
    """All of paper 002 on one sinusoidal-rate campaign (Sun, Ren & Wang).

    Parameters
    ----------
    runs : sequence
        ``(meta, data)`` pairs or RunFile-like objects (:func:`prepare_runs`).
    rig_id : str
    tool_errors : mapping, optional
        Tool errors to identify (default :data:`DEFAULT_TOOL_ERRORS`).
    rate_source, rate_derivative : str
        :func:`prepare_runs`.
    compare_rate_sources : bool
        Also run :func:`rate_source_comparison` (five linear fits, cheap).

    Returns
    -------
    (coefficients, extras)
        Coefficients of the compensated fit (tool errors identified and compensated),
        method 'sine_ls', SI units, K0 and K1 shared over the attitudes; paper 002's KPPP
        and KOOO are tried and kept only when identifiable and significant (|z| > 3); no
        coefficient when an attitude is missing.  extras (JSON-able): 'aliasing' (per
        attitude), 'tool_errors', 'compensation' (with vs without), 'residual_rms',
        'sigma', 'diagnostics' (rank, condition, effective rank), 'lack_of_fit' (pure error
        of the drive's phases), 'per_run_bias' (F test shared vs per-run K0),
        'third_order', 'attitudes', 'rate_sources', 'options', 'flags'.
        :func:`budget_terms` gives their GUM budgets.
    """
    prep = prepare_runs(runs, rate_source, rate_derivative)
    atts = sorted({_attitude(r.geometry) for r in prep})
    missing = sorted(set(ATTITUDES) - set(atts))
    flags = [f"attitudes present {atts}: paper 002 needs a, b and c for every term"] if missing else []
    # third-order terms the data support
    base = identify_sine_campaign(None, tool_errors={}, prepared=prep)
    third = identify_sine_campaign(None, tool_errors={}, extra_terms=EXTRA_TERMS, prepared=prep)
    keep = [e for e in EXTRA_TERMS if e in third.values and third.std[e] > 0
            and abs(third.values[e]) > 3 * third.std[e]]
    third_info = {"K3": {"identifiable": True, "in_model": True},
                  **{e: {"identifiable": e in third.values and e not in third.dropped,
                         "value": third.values.get(e), "std": third.std.get(e), "unit": "s4/m2",
                         "in_model": e in keep} for e in EXTRA_TERMS},
                  "f_test": _f_test(base, third),
                  "dropped": {k: h.reason for k, h in third.dropped.items()}}
    # identify-then-compensate
    f1, fit, cmp = compare_compensation(None, tool_errors, prepared=prep, extra_terms=keep,
                                        uncompensated=None if keep else base)
    if not fit.result.converged:
        flags.append(f"compensated fit did not converge: {fit.result.message}")
    per_run = identify_sine_campaign(None, tool_errors={}, per_run_bias=True, extra_terms=keep, prepared=prep)
    bias_test = _f_test(f1, per_run)          # on the nominal-input model (cheap; tool errors ~ K1/K0)
    bias_test["K0_per_run"] = {n: {"value": per_run.values[n], "std": per_run.std[n]}
                               for n in per_run.names if n.startswith("K0[")}
    if bias_test["p_value"] is not None and bias_test["p_value"] < ALPHA:
        flags.append("K0 differs between attitudes (p < 0.01): shared-bias fit questionable")
    if fit.diagnostics["rank"] < fit.diagnostics["n_params"]:
        flags.append(f"joint design rank {fit.diagnostics['rank']} < {fit.diagnostics['n_params']} parameters")
    if missing:
        # paper 002's method is the joint least squares of the three attitudes; with one of
        # them missing its coefficients alias in ways its own design does not show
        # (K2 with Koq where a_I >= 0, Kp with Ko): no value of it is reported
        flags.append(_no_values_flag(missing))
    results = [CoefficientResult(
        name=n, value=fit.values[n], std_uncertainty=fit.std[n], unit=fit.units[n], method=METHOD,
        rig_id=rig_id, dof=float(fit.dof),
        note="paper 002 joint 3-attitude LS, tool errors identified and compensated; "
             "residual-scaled covariance") for n in ([] if missing else fit.names) if n not in fit.tool_errors]
    extras = {"method": METHOD, "aliasing": aliasing_report(fit), "aliasing_coefficients_only": aliasing_report(f1),
              "tool_errors": cmp["tool_errors"], "compensation": cmp, "residual_rms": fit.residual_rms,
              "sigma": fit.sigma, "dof": fit.dof, "diagnostics": fit.diagnostics, "per_run_bias": bias_test,
              "third_order": third_info, "attitudes": fit.attitudes, "options": fit.options, "flags": flags}
    if compare_rate_sources:
        extras["rate_sources"] = rate_source_comparison(runs)
    lof = fit.result.lof
    extras["lack_of_fit"] = {"status": lof.status, "F": lof.statistic, "df1": lof.dof_lof, "df2": lof.dof_pe,
                             "p_value": lof.p_value}
    return results, jsonable(extras)



def budget_terms(coefficients: Sequence[CoefficientResult]) -> list[BudgetTerm]:
    """GUM budget lines of paper 002's coefficients: one type-A line each, the joint
    three-attitude least squares with its residual-scaled covariance s^2 (J^T W J)^+ (the tool
    errors identified and compensated, so they leave no type-B term of their own)."""
    term = "joint 3-attitude LS (paper 002), residual-scaled s^2 (J'WJ)^-1"
    return [b for c in coefficients for b in unc.linear_budget(
        c.name, [(term, c.value, c.std_uncertainty, 1.0, "A", "normal")], method=c.method, rig_id=c.rig_id,
        value=c.value).terms]


# ----------------------------------------------------------------------------- the campaign's sine step

def campaign_records(runs: Sequence, steps: Mapping[str, Any]) -> list:
    """Paper 002 on the sinusoidal-centrifuge runs of each rig of a campaign
    (:func:`process_sine_campaign`), with the budgets; a rig that fails is a flag, and so is
    a rig whose attitudes leave paper 002 without values."""
    out = []
    for rig in dict.fromkeys(str(r.meta.get("rig_id", "")) for r in runs):
        try:
            coeffs, extras = process_sine_campaign([(r.meta, r.data) for r in runs
                                                    if str(r.meta.get("rig_id", "")) == rig], rig)
        except Exception as exc:
            out.append(Records(flags=[f"sine_centrifuge {rig}: {type(exc).__name__}: {exc}"]))
            continue
        # the method's own flags stay in its extras; that it gave no values is the campaign's
        missing = sorted(set(ATTITUDES) - set(extras["attitudes"].values()))
        out.append(Records(coefficients=coeffs, budget=budget_terms(coeffs), extras={"sine": {rig: extras}},
                           flags=[f"{rig}: {_no_values_flag(missing)}"] if missing else []).checked())
    return out


def mc_truth(c, eff, test, g, notes) -> dict[tuple[str, str], tuple[float, str]]:
    """What each paper-002 coefficient estimates in a simulated test: the instrument values
    of the 12 coefficients (K0 shared by the attitudes, K1 at the run temperature)
    (signature of :data:`accelcal.estimators.registry.TruthMapping`)."""
    return {(k, str(test["rig_id"])): (c[k], "instrument value") for k in COEFFS}


def residual_figures(extras: Mapping[str, Any]) -> list[ResidualFigure]:
    """Per run, the rms residual of the sine fit relative to its pooled sigma (a run whose
    model misses shows as a bar well above 1), from what :func:`campaign_records` stored
    (``extras['sine']``; the fit stores no residual series), for the certificate.

    Parameters
    ----------
    extras : mapping
        A stored result's extras.

    Returns
    -------
    list of ResidualFigure
        One ``'bars'`` figure, or none.
    """
    bars = [(f"{rig} {run}", rms / s["sigma"]) for rig, s in (extras.get("sine") or {}).items()
            if isinstance(s, dict) and isinstance(s.get("residual_rms"), dict) and s.get("sigma")
            for run, rms in sorted(s["residual_rms"].items())]
    if not bars:
        return []
    return [ResidualFigure("bars", "Residual rms of the joint sine fit per run, relative to its pooled σ "
                           "(the fit stores no residual series).", (ResidualPanel(
                               "sine fit: residual rms per run", "",
                               (ResidualSeries("", tuple(float(k) for k in range(len(bars))),
                                               tuple(v for _, v in bars), colour="#1f5fa8"),),
                               tuple(lab for lab, _ in bars)),), y_label="rms residual / pooled σ")]


def fit_checks(extras: Mapping[str, Any]) -> list[FitCheck]:
    """The certificate's fit statistics of a stored sine result: per rig the lack-of-fit test
    of the compensated fit (passes when adequate) and the F tests of the tool-error terms,
    the third-order terms Kppp, Kooo and the per-run bias (paper 002 §3; a term passes when
    it is not needed).

    Parameters
    ----------
    extras : mapping
        The stored result's extras (``extras['sine'][rig]``).

    Returns
    -------
    list of FitCheck
    """
    f = display_number
    term = ("not needed (model adequate without)", "significant: model needs them")
    tests = [(rig, label, t, words) for rig, s in (extras.get("sine") or {}).items() for label, t, words in (
        ("lack of fit (F test against the pure error of the drive's phases)", (s or {}).get("lack_of_fit"),
         ("adequate", "the model misses the data")),
        ("tool-error terms (joint F test)", ((s or {}).get("compensation") or {}).get("f_test_tool_errors"), term),
        ("third-order terms Kppp, Kooo (F test)", ((s or {}).get("third_order") or {}).get("f_test"), term),
        ("per-run bias (F test)", (s or {}).get("per_run_bias"), term))]
    return [FitCheck("sine", rig, label, f"F = {f(t.get('F'), '.3g')}", f"{f(t.get('df1'))} / {f(t.get('df2'))}",
                     t.get("p_value"), yes=words[0], no=words[1])
            for rig, label, t, words in tests if isinstance(t, dict) and t.get("p_value") is not None]


ESTIMATOR = register(Estimator(
    method=METHOD, tests=("sine_centrifuge",),
    certificate=("paper 002 (Sun, Ren & Wang): joint least squares of the instrument "
                 "model with the rig's tool errors through the forward model, with an "
                 "aliasing analysis"),
    records=campaign_records, truth=mc_truth, adoption=2, main=("K2", "Kip"), order=3,
    figures=residual_figures, checks=fit_checks))
