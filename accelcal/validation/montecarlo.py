"""Monte Carlo validity study of the estimators (issue 3): ``accelcal montecarlo SCENARIO --n 200``.

Part of the validation wing (:mod:`accelcal.validation`).

For i = 0 .. n-1 the scenario is simulated in memory with seed ``seed + i``
(:func:`accelcal.simulate.simulate_campaign`), every run is wrapped as a RunFile-like
object (``meta``, ``data``, ``sha256`` of its content) and the whole campaign goes through
:func:`accelcal.estimators.campaign.process_campaign`.  Every coefficient the science
returns, keyed by (name, method, rig_id), is compared with its truth:

* bias = mean estimate - truth, and bias / (sd / sqrt(n)) (a z score: |z| > 3 is a real bias);
* the empirical sd against the stated standard uncertainty (sd / u_rms, u_rms = sqrt(mean u^2));
* coverage of the intervals estimate +- 1.96 u (target 95 % +- 3 %, issue 3), with the
  binomial sampling half-width 1.96 sqrt(0.95 * 0.05 / n) and a Wilson interval;
* var / CRB for the coefficients whose Cramer-Rao bound is computed (see below).

Truth mapping (what each reported coefficient estimates; :func:`truth_table`)
-------------------------------------------------------------------------------
The instrument coefficients of the scenario (``[unit.coefficients]``) plus the
instrument-term effects (odd_quadratic -> Koq, cubic -> K3, cross_coupling -> Kip,
bias_temperature -> K0T, scale_temperature -> K1T) that apply to the test of that rig.

* ``centrifuge_eq9`` (K2, Kpp, Koo, Kip, Kio, Kpo, Koq, K3): the instrument values.
* ``sine_ls`` (K0, K1, Kp, Ko and all second/third-order terms): the instrument values
  (K0 is shared by the three attitudes, K1 at the run temperature -- no temp_c column).
* ``tumble_lm`` (cos_axis = +-IA, sin_axis s with sign ss, cos sign cs, temperature T of
  the tumble test): K0 -> K0(T) + K_ss g^2 (the sin axis' square term Koo/Kpp is
  g^2 sin^2 = g^2 - g^2 cos^2: it shifts the bias and is taken from K2);
  K1 -> K1 (1 + K1T (T - 20)); K2 -> K2 when the campaign's centrifuge K_ss was added
  (tumble.tumble_records), else K2 - K_ss (the note says which);
  theta0 -> initial_misalignment - cs ss K_s (K_s = Ko/Kp of the sin axis aliases the
  misalignment in one tumble); Kio/Kip (cross term) -> the instrument value.
  Not compared when IA is not the cos axis.
* ``tilt_rotation_ls`` (tilt gamma, normal axis n with sign ns, cos axis c): K0 -> the
  apparent bias at 20 degC, K0 + ns K_n g cos(gamma) + K_nn g^2 cos^2(gamma)
  + (K2 + K_cc) g^2 sin^2(gamma) / 2; K1 -> K1; K0T -> K0T + g c cos(gamma), c the
  ``fixture_thermal_tilt`` (rad/degC; paper 001 sec. 3.2: the method cannot separate them);
  K1T -> K1T.
* anything else (other methods, theta0 with IA on the sin axis, ...): truth undefined,
  reported without bias/coverage.

Cramer-Rao bound (:func:`cramer_rao`)
--------------------------------------
For the data a method uses, F = J^T Sigma^-1 J with J the Jacobian of the forward model
(:func:`accelcal.physics.rigs.rig_output`, central differences; the instrument coefficients
enter linearly or bilinearly, so their columns are exact) at the truth, evaluated at the
readings of one simulated campaign (logged rates, recorded temperatures: the simulator
makes the output from those, so they are exactly known regressors).  Sigma is diagonal,
the simulator's noise per reading: var = (K1(T) white)^2 + (dE/d omega * omega/2 * jitter)^2
(true omega^2 = logged omega^2 (1 + delta), delta ~ N(0, rate_jitter_rel) per reading or
sample; the logged-rate noise does not reach the output given the logged rate; bias random
walk and sensor lag are not modelled in Sigma -- they are zero in the shipped scenarios).
CRB(k) = [F^+]_kk for every parameter that is estimable (e_k in the row space of the
column-scaled J; aliased parameters get no bound).  The parameter vector per method:

* ``centrifuge_eq9``: K2, K3, Koq, Kp, Ko, Kip, Kio, Kpo, Kpp, Koo (one instrument, shared
  by all mounts) + per run a free bias and a free scale of the IA input (eq 9's K0+-, 1+c+-:
  they absorb radius, ia_tilt, K0, Ko g); K1 and K0 known (the tumble gives K1 to 2e-8).
  The estimator fits c2, d, c3 per mount pair and combines them, and adds type-B terms for
  a mount-angle error the simulation does not have: var/CRB > 1 measures that price.
* ``tilt_rotation_ls``: K0, K1, K0T (apparent: its column is identical to the fixture
  tilt's up to a constant), K1T and the cross-axis term of the cos axis (Kp/Ko).
* ``sine_ls``: the 12 coefficients of the effects.md model and the tool errors the
  estimator identifies (spindle_tilt, mass_centre_offset, rate_scale_error, sensor_lag;
  the last by a forward difference at tau = 0).
The bound is for an unbiased estimator of the *full physical model*, so it is a lower
bound also for estimators with more nuisance parameters than it has.
"""
from __future__ import annotations

