"""Gravity (dividing-head tumble) calibration with an initial misalignment angle (paper 003).

A dividing head turns the accelerometer about a horizontal axis in the gravity
field (drop-format.md, ``test: tumble``).  With IA on ``cos_axis = +IA`` and OA on
``sin_axis = +OA`` the specific force at head angle theta is (paper 003)

    a_i = g cos(theta + theta0),   a_o = g sin(theta + theta0)

and the instrument model (effects.md) reduces to

    E = K1 (K0 + a_i + K2 a_i^2)                                  (paper 003, model)

with E in the run's ``output_unit``, K0 in m/s^2, K1 in output_unit per m/s^2,
K2 in s^2/m and theta0 in rad.  Other axis assignments (``-IA``, IA on the
``sin_axis``) only change the phase and sign of a_i.

Paper 003 is a configuration of the one fit: the run's readings are the cells of a
:class:`accelcal.fitting.model.CampaignModel` (the forward model
:func:`accelcal.physics.rigs.rig_output` with theta0 as the ``initial_misalignment``
effect), K0, K1, K2, theta0 (and any extra terms) free, every other coefficient held at
0, solved by :func:`accelcal.fitting.core.gauss_newton` with equal weights; the paper's
reporting (lack of fit against the pure error of the head positions, two-position values,
Birge-ratio pooling of a campaign's runs, theta0 per head) is this module's.

**Aliasing (paper 003, note; effects.md).**  In a single tumble an OA (or, more
generally, the other in-plane axis) cross-axis sensitivity Ko cannot be told apart
from theta0: K1 (g cos psi + Ko g sin psi) = K1 sqrt(1 + Ko^2) g cos(psi - atan Ko),
so with +IA/+OA the fit returns theta0 - atan(Ko) (and K1 sqrt(1 + Ko^2)), up to a
K2-sized residual.  The fit does **not** estimate Ko; its theta0 is
"misalignment + cross-axis term" and must be reported as such.  Likewise the
quadratic term of the other in-plane axis aliases: Koo g^2 sin^2 psi = Koo g^2 -
Koo g^2 cos^2 psi, so the fitted K2 is K2 - Koo and the fitted K0 is K0 + Koo g^2.
The IA x OA cross term Kio (g^2 sin(2 psi)/2) and the cubic K3 are separable and
may be added as extra terms; without them they show up as lack of fit (and,
on a symmetric set of head angles, do not bias K0, K2, theta0; K3 scales K1 by
1 + 3 K3 g^2 / 4).  K3 and the odd quadratic Koq are nearly aliased: a_i |a_i| =
g^2 (8/(3 pi) cos psi + 8/(15 pi) cos 3 psi - ...), so a K3-only fit returns about
K3 + 32 Koq / (15 pi g); only the weak cos 5 psi and higher harmonics separate them.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import pandas as pd

from ..constants import T_REF_C
from ..effects import (CROSS_AXIS_TERM, CROSS_TERM, SQUARE_TERM, combination_formula, combination_name,
                       si_unit)
from ..fitting.core import FitResult, Parameter, ParameterSet, birge_ratio, finish_fit, gauss_newton, lstsq_svd
from ..fitting.data import Groups, RunCells
from ..fitting.distributions import chi2_sf
from ..fitting.model import ACTING, CampaignModel
from ..physics.axes import AXES, parse_signed_axis
from ..physics.geometry import TumbleHead, geometry_of
from ..results import BudgetTerm, CoefficientResult, FitCheck, display_number
from . import registry
from . import uncertainty as unc
from .adequacy import pure_error_test
from .records import Records, TumbleCoefficient, run_columns

#: Method id of the tumble fit's records (paper 003).
METHOD = "tumble_lm"

#: Parameters of the tumble fit, in order (effects.md names; theta0 = ``initial_misalignment``).
PARAMS = ("K0", "K1", "K2", "theta0")

_ALIAS_NOTE = ("theta0 aliases with an OA cross-axis sensitivity Ko in a single tumble "
               "(paper 003): the value is theta0 - atan(Ko) for +IA/+OA")


def _head(meta: Mapping) -> TumbleHead:
    """The dividing head's axes (IA up at ``ia_phase_deg``); raises if IA lies on the head axis."""
    head = geometry_of(meta)
    if head.ia_phase_deg is not None:
        return head
    raise ValueError(f"tumble run has IA on the head axis ({meta.get('head_axis')!r}): "
                     "IA never turns in the vertical plane, K0/K1/K2 cannot be calibrated")


def _clean(data) -> pd.DataFrame:
    cols = {k: np.asarray(data[k]) for k in ("angle_deg", "output", "time_s", "position", "temp_c")
            if k in data or k in ("angle_deg", "output")}
    n = len(cols["angle_deg"])
    if any(len(v) != n for v in cols.values()):
        raise ValueError(f"tumble columns of different lengths: { {k: len(v) for k, v in cols.items()} }")
    ok = np.isfinite(cols["output"].astype(float)) & np.isfinite(cols["angle_deg"].astype(float))
    df = pd.DataFrame({k: v[ok] for k, v in cols.items()})
    if "position" not in df:
        df["position"] = pd.factorize(df["angle_deg"].round(9))[0]
    return df


def separable_extra_terms(meta: Mapping) -> dict[str, str]:
    """Instrument terms (besides K0, K1, K2) that one tumble can separate from theta0.

    Parameters
    ----------
    meta : mapping
        The tumble run's metadata.

    Returns
    -------
    dict
        Name -> SI unit: K3 [s4/m2], Koq [s2/m] and the cross term of IA with the other
        in-plane axis (Kio for OA, Kip for PA) [s2/m].  Ko/Kp (alias theta0) and Koo/Kpp
        (alias K2, K0) are not separable (paper 003 note); head-axis terms are zero.
    """
    return {k: si_unit(k) for k in ("K3", "Koq", CROSS_TERM[frozenset((0, _head(meta).other_axis))])}


