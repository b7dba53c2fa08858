"""Test radius of a centrifuge (paper 000 §2.1).

* :func:`test_radius_static` — static back-calculation, eqs 4–6, with the misprint of
  eq 5 corrected (a_g = E_a/K1 − K0, not E_a/(K1 − K0)), the earth rate and the total
  misalignment lambda_c included.
* :func:`test_radius_iterative` — the iterative regression of eq 7 on both polarities.

Radii are the distances from the spindle axis to the accelerometer's effective mass
centre for the two IA polarities: '+' (IA towards the spindle, phi = 0) and '-'
(IA away, phi = 180 deg).  Units: m, rad, m/s^2, rad/s.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..constants import G_STANDARD
from ..physics.geometry import geometry_of
from ..physics.instrument import indicated_acceleration
from ..physics.rigs import NOMINAL, centrifuge_specific_force
from .adequacy import DwellFit, weighted_dwell_fit
from .dwells import dwell_columns, merged_dwell_columns, noise_model, rest_mean


def centripetal_unit_input(meta: Mapping, radius_m: float = 1.0, mass_centre_offset: float = 0.0) -> np.ndarray:
    """Specific force on (IA, PA, OA) [m/s2] per unit (rad/s)^2 of table rate.

    The centripetal part of :func:`accelcal.physics.rigs.centrifuge_specific_force` (rate 1
    minus rate 0, no earth rate) for a turning centre at ``radius_m`` [m] and the effects.md
    ``mass_centre_offset`` [m] along the first plane axis; at the defaults, the unit vector
    towards the spindle in instrument axes.
    """
    eff = {"mass_centre_offset": float(mass_centre_offset)}
    F = centrifuge_specific_force(meta, {"table_rate_rad_s": np.array([1.0, 0.0])}, eff, radius_m=radius_m)
    return F[0] - F[1]


def radial_input_columns(meta: Mapping, rate: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d a / d R and d a / d r of the signed input a = f . direction.

    Parameters
    ----------
    meta : mapping
        The run's metadata.
    rate : ndarray
        Logged table rate of each dwell [rad/s] (the earth rate is added by the forward model).
    direction : (3,) ndarray
        Unit vector in instrument axes (the pair's nominal direction to the spindle).

    Returns
    -------
    dR, dr : ndarray
        [m/s2 per m]: the specific force of :func:`accelcal.physics.rigs.centrifuge_specific_force`
        (earth rate included) along ``direction`` per metre of turning-centre radius and per
        metre of mass-centre offset.  The centripetal input is linear in both, so
        a = R dR + r dr exactly.
    """
    d = {"table_rate_rad_s": np.asarray(rate, float)}
    f0 = centrifuge_specific_force(meta, d, NOMINAL, radius_m=0.0) @ direction
    fR = centrifuge_specific_force(meta, d, NOMINAL, radius_m=1.0) @ direction
    fr = centrifuge_specific_force(meta, d, {**NOMINAL, "mass_centre_offset": 1.0}, radius_m=0.0) @ direction
    return fR - f0, fr - f0


@dataclass
class StaticRadius:
    """Result of :func:`test_radius_static` for one IA polarity ('+' or '-').

    Attributes
    ----------
    radius_m, std_uncertainty_m : float
        R [m] and its GUM u (K0 cancelling exactly, correlations kept).
    std_uncertainty_printed_m : float
        u by the form printed under eq 6 (a_g and lambda_c independent) [m].
    lambda_c_rad, u_lambda_c_rad : float
        Total misalignment of IA to the horizontal (eq 4) [rad].
    omega_g, a_g : list of float
        Logged rate [rad/s] and a_g [m/s2] of each reference dwell.
    budget : list of dict
        Contribution of each input [m].
    """
    polarity: str
    radius_m: float
    std_uncertainty_m: float          # GUM, K0 cancelling exactly (correlations kept)
    std_uncertainty_printed_m: float  # the form printed under eq 6 (a_g and lambda_c independent)
    lambda_c_rad: float
    u_lambda_c_rad: float
    omega_g: list[float]
    a_g: list[float]
    budget: list[dict] = field(default_factory=list)