import copy
import math
import time
from collections import defaultdict
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..constants import T_REF_C
from ..effects import plausible_size, split_combination, typical_size
from ..estimators import registry
from .simruns import SimRunFile
from ..fitting.core import thin_svd
from ..physics.rigs import INSTRUMENT_EFFECTS, rig_output, sine_drive

#: coverage target of issue 3 (95 % +- 3 %) and the coverage factor of the intervals
TARGET, TARGET_TOL, K_COVER = 0.95, 0.03, 1.96

#: the adopted values' coefficients whose var/CRB the issue asks for (the paper methods
#: declare theirs in the registry, ``Estimator.main``)
ADOPTED_MAIN = ("K2", "K3", "Koq", "Kip", "Kio", "Kpo", "Kpp", "Koo", "K0T", "K1T")


def main_coefficients() -> dict[str, tuple[str, ...]]:
    """Method id -> the coefficients the study reports as its headline."""
    return {**registry.main_coefficients(), registry.ADOPTED: ADOPTED_MAIN}

_ALL_COEFFS = ("K0", "K1", "K2", "K3", "Koq", "Kp", "Ko", "Kip", "Kio", "Kpo", "Kpp", "Koo", "K0T", "K1T")


# ---------------------------------------------------------------- runs and scenarios

def _scenario(scenario):
    from ..simulate import Scenario, load_scenario
    return scenario if isinstance(scenario, Scenario) else load_scenario(scenario)


#: the "noise-free" campaign has every noise scaled by this (exactly zero noise makes
#: residual-scaled weights singular): its estimate shows the estimator's bias at no noise
QUIET = 1e-2


def _noise_free(sc):
    sc2 = copy.deepcopy(sc)
    sc2.noise = {k: QUIET * v for k, v in sc2.noise.items()}
    for t in sc2.tests:
        t["noise"] = {k: QUIET * v for k, v in t.get("noise", {}).items()}
    return sc2


def _campaign(sc, seed: int):
    from ..estimators.campaign import process_campaign
    from ..simulate import simulate_campaign
    runs = simulate_campaign(sc, seed)
    return process_campaign([SimRunFile.from_simrun(r) for r in runs])


def _one(args) -> list[tuple[str, str, str, float, float, str]] | str:
    """Worker: one campaign -> [(name, method, rig, value, u, note)], or an error string."""
    import warnings
    sc, seed = args
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            res = _campaign(sc, seed)
    except Exception as exc:  # a crash is a finding, not the end of the study
        return f"seed {seed}: {type(exc).__name__}: {exc}"
    return [(c.name, c.method, c.rig_id, float(c.value), float(c.std_uncertainty), c.note)
            for c in res.coefficients]


# ---------------------------------------------------------------- truth

def _coeffs_for(sc, test: Mapping) -> dict[str, float]:
    """Instrument coefficients seen by the runs of one test (instrument-term effects added)."""
    from ..effects import EFFECTS
    c = {k: 0.0 for k in _ALL_COEFFS}
    c["K1"] = 1.0
    c.update(sc.coefficients)
    eff = {**sc.effects, **test.get("effects", {})}
    for eid, name in INSTRUMENT_EFFECTS.items():
        if eid in eff and test["kind"] in EFFECTS[eid].tests:
            c[name] += float(eff[eid])
    return c


