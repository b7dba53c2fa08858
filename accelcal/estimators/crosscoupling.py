"""Second-order and cross-coupling coefficients from centrifuge mount pairs
(paper 000 §1, §2.2, §3.1).

Each mount pair (angles phi and phi + 180 deg in one mount plane) is fitted with the
data-processing model of eq 9, generalised to any mount angle:

    E/K1 = K0± + b± a± + c2 a^2 + d a|a| + c3 a^3

with a± the signed specific force of each polarity along the mount's nominal direction to
the spindle, from the one forward model (turning centre and mass-centre offset from the
test radii; ±omega_z^2 rho± up to the second-order angle term of eq 8), b± the separate scale factors of the two polarities (paper 000 §2.2: polarity
asymmetry makes them differ, and would leak into the even terms if they were shared),
d the polarity-odd quadratic (eq 9's Koq term; the instrument's Koq for the IA pair)
and c3 the odd cubic (K3 for the IA pair).  Weighted by the reading noise, which grows
with g.  The coefficient of a^2 is (eq 2, for the plane e1-e2 at nominal angle phi0)

    c2 = K11 cos^2 phi0 + K22 sin^2 phi0 + K12 cos phi0 sin phi0

(:func:`eq2_row`: the derivatives of the instrument model for a unit centripetal input
from the forward model), K11, K22 the square terms of the plane axes (K2 for IA, Kpp for
PA, Koo for OA) and K12 their cross term (Kip for IA-PA, Kio for IA-OA, Kpo for PA-OA).  All pairs present are
combined by weighted least squares; with the standard set it reduces to eq 3:
K2 = c2(IA 0/180), Kpp = c2(IA-PA 90/270), Kip = 2 c2(IA-PA 45/225) − (K2 + Kpp),
Koo = c2(IA-OA 90/270), Kio = 2 c2(IA-OA 45/225) − (K2 + Koo).
Units: c2 and the K's in s^2/m, c3 and K3 in s^4/m^2, angles in rad.

Reference: He & Yin 2017, cross-coupling coefficients on a precision centrifuge (paper 000;
``shared/docs/methods.md``).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..effects import CROSS_TERM
from ..fitting import identify
from ..fitting.core import lstsq_svd
from ..physics.axes import AXES, parse_plane
from ..physics.geometry import geometry_of
from ..physics.instrument import output_derivative
from .adequacy import DwellFit, choose_order
from .radius import PairData, centripetal_unit_input

UNKNOWNS = ["K2", "Kpp", "Koo", "Kip", "Kio", "Kpo"]


def mount_meta(plane: str, phi_deg: float, radius_m: float = 1.0) -> dict:
    """Metadata of a centrifuge mount in plane ``plane`` at mount angle ``phi_deg`` [deg] (the
    third axis up, ccw table): what the forward model needs to place the instrument."""
    e1, e2 = parse_plane(plane)
    return {"test": "centrifuge", "mount_plane": plane, "mount_angle_deg": float(phi_deg),
            "vertical_axis": f"+{AXES[3 - e1 - e2]}", "arm_radius_m": float(radius_m),
            "rotation_sense": "ccw", "site_latitude_deg": 0.0, "g_local_m_s2": 0.0}


def eq2_row(plane: str, phi0_rad: float) -> dict[str, float]:
    """Coefficients of eq 2, c2 = sum_K row[K] K, for the mount at nominal angle phi0.

    Returns
    -------
    dict
        K -> dA/dK of the instrument model (:func:`accelcal.physics.instrument.output_derivative`
        at K1 = 1) for a unit centripetal input along the direction to the spindle (from the
        forward model): K11 cos^2 phi0, K22 sin^2 phi0, K12 cos phi0 sin phi0 (paper 000 eq 2),
        0 for the terms of the vertical axis.
    """
    u = centripetal_unit_input(mount_meta(plane, math.degrees(phi0_rad)))[None, :]
    return {k: float(output_derivative(k, {"K1": 1.0}, u)[0]) for k in UNKNOWNS}


def delta_c2(K: Mapping[str, float], plane: str, phi0_rad: float, dphi_rad: float) -> float:
    """eq 8, any plane: Delta c2 = [(K22 - K11) sin 2 phi0 + K12 cos 2 phi0] Delta phi0 [s2/m].

    IA-PA at 45 deg: (Kpp - K2) dphi; at 90 deg: -Kip dphi (He & Yin 2017, paper 000 eq 8).
    Computed as the derivative of eq 2 along the mount angle: with u the unit centripetal
    input and v = du/dphi (the input of the mount turned by 90 deg), each term of eq 2 is
    quadratic in the input, so its derivative is exactly [row(u + v) - row(u - v)] / 2.
    """
    u = centripetal_unit_input(mount_meta(plane, math.degrees(phi0_rad)))
    v = centripetal_unit_input(mount_meta(plane, math.degrees(phi0_rad) + 90.0))
    d = 0.0
    for k in UNKNOWNS:
        if K.get(k, 0.0):
            plus = output_derivative(k, {"K1": 1.0}, (u + v)[None, :])[0]
            minus = output_derivative(k, {"K1": 1.0}, (u - v)[None, :])[0]
            d += K[k] * (plus - minus) / 2.0
    return float(d * dphi_rad)


@dataclass
class Alignment:
    """Alignment analysis of paper 000 §2.2 for one nominal mount angle phi0."""
    plane: str
    phi0_deg: float
    R: float              # turning centre radius, m: (R+ + R-)/2
    r: float              # mass-centre offset along the first plane axis, m (effects.md sign)
    R1: float             # distance of the mass centre, polarity at phi0, m
    dphi1: float          # angle error of the centripetal direction, rad
    R2: float             # the same at phi0 + 180 deg
    dphi2: float


def mount_geometry(R: float, r: float, phi_rad: float) -> tuple[float, float]:
    """Distance and direction error of the effective mass centre (paper 000 §2.2).

    Parameters
    ----------
    R : float
        Spindle to fixture turning centre [m].
    r : float
        Mass-centre offset along the first plane axis [m] (effects.md ``mass_centre_offset``).
    phi_rad : float
        Nominal mount angle [rad].

    Returns
    -------
    rho, dphi : float
        Distance of the mass centre from the spindle [m] and angle error of the direction to
        the spindle [rad], from the centripetal input of the forward model
        (:func:`centripetal_unit_input`): phi = 0 gives rho = R - r, phi = 180 deg R + r.
    """
    f = centripetal_unit_input(mount_meta("IA-PA", math.degrees(phi_rad)), R, r)
    rho = float(math.hypot(f[0], f[1]))
    dphi = float((math.atan2(f[1], f[0]) - phi_rad + math.pi) % (2 * math.pi) - math.pi)
    return rho, dphi


def alignment(R_plus: float, R_minus: float, plane: str, phi0_deg: float) -> Alignment:
    """Alignment analysis of a mount (He & Yin 2017, paper 000 §2.2).

    .. math::

        R = (R_+ + R_-)/2, \\quad r = (R_- - R_+)/2, \\quad
        R_{1,2} = \\sqrt{(R \\mp r \\cos\\varphi_0)^2 + (r \\sin\\varphi_0)^2}, \\quad
        \\Delta\\varphi_{1,2} = \\arctan\\frac{r \\sin\\varphi_0}{R \\mp r \\cos\\varphi_0}

    Parameters
    ----------
    R_plus, R_minus : float
        Test radii of the IA polarities [m].
    plane : str
        The mount's plane.
    phi0_deg : float
        Nominal mount angle [deg].

    Returns
    -------
    Alignment
        R, r [m] (r along the first plane axis, so that rho(0) = R - r = R+), and for the
        mount at phi0 and phi0 + 180 deg the distance [m] and angle error [rad] of the mass
        centre (:func:`mount_geometry`, from the forward model).
    """
    R = 0.5 * (R_plus + R_minus)
    r = 0.5 * (R_minus - R_plus)
    phi = np.radians(phi0_deg)
    R1, d1 = mount_geometry(R, r, phi)
    R2, d2 = mount_geometry(R, r, phi + np.pi)
    return Alignment(plane, float(phi0_deg), R, r, R1, d1, R2, d2)


def _fitted_term(name: str, std: bool) -> property:
    """A term of a pair's chosen eq 9 fit: its value, or with ``std`` its standard error;
    None where the chosen order has no such term (c3 of an order-2 fit)."""
    return property(lambda self: (self.fit.std_error if std else self.fit.value)(name)
                    if name in self.fit.names else None)


@dataclass
class PairFit:
    """Eq 9 fit of one mount pair (:func:`fit_mount_pair`).

    Attributes
    ----------
    plane, phi0_deg : str, float
        The mount [deg].
    run_ids : (str, str)
    order : int
        Chosen model order; ``fits`` holds every order tried, ``fit`` the chosen one.
    c2, u_c2 : float
        Coefficient of a^2 [s2/m] (eq 2's combination of the second-order terms), read from
        ``fit`` (its FitResult).
    d, u_d : float
        Polarity-odd quadratic [s2/m] (Koq for the IA pair), from ``fit``.
    c3, u_c3 : float or None
        Cubic [s4/m2] (K3 for the IA pair), order 3 only, from ``fit``.
    adequate : bool
    geometry : Alignment
    dwells : DataFrame
        Dwell table with the signed input ``a`` [m/s2], residuals and fitted values.
    """
    plane: str
    phi0_deg: float
    run_ids: tuple[str, str]
    order: int
    fit: DwellFit
    fits: dict[int, DwellFit]
    adequate: bool
    geometry: Alignment
    dwells: pd.DataFrame = field(repr=False, default=None)

    c2, u_c2, d, u_d, c3, u_c3 = (_fitted_term(name, std) for name in ("c2", "d", "c3") for std in (False, True))


def fit_mount_pair(run_a: tuple[Mapping, pd.DataFrame], run_b: tuple[Mapping, pd.DataFrame],
                   K1: float, R_plus: float, R_minus: float, orders=(2, 3), *,
                   pair: PairData | None = None) -> PairFit:
    """Fit eq 9 to a mount pair (He & Yin 2017, paper 000 §3.1).

    .. math::

        E/K_1 = K_{0\\pm} + b_\\pm a_\\pm + c_2 a^2 + d\\, a |a| + c_3 a^3

    Parameters
    ----------
    run_a, run_b : (meta, data)
        The runs at phi0 < 180 deg and phi0 + 180 deg.
    K1 : float
        Scale factor [output_unit/(m/s2)] from the tumble.
    R_plus, R_minus : float
        Test radii of the IA pair [m]: turning centre R = (R+ + R-)/2, mass-centre offset
        r = (R- - R+)/2 along the first plane axis.
    orders : tuple of int
        Model orders tried (2: c2 and d; 3: + c3).
    pair : PairData, optional
        The pair's dwell data when already built (with the same K1).

    Returns
    -------
    PairFit
        c2 [s2/m], d [s2/m] (Koq for the IA pair), c3 [s4/m2] with their standard
        uncertainties, the alignment geometry and the dwell table.

    Notes
    -----
    The signed input a [m/s2] of each dwell is the specific force of the forward model
    (:meth:`accelcal.estimators.radius.PairData.inputs`) along the mount's nominal direction
    to the spindle; the lowest adequate order is chosen by :func:`adequacy.choose_order`;
    if none is adequate the highest is used and the fit is marked inadequate.
    """
    (ma, da), (mb, db) = run_a, run_b
    plane, phi0 = geometry_of(ma).mount_key
    geo = alignment(R_plus, R_minus, plane, phi0)
    if pair is None:
        pair = PairData.from_runs([(ma, da, 1), (mb, db, -1)], K1)
    # eq 9's signed input: the specific force of the forward model along the mount's nominal
    # direction to the spindle, turning centre R and mass centre r from the test radii (the
    # second-order difference to omega_z^2 rho, an angle error, is eq 8's type-B term)
    a = pair.inputs(geo.R, geo.r)
    fits = {order: pair.fit(a, order, subtract_a=False) for order in orders}
    chosen, adequate = choose_order(fits, {3: ["c3"]})
    f = fits[chosen]
    T = pair.table.assign(a=a, std_resid=f.std_resid, fitted=f.yhat)
    return PairFit(plane, phi0, (str(ma.get("run_id")), str(mb.get("run_id"))), chosen, f, fits,
                   adequate, geo, T)


@dataclass
class Combination:
    """The second-order coefficients from all mount pairs (eq 2/3 by weighted LS)."""
    values: dict[str, float]
    cov: dict[tuple[str, str], float]
    std: dict[str, float]
    design: list[dict]                 # one row per pair: plane, phi0, c2, u_c2 (A), u_dc2 (B), weights
    sensitivities: dict[str, dict[str, float]]   # coefficient -> {pair label: d coef / d c2}
    #: a combination's name -> the factors of the terms it takes up (its row's ``factors``)
    factors: dict[str, dict[str, float]] = field(default_factory=dict)


def combine_second_order(pairs: list[PairFit], u_dc2: Mapping[str, float] | None = None) -> Combination:
    """The second-order coefficients from every mount pair: eq 2 by weighted least squares
    (He & Yin 2017, paper 000 eqs 2–3).

    .. math::

        c_2(\\text{pair}) = K_{11} \\cos^2\\varphi_0 + K_{22} \\sin^2\\varphi_0
            + K_{12} \\cos\\varphi_0 \\sin\\varphi_0

    With the standard set of mounts this is eq 3: Kip = 2 c2(45 deg) - (K2 + Kpp).

    Parameters
    ----------
    pairs : list of PairFit
        The eq 9 fits, c2 [s2/m] with type-A u.
    u_dc2 : mapping, optional
        Pair label -> type-B standard uncertainty of c2 from eq 8 [s2/m].

    Returns
    -------
    Combination
        Values [s2/m], covariance, std and each coefficient's sensitivity to each pair's c2
        (the GUM sensitivity coefficients: 2 for Kip on c2(45 deg), -1 on K2 and Kpp).
        Weights 1/(u_A(c2)^2 + u_B(dc2)^2); coefficients no pair can see, or that the pairs
        only determine in combinations, are left out.  The rows are :func:`eq2_row` (the
        forward model); the solve is :func:`accelcal.fitting.core.lstsq_svd`.
    """
    u_dc2 = u_dc2 or {}
    rows, y, var, labels = [], [], [], []
    for p in pairs:
        row = eq2_row(p.plane, math.radians(p.phi0_deg))
        lab = pair_label(p)
        rows.append([row[k] for k in UNKNOWNS])
        y.append(p.c2)
        var.append(p.u_c2**2 + u_dc2.get(lab, 0.0) ** 2)
        labels.append(lab)
    A = np.array(rows)
    A[np.abs(A) < 1e-12] = 0.0
    used = [j for j in range(len(UNKNOWNS)) if np.any(A[:, j] != 0)]
    A = A[:, used]
    names = [UNKNOWNS[j] for j in used]
    w = 1.0 / np.asarray(var)
    Aw = A * np.sqrt(w)[:, None]
    # the fitting core's weighted least squares; only identifiable unknowns (unit vector in
    # the row space of the design) are kept
    sol = lstsq_svd(Aw, np.asarray(y) * np.sqrt(w))
    ident = [j for j in range(len(names)) if sol.estimable[j]]
    S = (sol.cov @ Aw.T) * np.sqrt(w)[None, :]  # d K / d c2: the solution is linear in the c2's
    # what the pairs determine of the unknowns they cannot separate: one combination per
    # pair of them that one null direction ties (45/225 without 90/270: Kip + Kpp)
    combs = _determined_combinations(names, sol)
    cfactors = {identify.display_name(c.kept, c): dict(c.factors) for c in combs}
    if combs:
        C = np.array([[1.0 if nm == c.kept else c.factors.get(nm, 0.0) for nm in names] for c in combs])
        S = np.vstack([S, C @ S])
        names = names + [identify.display_name(c.kept, c) for c in combs]
        ident = ident + list(range(len(names) - len(combs), len(names)))
    beta = S @ np.asarray(y)
    cov = S @ np.diag(var) @ S.T
    values = {names[j]: float(beta[j]) for j in ident}
    std = {names[j]: float(np.sqrt(cov[j, j])) for j in ident}
    covd = {(names[i], names[j]): float(cov[i, j]) for i in ident for j in ident}
    sens = {names[j]: {labels[i]: float(S[j, i]) for i in range(len(labels)) if abs(S[j, i]) > 1e-12}
            for j in ident}
    design = [{"pair": labels[i], "c2": y[i], "u_c2_A": float(pairs[i].u_c2),
               "u_dc2_B": float(u_dc2.get(labels[i], 0.0)),
               **{names[j]: float(A[i, j]) for j in range(A.shape[1])}} for i in range(len(labels))]
    return Combination(values, covd, std, design, sens, cfactors)


def _determined_combinations(names: list[str], sol) -> list[identify.Combination]:
    """Combinations of the unknowns the pairs leave undetermined alone that the pairs do
    determine: with the one null direction n of the solve, ``K_k - (n_k / n_m) K_m`` for the
    first of them (cross terms first: ``Kip+Kpp``) and each other one.

    Parameters
    ----------
    names : list of str
        The unknowns of the solve, in column order.
    sol : LinearSolution
        :func:`accelcal.fitting.core.lstsq_svd` of the weighted design: which unknowns are
        determined (its ``estimable``, the fitting core's rank decision) and its null space.

    Returns
    -------
    list of accelcal.fitting.identify.Combination
        The kept unknown with the factor [1] of the other; empty when every unknown is
        determined or the null space has more than one direction.
    """
    held = sorted((j for j in range(len(names)) if not sol.estimable[j]),
                  key=lambda j: (names[j] not in CROSS_TERM.values(), j))
    if not held or sol.null_space.shape[1] != 1:
        return []
    n = sol.null_space[:, 0] / np.where(sol.column_norm > 0, sol.column_norm, 1.0)
    k = held[0]
    return [identify.Combination(names[k], ((names[m], -n[k] / n[m]),)) for m in held[1:]]


def pair_label(p: PairFit) -> str:
    """'IA-PA 45/225': the pair's plane and its two mount angles [deg]."""
    return f"{p.plane} {p.phi0_deg:g}/{p.phi0_deg + 180:g}"

