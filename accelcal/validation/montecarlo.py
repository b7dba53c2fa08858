"""Monte Carlo validity study of the estimators: ``accelcal montecarlo SCENARIO --n 200``.

Part of the validation wing (:mod:`accelcal.validation`).

For i = 0 .. n-1 the scenario is simulated in memory with seed ``seed + i``
(:func:`accelcal.simulate.simulate_campaign`), every run is wrapped as a RunFile-like
object (``meta``, ``data``, ``sha256`` of its content) and the whole campaign goes through
:func:`accelcal.estimators.campaign.process_campaign`.  Every coefficient the science
returns, keyed by (name, method, rig_id), is compared with its truth:

* bias = mean estimate - truth, and bias / (sd / sqrt(n)) (a z score: |z| > 3 is a real bias);
* the empirical sd against the stated standard uncertainty (sd / u_rms, u_rms = sqrt(mean u^2));
* coverage of the intervals estimate +- 1.96 u (target 95 % +- 3 %), with the
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
For the data of a campaign, F = J^T Sigma^-1 J with J the Jacobian of the campaign model
(:class:`accelcal.fitting.model.CampaignModel`, whose columns are the derivatives of
:func:`accelcal.physics.rigs.rig_output`) at the truth, evaluated at the readings of one
simulated campaign (logged rates, recorded temperatures: the simulator makes the output
from those, so they are exactly known regressors), each reading its own cell.  Sigma is
diagonal, the simulator's noise per reading: var = (K1(T) white)^2 + (dE/d omega * omega/2
* jitter)^2 + (K1 centripetal_rel omega_z^2 R)^2 (true omega^2 = logged omega^2 (1 + delta),
delta ~ N(0, rate_jitter_rel) per reading or sample; the logged-rate noise does not reach
the output given the logged rate; bias random walk and sensor lag are not modelled in
Sigma -- they are zero in the shipped scenarios).  The unknowns are the coefficients the
campaign's tests are designed to determine, a bias per centrifuge run, the turning-centre
radius per rig and the effects of :data:`UNKNOWN_EFFECTS` where effects.md applies them;
the model holds what it holds in a fit (aliased or weakly determined,
:meth:`~accelcal.fitting.model.CampaignModel.holds`) and CRB(k) = [F^-1]_kk over the rest.
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
from scipy import stats

from ..constants import T_REF_C
from ..effects import COEFFICIENTS, split_combination
from ..estimators import registry
from ..estimators.tumble import reading_cells
from .simruns import SimRunFile
from ..fitting.core import lstsq_svd
from ..fitting.identify import holds
from ..fitting.model import DESIGNED, CampaignModel
from ..physics import scale_factor
from ..physics.rigs import INSTRUMENT_EFFECTS, instrument_coefficients, omega_z, rig_output, sine_drive
from ..results import CoefficientResult

#: coverage target (95 % +- 3 %) and the coverage factor of the intervals
TARGET, TARGET_TOL, K_COVER = 0.95, 0.03, 1.96

#: the adopted values' coefficients whose var/CRB the study reports (the paper methods
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


def _one(args) -> list[tuple[str, str, str, float, float, CoefficientResult]] | str:
    """Worker: one campaign -> [(name, method, rig, value, u, record)], or an error string."""
    import warnings
    sc, seed = args
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            res = _campaign(sc, seed)
    except Exception as exc:  # a crash is a finding, not the end of the study
        return f"seed {seed}: {type(exc).__name__}: {exc}"
    return [(c.name, c.method, c.rig_id, float(c.value), float(c.std_uncertainty), c)
            for c in res.coefficients]


# ---------------------------------------------------------------- truth

def _coeffs_for(sc, test: Mapping | None = None) -> dict[str, float]:
    """Instrument coefficients of the scenario, as seen by the runs of ``test`` when given
    (the instrument-term effects acting in it added)."""
    c = {**{k: 0.0 for k in _ALL_COEFFS}, "K1": 1.0, **sc.coefficients}
    return c if test is None else instrument_coefficients(c, _effects_for(sc, test))


def _effects_for(sc, test: Mapping) -> dict[str, float]:
    from ..simulate.engine import acting_effects
    return acting_effects(test["kind"], sc.effects, test.get("effects"))


def truth_table(scenario, records: Mapping[tuple[str, str, str], CoefficientResult] | None = None
                ) -> dict[tuple[str, str, str], tuple[float, str]]:
    """(name, method, rig_id) -> (truth, how it was mapped).  ``records``: the coefficient
    records of one processed campaign (the tumble K2's says whether the centrifuge corrected
    it).  See the module docstring for each mapping."""
    sc = _scenario(scenario)
    records = records or {}
    g = float(sc.site["g_local_m_s2"])
    out: dict[tuple[str, str, str], tuple[float, str]] = {}
    for t in sc.tests:
        kind, rig = t["kind"], str(t["rig_id"])
        c = _coeffs_for(sc, t)
        eff = _effects_for(sc, t)
        for est in (e for e in registry.for_test(kind) if e.truth is not None):
            own = {name: rec for (name, method, rg), rec in records.items() if method == est.method and rg == rig}
            out.update({(name, est.method, rg): v for (name, rg), v in est.truth(c, eff, t, g, own).items()})
    out.update(_joint_truth(sc, out))
    return out


#: key of :func:`cramer_rao`'s whole bound covariance {(name, name): [SI^2]}
COVARIANCE = ("__covariance__", "", "")


def combination_bound(name: str, factors: Mapping[str, float],
                      cov: Mapping[tuple[str, str], float]) -> float | None:
    """Cramér–Rao variance of a row named as a combination: c^T F^+ c over the
    terms the bound has free; a term the bound holds (aliased, as the estimator holds it)
    is left out, so a coefficient that takes up a held one has its own bound.

    Parameters
    ----------
    name : str
        Row name (:func:`accelcal.effects.combination_name`, ``'Kip(Kpp)'``, ``'K0(Koo)'``).
    factors : mapping of str to float
        The row's factors (``CoefficientResult.factors``).
    cov : mapping
        :func:`cramer_rao`'s ``COVARIANCE`` entry [SI^2].

    Returns
    -------
    float or None
        [SI^2]; None when the coefficient itself is not free in the bound.
    """
    base = split_combination(name)[0]
    c = {base: 1.0, **{k: f for k, f in factors.items() if (k, k) in cov}}
    if (base, base) not in cov:
        return None
    return float(sum(fa * fb * cov[(a, b)] for a, fa in c.items() for b, fb in c.items()))


def combination_truth(key: tuple[str, str, str], factors: Mapping[str, float],
                      truth: Mapping) -> tuple[float, str] | None:
    """Truth of a row that is a combination (:func:`accelcal.effects.combination_name`):
    where the table maps its coefficient to an apparent value (a tumble's K0 is
    K0 + K_ss g^2), that mapping already is the combination; where it maps it to the
    instrument value, the other terms' instrument values are added with their factors.

    Parameters
    ----------
    key : (name, method, rig_id)
    factors : mapping of str to float
        The row's factors (of its first draw: they move by parts in 1e6 between draws).
    truth : mapping
        :func:`truth_table`.

    Returns
    -------
    (float, str) or None
        Truth [SI] and how it was mapped; None for a plain name or an unknown term.
    """
    name, method, rig = key
    base = split_combination(name)[0]
    if not factors:
        return None
    got = truth.get((base, method, rig)) or truth.get((base, method, "*"))
    if got is None:
        return None
    if got[1] != "instrument value":
        return got[0], f"{got[1]} (the combination {name})"
    total = got[0]
    for k, f in factors.items():
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
    c = _coeffs_for(sc)
    for t in sc.tests:
        cc = _coeffs_for(sc, t)
        c.update({k: cc[k] for k in ("K2", "K3", "Koq", "Kip", "K0T", "K1T") if cc[k] != c[k]})
    out = {(k, "joint_ml", label): (c[k], "instrument value")
           for k in ("K2", "K3", "Koq", "Kp", "Ko", "Kip", "Kio", "Kpo", "Kpp", "Koo", "K0", "K1", "K0T", "K1T")}
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
    temp = np.asarray(data["temp_c"], float) if "temp_c" in data.columns else None
    K1 = np.broadcast_to(np.asarray(scale_factor(coeffs, temp), float), (len(data),))
    var = (K1 * float(noise.get("white_m_s2", 0.0))) ** 2
    jit = float(noise.get("rate_jitter_rel", 0.0))
    if jit > 0 and "table_rate_rad_s" in data.columns:
        w = np.asarray(data["table_rate_rad_s"], float)
        h = 1e-6 * np.maximum(np.abs(w), 1e-3)
        up, dn = data.assign(table_rate_rad_s=w + h), data.assign(table_rate_rad_s=w - h)
        dEdw = (rig_output(kind, meta, up, coeffs, effects) - rig_output(kind, meta, dn, coeffs, effects)) / (2 * h)
        var = var + (dEdw * w / 2 * jit) ** 2
    cen = float(noise.get("centripetal_rel", 0.0))
    if cen > 0 and "table_rate_rad_s" in data.columns:
        level = omega_z(meta, np.asarray(data["table_rate_rad_s"], float), {"earth_rate": 1.0}) ** 2 * float(
            meta["arm_radius_m"])
        var = var + (K1 * cen * level) ** 2
    return var


#: effects the bound takes as unknown, with the run biases, radii and designed coefficients
#: (effects.md ids, in the order they claim a direction of the design)
UNKNOWN_EFFECTS = ("initial_misalignment", "mass_centre_offset", "mount_angle_error", "spindle_tilt",
                   "sensor_lag")


def _truth_point(model: CampaignModel, coeffs: Sequence[Mapping[str, float]],
                 effects: Sequence[Mapping[str, float]]) -> np.ndarray:
    """The model's parameter vector at the simulator's truth: each parameter at the value
    of the runs it acts on (coefficients and effects per run; a run bias at that run's K0,
    a radius at the runs' nominal arm radius)."""
    p = model.params.values()
    for i, (prm, role) in enumerate(zip(model.params, model.roles)):
        if role.kind == "radius":
            continue
        vals = {float(coeffs[j][role.key]) if role.kind in ("coef", "bias") else float(effects[j].get(role.key, 0.0))
                for j in prm.runs}
        if len(vals) > 1:
            raise ValueError(f"the simulator's truth of {prm.name} differs between the runs it acts on: {sorted(vals)}")
        p[i] = vals.pop()
    return p


def cramer_rao(scenario, seed: int | None = None) -> dict[tuple[str, str, str], float | None]:
    """Whole-campaign Cramér–Rao bound: (name, method, rig_id) -> CRB variance (SI units
    squared).

    The campaign model (:class:`accelcal.fitting.model.CampaignModel`) over every reading of
    every run of one simulated campaign (tumble and centrifuge pooled), each reading its own
    cell weighted by the simulator's variance of it (:func:`_reading_variance`); every
    coefficient and effect of the simulation a parameter at its true value.  The unknowns are
    the coefficients the campaign's tests are designed to determine, a bias per centrifuge
    run, the radii and :data:`UNKNOWN_EFFECTS`; of those, the model holds what it holds in a
    fit (:meth:`~accelcal.fitting.model.CampaignModel.holds`), and the bound is the inverse
    of the information J^T W J of the others (W = diag(1 / var)).  The same bound applies
    to every method that estimates the same quantity; it is reported for the rows whose
    truth is the instrument value (and for K0T/K1T of a tilt-rotation campaign)."""
    from ..simulate import simulate_campaign
    sc = _scenario(scenario)
    runs = simulate_campaign(sc, sc.seed if seed is None else seed)
    tests = {(t["kind"], str(t["rig_id"])): t for t in sc.tests}
    cells, coeffs, effects = [], [], []
    for j, r in enumerate(runs):
        kind = str(r.meta["test"])
        c = _coeffs_for(sc, tests[(kind, str(r.meta["rig_id"]))])
        eff = dict(r.truth["effects"])
        data = r.data.copy()
        if kind == "sine_centrifuge":           # the expectation of the true rate: the drive
            data["table_rate_rad_s"] = sine_drive(r.meta, data["time_s"].to_numpy(float))
        var = _reading_variance(kind, r.meta, data, c, eff, r.truth["noise"])
        cells.append(reading_cells(r.meta, {k: np.asarray(data[k], float) for k in data.columns}, j, var))
        coeffs.append(c)
        effects.append(eff)
    kinds = {r.test for r in cells}
    designed = {k for t in kinds for k in DESIGNED[t]}
    simulated = [e for e in dict.fromkeys(e for eff in effects for e in eff) if e not in INSTRUMENT_EFFECTS]
    model = CampaignModel(cells, [*UNKNOWN_EFFECTS, *simulated], include=_ALL_COEFFS,
                          acting={t: _ALL_COEFFS for t in kinds}, fixed=())
    p = _truth_point(model, coeffs, effects)
    cols = [i for i, role in enumerate(model.roles)
            if role.kind in ("bias", "radius") or (role.kind == "coef" and role.key in designed)
            or (role.kind == "effect" and role.key in UNKNOWN_EFFECTS)]
    J = model.jacobian(p, cols)
    held = holds(J, model.columns(cols, p))
    keep = [c for c, i in enumerate(cols) if model.params[i].name not in held]
    C = lstsq_svd(J[:, keep], np.zeros(J.shape[0])).cov
    names = [model.params[cols[c]].name for c in keep]
    cov = {(a, b): float(C[i, k]) for i, a in enumerate(names) for k, b in enumerate(names)}
    out: dict = {COVARIANCE: cov}
    for (kind, rig), t in [(("", "*"), None), *tests.items()]:
        for method in (["joint_ml"] if t is None else [e.method for e in registry.for_test(kind) if e.crb]):
            out.update({(k, method, rig): cov[(k, k)] for k in _ALL_COEFFS if (k, k) in cov})
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


def wilson(k: int, n: int, z: float | None = None) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n, ``z`` standard normal deviates
    wide [1] (default the two-sided 95 % interval's)."""
    if n == 0:
        return 0.0, 1.0
    z = float(stats.norm.isf((1 - 0.95) / 2)) if z is None else z
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def run_study(scenario, n: int = 200, seed: int = 0, workers: int = 1, *, crb: bool = True) -> StudyResult:
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
        results = [_one(j) for j in jobs]
    seconds = time.perf_counter() - t0
    failures = [r for r in results if isinstance(r, str)]
    ok = [r for r in results if not isinstance(r, str)]
    vals: dict[tuple[str, str, str], list[tuple[float, float]]] = defaultdict(list)
    records: dict[tuple[str, str, str], CoefficientResult] = {}
    for rows in ok:
        for name, method, rig, v, u, rec in rows:
            vals[(name, method, rig)].append((v, u))
            records.setdefault((name, method, rig), rec)
    truth = truth_table(sc, records)
    quiet = _one((_noise_free(sc), sc.seed if sc.seed is not None else seed))
    nf = {} if isinstance(quiet, str) else {(a, b, c): v for a, b, c, v, *_ in quiet}
    bounds = cramer_rao(sc, seed) if crb else {}
    table = []
    for key, vu in vals.items():
        name, method, rig = key
        x = np.array([a for a, _ in vu])
        u = np.array([b for _, b in vu])
        m = len(x)
        sd = float(np.std(x, ddof=1)) if m > 1 else float("nan")
        u_rms = float(np.sqrt(np.mean(u**2)))
        tv, tnote = truth.get(key) or truth.get((name, method, "*")) or combination_truth(key, records[key].factors, truth) or (
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
            cs.coverage_wilson = wilson(int(inside.sum()), m, 1.96)
            with np.errstate(divide="ignore", invalid="ignore"):
                z = (x - tv) / u
            z = z[np.isfinite(z)]
            cs.z_sd = float(np.std(z, ddof=1)) if z.size > 1 else None
            lo, hi = cs.coverage_wilson
            cs.status = "ok" if lo <= TARGET <= hi else ("UNDER" if hi < TARGET else "OVER")
            cs.bias_over_sd = cs.bias / sd if sd > 0 else None
        b = next((bounds[k] for k in (key, (name, method, "*")) if bounds.get(k) is not None), None)
        if b is None and bounds:
            b = combination_bound(name, records[key].factors, bounds[COVARIANCE])
        if b is not None and b > 0 and tv is not None and m > 1:
            cs.crb_sd = math.sqrt(b)
            cs.var_over_crb = sd**2 / b
            cs.var_over_crb_interval = ((m - 1) * sd**2 / stats.chi2.ppf(0.975, m - 1) / b,
                                        (m - 1) * sd**2 / stats.chi2.ppf(0.025, m - 1) / b)
        table.append(cs)
    order = registry.display_order()
    cnames = list(COEFFICIENTS)
    table.sort(key=lambda s: (order.get(s.method, 9), s.rig_id,
                              cnames.index(s.name) if s.name in cnames else 99, s.name))
    return StudyResult(scenario=sc.name, n=n, seed=seed, workers=workers, seconds=seconds,
                       seconds_per_campaign=seconds * max(workers, 1) / max(n, 1), failures=failures,
                       coefficients=table, band=K_COVER * math.sqrt(TARGET * (1 - TARGET) / max(n, 1)))


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