def _effects_for(sc, test: Mapping) -> dict[str, float]:
    from ..effects import EFFECTS
    eff = {**sc.effects, **test.get("effects", {})}
    return {k: float(v) for k, v in eff.items() if test["kind"] in EFFECTS[k].tests}


def truth_table(scenario, notes: Mapping[tuple[str, str, str], str] | None = None
                ) -> dict[tuple[str, str, str], tuple[float, str]]:
    """(name, method, rig_id) -> (truth, how it was mapped).  ``notes``: the coefficient
    notes of one processed campaign (the tumble K2 says whether the centrifuge corrected it).
    See the module docstring for each mapping."""
    sc = _scenario(scenario)
    notes = notes or {}
    g = float(sc.site["g_local_m_s2"])
    out: dict[tuple[str, str, str], tuple[float, str]] = {}
    for t in sc.tests:
        kind, rig = t["kind"], str(t["rig_id"])
        c = _coeffs_for(sc, t)
        eff = _effects_for(sc, t)
        for est in registry.for_test(kind):
            if est.truth is None:
                continue
            own = {name: note for (name, method, rg), note in notes.items() if method == est.method and rg == rig}
            for (name, rg), v in est.truth(c, eff, t, g, own).items():
                out[(name, est.method, rg)] = v
    out.update(_joint_truth(sc, out))
    return out


#: key of :func:`cramer_rao`'s whole bound covariance {(name, name): [SI^2]}
COVARIANCE = ("__covariance__", "", "")


def combination_bound(name: str, cov: Mapping[tuple[str, str], float]) -> float | None:
    """Cramér–Rao variance of a row named as a combination (issue 30): c^T F^+ c over the
    terms the bound has free; a term the bound holds (aliased, as the estimator holds it)
    is left out, so a coefficient that takes up a held one has its own bound.

    Parameters
    ----------
    name : str
        :func:`accelcal.effects.split_combination` form (``'Kip+Kpp'``, ``'K0+96.1*Koo'``).
    cov : mapping
        :func:`cramer_rao`'s ``COVARIANCE`` entry [SI^2].

    Returns
    -------
    float or None
        [SI^2]; None when the coefficient itself is not free in the bound.
    """
    base, terms = split_combination(name)
    c = {base: 1.0, **{k: f for k, f in terms.items() if (k, k) in cov}}
    if (base, base) not in cov:
        return None
    return float(sum(fa * fb * cov[(a, b)] for a, fa in c.items() for b, fb in c.items()))


def combination_truth(key: tuple[str, str, str], truth: Mapping) -> tuple[float, str] | None:
    """Truth of a row named as a combination (:func:`accelcal.effects.split_combination`,
    issue 30): where the table maps its coefficient to an apparent value (a tumble's K0 is
    K0 + K_ss g^2), that mapping already is the combination; where it maps it to the
    instrument value, the other terms' instrument values are added with their factors.

    Parameters
    ----------
    key : (name, method, rig_id)
    truth : mapping
        :func:`truth_table`.

    Returns
    -------
    (float, str) or None
        Truth [SI] and how it was mapped; None for a plain name or an unknown term.
    """
    name, method, rig = key
    base, terms = split_combination(name)
    if not terms:
        return None
    got = truth.get((base, method, rig)) or truth.get((base, method, "*"))
    if got is None:
        return None
    if got[1] != "instrument value":
        return got[0], f"{got[1]} (the combination {name})"
    total = got[0]
    for k, f in terms.items():
        t = truth.get((k, "joint_ml", "*"))
        if t is None:
            return None
        total += f * t[0]
    return total, f"instrument values of {name}"