def position_means(df: pd.DataFrame) -> pd.DataFrame:
    """Statistics of the output at each head position.

    Parameters
    ----------
    df : DataFrame
        ``position``, ``angle_deg`` [deg], ``output`` [output_unit].

    Returns
    -------
    DataFrame
        position, angle_deg [deg], n, mean_output, std_output, sem_output [output_unit].
    """
    grp = Groups(np.asarray(df["position"]))
    std = grp.std(df["output"])
    return pd.DataFrame({"position": grp.keys, "angle_deg": grp.mean(df["angle_deg"]), "n": grp.counts,
                         "mean_output": grp.mean(df["output"]), "std_output": std,
                         "sem_output": std / np.sqrt(grp.counts)})


@dataclass(frozen=True)
class TumbleRun:
    """Paper 003 on one run: the one fit's result and the paper's reporting of it.

    Attributes
    ----------
    run_id, rig_id : str
    head : TumbleHead
        The dividing head's axis assignment (physics.geometry).
    result : FitResult
        The core's result in :data:`PARAMS` order (+ ``extras``): K0 [m/s2], K1
        [output_unit/(m/s2)], K2 [s2/m], theta0 [rad]; residuals whitened by s, so its
        ``cov_noise`` is s^2 (J^T J)^+ and ``cov`` that times F when the lack-of-fit test fails.
    s, residual_rms : float
        sqrt(RSS / dof) and sqrt(mean(r^2)) of the readings [output_unit].
    n : int
        Readings used.
    position_means : DataFrame
        Per head position: position, angle_deg, n, mean_output, predicted, mean_residual
        [output_unit].
    g_local_m_s2 : float
    extras : tuple of str
        Extra instrument terms fitted (:func:`separable_extra_terms`).
    s_pure_error : float
        Within-position (pure error) standard deviation of the readings [output_unit].
    start : dict
        Start values by name (theta0 = 0; K0, K1, K2 from the nominal input).
    two_position : dict
        :func:`two_position` (or {'error': ...}).
    model_choice : dict or None
        The extended model chosen when the basic one failed its lack-of-fit test.
    flags : tuple of str
    """
    run_id: str
    rig_id: str
    head: TumbleHead
    result: FitResult
    s: float
    residual_rms: float
    n: int
    position_means: pd.DataFrame
    g_local_m_s2: float
    extras: tuple[str, ...] = ()
    s_pure_error: float = float("nan")
    start: dict = field(default_factory=dict)
    two_position: dict = field(default_factory=dict)
    model_choice: dict | None = None
    flags: tuple[str, ...] = ()

    @property
    def values(self) -> dict[str, float]:
        """Estimates by name [SI units of each parameter]."""
        return {k: self.result.value(k) for k in self.result.names}

    @property
    def std_uncertainties(self) -> dict[str, float]:
        """Standard uncertainties by name, lack-of-fit scaled [SI units]."""
        return {k: self.result.std(k) for k in self.result.names}

    @property
    def lack_of_fit(self) -> dict | None:
        """F, p, dof_lof = P - p, dof_pe = n - P, s_pure_error [output_unit], status of the
        test of the position means against the within-position scatter (``result.lof``);
        None when untestable."""
        lof = self.result.lof
        if lof.status == "untestable":
            return None
        return {"F": float(lof.statistic), "p": float(lof.p_value), "dof_lof": lof.dof_lof, "dof_pe": lof.dof_pe,
                "s_pure_error": self.s_pure_error, "status": lof.status}

    @property
    def dof(self) -> int:
        """Readings minus parameters."""
        return self.result.dof

    @property
    def group(self) -> str:
        """Instrument axis on the head axis: the runs of one group measure the same K0, K2 and
        theta0 (the other turning axis, whose square term aliases into K2, is the same)."""
        return AXES[self.head.head_axis]

    def u_parts(self, name: str) -> tuple[float, float, float]:
        """(u, u from the reading noise, lack-of-fit factor) of a fitted parameter."""
        return self.result.std(name), self.result.std_noise(name), float(self.result.lof.factor)


def reading_cells(meta: Mapping, cols: Mapping[str, np.ndarray], index: int = 0,
                  var_mean: np.ndarray | None = None) -> RunCells:
    """A run as cells of one reading each (paper 003 fits every reading): the campaign
    model's cell means are then the readings themselves; ``var_mean``: the variance of
    each reading [output_unit^2], else the run's noise model is left unset."""
    y = np.asarray(cols["output"], float)
    n = y.size
    return RunCells(index=index, meta=dict(meta), geometry=geometry_of(meta), cols=dict(cols), rate_derivative=None,
                    cid=np.arange(n), n=np.ones(n), y_rows=y, y=y, x_rows=np.zeros(n), x=np.zeros(n),
                    lines=np.zeros(n, int), var_mean=var_mean)


def _readings_model(meta: Mapping, df: pd.DataFrame) -> CampaignModel:
    """The campaign model of one tumble run whose cells are its readings, unweighted."""
    return CampaignModel([reading_cells(meta, {k: df[k].to_numpy() for k in df.columns})], ["initial_misalignment"],
                         include=("Kip", *ACTING["tumble"]), acting=ACTING)