def static_radius_column(meta: Mapping, rate: np.ndarray, lam: float) -> np.ndarray:
    """d a_IA / d R [m/s2 per m] of dwells at logged rates ``rate`` [rad/s] with IA tilted by
    ``lam`` [rad] (effects.md ``ia_tilt``): s omega_z^2 cos(lam) of the forward model
    (:func:`accelcal.physics.rigs.centrifuge_specific_force`, earth rate included), the
    denominator of paper 000 eq 6."""
    d = {"table_rate_rad_s": np.asarray(rate, float)}
    eff = {**NOMINAL, "ia_tilt": float(lam)}
    return (centrifuge_specific_force(meta, d, eff, radius_m=1.0)[:, 0]
            - centrifuge_specific_force(meta, d, eff, radius_m=0.0)[:, 0])


def geometric_static_radius(meta: Mapping, st: "StaticRadius", coeffs: Mapping[str, float]) -> float:
    """The radius at which the forward model reproduces the static back-calculation's input.

    Eq 6 takes the rate-dependent part of the indicated acceleration, A_k = (E_a,k - E0)/K1,
    for the centripetal input; the instrument's own terms (K2 a^2, Koq a|a|, K3 a^3, the IA
    cross term with gravity on the vertical axis) are in it.  This returns the R' for which
    mean_k [A(f_k(R')) - A(f_rest)] = mean_k A_k, with f from
    :func:`accelcal.physics.rigs.centrifuge_specific_force` (IA tilted by lambda_c, earth rate)
    and A from :func:`accelcal.physics.instrument.indicated_acceleration` with ``coeffs``
    [SI]; K0 and K1 cancel.  Secant iteration from eq 6's R.
    """
    g = float(meta["g_local_m_s2"])
    eff = {**NOMINAL, "ia_tilt": float(st.lambda_c_rad)}
    c = {k: v for k, v in coeffs.items() if k not in ("K0", "K1")}
    rates = np.r_[np.asarray(st.omega_g, float), 0.0]
    target = float(np.mean(st.a_g)) - st.lambda_c_rad * g

    def h(R):
        A = indicated_acceleration(c, centrifuge_specific_force(meta, {"table_rate_rad_s": rates}, eff, radius_m=R))
        return float(np.mean(A[:-1] - A[-1])) - target

    R0, R1 = st.radius_m, st.radius_m * (1.0 + 1e-6)
    h0, h1 = h(R0), h(R1)
    for _ in range(50):
        if h1 == h0:
            break
        R0, R1, h0 = R1, R1 - h1 * (R1 - R0) / (h1 - h0), h1
        h1 = h(R1)
        if abs(R1 - R0) <= 1e-15 * abs(R1):
            break
    return float(R1)