def _joint_truth(sc, per_method: Mapping) -> dict[tuple[str, str, str], tuple[float, str]]:
    """Truth of the joint fit (method 'joint_ml', one row per campaign, rig_id the '+'-joined
    rigs): the instrument values; K0 and K1 at the tumble's temperature when there is a
    tumble; theta0 the head's initial misalignment (a row that absorbs Ko says so in its
    name, :func:`combination_truth`); for a tilt-rotation
    campaign the apparent K0 and K0T of tilt_rotation_ls (the design aliases them)."""
    label = "*"           # the joint fit names each coefficient's rig (the one its information comes from)
    kinds = {t["kind"] for t in sc.tests}
    c = {k: 0.0 for k in _ALL_COEFFS}
    c["K1"] = 1.0
    c.update(sc.coefficients)
    for t in sc.tests:
        cc = _coeffs_for(sc, t)
        for k in ("K2", "K3", "Koq", "Kip", "K0T", "K1T"):
            if cc[k] != c[k]:
                c[k] = cc[k]
    out: dict[tuple[str, str, str], tuple[float, str]] = {}
    for k in ("K2", "K3", "Koq", "Kp", "Ko", "Kip", "Kio", "Kpo", "Kpp", "Koo", "K0", "K1", "K0T", "K1T"):
        out[(k, "joint_ml", label)] = (c[k], "instrument value")
    tumble = next((t for t in sc.tests if t["kind"] == "tumble"), None)
    if tumble is not None:
        dT = float(tumble.get("temp_c", 23.0)) - T_REF_C
        out[("K0", "joint_ml", label)] = (c["K0"] + c["K0T"] * dT, "K0(T) at the tumble's temperature")
        out[("K1", "joint_ml", label)] = (c["K1"] * (1 + c["K1T"] * dT), "K1(T) at the tumble's temperature")
        # the joint fit names what its theta0 row absorbs (theta0-Ko in one tumble, plain
        # theta0 where a centrifuge's IA-OA mounts give Ko): the combination adds the rest
        eff = {**sc.effects, **(tumble.get("effects") or {})}
        out[("theta0", "joint_ml", label)] = (float(eff.get("initial_misalignment", 0.0)), "instrument value")
    if kinds == {"tilt_rotation"}:
        rig = str(sc.tests[0]["rig_id"])
        for k in ("K0", "K0T"):
            if (k, "tilt_rotation_ls", rig) in per_method:
                out[(k, "joint_ml", label)] = per_method[(k, "tilt_rotation_ls", rig)]
    return out


# ---------------------------------------------------------------- Cramer-Rao bound

def _reading_variance(kind: str, meta, data, coeffs, effects, noise) -> np.ndarray:
    """Variance of each reading's output (output_unit^2), the simulator's noise model."""
    from ..physics import scale_factor
    temp = np.asarray(data["temp_c"], float) if "temp_c" in data.columns else None
    K1 = np.broadcast_to(np.asarray(scale_factor(coeffs, temp), float), (len(data),))
    var = (K1 * float(noise.get("white_m_s2", 0.0))) ** 2
    jit = float(noise.get("rate_jitter_rel", 0.0))
    if jit > 0 and "table_rate_rad_s" in data.columns:
        w = np.asarray(data["table_rate_rad_s"], float)
        h = 1e-6 * np.maximum(np.abs(w), 1e-3)
        up, dn = data.copy(), data.copy()
        up["table_rate_rad_s"] = w + h
        dn["table_rate_rad_s"] = w - h
        dEdw = (rig_output(kind, meta, up, coeffs, effects) - rig_output(kind, meta, dn, coeffs, effects)) / (2 * h)
        var = var + (dEdw * w / 2 * jit) ** 2
    cen = float(noise.get("centripetal_rel", 0.0))
    if cen > 0 and "table_rate_rad_s" in data.columns:
        from ..physics.rigs import omega_z
        level = omega_z(meta, np.asarray(data["table_rate_rad_s"], float), {"earth_rate": 1.0}) ** 2 * float(
            meta["arm_radius_m"])
        var = var + (K1 * cen * level) ** 2
    return var


def _column(kind, meta, data, coeffs, effects, name) -> np.ndarray:
    """d E / d name at the truth (central differences; forward for sensor_lag >= 0)."""
    if name in _ALL_COEFFS:
        # exact for the coefficients, in which the output is linear; K1 relative to its value
        h = 1e-3 * abs(coeffs["K1"]) if name == "K1" else typical_size(name)
        up, dn = dict(coeffs), dict(coeffs)
        up[name] += h
        dn[name] -= h
        return (rig_output(kind, meta, data, up, effects) - rig_output(kind, meta, data, dn, effects)) / (2 * h)
    h = 1e-3 * typical_size(name)      # as the campaign model's difference steps
    up, dn = dict(effects), dict(effects)
    v = float(effects.get(name, 0.0))
    up[name] = v + h
    if name == "sensor_lag" and v < h:
        return (rig_output(kind, meta, data, coeffs, up) - rig_output(kind, meta, data, coeffs, effects)) / h
    dn[name] = v - h
    return (rig_output(kind, meta, data, coeffs, up) - rig_output(kind, meta, data, coeffs, dn)) / (2 * h)