def fit_run(meta: Mapping, data, extra_terms: Sequence[str] = ()) -> TumbleRun:
    """Levenberg-Marquardt fit of the paper 003 tumble model on every reading of a run.

    .. math::

        E = K_1 (K_0 + a_i + K_2 a_i^2), \\quad a_i = g \\cos(\\theta + \\theta_0)

    (Zhan & Cai, paper 003, with a_i from the head angle and the axis assignment; effects.md
    instrument model).

    Parameters
    ----------
    meta : mapping
        Typed run metadata: ``g_local_m_s2`` [m/s2], ``cos_axis``, ``sin_axis``,
        ``head_axis``, ``output_unit``.
    data : DataFrame or mapping
        ``angle_deg`` [deg], ``output`` [output_unit]; optional ``position``, ``time_s`` [s],
        ``temp_c`` [degC].
    extra_terms : sequence of str
        Separable instrument terms to add (:func:`separable_extra_terms`: K3 [s4/m2], Koq,
        Kio or Kip [s2/m]), started at 0.

    Returns
    -------
    TumbleRun
        K0 [m/s2], K1 [output_unit/(m/s2)], K2 [s2/m], theta0 [rad] (+ extras) with their
        covariance and lack of fit.

    Raises
    ------
    ValueError
        IA on the head axis, an extra term that is not separable, fewer than p + 1 readings
        at p - 1 or more distinct angles, or a singular design.

    Notes
    -----
    The model is :func:`_readings_model` with every coefficient but K0, K1, K2 and the
    extras held at 0; its Jacobian columns are the exact coefficient derivatives and the
    central difference of ``rig_output`` in theta0
    (:meth:`~accelcal.fitting.model.CampaignModel.jacobian`).  Start: theta0 = 0, K0, K1,
    K2 from a linear fit on the nominal input (paper 003 starts from the nominal
    sensitivity).  Solver: :func:`accelcal.fitting.core.gauss_newton` (Marquardt damping),
    unweighted (equal-variance readings).  Covariance: s^2 (J^T J)^+ with
    s^2 = RSS / (n - p), times the lack-of-fit factor F when the test of the position means
    against the within-position scatter fails; with as many positions as parameters the
    test is 'untestable' and the covariance counts reading noise only.
    """
    extras = tuple(extra_terms)
    allowed = separable_extra_terms(meta)
    bad = [e for e in extras if e not in allowed]
    if bad or len(set(extras)) != len(extras):
        raise ValueError(f"extra_terms {bad or extras} not separable in this tumble; allowed: {sorted(allowed)}")
    names = PARAMS + extras
    npar = len(names)
    df = _clean(data)
    n_ang = df["angle_deg"].round(6).nunique()
    if len(df) < npar + 1 or n_ang < npar - 1:
        raise ValueError(f"tumble fit of {npar} parameters needs >= {npar + 1} readings at >= "
                         f"{npar - 1} head angles, got {len(df)} readings at {n_ang} angles")
    model = _readings_model(meta, df)
    idx = [model.params.index[k] for k in ("K0", "K1", "K2", "initial_misalignment", *extras)]

    def point(q):
        p = np.zeros(len(model.params))
        p[idx] = q
        return p

    # start (paper 003: from the nominal sensitivity): theta0 = 0 and E linear in (K1 K0, K1,
    # K1 K2), fitted on the model's columns (1, a_i, a_i^2) at the nominal instrument
    b = lstsq_svd(model.jacobian(point(np.r_[0.0, 1.0, np.zeros(npar - 2)]), idx[:3]), model.y).x
    K1 = b[1] if b[1] != 0 else 1.0
    p0 = np.r_[b[0] / K1, K1, b[2] / K1, np.zeros(npar - 3)]
    gn = gauss_newton(lambda q: model.residual(point(q)), lambda q: model.jacobian(point(q), idx), p0,
                      max_iter=100, rtol=1e-14)
    r, y = gn.z, model.y
    n, rss = y.size, float(gn.z @ gn.z)
    s2 = rss / (n - npar)
    pm = position_means(df)
    grp = Groups(df["position"].to_numpy())
    pm["predicted"] = grp.mean(y - r)
    pm["mean_residual"] = pm["mean_output"] - pm["predicted"]
    # lack of fit: position-mean residuals against the within-position (pure error) scatter
    ss_lof = float((pm["n"] * pm["mean_residual"] ** 2).sum())
    ss_pe = float(((r - grp.mean(r)[grp.ids]) ** 2).sum())
    dof_lof, dof_pe = len(pm) - npar, n - len(pm)
    test = pure_error_test(ss_lof, dof_lof, ss_pe, dof_pe)
    # residuals whitened by s (equal-variance readings): the noise-model covariance is
    # s^2 (J^T J)^+, scaled by sqrt(F) when the lack-of-fit test fails
    w = 1.0 / np.sqrt(s2) if np.isfinite(s2) and s2 > 0 else 1.0
    unit = str(meta.get("output_unit", "out"))
    params = ParameterSet(Parameter(nm, nm, si_unit(nm, unit), value=float(v)) for nm, v in zip(names, p0))
    result = finish_fit(params, replace(gn, z=r * w, J=gn.J * w, chi2=rss * w * w), test)
    if result.rank < npar:
        raise ValueError(f"tumble fit is singular: the head angles do not separate {names}")
    return TumbleRun(str(meta.get("run_id")), str(meta.get("rig_id", "")), geometry_of(meta), result,
                     float(np.sqrt(s2)), float(np.sqrt(rss / n)), n, pm, float(meta["g_local_m_s2"]), extras,
                     float(np.sqrt(ss_pe / dof_pe)) if dof_pe > 0 else float("nan"),
                     dict(zip(names, map(float, p0))))


def _mean_at(pm: pd.DataFrame, angle: float, tol: float) -> float | None:
    """Mean output at the head angle ``angle`` [deg] (within ``tol``), None where there is none."""
    sel = np.abs((pm["angle_deg"].to_numpy() - angle + 180.0) % 360.0 - 180.0) <= tol
    return float(np.average(pm["mean_output"].to_numpy()[sel], weights=pm["n"].to_numpy(float)[sel])) \
        if sel.any() else None


