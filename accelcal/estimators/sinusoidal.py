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

What this module does (all SI, effects.md names and units):

* The input is *the* forward model (:mod:`accelcal.physics.rigs`):
  :func:`~accelcal.physics.rigs.rig_output` with the drop format's NOMINAL
  effects (earth rate) plus the tool errors being identified.  Nothing of the
  rig kinematics is re-implemented here.  The coefficients enter linearly, so
  their Jacobian columns are evaluated exactly through
  :func:`~accelcal.physics.instrument.indicated_acceleration`; tool-error
  columns are central differences of the forward model.
* The fit is a joint nonlinear least squares (``scipy.optimize.least_squares``)
  over the three attitudes, with K1 shared (one instrument; in attitude (c) IA
  only sees +g, so a per-run K1 there is inseparable from its K0) and K0 shared
  by default (a repeatable bias makes K1 absolute through gravity: the
  constant of (c) minus that of (a) is K1·g; this is also what separates
  ``mass_centre_offset`` from ``rate_scale_error``).  ``per_run_bias=True``
  frees K0 per run; an F test of the two is returned.
* Covariance: s²·(JᵀJ)⁺ with s² the residual variance (residual-scaled);
  rank, condition number and Roy–Vetterli effective rank of the column-scaled
  Jacobian are reported, and optional parameters (tool errors, KPPP, KOOO)
  whose column is (numerically) inside the span of the others are dropped and
  named as unidentifiable.
* :func:`aliasing_report` analyses each attitude's columns alone (SVD of the
  column-scaled Jacobian, projector onto its near-null space) and returns the
  groups of parameters that only enter as combinations.
* :func:`compare_compensation` is paper 002's identify-then-compensate
  comparison: coefficients fitted with the nominal input versus with the tool
  errors identified and compensated.

Rate source (checked on the 2026-11-19 sample, see the report in
``rate_source_comparison``).  The logged ``table_rate_rad_s`` is the drive
Ω·sin 2πft plus white measurement noise (σ ≈ 9e-6 rad/s; amplitude equal to Ω
within 3e-8) that is *not* in the table's motion: squaring it for the
centripetal input puts that noise into the regressors (errors in variables;
attitude (a) residual 2.6e-5 mA instead of 1.36e-6 mA), and differentiating it
numerically amplifies it (5-point stencil: ≈ 6e-4 rad/s²; attitude (b)
residual ~1e-4 mA; np.gradient also carries a 0.26 % truncation bias at 50 Hz).
Even a harmonic fit of the logged rate leaves an amplitude error (~3e-8 of Ω)
that is visible at this output noise.  ``rate_source`` selects:
``'drive'`` (default; Ω·sin 2πft from ``rate_amplitude_rad_s`` and
``rate_frequency_hz`` with the physics default analytic derivative),
``'fitted'`` (the logged rate least-squares fitted by a constant and
``n_harmonics`` harmonics of f, with its analytic derivative; for a rig whose
motion departs from the command) or ``'logged'`` (raw logged rate);
``rate_derivative`` may be forced to ``'drive'``, ``'fitted'`` or ``'numeric'``.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from scipy.optimize import least_squares
from scipy.stats import f as f_dist

from ..fitting.data import fitted_drive
from ..physics import instrument, rigs
from ..results import CoefficientResult

TEST = "sine_centrifuge"

#: Instrument coefficients of the effects.md model fitted here (K1 multiplies everything).
COEFFS = ("K0", "K1", "Kp", "Ko", "K2", "K3", "Koq", "Kip", "Kio", "Kpo", "Kpp", "Koo")
#: Paper 002's extra third-order terms (KPPP·a_P³, KOOO·a_O³), not in the effects.md model.
EXTRA_TERMS = ("Kppp", "Kooo")
#: Tool errors visible to the design (effects.md ids) and their default scope.
DEFAULT_TOOL_ERRORS: dict[str, str] = {"spindle_tilt": "shared", "mass_centre_offset": "shared",
                                        "rate_scale_error": "shared", "sensor_lag": "shared"}

_UNITS = {"K0": "m/s2", "K1": "<output_unit>/(m/s2)", "Kp": "rad", "Ko": "rad", "K3": "s4/m2",
          "Kppp": "s4/m2", "Kooo": "s4/m2",
          "spindle_tilt": "rad", "mass_centre_offset": "m", "rate_scale_error": "1",
          "sensor_lag": "s", "ia_tilt": "rad", "arm_stretch": "s2"}
#: Typical magnitudes (parameter scaling of the solver, finite-difference steps).
_SCALE = {"K0": 1e-3, "Kp": 1e-4, "Ko": 1e-4, "K3": 1e-9, "Kppp": 1e-9, "Kooo": 1e-9,
          "spindle_tilt": 1e-4, "mass_centre_offset": 1e-3, "rate_scale_error": 1e-4,
          "sensor_lag": 1e-4, "ia_tilt": 1e-4, "arm_stretch": 1e-6}
_SECOND = 1e-7

#: Relative singular value below which a direction of the column-scaled design is aliased.
ALIAS_RTOL = 1e-4


def _unit(name: str, output_unit: str = "") -> str:
    u = _UNITS.get(name, "s2/m")
    return u.replace("<output_unit>", output_unit) if output_unit else u


def _scale(name: str) -> float:
    return _SCALE.get(name, _SECOND)