def _bound(J: np.ndarray, names: Sequence[str], rtol: float = 1e-10,
           cov: dict | None = None) -> dict[str, float | None]:
    """diag(F^+) for the estimable parameters of the whitened Jacobian J (None if aliased);
    ``cov``, when given, receives every element of F^+ keyed by (name, name)."""
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    _, s, Vt = thin_svd(J / scale)
    keep = s > rtol * s[0]
    V, sk = Vt[keep].T, s[keep]
    Vnull = Vt[~keep].T
    cov_s = (V / sk**2) @ V.T
    out = {}
    for i, n in enumerate(names):
        if Vnull.size and np.linalg.norm(Vnull[i]) > 1e-3:
            out[n] = None
        else:
            out[n] = float(cov_s[i, i] / scale[i] ** 2)
    if cov is not None:
        cov.update({(a, b): float(cov_s[i, j] / (scale[i] * scale[j]))
                    for i, a in enumerate(names) for j, b in enumerate(names)})
    return out


def _crb_parameters(kind: str, run, j: int, campaign_rigs) -> list[tuple[str, str, object]]:  # noqa: C901
    """(parameter name, kind, key) of the whole-campaign model that act on run j.

    Instrument coefficients (one instrument, shared by every run); the nuisance parameters
    the lab does not know, free: a bias per centrifuge run (replacing K0 there), the
    turning-centre radius per centrifuge rig, the mass-centre offset, one mount-angle error
    per centrifuge mount (both polarities), theta0 per dividing head, and for the sine
    centrifuge the tool errors spindle_tilt and sensor_lag."""
    from ..physics.geometry import geometry_of
    meta = run.meta
    rig = str(meta["rig_id"])
    out: list[tuple[str, str, object]] = []
    for k in _ALL_COEFFS:
        if k not in campaign_rigs:          # the coefficients the campaign's tests determine
            continue
        if k == "K0" and kind == "centrifuge":
            out.append((f"bias[{meta['run_id']}]", "coef", "K0"))
        else:
            out.append((k, "coef", k))
    if kind == "tumble":
        g = geometry_of(meta)
        out.append((f"theta0[{rig} {g.label}]", "effect", "initial_misalignment"))
    if kind in ("centrifuge", "sine_centrifuge"):
        g = geometry_of(meta)
        out.append((f"R[{rig}]", "radius", None))
        out.append((f"r[{rig}]", "effect", "mass_centre_offset"))
        if kind == "centrifuge" and g.ia_polarity is None:   # IA radial: not separable (type B)
            plane, phi = g.mount_key
            out.append((f"dphi[{rig} {plane} {phi:g}]", "effect", "mount_angle_error"))
        else:
            out += [(f"spindle_tilt[{rig}]", "effect", "spindle_tilt"), ("sensor_lag", "effect", "sensor_lag")]
    return out


def _crb_column(kind, meta, data, coeffs, effects, what, key, R0) -> np.ndarray:
    """d E / d parameter at the truth, central differences of rig_output (forward for a
    sensor lag at 0, where the parameter sits on its bound)."""
    if what == "coef":
        return _column(kind, meta, data, coeffs, effects, key)
    if what == "radius":
        h = 1e-6 * R0
        return (rig_output(kind, meta, data, coeffs, effects, radius_m=R0 + h)
                - rig_output(kind, meta, data, coeffs, effects, radius_m=R0 - h)) / (2 * h)
    return _column(kind, meta, data, coeffs, effects, key)