def two_position(meta: Mapping, data, angle_tol_deg: float = 1e-3, means: pd.DataFrame | None = None) -> dict:
    """Two-position (and four-point) closed forms (paper 003), for comparison with the LM fit.

    With E_up, E_down the mean outputs where IA nominally points up and down (head angles
    0 and 180 deg for cos_axis = +IA; the IA phase is taken from the axis assignment):

        SH = (E_up - E_down) / (2 g)     output_unit per m/s^2   (-> K1)
        KH = (E_up + E_down) / 2         output_unit             (-> K0 = KH / SH, m/s^2)

    With theta0 and K2 (closed form): E_up/down = K1 (K0 +- g cos theta0 + K2 g^2 cos^2 theta0),
    so SH = K1 cos theta0 and KH / SH = (K0 + K2 g^2 cos^2 theta0) / cos theta0: the method
    takes the misalignment for a scale-factor change and K2 g^2 for bias.

    Where the quadrature positions (IA horizontal, E_90 and E_270 at phase +90/+270 deg)
    exist too, the four-point closed form is exact for the paper 003 model (no Ko):

        K1 cos theta0 = (E_0 - E_180)/(2g),  K1 sin theta0 = (E_270 - E_90)/(2g)
        K1 K2 g^2 cos(2 theta0) = (E_0 + E_180 - E_90 - E_270)/2
        K1 (K0 + K2 g^2 / 2) = (E_0 + E_90 + E_180 + E_270)/4

    ``means``, when given, are the run's :func:`position_means` (``data`` is then not read).

    Returns dict: E_up, E_down (output_unit), SH, KH, K1, K0 (two-position), and when
    available 'four_point': dict(K0, K1, K2, theta0, E_90, E_270); g_local_m_s2; ia_phase_deg.
    Raises ValueError if the up/down positions are missing.
    """
    g = float(meta["g_local_m_s2"])
    phase = _head(meta).ia_phase_deg
    pm = position_means(_clean(data)) if means is None else means
    Eu, Ed = _mean_at(pm, phase, angle_tol_deg), _mean_at(pm, phase + 180.0, angle_tol_deg)
    if Eu is None or Ed is None:
        raise ValueError(f"two-position method needs readings at head angles {phase:g} and "
                         f"{(phase + 180) % 360:g} deg (IA up and down)")
    SH = (Eu - Ed) / (2 * g)
    KH = (Eu + Ed) / 2
    out = {"E_up": Eu, "E_down": Ed, "SH": SH, "KH": KH, "K1": SH, "K0": KH / SH,
           "g_local_m_s2": g, "ia_phase_deg": phase, "output_unit": str(meta.get("output_unit", "")),
           "four_point": None}
    E90, E270 = _mean_at(pm, phase + 90.0, angle_tol_deg), _mean_at(pm, phase + 270.0, angle_tol_deg)
    if E90 is not None and E270 is not None:
        s = (E270 - E90) / (2 * g)         # K1 sin theta0 (SH: K1 cos theta0)
        K1 = float(np.hypot(SH, s))
        th0 = float(np.arctan2(s, SH))
        K2 = (Eu + Ed - E90 - E270) / (2 * K1 * g**2 * np.cos(2 * th0))
        K0 = (Eu + Ed + E90 + E270) / (4 * K1) - K2 * g**2 / 2
        out["four_point"] = {"K0": float(K0), "K1": K1, "K2": float(K2), "theta0": th0,
                             "E_90": E90, "E_270": E270}
    return out



def fit_tumble_run(meta: Mapping, data) -> TumbleRun:
    """Paper 003 on one run, with its model adequacy.

    Fits K0, K1, K2, theta0 (:func:`fit_run`); when that fails its lack-of-fit test the IA
    cross term with the other in-plane axis (separable from theta0 in one tumble) is added
    and kept if it improves the fit.  A fit that stays inadequate is used and flagged (its u
    carries the lack-of-fit factor); one with as many positions as parameters is flagged as
    untestable.

    Returns
    -------
    TumbleRun
        With ``two_position``, ``model_choice`` and ``flags``.
    """
    run_id = str(meta.get("run_id"))
    fit = fit_run(meta, data)
    choice, flags = None, []
    lof = fit.result.lof
    if lof.status == "inadequate":
        cross = tuple(k for k in separable_extra_terms(meta) if k in ("Kio", "Kip"))
        try:
            fit2 = fit_run(meta, data, cross)
        except Exception:
            fit2 = None
        if fit2 is not None and fit2.result.lof.status != "untestable" and fit2.result.lof.p_value > lof.p_value:
            choice = {"run_id": run_id, "basic_lof_p": float(lof.p_value), "extended_terms": list(cross),
                      "extended_lof_p": float(fit2.result.lof.p_value)}
            fit, lof = fit2, fit2.result.lof
        if lof.status == "inadequate":
            flags.append(f"tumble {run_id}: model inadequate (lack-of-fit p = {lof.p_value:.2g}); "
                         f"used and flagged, u scaled by sqrt(F) = {math.sqrt(lof.statistic):.3g}")
    if fit.result.lof.status == "untestable":
        flags.append(f"tumble {run_id}: untestable: {len(fit.position_means)} head positions for "
                     f"{len(fit.result.names)} parameters leave no degrees of freedom to test the model; "
                     "its u counts reading noise only")
    try:
        tp = two_position(meta, data, means=fit.position_means)
    except Exception as exc:
        tp = {"error": str(exc)}
    return replace(fit, two_position=tp, model_choice=choice, flags=tuple(flags))


@dataclass(frozen=True)
class Pooled:
    """A quantity from one or more tumble runs: weighted mean with the Birge ratio applied.

    Attributes
    ----------
    name : str
        Record name (``'K0'``, ``'theta0[PA]'``, ...).
    key : str
        The fitted parameter.
    value, u : float
        Weighted mean [SI] and its standard uncertainty: 1/sqrt(sum w) times the Birge ratio
        when that exceeds 1.
    runs : tuple of TumbleRun
    birge, p_value : float
        Birge ratio sqrt(chi2 / (N - 1)) and P(chi2 > observed) (NaN for one run).
    disagree : bool
        p < 0.01: the runs disagree beyond their uncertainties.
    head : str
        The head axis of a row pooled per head in a campaign of several heads, else ''.
    """
    name: str
    key: str
    value: float
    u: float
    u_internal: float
    runs: tuple
    birge: float = float("nan")
    p_value: float = float("nan")
    disagree: bool = False
    head: str = ""

    @property
    def weights(self) -> np.ndarray:
        w = np.array([1.0 / r.u_parts(self.key)[0] ** 2 for r in self.runs])
        return w / w.sum()


def pool(name: str, key: str, runs: Sequence[TumbleRun], alpha: float = 0.01) -> Pooled:
    """Weighted mean of one fitted parameter over tumble runs, with the Birge ratio.

    .. math::

        \\bar x = \\frac{\\sum w_i x_i}{\\sum w_i}, \\quad w_i = u_i^{-2}, \\quad
        u(\\bar x) = \\frac{\\max(1, R_B)}{\\sqrt{\\sum w_i}}, \\quad
        R_B = \\sqrt{\\chi^2 / (N - 1)}

    (Birge 1932; :func:`accelcal.fitting.core.birge_ratio`).

    Parameters
    ----------
    name : str
        Record name.
    key : str
        The fitted parameter.
    runs : sequence of TumbleRun
    alpha : float
        The runs disagree when P(chi2 > observed) < alpha.

    Returns
    -------
    Pooled
    """
    vals = [r.values[key] for r in runs]
    us = [r.u_parts(key)[0] for r in runs]
    if len(runs) == 1:
        return Pooled(name, key, float(vals[0]), float(us[0]), float(us[0]), tuple(runs))
    if not all(np.isfinite(us)) or min(us) <= 0:
        return Pooled(name, key, float(np.mean(vals)), float("nan"), float("nan"), tuple(runs))
    mean, u_int, birge, dof = birge_ratio(vals, us)
    p = float(chi2_sf(birge ** 2 * dof, dof))
    return Pooled(name, key, mean, u_int * max(1.0, birge), u_int, tuple(runs), birge, p, p < alpha)


