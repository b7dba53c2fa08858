"""The fitted forward model of the diagnosis: parameters, predictions through
:func:`accelcal.physics.rig_output` (the one forward model), numerical Jacobians and a
Gauss-Newton fit on whitened cell means.

Bare model (``--baseline none``), per campaign (one instrument):
- shared instrument terms K1, K2 (and K0T, K1T when the campaign has tilt_rotation runs);
- K2-like terms (decision for cross mounts, documented in docs/diagnosis.md): per centrifuge
  mount orientation one c2, the coefficient of a_c^2 that the lab's processing model fits
  (paper 000 eq 9); it holds K2, Kpp, Koo, Kip, Kio as the mount mixes them, so
  ``cross_coupling`` is absorbed by it (Kip is read from the c2 of several mounts, eq 3,
  by the estimators, not by the diagnosis).  A tumble head gets the cross product of its two
  turning axes (Kio for an IA/OA head) -- its squares are K2 and a constant;
- per run a bias K0 (per polarity, since every centrifuge run is one polarity);
- per centrifuge / sine-centrifuge run a *scale*: the run's effective radius along the
  first plane axis (paper 000, 2.1.2: one radius per polarity).  It is carried through the
  physics as that run's own ``mass_centre_offset`` r_run, i.e. the IA input becomes
  omega_z^2 (R cos(phi) - r_run): for an IA mount a scale change of the centripetal input,
  for a transverse mount (cos(phi) = 0) the linear term c1 that a transverse fit carries
  (paper 000, 2.2: there the mass-centre offset shows as an angle error).
  ``transverse_scale=False`` drops it for runs with |cos(phi)| < 0.1 (a stricter model).
The bare model has no Kp, Ko, Kip, Kpp, ...: the cross terms of a 45 deg mount are the
``cross_coupling`` effect (Kip); Kpp is not a catalogue effect.
Baseline effects are added with their parameter fitted (shared by all runs they apply
to), except ``earth_rate``, which the baseline includes at its physical size (1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..effects import EFFECTS
from ..physics import rig_output
from ..physics.axes import parse_plane, parse_signed_axis

SQUARE = {0: "K2", 1: "Kpp", 2: "Koo"}
CROSS = {frozenset((0, 1)): "Kip", frozenset((0, 2)): "Kio", frozenset((1, 2)): "Kpo"}

#: typical size of each effect's parameter (difference step and benchmark scale)
EFFECT_STEP = {
    "earth_rate": 1.0, "ia_tilt": 1e-4, "mass_centre_offset": 1e-3, "mount_angle_error": 1e-3,
    "arm_stretch": 1e-6, "rate_scale_error": 1e-5, "spindle_tilt": 1e-4, "sensor_lag": 1e-3,
    "initial_misalignment": 1e-4, "fixture_thermal_tilt": 1e-6, "base_tilt_drift": 1e-9,
    "tilt_tide": 1e-6, "bias_temperature": 1e-5, "scale_temperature": 1e-5, "bias_drift": 1e-8,
    "odd_quadratic": 1e-8, "cubic": 1e-10, "cross_coupling": 1e-7,
}
#: largest physically plausible size (an effect whose minimum detectable size exceeds it is
#: reported as not observable in these runs)
PLAUSIBLE_MAX = {
    "earth_rate": 3.0, "ia_tilt": 0.01, "mass_centre_offset": 0.02, "mount_angle_error": 0.02,
    "arm_stretch": 1e-5, "rate_scale_error": 1e-2, "spindle_tilt": 0.01, "sensor_lag": 0.05,
    "initial_misalignment": 0.05, "fixture_thermal_tilt": 1e-4, "base_tilt_drift": 1e-7,
    "tilt_tide": 1e-4, "bias_temperature": 1e-3, "scale_temperature": 1e-3, "bias_drift": 1e-5,
    "odd_quadratic": 1e-5, "cubic": 1e-7, "cross_coupling": 1e-5,
}
CENTRIFUGES = ("centrifuge", "sine_centrifuge")


@dataclass
class Param:
    name: str          # e.g. 'K0[run]', 'r[run]', 'K1[campaign]', 'effect:odd_quadratic'
    kind: str          # K0 | r | K1 | K2 | K0T | K1T | effect
    key: str           # run id, campaign or effect id
    runs: list         # indices of the runs it acts on
    h: float           # difference step
    group: str         # for reports: 'per-run bias', 'per-run scale (radius)', ...


class Model:
    def __init__(self, runs, baseline: list[str], free_effects: list[str], transverse_scale=True):
        self.runs = runs
        self.baseline = list(baseline)
        self.fixed = {"earth_rate": 1.0} if "earth_rate" in baseline else {}
        self.free_effects = [e for e in baseline if e != "earth_rate"] + [
            e for e in free_effects if e not in baseline]
        self.params: list[Param] = []
        camps = sorted({r.campaign for r in runs})
        self.camp_index = {c: i for i, c in enumerate(camps)}
        for c in camps:
            idx = [j for j, r in enumerate(runs) if r.campaign == c]
            self.params.append(Param(f"K1[{c}]", "K1", c, idx, 1e-4, "scale factor K1"))
            self.params.append(Param(f"K2[{c}]", "K2", c, idx, 1e-7, "K2"))
            if any(runs[j].test == "tilt_rotation" for j in idx):
                self.params.append(Param(f"K0T[{c}]", "K0T", c, idx, 1e-5, "K0T, K1T"))
                self.params.append(Param(f"K1T[{c}]", "K1T", c, idx, 1e-5, "K0T, K1T"))
        # K2-like terms: per centrifuge mount orientation (plane, phi mod 180) one c2, the
        # coefficient of a_c^2 (paper 000 eq 2/eq 9), carried as the square coefficient of IA
        # (|cos phi| >= 0.1) or of the second plane axis (transverse mounts); per tumble head the
        # cross product of the two turning axes (its cos^2 and sin^2 terms are K2 and a constant).
        self.c2_of_run: dict[int, tuple[str, str]] = {}
        groups: dict[tuple, list] = {}
        for j, r in enumerate(runs):
            if r.test in CENTRIFUGES:
                phi = float(r.meta["mount_angle_deg"]) % 180.0
                key = (r.campaign, str(r.meta["mount_plane"]), round(phi, 3))
                e1, e2 = parse_plane(r.meta["mount_plane"])
                cname = SQUARE[0] if abs(np.cos(np.radians(phi))) >= 0.1 else SQUARE[e2]
                groups.setdefault(key, []).append(j)
                self.c2_of_run[j] = (f"c2[{key[0]}|{key[1]}@{key[2]:g}]", cname)
            elif r.test == "tumble":
                a, _ = parse_signed_axis(r.meta["cos_axis"])
                b, _ = parse_signed_axis(r.meta["sin_axis"])
                key = (r.campaign, f"head {r.meta['head_axis']}")
                groups.setdefault(key, []).append(j)
                self.c2_of_run[j] = (f"c2[{key[0]}|{key[1]}]", CROSS[frozenset((a, b))])
        for key, idx in groups.items():
            name = self.c2_of_run[idx[0]][0]
            self.params.append(Param(name, "c2", name, idx, 1e-7, "per-mount K2-like term c2"))
        for j, r in enumerate(runs):
            self.params.append(Param(f"K0[{r.run_id}]", "K0", r.run_id, [j], 1e-4, "per-run bias K0"))
            if r.test in CENTRIFUGES:
                cphi = abs(np.cos(np.radians(float(r.meta["mount_angle_deg"]))))
                if transverse_scale or cphi >= 0.1:
                    self.params.append(Param(f"r[{r.run_id}]", "r", r.run_id, [j], 1e-4,
                                             "per-run scale (radius)"))
        for e in self.free_effects:
            idx = [j for j, r in enumerate(runs) if r.test in EFFECTS[e].tests]
            self.params.append(Param(f"effect:{e}", "effect", e, idx, EFFECT_STEP[e], f"effect {e}"))
        self.index = {p.name: i for i, p in enumerate(self.params)}
        self.run_params = [[i for i, p in enumerate(self.params) if j in p.runs] for j in range(len(runs))]
        self.offsets = np.concatenate([[0], np.cumsum([r.ncell for r in runs])]).astype(int)
        self.N = int(self.offsets[-1])
        self.sig = np.concatenate([np.sqrt(r.var) for r in runs])
        self.y = np.concatenate([r.y for r in runs])

    # ------------------------------------------------------------ values
    def initial(self, prev: "Model | None" = None, pprev=None) -> np.ndarray:
        p = np.zeros(len(self.params))
        if prev is not None:
            for i, q in enumerate(self.params):
                if q.name in prev.index:
                    p[i] = pprev[prev.index[q.name]]
            return p
        # K1 by regression of the outputs on the nominal IA input (per campaign)
        for c, ci in self.camp_index.items():
            num = den = 0.0
            for j, r in enumerate(self.runs):
                if r.campaign != c:
                    continue
                a = r.cell_mean(rig_output(r.test, r.meta, r.cols, {"K1": 1.0}, self.fixed))
                a = a - a.mean()
                num += float(np.sum(a * (r.y - r.y.mean())))
                den += float(np.sum(a * a))
            p[self.index[f"K1[{c}]"]] = num / den if den > 0 and num != 0 else 1.0
        for i, q in enumerate(self.params):
            if q.kind == "K1":
                q.h = 1e-4 * abs(p[i])
        return p

    def run_inputs(self, p, j):
        r = self.runs[j]
        c = r.campaign
        co = {"K1": p[self.index[f"K1[{c}]"]], "K2": p[self.index[f"K2[{c}]"]],
              "K0": p[self.index[f"K0[{r.run_id}]"]]}
        if j in self.c2_of_run:
            name, cname = self.c2_of_run[j]
            co[cname] = p[self.index[name]]
        if f"K0T[{c}]" in self.index:
            co["K0T"] = p[self.index[f"K0T[{c}]"]]
            co["K1T"] = p[self.index[f"K1T[{c}]"]]
        eff = {k: v for k, v in self.fixed.items() if r.test in EFFECTS[k].tests}
        for e in self.free_effects:
            if r.test in EFFECTS[e].tests:
                eff[e] = eff.get(e, 0.0) + p[self.index[f"effect:{e}"]]
        ri = self.index.get(f"r[{r.run_id}]")
        if ri is not None:
            eff["mass_centre_offset"] = eff.get("mass_centre_offset", 0.0) + p[ri]
        return co, eff

    def predict_run(self, p, j, extra: dict | None = None) -> np.ndarray:
        r = self.runs[j]
        co, eff = self.run_inputs(p, j)
        if extra:
            for k, v in extra.items():
                if r.test in EFFECTS[k].tests:
                    eff[k] = eff.get(k, 0.0) + v
        return r.cell_mean(rig_output(r.test, r.meta, r.cols, co, eff))

    def predict(self, p) -> np.ndarray:
        return np.concatenate([self.predict_run(p, j) for j in range(len(self.runs))])

    def z(self, p) -> np.ndarray:
        return (self.y - self.predict(p)) / self.sig

    def jac(self, p) -> np.ndarray:
        """Whitened Jacobian d(prediction)/d(param) / sigma: K1 exactly (the output is
        proportional to K1), the rest by forward differences from the run's prediction."""
        J = np.zeros((self.N, len(self.params)))
        for j in range(len(self.runs)):
            a, b = self.offsets[j], self.offsets[j + 1]
            s = self.sig[a:b]
            base = self.predict_run(p, j)
            for i in self.run_params[j]:
                q = self.params[i]
                if q.kind == "K1":
                    J[a:b, i] = base / p[i] / s if p[i] != 0 else 0.0
                    continue
                h = q.h or 1e-8
                pp = p.copy()
                pp[i] += h
                J[a:b, i] = (self.predict_run(pp, j) - base) / h / s
        return J

    def signature(self, p, effect: str, h: float | None = None) -> np.ndarray:
        """Whitened derivative of the prediction w.r.t. an effect not in the model."""
        h = h or EFFECT_STEP[effect]
        out = np.zeros(self.N)
        for j, r in enumerate(self.runs):
            if r.test not in EFFECTS[effect].tests:
                continue
            a, b = self.offsets[j], self.offsets[j + 1]
            up = self.predict_run(p, j, {effect: h})
            dn = self.predict_run(p, j, {effect: -h})
            out[a:b] = (up - dn) / (2 * h) / self.sig[a:b]
        return out

    def run_rows(self, j) -> slice:
        return slice(int(self.offsets[j]), int(self.offsets[j + 1]))