def _crb_selection(J: np.ndarray, names: Sequence[str]) -> list[int]:
    """Which parameters the bound treats as free: in the estimator's priority order, those
    whose column adds a new direction (an aliased combination is counted once), then
    without the extension terms whose bound exceeds their plausible size (they are held,
    as the estimator holds them).  accelcal.fitting.model documents the rule."""
    from ..fitting.core import lstsq_svd
    from ..fitting.model import ALIAS_TOL, BASE, PRIORITY, SCALE_TERMS, scale_referenced_columns

    def kind(n):
        b = n.split("[", 1)[0]
        return {"bias": "bias", "theta0": "theta0", "R": "radius", "r": "mass_centre_offset",
                "dphi": "mount_angle_error", "spindle_tilt": "effect", "sensor_lag": "effect"}.get(b, b)

    order = sorted(range(len(names)), key=lambda i: (PRIORITY.index(kind(names[i])), i))
    kept = scale_referenced_columns(J, order, ALIAS_TOL, radius=[kind(n) == "radius" for n in names],
                                    scale=[n in SCALE_TERMS for n in names])
    while True:
        u = np.sqrt(np.clip(np.diag(lstsq_svd(J[:, kept], np.zeros(J.shape[0])).cov), 0, None))
        worst, ratio = None, 1.0
        for c, i in enumerate(kept):
            k, b = kind(names[i]), names[i].split("[", 1)[0]
            if k in BASE:
                continue
            lim = plausible_size(b)
            if lim and u[c] / lim > ratio:
                worst, ratio = c, u[c] / lim
        if worst is None:
            return kept
        kept.pop(worst)


def cramer_rao(scenario, seed: int | None = None) -> dict[tuple[str, str, str], float | None]:
    """Whole-campaign Cramer-Rao bound: (name, method, rig_id) -> CRB variance (SI units
    squared), or None where the coefficient is aliased.

    Computed from the simulator's truth and its noise model (module docstring), over every
    reading of every run of the scenario's campaign (tumble and centrifuge pooled), with the
    nuisance parameters of :func:`_crb_parameters` free.  The same bound applies to every
    method that estimates the same quantity; it is reported for the rows whose truth is the
    instrument value (and for K0T/K1T of a tilt-rotation campaign)."""
    from ..simulate import simulate_campaign
    sc = _scenario(scenario)
    runs = simulate_campaign(sc, sc.seed if seed is None else seed)
    tests = {(t["kind"], str(t["rig_id"])): t for t in sc.tests}
    from ..fitting.model import DESIGNED
    designed = {k for r in runs for k in DESIGNED[str(r.meta["test"])]}
    blocks, names = [], {}
    per_run = []
    for j, r in enumerate(runs):
        kind = str(r.meta["test"])
        t = tests[(kind, str(r.meta["rig_id"]))]
        coeffs = _coeffs_for(sc, t)
        eff = dict(r.truth["effects"])
        data = r.data.copy()
        if kind == "sine_centrifuge":           # the expectation of the true rate: the drive
            data["table_rate_rad_s"] = sine_drive(r.meta, data["time_s"].to_numpy(float))
        plist = _crb_parameters(kind, r, j, designed)
        R0 = float(r.meta.get("arm_radius_m", 1.0))
        cols = {}
        for name, what, key in plist:
            names.setdefault(name, len(names))
            cols[name] = _crb_column(kind, r.meta, data, coeffs, eff, what, key, R0)
        var = _reading_variance(kind, r.meta, data, coeffs, eff, r.truth["noise"])
        per_run.append((cols, np.sqrt(var)))
    order = list(names)
    for cols, sig in per_run:
        n = len(sig)
        M = np.zeros((n, len(order)))
        for name, c in cols.items():
            M[:, names[name]] = c
        blocks.append(M / sig[:, None])
    J = np.vstack(blocks)
    keep = _crb_selection(J, order)
    cov: dict = {}
    bound = _bound(J[:, keep], [order[i] for i in keep], cov=cov)
    label = "*"
    out: dict = {COVARIANCE: cov}
    for k in _ALL_COEFFS:
        if k in bound:
            out[(k, "joint_ml", label)] = bound[k]
    for (kind, rig), t in tests.items():
        for est in registry.for_test(kind):
            if not est.crb:
                continue
            for k in _ALL_COEFFS:
                if k in bound:
                    out[(k, est.method, rig)] = bound[k]
    return out


# ---------------------------------------------------------------- the study