def _group_name(key: str, group: str, several: bool) -> str:
    return f"{key}[{group}]" if several else key


def pool_runs(runs: Sequence[TumbleRun]) -> dict[str, Pooled]:
    """The campaign's tumble quantities: K0 and K1 over every run, K2 and theta0 per head axis
    (never pooled across heads: a head about another axis measures K2 minus another square
    term, and its own misalignment), extra terms over the runs that fitted them.

    Returns
    -------
    dict
        record name -> Pooled; names carry the head axis (``theta0[PA]``) when the campaign has
        several head axes.
    """
    groups: dict[str, list[TumbleRun]] = {}
    for r in runs:
        groups.setdefault(r.group, []).append(r)
    several = len(groups) > 1
    out = {k: pool(k, k, runs) for k in ("K0", "K1")}
    for g, rr in groups.items():
        for k in ("K2", "theta0"):
            out[_group_name(k, g, several)] = replace(pool(_group_name(k, g, several), k, rr),
                                                      head=g if several else "")
    for k in sorted({e for r in runs for e in r.extras}):
        out[k] = pool(k, k, [r for r in runs if k in r.extras])
    return out


def k1_correction(g: float, koq: tuple[float, float], k3: tuple[float, float] | None) -> tuple[float, float]:
    """(delta, u(delta)): the tumble's K1 fits the cos(psi) fundamental of the IA input, which
    Koq a|a| and K3 a^3 also feed (cos|cos| has fundamental 8/(3 pi), cos^3 has 3/4), so
    K1_fitted = K1 (1 + delta) with delta = Koq g 8/(3 pi) + K3 g^2 3/4 (paper 003 model with
    the effects.md terms).  Koq [s2/m], K3 [s4/m2] as (value, u); g [m/s2]."""
    a, b = g * 8 / (3 * math.pi), 0.75 * g * g
    delta = koq[0] * a + (k3[0] * b if k3 else 0.0)
    return delta, math.hypot(koq[1] * a, (k3[1] * b) if k3 else 0.0)


_NOTES = {"theta0": _ALIAS_NOTE, "K2": "a single tumble gives K2 - Koo (Koo aliases)"}


def tumble_records(pooled: Mapping[str, Pooled], *, square_terms: Mapping[str, tuple[float, float]] | None = None,
                   k1: tuple[float, float] | None = None, out_unit: str = "out"
                   ) -> tuple[list[CoefficientResult], list[BudgetTerm], set[str]]:
    """Coefficient records and GUM budgets of the campaign's tumble quantities (paper 003).

    Parameters
    ----------
    pooled : mapping
        :func:`pool_runs`.
    square_terms : mapping, optional
        Square term of an axis (Kpp, Koo) -> (value, u) [s2/m] from the centrifuge: a tumble
        measures K2 minus the square term of its other turning axis, which is added back.
    k1 : (delta, u_delta), optional
        :func:`k1_correction`; K1 is divided by 1 + delta.
    out_unit : str
        The runs' output unit.

    Returns
    -------
    (coefficients, budget, corrected)
        Budgets: one type-A line per run (its fit; split into reading noise and lack-of-fit
        scaling for a single run), the between-run scatter (Birge ratio) when it exceeds the
        runs' u, and the centrifuge terms of a correction.  u = the budget's combined u.
        ``corrected``: the names of the rows the centrifuge's terms corrected (a K2 with its
        square terms added back, a K1 with Koq and K3 removed).
    """
    square_terms = square_terms or {}
    coeffs, budget, corrected = [], [], set()
    # K2: a head measures K2 minus the square term of its other turning axis; that is added
    # back per head, and the heads are pooled only when every one of them is corrected
    k2_rows = {n: q for n, q in pooled.items() if q.key == "K2"}
    if len(k2_rows) > 1 and all(SQUARE_TERM[q.runs[0].head.other_axis] in square_terms for q in k2_rows.values()):
        k2_rows = {"K2": pool("K2", "K2", tuple(r for q in k2_rows.values() for r in q.runs))}
    items = ([(n, q) for n, q in pooled.items() if q.key in ("K0", "K1")] + list(k2_rows.items())
             + [(n, q) for n, q in pooled.items() if q.key not in ("K0", "K1", "K2")])
    for name, q in items:
        (terms, pool_notes), note = _fit_terms(q), []
        value = q.value
        unit = si_unit(q.key, out_unit)
        if q.key == "K2":
            adds = {}
            for r, w in zip(q.runs, q.weights):
                sq = SQUARE_TERM[r.head.other_axis]
                adds[sq] = adds.get(sq, 0.0) + w
            if all(sq in square_terms for sq in adds):
                corrected.add(name)
                for sq, wsum in adds.items():
                    v, u = square_terms[sq]
                    value += wsum * v
                    terms.append((f"{sq} from the centrifuge (a tumble measures K2 - {sq})", v, u, wsum, "A", "normal"))
                note.append("one tumble measures K2 − " + "/".join(adds) + "; " + ", ".join(
                    f"{sq} = {square_terms[sq][0]:.3e} s2/m" for sq in adds) + " from the centrifuge added")
            else:
                note.append("measures K2 − " + "/".join(adds) + " (aliased in one tumble; no centrifuge "
                            + "/".join(adds) + " to correct it)")
        elif q.key == "K1":
            if k1 is not None:
                corrected.add(name)
                delta, u_delta = k1
                value = q.value / (1.0 + delta)
                terms = [(t[0], t[1], t[2], t[3] / (1.0 + delta), t[4], t[5]) for t in terms]
                terms.append(("Koq g 8/(3 pi) + K3 g^2 3/4 from the centrifuge (in the fitted K1)", delta, u_delta,
                              -value / (1.0 + delta), "A", "normal"))
                note.append(f"corrected for Koq and K3 from the centrifuge: fitted K1 = K1 (1 + {delta:.3e})")
            else:
                note.append("includes Koq g 8/(3 pi) + K3 g^2 3/4 (no centrifuge values to remove it)")
        else:
            if _NOTES.get(q.key):
                note.insert(0, _NOTES[q.key])
        if q.key == "theta0" and q.head:
            note.append("initial misalignment of this dividing head (never pooled across heads)")
        note += pool_notes
        gb = unc.linear_budget(name, terms, method=METHOD, rig_id=_rig(q), value=value)
        u = float(gb.u_c) if math.isfinite(q.u) else float("nan")
        dof = float(q.runs[0].dof) if len(q.runs) == 1 else None
        coeffs.append(TumbleCoefficient(name, float(value), u, unit, METHOD, _rig(q), dof, "; ".join(note),
                                        less=tuple(adds) if q.key == "K2" and name not in corrected else (),
                                        key=q.key, head=q.head))
        budget += gb.terms
    return coeffs, budget, corrected