def test_radius_static(meta: Mapping, data, K0: float, K1: float,
                       u_K0: float = 0.0, u_K1: float = 0.0, level_g: float = 1.0) -> StaticRadius:
    """Static back-calculation of the test radius (He & Yin 2017, paper 000 eqs 4–6).

    .. math::

        \\lambda_c = (E_0/K_1 - K_0)/g \\quad (4), \\qquad a_g = E_a/K_1 - K_0 \\quad (5),
        \\qquad R_g = \\frac{a_g - \\lambda_c g}{s \\, \\omega_z^2 \\cos\\lambda_c} \\quad (6)

    (eq 5 corrected: the paper prints E_a/(K1 - K0)).

    Parameters
    ----------
    meta : mapping
        Typed metadata of an IA-radial centrifuge run (``g_local_m_s2`` [m/s2]).
    data : DataFrame or mapping of arrays
        The run's readings (``step``, ``table_rate_rad_s`` [rad/s], ``table_angle_deg``
        [deg], ``output`` [output_unit]).
    K0, K1 : float
        Bias [m/s2] and scale factor [output_unit/(m/s2)] from the tumble.
    u_K0, u_K1 : float
        Their standard uncertainties.
    level_g : float
        Reference level of eq 5 [g]: the dwells nearest it (up and down sweeps) are used.

    Returns
    -------
    StaticRadius
        R [m] with its GUM u (K0 cancels: a_g - lambda_c g = (E_a - E0)/K1; inputs E_a, E0,
        K1, omega) and the u of the form printed under eq 6 (a_g and lambda_c independent,
        u(K0) counted twice), lambda_c [rad].

    Notes
    -----
    E0 is the mean rest output over the table azimuths (eq 4: the spindle tilt cancels).
    The denominator s omega_z^2 cos(lambda_c) is the regressor of R of the forward model
    (:func:`static_radius_column`: earth rate in omega_z, exact for either rotation sense).
    """
    s = geometry_of(meta).ia_polarity
    if s is None:
        raise ValueError(f"run {meta.get('run_id')} is not an IA-radial mount")
    g = float(meta["g_local_m_s2"])
    dw = dwell_columns(meta, data, {"earth_rate": 1.0})
    E0, uE0, _ = rest_mean(dw)
    lam = (E0 / K1 - K0) / g
    u_lam = np.sqrt(u_K0**2 + (uE0 / K1) ** 2 + (E0 / K1**2 * u_K1) ** 2) / g
    mv = ~dw["rest"]
    lvl = np.abs(dw["mean_output"][mv] - E0) / abs(K1) / g
    k = np.abs(lvl - level_g)
    # the nearest dwells (a nan level is never one, as no level is when all are nan)
    ref = np.flatnonzero(mv)[k <= (np.nanmin(k) if np.any(k == k) else np.nan) + 0.05]
    Ea = dw["mean_output"][ref]
    uEa = np.sqrt(dw["var_output"][ref] / dw["n"][ref])
    wz = dw["omega_z"][ref]
    w = dw["rate"][ref]
    uw = dw["rate_std"][ref] / np.sqrt(dw["n"][ref])
    a_g = Ea / K1 - K0
    # eq 6's denominator is the regressor of R: d a_IA / d R = s omega_z^2 cos(lambda_c) of the
    # forward model with IA tilted by lambda_c (effects.md ia_tilt), earth rate included
    cR = static_radius_column(meta, w, lam)
    Rk = (a_g - lam * g) / cR
    R = float(Rk.mean())
    m = len(Rk)
    # GUM: R = mean_k (E_a,k − E0) / (K1 c_R,k)
    dR_dEa = 1.0 / (K1 * cR) / m
    dR_dE0 = -float(np.sum(1.0 / (K1 * cR))) / m
    dR_dK1 = -R / K1
    dR_dw = -2.0 * Rk / wz * np.sign(wz) * np.sign(w) / m   # d(omega_z)/d(omega) = s_rot
    terms = [("E_a", float(np.sqrt(np.sum((dR_dEa * uEa) ** 2)))),
             ("E0", abs(dR_dE0) * uE0), ("K1", abs(dR_dK1) * u_K1),
             ("omega", float(np.sqrt(np.sum((dR_dw * uw) ** 2))))]
    u = float(np.sqrt(sum(t[1] ** 2 for t in terms)))
    # the printed form, per reference dwell then averaged (as independent dwells)
    u_ag = np.sqrt(u_K0**2 + (uEa / K1) ** 2 + (Ea / K1**2 * u_K1) ** 2)
    u_pr_k = np.sqrt(u_ag**2 + (g * u_lam) ** 2 + (2 * Rk * w * uw) ** 2) / w**2
    u_pr = float(np.sqrt(np.mean(u_pr_k**2)))
    budget = [{"quantity": q, "contribution_m": c} for q, c in terms]
    return StaticRadius("+" if s > 0 else "-", R, u, u_pr, float(lam), float(u_lam),
                        [float(x) for x in w], [float(x) for x in a_g], budget)


# ---------------------------------------------------------------- iterative (eq 7)

def polarity_design(a: np.ndarray, pol: np.ndarray, order: int) -> tuple[np.ndarray, list[str]]:
    """Regressors of eq 7 / eq 9 (He & Yin 2017, paper 000).

    Parameters
    ----------
    a : ndarray
        Signed input of each row [m/s2] (:meth:`PairData.inputs`).
    pol : ndarray
        Polarity of each row, +1 / -1.
    order : int
        1: K0+-, b+-; 2: + c2 a^2 and d a|a| (the polarity-odd quadratic, eq 9's Koq term);
        3: + c3 a^3.

    Returns
    -------
    X, names : ndarray, list of str
        Columns [1, 1, m/s2, m/s2, (m/s2)^2, (m/s2)^2, (m/s2)^3]; each polarity's own terms
        are zero for the other's rows.
    """
    p = (pol > 0).astype(float)
    m = 1.0 - p
    cols = [p, m, a * p, a * m]
    names = ["K0+", "K0-", "b+", "b-"]
    if order >= 2:
        cols += [a**2, a * np.abs(a)]
        names += ["c2", "d"]
    if order >= 3:
        cols.append(a**3)
        names.append("c3")
    return np.column_stack(cols), names