@dataclass
class CoefficientStats:
    name: str
    method: str
    rig_id: str
    n: int
    truth: float | None
    truth_note: str
    mean: float
    sd: float
    u_rms: float
    u_mean: float
    bias: float | None = None
    bias_z: float | None = None              # bias / (sd / sqrt(n))
    sd_over_u: float | None = None
    coverage: float | None = None            # fraction with |x - truth| <= 1.96 u
    coverage_wilson: tuple[float, float] | None = None
    z_sd: float | None = None                # sd of (x - truth) / u
    noise_free: float | None = None          # estimate from the campaign with noise x 0.01 (QUIET)
    crb_sd: float | None = None
    var_over_crb: float | None = None
    var_over_crb_interval: tuple[float, float] | None = None   # 95 %, from chi^2_{n-1}
    bias_over_sd: float | None = None
    main: bool = False
    status: str = ""       # ok | UNDER | OVER (Wilson interval excludes 95 %) | blank: no truth


@dataclass
class StudyResult:
    scenario: str
    n: int
    seed: int
    workers: int
    seconds: float
    seconds_per_campaign: float
    failures: list[str] = field(default_factory=list)
    coefficients: list[CoefficientStats] = field(default_factory=list)
    band: float = 0.0                        # binomial 95 % half-width of the coverage at n

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def get(self, name: str, method: str | None = None) -> CoefficientStats:
        for c in self.coefficients:
            if c.name == name and (method is None or c.method == method):
                return c
        raise KeyError((name, method))

    def to_markdown(self) -> str:
        return study_markdown(self)


def _wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (max(0.0, c - h), min(1.0, c + h))