def _rig(q: Pooled) -> str:
    rigs = sorted({r.rig_id for r in q.runs})
    return rigs[0] if len(rigs) == 1 else "+".join(rigs)


def _fit_terms(q: Pooled) -> tuple[list[tuple], list[str]]:
    """Type-A lines and notes of a pooled quantity: per run its fit (reading noise and
    lack-of-fit scaling apart for one run), and the Birge scatter of several runs."""
    if len(q.runs) == 1:
        r = q.runs[0]
        u, u_noise, factor = r.u_parts(q.key)
        rows = [(f"readings of {r.run_id}: LM fit (paper 003), s^2 (J'J)^-1", r.values[q.key], u_noise, 1.0,
                 "A", "normal")]
        notes = ["covariance from readings"]
        if factor > 1.0:
            rows.append((f"model inadequacy of {r.run_id}: lack-of-fit scaling sqrt(F) = {factor:.3g}", 0.0,
                         u_noise * math.sqrt(factor ** 2 - 1.0), 1.0, "A", "normal"))
        if r.result.lof.status == "inadequate":
            notes.append(f"lack of fit: F = {r.result.lof.statistic:.3g}, p = {r.result.lof.p_value:.2g}")
        if r.result.lof.status == "untestable":
            notes.append("untestable: as many head positions as parameters, u from reading noise only")
        return rows, notes
    rows = [(f"{r.run_id}: LM fit (paper 003)", r.values[q.key], r.u_parts(q.key)[0], float(w), "A", "normal")
            for r, w in zip(q.runs, q.weights)]
    notes = [f"weighted mean of {len(q.runs)} tumble runs"]
    if math.isfinite(q.birge) and q.birge > 1.0:
        rows.append((f"between-run scatter: Birge ratio {q.birge:.3g} ({len(q.runs)} runs)", 0.0,
                     q.u_internal * math.sqrt(q.birge ** 2 - 1.0), 1.0, "A", "normal"))
    if math.isfinite(q.birge):
        notes.append(f"Birge ratio {q.birge:.3g} (p = {q.p_value:.2g})" + ("; u scaled by it" if q.birge > 1 else ""))
    return rows, notes


def pooling_flags(pooled: Mapping[str, Pooled]) -> list[str]:
    """Flags for the pooled quantities whose runs disagree beyond their u.

    Parameters
    ----------
    pooled : mapping
        :func:`pool_runs`.

    Returns
    -------
    list of str
        One flag per quantity with P(chi2) < 0.01, naming each run's value and u and the
        Birge ratio applied.
    """
    return [f"tumble runs disagree on {name}: "
            + ", ".join(f"{r.run_id} {r.values[q.key]:.6g} ± {r.u_parts(q.key)[0]:.2g}" for r in q.runs)
            + f" (Birge ratio {q.birge:.3g}, p = {q.p_value:.2g}); not averaged silently: weighted mean "
            f"{q.value:.6g} with u scaled by the Birge ratio" for name, q in pooled.items() if q.disagree]


# ------------------------------------------------------------------ the campaign's tumble step

@dataclass(frozen=True)
class Reference:
    """K0 [m/s2] and K1 [output_unit/(m/s2)] with their standard uncertainties, and K2 [s2/m]:
    the scale reference of the centrifuge's radius (paper 000 §2.1): from the tumble
    (``from_tumble``) or from the IA pair at the nominal arm radius."""
    K0: float
    K1: float
    u_K0: float
    u_K1: float
    K2: float
    from_tumble: bool = True
    #: the cross-coupling terms the tumble determines, name -> (value [s2/m], u): the
    #: centrifuge's K_iv where its own mount pairs leave it undetermined
    cross: tuple[tuple[str, float, float], ...] = ()


@dataclass(frozen=True)
class TumbleStep:
    """The campaign's tumble runs, fitted and pooled (:func:`tumble_step`).

    Attributes
    ----------
    runs : tuple of TumbleRun
    pooled : dict
        Record name -> :class:`Pooled`.
    flags : tuple of str
    """
    runs: tuple[TumbleRun, ...]
    pooled: dict
    flags: tuple[str, ...]

    @property
    def reference(self):
        """K0, K1 (pooled over the runs, as fitted) and K2 for the centrifuge radius
        (:class:`Reference`)."""
        k2 = next(q for q in self.pooled.values() if q.key == "K2")
        K0, K1 = self.pooled["K0"], self.pooled["K1"]
        cross = tuple((q.key, q.value, q.u) for q in self.pooled.values()
                      if q.key in CROSS_TERM.values() and q.name == q.key)
        return Reference(K0.value, K1.value, K0.u, K1.u, k2.value, cross=cross)

    @property
    def g(self) -> float:
        """Local gravity of the tumble [m/s2]."""
        return float(self.runs[0].g_local_m_s2)