@dataclass
class PairData:
    """Dwell data of a mount pair, stacked: one row per dwell group (rest merged per run).

    Attributes
    ----------
    cols : dict of ndarray
        n, mean_output, ss_within, dof_pe, rate, omega_z, time_mid, sweep, pol, rest, run_id
        (:func:`~accelcal.estimators.dwells.merged_dwell_columns` of each run, stacked).
    K1 : float
        Scale factor the outputs are divided by [output_unit/(m/s2)].
    metas : dict
        Polarity (+1 / -1) -> the run's metadata.
    """
    cols: dict
    K1: float
    metas: dict = field(default_factory=dict)

    @classmethod
    def from_runs(cls, runs: list[tuple[Mapping, pd.DataFrame, int]], K1: float) -> "PairData":
        metas = {pol: meta for meta, _, pol in runs}
        runs_cols = [merged_dwell_columns(meta, data) for meta, data, _ in runs]
        if not runs_cols:
            raise ValueError("a mount pair needs its runs")
        cols = {k: np.concatenate([c[k] for c in runs_cols]) for k in runs_cols[0]}
        cols["pol"] = np.concatenate([np.full(len(c["n"]), pol, dtype=np.int64)
                                      for c, (_, _, pol) in zip(runs_cols, runs)])
        cols["run_id"] = np.concatenate([np.full(len(c["n"]), str(meta.get("run_id", "")), dtype=object)
                                         for c, (meta, _, _) in zip(runs_cols, runs)])
        return cls(cols, K1, metas)

    @property
    def table(self) -> pd.DataFrame:
        """:attr:`cols` as a DataFrame (for a person's tables; the fits read :meth:`column`)."""
        return pd.DataFrame(self.cols)

    def column(self, name: str) -> np.ndarray:
        """The column ``name`` of every row (not to be changed: the pair is read only)."""
        return self.cols[name]

    def subset(self, keep: np.ndarray) -> "PairData":
        """The pair restricted to the rows ``keep``."""
        return PairData({k: v[keep] for k, v in self.cols.items()}, self.K1, self.metas)

    @property
    def direction(self) -> np.ndarray:
        """Unit vector towards the spindle of the pair's first polarity (phi0 < 180 deg), in
        instrument axes, from the forward model (:func:`centripetal_unit_input`)."""
        meta = self.metas[1] if 1 in self.metas else self.metas[-1]
        u = centripetal_unit_input(meta)
        return u if 1 in self.metas else -u

    def input_columns(self) -> tuple[np.ndarray, np.ndarray]:
        """d a / d R and d a / d r of every row (:func:`radial_input_columns`): a is the
        specific force along :attr:`direction`, positive for the '+' run, negative for '-'.
        Computed once (read-only arrays): the iterative radius asks for them at every order
        and g range, and the table and metadata do not change after the pair is built."""
        taken = self.__dict__.get("_input_columns")
        if taken is not None:
            return taken
        pol = self.column("pol")
        rate = self.column("rate").astype(float, copy=False)
        dR, dr = np.zeros(len(pol)), np.zeros(len(pol))
        u = self.direction
        for p, meta in self.metas.items():
            k = pol == p
            dR[k], dr[k] = radial_input_columns(meta, rate[k], u)
        dR.setflags(write=False)
        dr.setflags(write=False)
        self.__dict__["_input_columns"] = (dR, dr)
        return dR, dr

    def inputs(self, R: float | Mapping[int, float], r: float = 0.0) -> np.ndarray:
        """Signed input a [m/s2] of eq 7 / eq 9 for every row, from the forward model: a
        turning centre at R [m] (or one radius per polarity, {+1: R+, -1: R-}) with the
        mass centre r [m] along the first plane axis (effects.md ``mass_centre_offset``)."""
        dR, dr = self.input_columns()
        R = np.where(self.column("pol") > 0, R.get(1, 0.0), R.get(-1, 0.0)) if isinstance(R, Mapping) else float(R)
        return R * dR + r * dr

    def fit(self, a: np.ndarray, order: int, subtract_a: bool) -> DwellFit:
        """Weighted fit of y = E/K1 (− a when subtract_a) on the eq 7/9 regressors of every
        dwell group, with the noise model fitted on them."""
        T = {c: self.column(c) for c in ("mean_output", "ss_within", "n", "dof_pe", "pol", "time_mid",
                                         "sweep", "rest")}
        y = T["mean_output"] / self.K1 - (a if subtract_a else 0.0)
        ssw = T["ss_within"] / self.K1**2
        n = T["n"].astype(float)
        var = ssw / np.maximum(T["dof_pe"], 1)
        s0, k2 = noise_model(np.abs(a), var, T["dof_pe"] + 1)
        sigma2 = s0 + k2 * a**2
        X, names = polarity_design(a, T["pol"], order)
        fit = weighted_dwell_fit(X, names, y, n, ssw, sigma2, time=T["time_mid"],
                                 level=np.abs(a), sweep=T["sweep"],
                                 moving=~T["rest"], group=T["pol"],
                                 dof_pe_rows=T["dof_pe"])
        fit.extra.update(noise_s0=float(np.sqrt(s0)), noise_k=float(np.sqrt(k2)), n_groups=int(len(y)))
        return fit


