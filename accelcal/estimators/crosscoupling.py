"""Second-order and cross-coupling coefficients from centrifuge mount pairs
(paper 000 §1, §2.2, §3.1).

Each mount pair (angles phi and phi + 180 deg in one mount plane) is fitted with the
data-processing model of eq 9, generalised to any mount angle:

    E/K1 = K0± + b± a± + c2 a^2 + d a|a| + c3 a^3

with a± = ±omega_z^2 rho± the signed centripetal specific force of each polarity
(rho± the distance of the effective mass centre from the spindle, from the test
radii), b± the separate scale factors of the two polarities (paper 000 §2.2: polarity
asymmetry makes them differ, and would leak into the even terms if they were shared),
d the polarity-odd quadratic (eq 9's Koq term; the instrument's Koq for the IA pair)
and c3 the odd cubic (K3 for the IA pair).  Weighted by the reading noise, which grows
with g.  The coefficient of a^2 is (eq 2, for the plane e1-e2 at nominal angle phi0)

    c2 = K11 cos^2 phi0 + K22 sin^2 phi0 + K12 cos phi0 sin phi0

K11, K22 the square terms of the plane axes (K2 for IA, Kpp for PA, Koo for OA) and K12
their cross term (Kip for IA-PA, Kio for IA-OA, Kpo for PA-OA).  All pairs present are
combined by weighted least squares; with the standard set it reduces to eq 3:
K2 = c2(IA 0/180), Kpp = c2(IA-PA 90/270), Kip = 2 c2(IA-PA 45/225) − (K2 + Kpp),
Koo = c2(IA-OA 90/270), Kio = 2 c2(IA-OA 45/225) − (K2 + Koo).
Units: c2 and the K's in s^2/m, c3 and K3 in s^4/m^2, angles in rad.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..physics.axes import AXES, parse_plane
from .adequacy import DwellFit, choose_order
from .radius import PairData

SQUARE = {0: "K2", 1: "Kpp", 2: "Koo"}
CROSS = {frozenset((0, 1)): "Kip", frozenset((0, 2)): "Kio", frozenset((1, 2)): "Kpo"}
UNKNOWNS = ["K2", "Kpp", "Koo", "Kip", "Kio", "Kpo"]


def c2_of_mount(K: Mapping[str, float], plane: str, phi0_rad: float) -> float:
    """eq 2: c2 = K11 cos^2 phi0 + K22 sin^2 phi0 + K12 cos phi0 sin phi0 (s^2/m)."""
    e1, e2 = parse_plane(plane)
    c, s = np.cos(phi0_rad), np.sin(phi0_rad)
    return (K.get(SQUARE[e1], 0.0) * c * c + K.get(SQUARE[e2], 0.0) * s * s
            + K.get(CROSS[frozenset((e1, e2))], 0.0) * c * s)


def delta_c2(K: Mapping[str, float], plane: str, phi0_rad: float, dphi_rad: float) -> float:
    """eq 8, any plane: Delta c2 = [(K22 − K11) sin 2 phi0 + K12 cos 2 phi0] Delta phi0.
    IA-PA at 45 deg: (Kpp − K2) dphi; at 90 deg: −Kip dphi (s^2/m)."""
    e1, e2 = parse_plane(plane)
    K11, K22 = K.get(SQUARE[e1], 0.0), K.get(SQUARE[e2], 0.0)
    K12 = K.get(CROSS[frozenset((e1, e2))], 0.0)
    return ((K22 - K11) * np.sin(2 * phi0_rad) + K12 * np.cos(2 * phi0_rad)) * dphi_rad


def kip_from_45(c2_45: float, K2: float, Kpp: float) -> float:
    """eq 3: Kip = 2 c2(45 deg) − (K2 + Kpp)."""
    return 2.0 * c2_45 - (K2 + Kpp)


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

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def mount_geometry(R: float, r: float, phi_rad: float) -> tuple[float, float]:
    """Distance rho (m) of the effective mass centre from the spindle and the angle error
    dphi (rad) of the direction to the spindle, for a turning centre at R and a mass
    centre r along the first plane axis (effects.md ``mass_centre_offset``; paper 000 §2.2:
    phi = 0 gives rho = R − r, phi = 180 deg rho = R + r)."""
    ux, uy = np.cos(phi_rad), np.sin(phi_rad)
    p1, p2 = -R * ux + r, -R * uy
    rho = float(np.hypot(p1, p2))
    ang = np.arctan2(-p2, -p1)
    dphi = float((ang - phi_rad + np.pi) % (2 * np.pi) - np.pi)
    return rho, dphi


def alignment(R_plus: float, R_minus: float, plane: str, phi0_deg: float) -> Alignment:
    """R = (R+ + R-)/2, r = (R- − R+)/2 (so that rho(0) = R − r = R+), and for the mount
    at phi0 and phi0 + 180 deg the true radius and angle error (paper 000 §2.2)."""
    R = 0.5 * (R_plus + R_minus)
    r = 0.5 * (R_minus - R_plus)
    phi = np.radians(phi0_deg)
    R1, d1 = mount_geometry(R, r, phi)
    R2, d2 = mount_geometry(R, r, phi + np.pi)
    return Alignment(plane, float(phi0_deg), R, r, R1, d1, R2, d2)


@dataclass
class PairFit:
    plane: str
    phi0_deg: float
    run_ids: tuple[str, str]
    order: int
    fit: DwellFit
    fits: dict[int, DwellFit]
    c2: float
    u_c2: float
    d: float
    u_d: float
    c3: float | None
    u_c3: float | None
    adequate: bool
    geometry: Alignment
    dwells: pd.DataFrame = field(repr=False, default=None)


def pair_key(meta: Mapping) -> tuple[str, float]:
    """(mount_plane, phi mod 180) — the two polarities of one mount share the key."""
    return str(meta["mount_plane"]).replace(" ", ""), float(meta["mount_angle_deg"]) % 180.0


def fit_mount_pair(run_a: tuple[Mapping, pd.DataFrame], run_b: tuple[Mapping, pd.DataFrame],
                   K1: float, R_plus: float, R_minus: float, orders=(2, 3)) -> PairFit:
    """Fit eq 9 (module docstring) to a mount pair; run_a at phi0 < 180 deg, run_b at
    phi0 + 180 deg.  The signed input of each polarity is a = ±omega_z^2 rho± with rho±
    from the test radii (mass-centre geometry); the lowest adequate order is chosen
    by :func:`adequacy.choose_order` (order 2: c2 and d; order 3: + c3); if none is
    adequate the highest is used and the fit is marked inadequate."""
    (ma, da), (mb, db) = run_a, run_b
    plane, phi0 = pair_key(ma)
    geo = alignment(R_plus, R_minus, plane, phi0)
    pair = PairData.from_runs([(ma, da, 1), (mb, db, -1)], K1)
    T = pair.table
    rho = np.where(T["pol"].to_numpy() > 0, geo.R1, geo.R2)
    a = np.where(T["pol"].to_numpy() > 0, 1.0, -1.0) * T["omega_z"].to_numpy() ** 2 * rho
    fits = {}
    for order in orders:
        fits[order], _ = pair.fit(a, order, subtract_a=False)
    chosen, adequate = choose_order(fits, {3: ["c3"]})
    f = fits[chosen]
    has_c3 = "c3" in f.names
    T = T.assign(a=a, std_resid=f.std_resid, fitted=f.yhat)
    return PairFit(plane, phi0, (str(ma.get("run_id")), str(mb.get("run_id"))), chosen, f, fits,
                   f.value("c2"), f.std_error("c2"), f.value("d"), f.std_error("d"),
                   f.value("c3") if has_c3 else None, f.std_error("c3") if has_c3 else None,
                   adequate, geo, T)


@dataclass
class Combination:
    """The second-order coefficients from all mount pairs (eq 2/3 by weighted LS)."""
    values: dict[str, float]
    cov: dict[tuple[str, str], float]
    std: dict[str, float]
    design: list[dict]                 # one row per pair: plane, phi0, c2, u_c2 (A), u_dc2 (B), weights
    sensitivities: dict[str, dict[str, float]]   # coefficient -> {pair label: d coef / d c2}


def combine_second_order(pairs: list[PairFit], u_dc2: Mapping[str, float] | None = None) -> Combination:
    """Solve c2(pair) = K11 cos^2 + K22 sin^2 + K12 cos sin for the K's present (weighted
    by 1/(u_A(c2)^2 + u_B(dc2)^2)); coefficients no pair can see are left out.  Returns
    values, covariance and each coefficient's sensitivity to each pair's c2 (the GUM
    sensitivity coefficients: e.g. 2 for Kip on c2(45 deg), −1 on K2 and Kpp)."""
    u_dc2 = u_dc2 or {}
    rows, y, var, labels = [], [], [], []
    for p in pairs:
        e1, e2 = parse_plane(p.plane)
        phi = np.radians(p.phi0_deg)
        row = dict.fromkeys(UNKNOWNS, 0.0)
        row[SQUARE[e1]] += np.cos(phi) ** 2
        row[SQUARE[e2]] += np.sin(phi) ** 2
        row[CROSS[frozenset((e1, e2))]] += np.cos(phi) * np.sin(phi)
        lab = f"{p.plane} {p.phi0_deg:g}/{p.phi0_deg + 180:g}"
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
    # keep only identifiable unknowns: those whose unit vector lies in the row space
    _, sv, Vt = np.linalg.svd(Aw, full_matrices=False)
    rank = int(np.sum(sv > sv.max() * 1e-9)) if sv.size else 0
    V = Vt[:rank]
    ident = [j for j in range(len(names)) if np.linalg.norm(V[:, j]) > 1 - 1e-9]
    pinv = np.linalg.pinv(Aw)                  # (unknowns x pairs), weighted
    S = pinv * np.sqrt(w)[None, :]             # d K / d c2
    beta = S @ np.asarray(y)
    cov = S @ np.diag(var) @ S.T
    values = {names[j]: float(beta[j]) for j in ident}
    std = {names[j]: float(np.sqrt(cov[j, j])) for j in ident}
    covd = {(names[i], names[j]): float(cov[i, j]) for i in ident for j in ident}
    sens = {names[j]: {labels[i]: float(S[j, i]) for i in range(len(labels)) if abs(S[j, i]) > 1e-12}
            for j in ident}
    design = [{"pair": labels[i], "c2": y[i], "u_c2_A": float(pairs[i].u_c2),
               "u_dc2_B": float(u_dc2.get(labels[i], 0.0)),
               **{names[j]: float(A[i, j]) for j in range(len(names))}} for i in range(len(labels))]
    return Combination(values, covd, std, design, sens)


def pair_label(p: PairFit) -> str:
    return f"{p.plane} {p.phi0_deg:g}/{p.phi0_deg + 180:g}"


def axis_name(i: int) -> str:
    return AXES[i]