def tumble_step(runs: Sequence) -> TumbleStep | None:
    """The campaign's tumble runs (Zhan & Cai, paper 003).

    Parameters
    ----------
    runs : sequence
        RunFile-like tumble runs.

    Returns
    -------
    TumbleStep or None
        Every run fitted (:func:`fit_tumble_run`) and pooled (:func:`pool_runs`: weighted
        means with the Birge ratio applied and a flag when the runs disagree; K2 and theta0
        per head axis); None when no run could be fitted.
    """
    fitted, flags = [], []
    for run in runs:
        try:
            tr = fit_tumble_run(run.meta, run_columns(run))
        except Exception as exc:  # a fit that cannot run is a flag, not a crash
            flags.append(f"tumble {run.meta.get('run_id')}: fit failed: {exc}")
            continue
        fitted.append(tr)
        flags += tr.flags
    if not fitted:
        return None
    pooled = pool_runs(fitted)
    return TumbleStep(tuple(fitted), pooled, tuple(flags + pooling_flags(pooled)))


def _tumble_extras(step: TumbleStep) -> dict:
    out = {"tumble": [{"run_id": r.run_id, "values": r.values, "std": r.std_uncertainties,
                       "residual_rms": r.residual_rms, "dof": r.dof, "lack_of_fit": r.lack_of_fit,
                       "adequacy": r.result.lof.status,
                       "two_position": r.two_position, "note": _ALIAS_NOTE} for r in step.runs]}
    choices = [r.model_choice for r in step.runs if r.model_choice]
    if choices:
        out["tumble_model_choice"] = choices
    if len(step.runs) > 1:
        out["tumble_pooling"] = {n: {"value": q.value, "u": q.u, "u_internal": q.u_internal, "birge": q.birge,
                                     "p": q.p_value, "disagree": q.disagree,
                                     "runs": [r.run_id for r in q.runs]} for n, q in step.pooled.items()}
    return out


def _square_terms(rigs: Sequence) -> dict[str, tuple[float, float]]:
    """Kpp, Koo (value, u) of the first centrifuge rig that gives each: what one tumble
    aliases into K2."""
    out: dict[str, tuple[float, float]] = {}
    for rig in rigs:
        for name in SQUARE_TERM:
            c = rig.coefficient(name)
            if c is not None and name not in out:
                out[name] = (c.value, float(c.budget.u_c))
    return out


def _centrifuge_rigs(steps: Mapping[str, Any]) -> list:
    """The rigs of the campaign's centrifuge steps (the first passes of the estimators that
    take ``centrifuge`` runs, :func:`.registry.prepared`: (rigs, flags))."""
    return [rig for step in registry.prepared(steps, "centrifuge") for rig in step[0]]


def campaign_k1_correction(steps: Mapping[str, Any]) -> tuple[float, float] | None:
    """(delta, u_delta) of the tumble K1 from the first centrifuge rig's Koq and K3
    (:func:`k1_correction`); None without a tumble or a rig that gives Koq."""
    tumble = steps.get(METHOD)
    if tumble is None:
        return None
    for rig in _centrifuge_rigs(steps):
        koq = rig.coefficient("Koq")
        if koq is not None:
            k3 = rig.coefficient("K3")
            return k1_correction(tumble.g, (koq.value, float(koq.budget.u_c)),
                                 (k3.value, float(k3.budget.u_c)) if k3 is not None else None)
    return None


def campaign_records(runs: Sequence, steps: Mapping[str, Any]) -> list:
    """The tumble's records of a campaign: the pooled values with the centrifuge's square
    terms and K1 correction where the campaign has them (:func:`tumble_records`)."""
    tumble = steps.get(METHOD)
    if tumble is None:
        return []
    coeffs, budget, corrected = tumble_records(tumble.pooled, square_terms=_square_terms(_centrifuge_rigs(steps)),
                                               k1=campaign_k1_correction(steps),
                                               out_unit=str(runs[0].meta.get("output_unit", "out")))
    # where the campaign measures the temperature coefficients, K0 and K1 mean their values
    # at 20 degC, and a tumble's are at its own temperature
    thermal = ("bias_temperature", "scale_temperature") if any(registry.prepared(steps, "tilt_rotation")) else ()
    flags = list(tumble.flags) + name_combinations(runs, coeffs, budget, thermal, corrected)
    return [Records(coefficients=coeffs, budget=budget, extras=_tumble_extras(tumble), flags=flags).checked()]