def lstsq_scaled(J: np.ndarray, r: np.ndarray, rcond: float = 1e-10):
    """Min-norm least squares on column-scaled J. Returns (delta, cov, rank)."""
    P = J.shape[1]
    s = np.linalg.norm(J, axis=0)
    act = s > (s.max() * 1e-14 if s.size and s.max() > 0 else 0)
    delta = np.zeros(P)
    cov = np.zeros((P, P))
    if not act.any():
        return delta, cov, 0
    Js = J[:, act] / s[act]
    U, S, Vt = np.linalg.svd(Js, full_matrices=False)
    keep = S > S[0] * rcond
    V = Vt[keep].T
    d = V @ ((U[:, keep].T @ r) / S[keep])
    delta[act] = d / s[act]
    C = (V / S[keep] ** 2) @ V.T
    cov[np.ix_(act, act)] = C / np.outer(s[act], s[act])
    return delta, cov, int(keep.sum())


@dataclass
class Fit:
    model: Model
    p: np.ndarray
    z: np.ndarray
    J: np.ndarray
    cov: np.ndarray
    rank: int
    chi2: float

    @property
    def dof(self) -> int:
        return max(self.model.N - self.rank, 1)

    def value(self, name):
        return float(self.p[self.model.index[name]])

    def std(self, name):
        i = self.model.index[name]
        return float(np.sqrt(max(self.cov[i, i], 0.0)))