def run_study(scenario, n: int = 200, seed: int = 0, workers: int = 1, *, crb: bool = True,
              noise_free: bool = True, progress=None) -> StudyResult:
    """Simulate ``n`` campaigns of ``scenario`` (path, shipped name, dict or Scenario) with
    seeds seed .. seed+n-1, process each, and summarise every coefficient against its
    truth (module docstring).  ``workers`` > 1 uses a process pool."""
    sc = _scenario(scenario)
    t0 = time.perf_counter()
    jobs = [(sc, seed + i) for i in range(n)]
    if workers > 1:
        with ProcessPoolExecutor(max_workers=workers) as ex:
            results = list(ex.map(_one, jobs, chunksize=max(1, n // (8 * workers))))
    else:
        results = []
        for j in jobs:
            results.append(_one(j))
            if progress:
                progress(len(results), n)
    seconds = time.perf_counter() - t0
    failures = [r for r in results if isinstance(r, str)]
    ok = [r for r in results if not isinstance(r, str)]
    vals: dict[tuple[str, str, str], list[tuple[float, float]]] = defaultdict(list)
    notes: dict[tuple[str, str, str], str] = {}
    for rows in ok:
        for name, method, rig, v, u, note in rows:
            vals[(name, method, rig)].append((v, u))
            notes.setdefault((name, method, rig), note)
    truth = truth_table(sc, notes)
    nf: dict[tuple[str, str, str], float] = {}
    if noise_free:
        rows = _one((_noise_free(sc), sc.seed if sc.seed is not None else seed))
        if not isinstance(rows, str):
            nf = {(a, b, c): v for a, b, c, v, _, _ in rows}
    bounds = cramer_rao(sc, seed) if crb else {}
    stats = []
    for key, vu in vals.items():
        name, method, rig = key
        x = np.array([a for a, _ in vu])
        u = np.array([b for _, b in vu])
        m = len(x)
        sd = float(np.std(x, ddof=1)) if m > 1 else float("nan")
        u_rms = float(np.sqrt(np.mean(u**2)))
        tv, tnote = truth.get(key) or truth.get((name, method, "*")) or combination_truth(key, truth) or (
            None, "no truth defined for this coefficient/method")
        cs = CoefficientStats(name, method, rig, m, tv, tnote, float(np.mean(x)), sd, u_rms,
                              float(np.mean(u)), noise_free=nf.get(key),
                              main=name in main_coefficients().get(method, ()))
        cs.sd_over_u = sd / u_rms if u_rms > 0 else None
        if tv is not None:
            cs.bias = cs.mean - tv
            cs.bias_z = cs.bias / (sd / math.sqrt(m)) if m > 1 and sd > 0 else None
            inside = np.abs(x - tv) <= K_COVER * u
            cs.coverage = float(np.mean(inside))
            cs.coverage_wilson = _wilson(int(inside.sum()), m)
            with np.errstate(divide="ignore", invalid="ignore"):
                z = (x - tv) / u
            z = z[np.isfinite(z)]
            cs.z_sd = float(np.std(z, ddof=1)) if z.size > 1 else None
            lo, hi = cs.coverage_wilson
            cs.status = "ok" if lo <= TARGET <= hi else ("UNDER" if hi < TARGET else "OVER")
            cs.bias_over_sd = cs.bias / sd if sd > 0 else None
        b = next((bounds[k] for k in (key, (name, method, "*")) if bounds.get(k) is not None), None)
        if b is None and bounds:
            b = combination_bound(name, bounds[COVARIANCE])
        if b is not None and b > 0 and tv is not None and m > 1:
            cs.crb_sd = math.sqrt(b)
            cs.var_over_crb = sd**2 / b
            from scipy import stats as _st
            cs.var_over_crb_interval = ((m - 1) * sd**2 / _st.chi2.ppf(0.975, m - 1) / b,
                                        (m - 1) * sd**2 / _st.chi2.ppf(0.025, m - 1) / b)
        stats.append(cs)
    order = registry.display_order()
    from ..effects import COEFFICIENTS
    cnames = list(COEFFICIENTS)
    stats.sort(key=lambda s: (order.get(s.method, 9), s.rig_id,
                              cnames.index(s.name) if s.name in cnames else 99, s.name))
    return StudyResult(scenario=sc.name, n=n, seed=seed, workers=workers, seconds=seconds,
                       seconds_per_campaign=seconds * max(workers, 1) / max(n, 1), failures=failures,
                       coefficients=stats, band=K_COVER * math.sqrt(TARGET * (1 - TARGET) / max(n, 1)))


# ---------------------------------------------------------------- output

def _g(x, d=3) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return f"{x:.{d}g}"


def study_markdown(res: StudyResult) -> str:
    """The study as a markdown table (SI units, effects.md)."""
    lines = [f"### Monte Carlo study: `{res.scenario}`, n = {res.n} campaigns (seeds {res.seed}.."
             f"{res.seed + res.n - 1})", "",
             f"{res.seconds:.0f} s on {res.workers} worker(s), {res.seconds_per_campaign:.2f} s of CPU per "
             f"campaign; {len(res.failures)} failed campaign(s). Coverage of x ± 1.96·u with its Wilson "
             f"95 % interval (binomial half-width at this n ±{100 * res.band:.1f} %); OVER/UNDER only when "
             "that interval excludes 95 %. bias/sd and bias z = bias/(sd/√n). var/CRB against the "
             "whole-campaign Cramér–Rao bound (every reading, nuisance parameters free; module "
             "docstring), with its 95 % interval from chi²(n−1). Bold: the adopted main coefficients. "
             "SI units.", "",
             "| coefficient | method | n | truth | mean | bias/sd | bias z | sd | rms u | sd/u | coverage "
             "(Wilson 95 %) | var/CRB (95 %) | |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in res.coefficients:
        cov = "—" if c.coverage is None else (
            f"{100 * c.coverage:.1f} % ({100 * c.coverage_wilson[0]:.1f}–{100 * c.coverage_wilson[1]:.1f})")
        crb = "—" if c.var_over_crb is None else (
            f"{c.var_over_crb:.3g} ({c.var_over_crb_interval[0]:.2f}–{c.var_over_crb_interval[1]:.2f})")
        name = f"**{c.name}**" if c.main and c.method == "joint_ml" else c.name
        lines.append(f"| {name} | {c.method} | {c.n} | {_g(c.truth, 4)} | {_g(c.mean, 5)} | "
                     f"{_g(c.bias_over_sd, 2)} | {_g(c.bias_z, 2)} | {_g(c.sd, 3)} | {_g(c.u_rms, 3)} | "
                     f"{_g(c.sd_over_u, 3)} | {cov} | {crb} | {c.status} |")
    lines += ["", "Truth mapping: " + "; ".join(
        sorted({f"{c.name} ({c.method}): {c.truth_note}" for c in res.coefficients
                if c.truth_note != "instrument value"}))]
    if res.failures:
        lines += ["", "Failures: " + "; ".join(res.failures[:5])]
    return "\n".join(lines) + "\n"


__all__ = ["run_study", "StudyResult", "CoefficientStats", "truth_table", "cramer_rao",
           "study_markdown", "SimRunFile", "main_coefficients"]