def name_combinations(runs: Sequence, coeffs: list[TumbleCoefficient], budget: list[BudgetTerm],
                      effects: Sequence[str] = (), corrected: set[str] = frozenset()) -> list[str]:
    """Name each tumble row after what the tumble runs determine (IEEE 1293): one
    head measures K0 + Koo g^2, K2 - Koo and theta0 - Ko (head about PA), not K0, K2, theta0.

    The answer is the campaign model's (:meth:`accelcal.fitting.model.CampaignModel.combinations`)
    of the tumble runs of each head axis alone, judged at its start, with what the paper
    method fits free and every other coefficient held: a row is renamed to the combination
    of the coefficients held at 0 that it takes up, where a typical size of them would move
    it by more than half its u (K0T and K1T of a campaign that measures them: a tumble's K0
    and K1 are at its own temperature).  A row the centrifuge's terms corrected (a K2 with
    its square term added back, a K1 with Koq and K3 removed) is the coefficient itself.  K0 and K1, pooled over the heads, are renamed only when
    every head measures the same combination; otherwise a flag says what each head measures.

    Parameters
    ----------
    runs : sequence
        RunFile-like tumble runs of the campaign.
    coeffs, budget : list
        :func:`tumble_records`; renamed in place.
    effects : sequence of str
        effects.md ids besides ``initial_misalignment`` in the model of the tumble runs
        (``bias_temperature``, ``scale_temperature`` where the campaign measures K0T, K1T).
    corrected : set of str
        Names of the rows the centrifuge's terms corrected (:func:`tumble_records`).

    Returns
    -------
    list of str
        Flags: each renamed row, and K0/K1 rows whose heads measure different combinations.
    """
    from .joint import prepare
    groups: dict[str, list] = {}
    for r in runs:
        if str(r.meta.get("test")) == "tumble":
            groups.setdefault(AXES[geometry_of(r.meta).head_axis], []).append(r)
    several = len(groups) > 1
    u = {c.name: c.std_uncertainty for c in coeffs}
    answer: dict[str, dict[str, dict[str, float]]] = {}
    for grp, rr in groups.items():
        cells, _ = prepare(rr)
        model = CampaignModel(cells, ["initial_misalignment", *effects], include=("Kip", "Koq", "K3"),
                              acting=ACTING)
        # the paper method fits K0, K1, K2, theta0 and the extra terms it chose; every other
        # term of the model is what its rows take up, where the runs cannot tell it apart
        fitted = {"K0", "K1", "K2", "initial_misalignment"} | {c.key for c in coeffs}
        p = model.start()
        model = model.with_holds(model.select(p, hold={
            prm.name: "not a parameter of the tumble fit" for i, prm in enumerate(model.params)
            if model.roles[i].kind == "coef" and model.roles[i].key not in fitted}))
        rows = {"K0": "K0", "K1": "K1", "K2": _group_name("K2", grp, several),
                "initial_misalignment": _group_name("theta0", grp, several)}
        meas = model.combinations(p, {k: u[v] for k, v in rows.items() if math.isfinite(u.get(v, math.nan))})
        answer[grp] = {("theta0" if k == "initial_misalignment" else k): c.factors for k, c in meas.items()}
    flags = []
    for c in coeffs:
        if c.name in corrected:
            continue
        combos = [answer[g].get(c.key, {}) for g in ([c.head] if c.head else groups)]
        if len({combination_formula(c.key, t) for t in combos}) > 1:
            flags.append(f"{c.name} ({METHOD}): the heads measure different combinations: " + "; ".join(
                combination_formula(c.key, t) for t in combos) + "; the pooled value is none of them")
            continue
        if not combos[0]:
            continue
        old, c.name, c.factors = c.name, combination_name(c.name, combos[0]), dict(combos[0])
        for b in budget:
            if b.coefficient == old:
                b.coefficient = c.name
        flags.append(f"{c.name} ({METHOD}): aliased in one tumble: the runs determine "
                     f"{combination_formula(old, c.factors)}, not {old} alone")
    return flags


def mc_truth(c: Mapping[str, float], eff: Mapping[str, float], test: Mapping[str, Any], g: float,
             records: Mapping[str, CoefficientResult]) -> dict[tuple[str, str], tuple[float, str]]:
    """What each tumble coefficient estimates in a simulated test (cos_axis = +-IA, sin
    axis s with sign ss, cos sign cs, temperature T): K0 -> K0(T) + K_ss g^2; K1 -> K1(T);
    K2 -> K2 when the centrifuge's K_ss was added, else K2 - K_ss; theta0 ->
    initial_misalignment - cs ss K_s; the cross term -> the instrument value.

    Parameters
    ----------
    c : mapping
        Instrument coefficients of the test [SI].
    eff : mapping
        Effect sizes of the test [effects.md units].
    test : mapping
        The scenario's test (``heads``, ``temp_c``, ``rig_id``).
    g : float
        Local gravity [m/s2].
    records : mapping
        Coefficient name -> record of the processed campaign: a K2
        :class:`~.records.TumbleCoefficient` less by no square term is corrected.

    Returns
    -------
    dict
        (name, rig_id) -> (truth [SI], how it was mapped).
    """
    rig = str(test["rig_id"])
    head = test["heads"][0]
    ci, cs = parse_signed_axis(head["cos_axis"])
    si, ss = parse_signed_axis(head["sin_axis"])
    if ci != 0:
        return {}
    dT = float(test.get("temp_c", 23.0)) - T_REF_C
    Kss, Ks = c[SQUARE_TERM[si]], c[CROSS_AXIS_TERM[si]]
    sq, cr = SQUARE_TERM[si], CROSS_AXIS_TERM[si]
    k2 = records.get("K2")
    corrected = isinstance(k2, TumbleCoefficient) and not k2.less
    cross = CROSS_TERM[frozenset((0, si))]
    return {("K0", rig): (c["K0"] + c["K0T"] * dT + Kss * g * g, f"K0(T) + {sq} g^2 (apparent bias of a tumble)"),
            ("K1", rig): (c["K1"] * (1 + c["K1T"] * dT), "K1(T)"),
            ("K2", rig): ((c["K2"], "K2 (centrifuge " + sq + " added)") if corrected
                          else (c["K2"] - Kss, f"K2 - {sq} (aliased in one tumble)")),
            ("theta0", rig): (eff.get("initial_misalignment", 0.0) - cs * ss * Ks,
                              f"initial_misalignment - {cr} (aliased)"),
            (cross, rig): (c[cross], "instrument value")}


def fit_checks(extras: Mapping[str, Any]) -> list[FitCheck]:
    """The certificate's fit statistics of a stored tumble result: per run the lack-of-fit
    F test against the pure error of replicated positions (paper 003), or why it is not
    testable.

    Parameters
    ----------
    extras : mapping
        The stored result's extras (``extras['tumble']``, one entry per run).

    Returns
    -------
    list of FitCheck
    """
    f = display_number
    out = []
    for t in extras.get("tumble") or []:
        lof = (t or {}).get("lack_of_fit") or {}
        if lof:
            out.append(FitCheck("tumble", t.get("run_id"), "lack of fit (pure error of replicates)",
                                f"F = {f(lof.get('F'), '.3g')}", f"{f(lof.get('dof_lof'))} / {f(lof.get('dof_pe'))}",
                                lof.get("p")))
        else:
            out.append(FitCheck("tumble", t.get("run_id"), "lack of fit", "not testable", f(t.get("dof")),
                                passes=False, no="no replicated positions beyond the parameters"))
    return out


ESTIMATOR = registry.register(registry.Estimator(
    method=METHOD, tests=("tumble",),
    certificate=("paper 003 (Zhan & Cai): Levenberg–Marquardt fit of K0, K1, K2 and the head's "
                 "initial misalignment through the forward model, with a lack-of-fit test; "
                 "two-position values for comparison"),
    prepare=lambda runs, steps: tumble_step(runs), records=campaign_records, truth=mc_truth,
    adoption=5, crb=False, order=0, checks=fit_checks))