@dataclass
class IterativeRadius:
    """Result of :func:`test_radius_iterative`.

    Attributes
    ----------
    order : int
        Model order of eq 7.
    g_max : float or None
        Upper end of the g range [g] (None: full range).
    R_plus, R_minus, u_plus, u_minus : float
        Radii of the two IA polarities and their standard uncertainties [m].
    iterations : int
    fit : DwellFit
        The last regression, with its adequacy.
    """
    order: int
    g_max: float | None              # g (standard), None = full range
    R_plus: float
    R_minus: float
    u_plus: float
    u_minus: float
    iterations: int
    fit: DwellFit


def test_radius_iterative(pair: PairData, R0_plus: float, R0_minus: float, order: int,
                          g_max: float | None = None, u_K1_rel: float = 0.0,
                          tol: float = 1e-11, max_iter: int = 30) -> IterativeRadius:
    """Iterative regression of paper 000 eq 7 on both IA polarities (He & Yin 2017).

    a_i± = R± d a_IA / d R, the IA specific force of the forward model at the current radii
    (:meth:`PairData.inputs`; ±omega_z^2 R± with the earth rate in omega_z); fit
    E/K1 − a_i = K0± + c± a_i± + [K2 a_i^2 + Koq a_i|a_i|]_(order>=2) + [K3 a_i^3]_(order 3)
    (the odd quadratic is included from order 2: it is separable because both polarities
    are measured, paper 000 §3.1); rescale R± <- R± (1 + c±) and repeat until |c±| < tol.
    R± = R0± prod(1 + c±_k).  u(R±) = R± sqrt(u(c±)^2 + (u(K1)/K1)^2): the radius scales
    as 1/K1 of the tumble.

    The loop is the paper's fixed-point rescaling, not a Gauss–Newton step: each pass is a
    linear weighted regression (:meth:`PairData.fit`) at the current inputs, with the
    higher-order terms and the noise model (the weights) refitted whole and their dependence
    on R± left out of the step.  It stops where c± = 0, the paper's answer; from order 2 the
    quadratic and cubic terms are shared by both polarities, so that point need not be the
    least-squares minimum over R±.
    """
    pol = pair.column("pol")
    dR, _ = pair.input_columns()            # a_i+- = R+- d a_IA / d R of the forward model
    Rp, Rm = float(R0_plus), float(R0_minus)
    gm = None if g_max is None else g_max * G_STANDARD
    it = 0
    sub = None
    for it in range(1, max_iter + 1):
        a = np.where(pol > 0, Rp, Rm) * dR
        # the g range is judged on the starting radii so the dwell set does not change
        if it == 1:
            keep = np.ones(len(pol), bool) if gm is None else (np.abs(a) <= gm * 1.02)
            sub = pair if keep.all() else pair.subset(keep)
        fit = sub.fit(a[keep], order, subtract_a=True)
        cp, cm = fit.value("b+"), fit.value("b-")
        Rp *= 1.0 + cp
        Rm *= 1.0 + cm
        if max(abs(cp), abs(cm)) < tol:
            break
    up = Rp * np.hypot(fit.std_error("b+"), u_K1_rel)
    um = Rm * np.hypot(fit.std_error("b-"), u_K1_rel)
    return IterativeRadius(order, g_max, Rp, Rm, float(up), float(um), it, fit)


def g_levels(pair: PairData, R_plus: float, R_minus: float) -> list[float]:
    """The distinct centripetal levels of the pair's dwells.

    Parameters
    ----------
    pair : PairData
    R_plus, R_minus : float
        Polarity radii [m].

    Returns
    -------
    list of float
        |a| of the moving dwells [g, standard], rounded to 0.1 g.
    """
    a = np.abs(pair.inputs({1: R_plus, -1: R_minus}))[~pair.column("rest")]
    return sorted({round(float(x) / G_STANDARD, 1) for x in a})


# the paper's names start with "test_"; tell pytest they are not tests
test_radius_static.__test__ = False
test_radius_iterative.__test__ = False