# --------------------------------------------------------------------------- inputs

@dataclass
class _Run:
    meta: dict
    data: pd.DataFrame          # columns as the forward model reads them (rate per rate_source)
    y: np.ndarray               # output, output_unit
    t: np.ndarray
    wdot: np.ndarray | None     # unsigned d(omega)/dt of the chosen source; None = physics default
    label: str
    attitude: str


def _attitude(meta: Mapping) -> str:
    """'a' / 'b' / 'c' of paper 002 from the axis pointing to the spindle (mount_angle 0/180),
    else the mount description."""
    e1, e2 = rigs.parse_plane(meta["mount_plane"])
    phi = float(meta["mount_angle_deg"]) % 360.0
    radial = {0.0: e1, 180.0: e1, 90.0: e2, 270.0: e2}.get(phi)
    return {0: "a", 2: "b", 1: "c"}.get(radial, f"{meta['mount_plane']}@{phi:g}") if radial is not None \
        else f"{meta['mount_plane']}@{phi:g}"


def _five_point(t: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Numerical derivative of the logged rate: 5-point (4th-order) stencils, central inside
    and one-sided at the two first and last samples (uniform sampling assumed)."""
    w = np.asarray(w, float)
    h = float(np.median(np.diff(t)))
    if w.size < 5:
        return np.gradient(w, t)
    d = np.empty_like(w)
    d[2:-2] = (w[:-4] - 8 * w[1:-3] + 8 * w[3:-1] - w[4:]) / (12 * h)
    a, b = w[:5], w[-5:][::-1]
    d[0] = (-25 * a[0] + 48 * a[1] - 36 * a[2] + 16 * a[3] - 3 * a[4]) / (12 * h)
    d[1] = (-3 * a[0] - 10 * a[1] + 18 * a[2] - 6 * a[3] + a[4]) / (12 * h)
    d[-1] = -(-25 * b[0] + 48 * b[1] - 36 * b[2] + 16 * b[3] - 3 * b[4]) / (12 * h)
    d[-2] = -(-3 * b[0] - 10 * b[1] + 18 * b[2] - 6 * b[3] + b[4]) / (12 * h)
    return d


def prepare_runs(runs: Sequence, rate_source: str = "drive", rate_derivative: str | None = None,
                 n_harmonics: int = 3) -> list[_Run]:
    """Turn ``(meta, data)`` pairs (or RunFile-like objects with .meta/.data) into fit inputs.

    rate_source: 'fitted' | 'drive' | 'logged' (centripetal rate, see module doc).
    rate_derivative: None (the source's own: analytic derivative of the fit, or the drive's
    analytic derivative for 'drive'/'logged'), 'drive', 'fitted' or 'numeric'.
    """
    out = []
    for i, r in enumerate(runs):
        meta, data = (r.meta, r.data) if hasattr(r, "meta") else r
        meta = dict(meta)
        if str(meta.get("test", TEST)) != TEST:
            raise ValueError(f"run {meta.get('run_id', i)} is a {meta.get('test')!r} run, not {TEST}")
        meta["test"] = TEST
        d = pd.DataFrame({k: np.asarray(data[k], float) for k in ("time_s", "table_rate_rad_s",
                                                                  "table_angle_deg", "output")})
        t = d["time_s"].to_numpy()
        w = d["table_rate_rad_s"].to_numpy()
        Om, f = float(meta["rate_amplitude_rad_s"]), float(meta["rate_frequency_hz"])
        fit_w, fit_d = fitted_drive(t, w, f, n_harmonics)
        if rate_source == "fitted":
            d["table_rate_rad_s"] = fit_w
        elif rate_source == "drive":
            d["table_rate_rad_s"] = Om * np.sin(2 * np.pi * f * t)
        elif rate_source != "logged":
            raise ValueError(f"rate_source {rate_source!r}")
        deriv = rate_derivative or ("fitted" if rate_source == "fitted" else "drive")
        wdot = {"drive": None, "fitted": fit_d, "numeric": None}[deriv] if deriv in ("drive", "fitted", "numeric") \
            else None
        if deriv == "numeric":
            wdot = _five_point(t, w)
        elif deriv not in ("drive", "fitted"):
            raise ValueError(f"rate_derivative {rate_derivative!r}")
        d["table_angle_deg"] = np.nan_to_num(d["table_angle_deg"].to_numpy())
        out.append(_Run(meta=meta, data=d, y=d["output"].to_numpy(), t=t, wdot=wdot,
                        label=str(meta.get("run_id", f"run{i}")), attitude=_attitude(meta)))
    return out


# --------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class Param:
    name: str                 # display name, e.g. 'K2', 'K0[DC1-...-0001]', 'ia_tilt[...]'
    key: str                  # coefficient name or effect id
    kind: str                 # 'coef' | 'extra' | 'tool'
    run: int | None           # None = shared by every run
    scale: float


def _build_params(prep: list[_Run], per_run_bias: bool, extra_terms: Sequence[str],
                  tool_errors: Mapping[str, str], K1_scale: float) -> list[Param]:
    ps = []
    for c in COEFFS:
        if c == "K0" and per_run_bias:
            ps += [Param(f"K0[{r.label}]", "K0", "coef", i, _scale("K0"))
                   for i, r in enumerate(prep)]
        else:
            ps.append(Param(c, c, "coef", None, K1_scale if c == "K1" else _scale(c)))
    ps += [Param(e, e, "extra", None, _scale(e)) for e in extra_terms]
    for eid, scope in tool_errors.items():
        if scope == "shared":
            ps.append(Param(eid, eid, "tool", None, _scale(eid)))
        elif scope == "per_run":
            ps += [Param(f"{eid}[{r.label}]", eid, "tool", i, _scale(eid)) for i, r in enumerate(prep)]
        else:
            raise ValueError(f"tool-error scope {scope!r} (use 'shared' or 'per_run')")
    return ps


def _run_values(params: list[Param], x: np.ndarray, i: int) -> tuple[dict, dict, dict]:
    """(coefficients, extra terms, effects) of run i for the parameter vector x."""
    coeffs, extra, eff = {}, {}, dict(rigs.NOMINAL)
    for p, v in zip(params, x):
        if p.run is not None and p.run != i:
            continue
        {"coef": coeffs, "extra": extra, "tool": eff}[p.kind][p.key] = float(v)
    return coeffs, extra, eff


def _kw(run: _Run, eff: Mapping) -> dict:
    if run.wdot is None:
        return {}
    eps = float(eff.get("rate_scale_error", 0.0))
    return {"rate_derivative": rigs.rotation_sign(run.meta) * (1.0 + eps) * run.wdot}


def _extra_accel(extra: Mapping, F: np.ndarray) -> np.ndarray:
    """Paper 002's KPPP·a_P³ + KOOO·a_O³ (m/s²), added to the effects.md indicated acceleration."""
    return extra.get("Kppp", 0.0) * F[:, 1] ** 3 + extra.get("Kooo", 0.0) * F[:, 2] ** 3


def model_output(run: _Run, coeffs: Mapping, extra: Mapping, eff: Mapping) -> np.ndarray:
    """E (output_unit) of one run: accelcal.physics.rigs.rig_output (+ the optional
    third-order extension terms, passed through the same sensor lag)."""
    kw = _kw(run, eff)
    E = rigs.rig_output(TEST, run.meta, run.data, coeffs, eff, **kw)
    if any(extra.values()):
        F = rigs.specific_force(TEST, run.meta, run.data, eff, **kw)
        x = float(coeffs.get("K1", 1.0)) * _extra_accel(extra, F)
        E = E + instrument.first_order_lag(x, run.t, float(eff.get("sensor_lag", 0.0)))
    return E


def _jacobian_run(params: list[Param], x: np.ndarray, run: _Run, i: int) -> np.ndarray:
    """d E_run / d x (n, p): exact columns for the (linear) coefficients through the
    instrument model, central differences of the forward model for tool errors."""
    coeffs, extra, eff = _run_values(params, x, i)
    kw = _kw(run, eff)
    F = rigs.specific_force(TEST, run.meta, run.data, eff, **kw)
    tau = float(eff.get("sensor_lag", 0.0))
    K1 = float(coeffs.get("K1", 1.0))
    base = instrument.indicated_acceleration({}, F)
    J = np.zeros((run.y.size, len(params)))
    lin = []
    for j, p in enumerate(params):
        if p.run is not None and p.run != i:
            continue
        if p.kind == "coef":
            lin.append(j)
            if p.key == "K1":
                J[:, j] = instrument.indicated_acceleration(coeffs, F) + _extra_accel(extra, F)
            else:
                J[:, j] = K1 * (instrument.indicated_acceleration({p.key: 1.0}, F) - base)
        elif p.kind == "extra":
            lin.append(j)
            J[:, j] = K1 * _extra_accel({p.key: 1.0}, F)
        else:
            h = 1e-2 * p.scale
            xp, xm = x.copy(), x.copy()
            if p.key == "sensor_lag" and x[j] < h:      # one-sided at the tau >= 0 bound
                xp[j] = x[j] + h
                xm[j] = x[j]
                den = h
            else:
                xp[j] += h
                xm[j] -= h
                den = 2 * h
            Ep = model_output(run, *_run_values(params, xp, i))
            Em = model_output(run, *_run_values(params, xm, i))
            J[:, j] = (Ep - Em) / den
    if tau > 0:                # the lag is linear: lagged columns are the columns of the lagged model
        for j in lin:
            J[:, j] = instrument.first_order_lag(J[:, j], run.t, tau)
    return J


# --------------------------------------------------------------------------- diagnostics

def _colscale(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.linalg.norm(J, axis=0)
    s = np.where(s > 0, s, 1.0)
    return J / s, s


def _svd(Js: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values (descending) and right singular vectors (rows) of a tall matrix with
    unit-norm columns, from the eigen-decomposition of its small Gram matrix (p x p).
    Accurate to ~1e-8 relative singular value, far below ALIAS_RTOL; avoids LAPACK on the
    tall matrix (slow under threaded BLAS contention)."""
    w, V = np.linalg.eigh(Js.T @ Js)
    order = np.argsort(w)[::-1]
    return np.sqrt(np.clip(w[order], 0.0, None)), V[:, order].T


def _lstsq(A: np.ndarray, b: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Minimum-norm least-squares solution through the Gram eigen-decomposition (column-scaled)."""
    As, c = _colscale(A)
    s, Vt = _svd(As)
    keep = s > rtol * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
    z = Vt[keep].T @ ((Vt[keep] @ (As.T @ b)) / s[keep] ** 2)
    return z / c


def design_diagnostics(J: np.ndarray, names: Sequence[str], rtol: float = ALIAS_RTOL) -> dict:
    """Rank / conditioning of a design (Jacobian) after scaling every column to unit norm:
    singular values (relative), condition number, numerical rank at ``rtol``, Roy–Vetterli
    effective rank exp(H(σ/Σσ)), and the aliased groups (see :func:`_alias_groups`)."""
    Js, _ = _colscale(J)
    s, Vt = _svd(Js)
    rel = s / s[0] if s.size and s[0] > 0 else s
    p = s / s.sum() if s.sum() > 0 else s
    p = p[p > 0]
    return {"n_params": len(names), "rank": int(np.sum(rel > rtol)),
            "condition_number": float(rel[0] / rel[-1]) if rel[-1] > 0 else float("inf"),
            "effective_rank_roy_vetterli": float(np.exp(-np.sum(p * np.log(p)))),
            "relative_singular_values": [float(v) for v in rel],
            **_alias_groups(Vt, rel, names, rtol)}


def _alias_groups(Vt: np.ndarray, rel: np.ndarray, names: Sequence[str], rtol: float) -> dict:
    """Groups of parameters coupled through the (near-)null space of the column-scaled design.

    P = V_null V_nullᵀ is the projector onto the directions the data cannot see; it does not
    depend on the choice of null basis.  Two parameters are aliased when |P_jk| is not
    negligible; groups are the connected components.  Each null direction is also returned as
    a combination {name: weight} (weights of unit-norm scaled columns)."""
    null = Vt[rel <= rtol]
    names = list(names)
    out: dict[str, Any] = {"aliased_groups": [], "null_combinations": []}
    if null.shape[0] == 0:
        return out
    P = null.T @ null
    involved = np.diag(P) > 1e-3
    adj = (np.abs(P) > 1e-3) & involved[:, None] & involved[None, :]
    seen = set()
    for j in range(len(names)):
        if not involved[j] or j in seen:
            continue
        stack, comp = [j], []
        while stack:
            k = stack.pop()
            if k in seen:
                continue
            seen.add(k)
            comp.append(k)
            stack += [m for m in np.nonzero(adj[k])[0] if m not in seen]
        out["aliased_groups"].append(sorted((names[k] for k in comp), key=names.index))
    for v, sv in zip(null, rel[rel <= rtol]):
        out["null_combinations"].append({"relative_singular_value": float(sv),
                                         "weights": {names[k]: round(float(v[k]), 4)
                                                     for k in np.argsort(-np.abs(v)) if abs(v[k]) > 0.05}})
    return out


def _collinearity(Js: np.ndarray, j: int) -> float:
    """Norm of column j (unit norm) left after projecting it onto the other columns
    (1/sqrt(VIF)); ~0 means the parameter is aliased with the others."""
    others = np.delete(Js, j, axis=1)
    b = _lstsq(others, Js[:, j])
    return float(np.linalg.norm(Js[:, j] - others @ b))


# --------------------------------------------------------------------------- the fit

@dataclass
class SineFit:
    """Result of :func:`identify_sine_campaign` (paper 002, joint three-attitude LS).

    values/std in SI (units per :attr:`units`); cov is residual-scaled s²(JᵀJ)⁺.
    """
    names: list[str]
    values: dict[str, float]
    std: dict[str, float]
    cov: np.ndarray
    units: dict[str, str]
    sigma: float                          # residual standard deviation (output_unit), weighted pooled
    dof: int
    n_obs: int
    residual_rms: dict[str, float]        # per run label, output_unit
    run_sigma: dict[str, float]           # per-run noise used as weight
    diagnostics: dict[str, Any]           # rank / condition / aliasing of the joint design
    dropped: dict[str, str]               # optional parameters dropped as unidentifiable -> why
    tool_errors: dict[str, float]
    options: dict[str, Any]
    attitudes: dict[str, str]             # run label -> 'a' | 'b' | 'c'
    success: bool = True
    message: str = ""
    correlation: np.ndarray | None = None
    rows: dict[str, tuple[int, int]] = field(default_factory=dict)   # run label -> rows of the Jacobian
    mounts: dict[str, str] = field(default_factory=dict)             # run label -> 'IA-PA@0 +OA'
    _jac: np.ndarray | None = field(default=None, repr=False)

    def value(self, name: str) -> float:
        return self.values[name]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        return {"values": self.values, "std": self.std, "units": self.units, "sigma": self.sigma,
                "dof": self.dof, "n_obs": self.n_obs, "residual_rms": self.residual_rms,
                "run_sigma": self.run_sigma, "diagnostics": self.diagnostics, "dropped": self.dropped,
                "tool_errors": self.tool_errors, "options": self.options, "attitudes": self.attitudes,
                "success": self.success, "message": self.message}


class _Solved:
    success = True
    message = "linear least squares (no tool-error parameter)"


def _linear_start(params: list[Param], prep: list[_Run], w: np.ndarray, tau: float = 0.0,
                  rss: list | None = None) -> np.ndarray:
    """Weighted LS optimum of the model with every tool error at zero (``sensor_lag`` at
    ``tau``): E is linear in (K1, K1*Kj) (one-to-one with (K1, Kj) for K1 != 0).  The
    residual sum of squares is appended to ``rss`` when given."""
    x1 = np.array([1.0 if p.key == "K1" else (tau if p.key == "sensor_lag" else 0.0) for p in params])
    lin = [j for j, p in enumerate(params) if p.kind != "tool"]
    J1 = np.vstack([w[i] * _jacobian_run(params, x1, r, i) for i, r in enumerate(prep)])[:, lin]
    y = np.concatenate([w[i] * r.y for i, r in enumerate(prep)])
    b = _lstsq(J1, y)
    if rss is not None:
        rss.append(float(np.sum((y - J1 @ b) ** 2)))
    K1 = float(b[[params[j].key for j in lin].index("K1")])
    if not np.isfinite(K1) or K1 == 0.0:
        K1 = 1.0
    x = np.zeros(len(params))
    for k, j in enumerate(lin):
        x[j] = K1 if params[j].key == "K1" else b[k] / K1
    return x


def _lag_start(params: list[Param], prep: list[_Run], x0: np.ndarray) -> np.ndarray:
    """Start of ``sensor_lag``: a sampled first-order lag shows nothing of a tau far below
    the sample period (its derivative vanishes at 0, physics.instrument.first_order_lag), so
    the start is the best of a few multiples of the period (0 included) by the residual of
    the coefficient-only fit."""
    j = next((k for k, p in enumerate(params) if p.key == "sensor_lag"), None)
    if j is None:
        return x0
    dt = float(np.median(np.concatenate([np.diff(r.t) for r in prep])))
    taus = [0.0] + [k * dt for k in (0.2, 0.5, 1.0, 2.0, 5.0)]
    rss: list[float] = []
    starts = [_linear_start(params, prep, np.ones(len(prep)), tau, rss) for tau in taus]
    best = int(np.argmin(rss))
    x = starts[best]
    x[j] = taus[best]
    return x


def identify_sine_campaign(runs: Sequence, *, tool_errors: Mapping[str, str] | None = None,
                           per_run_bias: bool = False, extra_terms: Sequence[str] = (),
                           rate_source: str = "drive", rate_derivative: str | None = None,
                           n_harmonics: int = 3, reweight: bool = True,
                           alias_rtol: float = ALIAS_RTOL, prepared: list[_Run] | None = None,
                           _prepared: list[_Run] | None = None) -> SineFit:
    """Joint least squares over the attitudes of a sinusoidal-rate campaign (paper 002).

    runs: list of ``(meta, data)`` (typed metadata mapping; DataFrame/mapping with
    time_s, table_rate_rad_s, table_angle_deg, output) or RunFile-like objects.
    tool_errors: effect id -> 'shared' | 'per_run' (effects.md ids: spindle_tilt,
    mass_centre_offset, rate_scale_error, sensor_lag, ia_tilt, arm_stretch); ``{}`` fits the
    nominal rig (earth rate only).  Default: none (use :data:`DEFAULT_TOOL_ERRORS` for the
    compensated fit).  Optional parameters whose design column lies (to ``alias_rtol``) in
    the span of the others are dropped and listed in ``SineFit.dropped``.
    per_run_bias: K0 per run instead of shared.  prepared: output of :func:`prepare_runs`
    (then ``runs`` and the rate options are ignored).  extra_terms: subset of ('Kppp', 'Kooo').
    Model (effects.md): E = K1·(K0 + a_i + K2 a_i² + K3 a_i³ + Koq a_i|a_i| + Kp a_p + Ko a_o
    + Kip a_i a_p + Kio a_i a_o + Kpo a_p a_o + Kpp a_p² + Koo a_o²), a in m/s², E in output_unit.
    """
    tool_errors = dict(tool_errors or {})
    prep = prepared if prepared is not None else _prepared
    if prep is None:
        prep = prepare_runs(runs, rate_source, rate_derivative, n_harmonics)
    params = _build_params(prep, per_run_bias, extra_terms, tool_errors, 1.0)

    # 0) starting point: with the tool errors at zero the model is linear in (K1, K1*Kj),
    #    so the coefficient-only optimum is one linear solve (exact start for the solver)
    x0 = _linear_start(params, prep, np.ones(len(prep)))
    K1_0 = float(x0[[p.key for p in params].index("K1")])
    params = [Param(p.name, p.key, p.kind, p.run, abs(K1_0)) if p.key == "K1" else p for p in params]
    x0 = _lag_start(params, prep, x0)

    # 1) identifiability of the optional parameters at the starting point (design only)
    J0 = np.vstack([_jacobian_run(params, x0, r, i) for i, r in enumerate(prep)])
    dropped: dict[str, str] = {}
    while True:
        Js, _ = _colscale(J0)
        s, _ = _svd(Js)
        if s[-1] / s[0] > alias_rtol:
            break
        cand = [(j, _collinearity(Js, j)) for j, p in enumerate(params) if p.kind != "coef"]
        cand = [c for c in cand if c[1] < alias_rtol ** 0.5]
        if not cand:
            break                                     # a core coefficient is aliased: report it
        j, c = min(cand, key=lambda z: z[1])
        dropped[params[j].name] = f"aliased in the joint design (column residual {c:.2e} after projection)"
        params.pop(j)
        x0 = np.delete(x0, j)
        J0 = np.delete(J0, j, axis=1)
    # weakly determined optional parameters: standard uncertainty (design + noise of the
    # coefficient-only fit) larger than the parameter's typical magnitude
    # (noise from one linearised step with every parameter free, so that a large tool error
    # is not taken for noise)
    r0 = np.concatenate([r.y - model_output(r, *_run_values(params, x0, i)) for i, r in enumerate(prep)])
    Js, cs = _colscale(J0)
    r0 = r0 - Js @ _lstsq(Js, r0)
    s2_0 = float(r0 @ r0 / max(r0.size - len(params), 1))
    while True:
        Js, cs = _colscale(J0)
        sv, V = _svd(Js)
        kk = sv > 1e-9 * sv[0]
        sd0 = np.sqrt(s2_0 * np.sum((V[kk].T / sv[kk]) ** 2, axis=1)) / cs
        ratio = [(sd0[j] / p.scale, j) for j, p in enumerate(params) if p.kind != "coef"]
        if not ratio or max(ratio)[0] <= 1.0:
            break
        q, j = max(ratio)
        dropped[params[j].name] = (f"weakly determined: u = {sd0[j]:.2e} exceeds its typical size "
                                   f"{params[j].scale:.0e} {_unit(params[j].key)}")
        params.pop(j)
        x0 = np.delete(x0, j)
        J0 = np.delete(J0, j, axis=1)

    scales = np.array([p.scale for p in params])
    w_run = np.ones(len(prep))
    lo = np.array([0.0 if p.key == "sensor_lag" else -np.inf for p in params]) / scales
    hi = np.full(len(params), np.inf)

    def resid(z, w):
        x = z * scales
        return np.concatenate([w[i] * (r.y - model_output(r, *_run_values(params, x, i)))
                               for i, r in enumerate(prep)])

    def jac(z, w):
        x = z * scales
        return -np.vstack([w[i] * _jacobian_run(params, x, r, i) for i, r in enumerate(prep)]) * scales

    z = x0 / scales
    sol = None
    for _ in range(2 if reweight else 1):
        if any(p.kind == "tool" for p in params):
            sol = least_squares(resid, z, jac=jac, args=(w_run,), bounds=(lo, hi), method="trf",
                                x_scale=1.0, xtol=1e-10, ftol=1e-12, gtol=1e-10, max_nfev=50)
            z = sol.x
        else:   # no tool error: (K1, K1*Kj) reparametrise a linear model -> exact linear solve
            z = _linear_start(params, prep, w_run) / scales
            sol = _Solved()
        raw = resid(z, np.ones(len(prep)))
        n_i = np.array([r.y.size for r in prep])
        splits = np.split(raw, np.cumsum(n_i)[:-1])
        sig = np.array([np.sqrt(np.mean(s_ ** 2)) for s_ in splits])
        if not reweight or len(prep) == 1:
            break
        w_run = 1.0 / np.where(sig > 0, sig, 1.0)
        w_run = w_run / np.exp(np.mean(np.log(w_run)))   # geometric-mean-one weights
    x = z * scales
    Jw = jac(z, w_run) / scales                         # weighted Jacobian in SI units (sign irrelevant)
    rw = resid(z, w_run)
    n_obs, p_n = rw.size, len(params)
    dof = n_obs - p_n
    s2 = float(rw @ rw / dof)
    Js, cs = _colscale(Jw)
    s, Vt = _svd(Js)
    keep = s / s[0] > 1e-9
    cov_s = (Vt[keep].T / s[keep] ** 2) @ Vt[keep]
    cov = s2 * cov_s / np.outer(cs, cs)
    sd = np.sqrt(np.diag(cov))
    names = [p.name for p in params]
    out_unit = str(prep[0].meta.get("output_unit", ""))
    diag = design_diagnostics(Jw, names, alias_rtol)
    raw = resid(z, np.ones(len(prep)))
    splits = np.split(raw, np.cumsum([r.y.size for r in prep])[:-1])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(sd, sd)
    return SineFit(
        names=names, values={n: float(v) for n, v in zip(names, x)},
        std={n: float(v) for n, v in zip(names, sd)}, cov=cov,
        units={p.name: _unit(p.key, out_unit) for p in params},
        sigma=float(np.sqrt(s2) / np.exp(np.mean(np.log(w_run)))), dof=int(dof), n_obs=int(n_obs),
        residual_rms={r.label: float(np.sqrt(np.mean(e ** 2))) for r, e in zip(prep, splits)},
        run_sigma={r.label: float(1.0 / w) * float(np.sqrt(s2)) for r, w in zip(prep, w_run)},
        diagnostics=diag, dropped=dropped,
        tool_errors={p.name: float(v) for p, v in zip(params, x) if p.kind == "tool"},
        options={"tool_errors": tool_errors, "per_run_bias": per_run_bias, "extra_terms": list(extra_terms),
                 "rate_source": rate_source, "rate_derivative": rate_derivative or
                 ("fitted" if rate_source == "fitted" else "drive"), "n_harmonics": n_harmonics,
                 "reweight": reweight, "alias_rtol": alias_rtol},
        attitudes={r.label: r.attitude for r in prep}, success=bool(sol.success), message=str(sol.message),
        correlation=corr, _jac=Jw,
        rows={r.label: (int(a), int(a + r.y.size)) for r, a in
              zip(prep, np.concatenate([[0], np.cumsum([q.y.size for q in prep])[:-1]]))},
        mounts={r.label: f"{r.meta['mount_plane']}@{float(r.meta['mount_angle_deg']):g} {r.meta['vertical_axis']}"
                for r in prep})


# --------------------------------------------------------------------------- aliasing, comparisons

def aliasing_report(fit: SineFit, rtol: float = ALIAS_RTOL) -> list[dict[str, Any]]:
    """Per attitude: which parameter combinations that attitude alone cannot separate.

    Computed from the design, not asserted: the rows of the fit's Jacobian that belong to
    one run, restricted to the parameters that act on that run, columns scaled to unit
    norm, SVD; directions with relative singular value ≤ rtol are the aliased (unseen)
    combinations and the groups are the connected components of the projector onto them
    (:func:`design_diagnostics`).  E.g. in attitude (a) (IA to the spindle) a_I ≥ 0, so
    a_I² ≡ a_I·|a_I| and K2 and Koq fall in one group; in (b) the tangential a_I changes
    sign and Koq separates from K2.
    """
    J = fit._jac
    out = []
    for label, (a, b) in fit.rows.items():
        Jr = J[a:b]
        act = [j for j in range(Jr.shape[1]) if np.any(Jr[:, j] != 0.0)]
        names = [fit.names[j] for j in act]
        d = design_diagnostics(Jr[:, act], names, rtol)
        grouped = {n for g in d["aliased_groups"] for n in g}
        d.update({"run": label, "attitude": fit.attitudes[label], "mount": fit.mounts.get(label, ""),
                  "parameters": names, "separable": [n for n in names if n not in grouped],
                  "not_excited": [fit.names[j] for j in range(Jr.shape[1]) if j not in act]})
        out.append(d)
    return out


def aliased_together(report: Mapping[str, Any], *names: str) -> bool:
    """True when all ``names`` fall in one aliased group of an attitude's report."""
    return any(all(n in g for n in names) for g in report["aliased_groups"])


def _summary(fit: SineFit) -> dict[str, Any]:
    return {n: {"value": fit.values[n], "std": fit.std[n], "unit": fit.units[n]} for n in fit.names}


def compare_compensation(runs: Sequence, tool_errors: Mapping[str, str] | None = None,
                         **kw) -> tuple[SineFit, SineFit, dict[str, Any]]:
    """Paper 002's identify-then-compensate comparison.

    Fit 1: coefficients with the nominal input (earth rate only; tool errors ignored).
    Fit 2: the same coefficients with the tool errors (effects.md ids, default
    :data:`DEFAULT_TOOL_ERRORS`) identified jointly through the forward model, i.e. the
    input compensated for them.  Returns (fit1, fit2, JSON-able comparison) with the
    coefficient shifts (fit2 − fit1, also in units of fit 2's standard uncertainty), the
    identified tool errors and an F test of the tool-error terms.
    """
    tool_errors = dict(DEFAULT_TOOL_ERRORS if tool_errors is None else tool_errors)
    prep = kw.pop("_prepared", None) or prepare_runs(runs, kw.get("rate_source", "drive"),
                                                     kw.get("rate_derivative"), kw.get("n_harmonics", 3))
    kw = {k: v for k, v in kw.items() if k not in ("rate_source", "rate_derivative", "n_harmonics")}
    f1 = identify_sine_campaign(None, tool_errors={}, _prepared=prep, **kw)
    f2 = identify_sine_campaign(None, tool_errors=tool_errors, _prepared=prep, **kw)
    coef = [n for n in f1.names if n in f2.values]
    rss1 = f1.sigma ** 2 * f1.dof
    rss2 = f2.sigma ** 2 * f2.dof
    q = len(f2.names) - len(f1.names)
    F = ((rss1 - rss2) / q) / (rss2 / f2.dof) if q > 0 and rss2 > 0 else float("nan")
    cmp = {
        "uncompensated": _summary(f1),
        "compensated": _summary(f2),
        "shift": {n: f2.values[n] - f1.values[n] for n in coef},
        "shift_in_sigma": {n: (f2.values[n] - f1.values[n]) / f2.std[n] if f2.std[n] > 0 else None for n in coef},
        "tool_errors": {n: {"value": f2.values[n], "std": f2.std[n], "unit": f2.units[n]} for n in f2.tool_errors},
        "dropped_as_unidentifiable": f2.dropped,
        "residual_rms": {"uncompensated": f1.residual_rms, "compensated": f2.residual_rms},
        "f_test_tool_errors": {"F": float(F), "df1": int(q), "df2": int(f2.dof),
                               "p_value": float(f_dist.sf(F, q, f2.dof)) if np.isfinite(F) else None},
    }
    return f1, f2, cmp


def rate_source_comparison(runs: Sequence, **kw) -> dict[str, Any]:
    """Residual RMS per run (output_unit) and reduced fit quality for each way of forming
    the input rate and its derivative: which one reproduces the data (see module doc)."""
    out = {}
    for rs, rd in (("drive", "drive"), ("fitted", "fitted"), ("logged", "drive"), ("drive", "numeric"),
                   ("logged", "numeric")):
        f = identify_sine_campaign(runs, tool_errors={}, rate_source=rs, rate_derivative=rd, reweight=False, **kw)
        out[f"rate={rs},derivative={rd}"] = {"residual_rms": f.residual_rms, "sigma": f.sigma}
    return out


def _f_test(f_small: SineFit, f_big: SineFit) -> dict[str, Any]:
    rss1, rss2 = f_small.sigma ** 2 * f_small.dof, f_big.sigma ** 2 * f_big.dof
    q = f_small.dof - f_big.dof
    if q <= 0 or rss2 <= 0:
        return {"F": None, "df1": int(q), "df2": int(f_big.dof), "p_value": None}
    F = ((rss1 - rss2) / q) / (rss2 / f_big.dof)
    return {"F": float(F), "df1": int(q), "df2": int(f_big.dof), "p_value": float(f_dist.sf(F, q, f_big.dof))}


def process_sine_campaign(runs: Sequence, rig_id: str = "", *, tool_errors: Mapping[str, str] | None = None,
                          rate_source: str = "drive", rate_derivative: str | None = None,
                          compare_rate_sources: bool = True) -> tuple[list[CoefficientResult], dict[str, Any]]:
    """All of paper 002 on one sinusoidal-rate campaign: returns the coefficients
    (method 'sine_ls', SI units) and JSON-able extras.

    The coefficients are those of the compensated fit (tool errors identified and
    compensated, paper 002), K0 and K1 shared over the attitudes.  Paper 002's KPPP and
    KOOO are tried as well and kept only when identifiable and significant (|z| > 3).
    extras: 'aliasing' (per attitude), 'tool_errors', 'compensation' (with vs without),
    'residual_rms', 'sigma', 'diagnostics' (rank, condition, effective rank),
    'per_run_bias' (F test shared vs per-run K0), 'third_order', 'rate_sources',
    'options', 'flags'.
    """
    prep = prepare_runs(runs, rate_source, rate_derivative)
    out_unit = str(prep[0].meta.get("output_unit", ""))
    flags: list[str] = []
    atts = sorted({r.attitude for r in prep})
    if not {"a", "b", "c"} <= set(atts):
        flags.append(f"attitudes present {atts}: paper 002 needs a, b and c for every term")
    # third-order terms the data support
    base = identify_sine_campaign(None, tool_errors={}, _prepared=prep)
    third = identify_sine_campaign(None, tool_errors={}, extra_terms=EXTRA_TERMS, _prepared=prep)
    keep = [e for e in EXTRA_TERMS if e in third.values and third.std[e] > 0
            and abs(third.values[e]) > 3 * third.std[e]]
    third_info = {"K3": {"identifiable": True, "in_model": True},
                  **{e: {"identifiable": e in third.values and e not in third.dropped,
                         "value": third.values.get(e), "std": third.std.get(e), "unit": "s4/m2",
                         "in_model": e in keep} for e in EXTRA_TERMS},
                  "f_test": _f_test(base, third), "dropped": third.dropped}
    # identify-then-compensate
    f1, f2, cmp = compare_compensation(None, tool_errors, _prepared=prep, extra_terms=keep)
    fit = f2
    if not fit.success:
        flags.append(f"compensated fit did not converge: {fit.message}")
    per_run = identify_sine_campaign(None, tool_errors={}, per_run_bias=True, extra_terms=keep, _prepared=prep)
    bias_test = _f_test(f1, per_run)          # on the nominal-input model (cheap; tool errors ~ K1/K0)
    bias_test["K0_per_run"] = {n: {"value": per_run.values[n], "std": per_run.std[n]}
                               for n in per_run.names if n.startswith("K0[")}
    if bias_test["p_value"] is not None and bias_test["p_value"] < 0.01:
        flags.append("K0 differs between attitudes (p < 0.01): shared-bias fit questionable")
    if fit.diagnostics["rank"] < fit.diagnostics["n_params"]:
        flags.append(f"joint design rank {fit.diagnostics['rank']} < {fit.diagnostics['n_params']} parameters")
    results = []
    for n in fit.names:
        p_kind = "tool" if n in fit.tool_errors else "coef"
        if p_kind == "tool":
            continue
        results.append(CoefficientResult(
            name=n, value=fit.values[n], std_uncertainty=fit.std[n], unit=_unit(n, out_unit), method="sine_ls",
            rig_id=rig_id, dof=float(fit.dof),
            note="paper 002 joint 3-attitude LS, tool errors identified and compensated; "
                 "residual-scaled covariance"))
    alias = aliasing_report(fit)
    alias_nominal = aliasing_report(f1)
    extras = {
        "method": "sine_ls",
        "aliasing": [{k: v for k, v in a.items()} for a in alias],
        "aliasing_coefficients_only": alias_nominal,
        "tool_errors": cmp["tool_errors"],
        "compensation": cmp,
        "residual_rms": fit.residual_rms,
        "sigma": fit.sigma,
        "dof": fit.dof,
        "diagnostics": fit.diagnostics,
        "per_run_bias": bias_test,
        "third_order": third_info,
        "attitudes": fit.attitudes,
        "options": {**fit.options, "tool_errors": dict(fit.options["tool_errors"])},
        "flags": flags,
    }
    if compare_rate_sources:
        extras["rate_sources"] = rate_source_comparison(runs)
    return results, _jsonable(extras)


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return [_jsonable(v) for v in o.tolist()]
    if isinstance(o, (np.floating, float)):
        v = float(o)
        return v if np.isfinite(v) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.bool_,)):
        return bool(o)
    return o