def _lm_steps(J, r, mus):
    """Levenberg-Marquardt steps (column-scaled, via one SVD) for each damping in mus
    (relative to the largest squared singular value)."""
    P = J.shape[1]
    s = np.linalg.norm(J, axis=0)
    act = s > (s.max() * 1e-14 if s.size and s.max() > 0 else 0)
    if not act.any():
        return [np.zeros(P) for _ in mus]
    U, S, Vt = np.linalg.svd(J[:, act] / s[act], full_matrices=False)
    keep = S > S[0] * 1e-10
    U, S, V = U[:, keep], S[keep], Vt[keep].T
    ur = U.T @ r
    out = []
    for mu in mus:
        d = np.zeros(P)
        d[act] = (V @ (S / (S ** 2 + mu * S[0] ** 2) * ur)) / s[act]
        out.append(d)
    return out


def fit(model: Model, p0: np.ndarray | None = None, max_iter: int = 15) -> Fit:
    """Gauss-Newton with Levenberg-Marquardt damping when a full step does not lower chi^2
    (near-degenerate directions, e.g. K1 against the per-run scales without a tumble)."""
    p = model.initial() if p0 is None else np.array(p0, float)
    z = model.z(p)
    chi2 = float(z @ z)
    J = model.jac(p)
    mus = [0.0, 1e-12, 1e-10, 1e-8, 1e-6, 1e-4, 1e-2]
    for _ in range(max_iter):
        improved = False
        for d in _lm_steps(J, z, mus):
            pn = p + d
            zn = model.z(pn)
            cn = float(zn @ zn)
            if np.isfinite(cn) and cn <= chi2:
                improved = True
                break
        if not improved:
            break
        dec = chi2 - cn
        p, z, chi2 = pn, zn, cn
        J = model.jac(p)
        if dec < 1e-9 * chi2 + 1e-9:
            break
    delta, cov, rank = lstsq_scaled(J, z, rcond=1e-10)
    return Fit(model, p, z, J, cov, rank, chi2)
