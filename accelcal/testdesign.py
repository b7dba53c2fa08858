"""Test-design advice: which run to add to a campaign, and what it will buy.

The answer follows from the campaign model (:class:`accelcal.fitting.model.CampaignModel`)
and its Fisher information.  Every instrument coefficient the tests can touch is unknown
(the catalogue's instrument terms K0T, K1T, Koq, K3 and Kip included, whatever the
baseline), the baseline effects and any target effect are parameters, each run keeps
its own nuisances (a centrifuge run's bias, a mount's angle).  For the runs made, the
whitened Jacobian J gives the information J^T J; a proposed run adds the information of
its own rows.  The predicted covariance of a set of runs is the pseudo-inverse of the
sum (:func:`accelcal.fitting.core.lstsq_svd` of the stacked square roots, so what the
runs cannot determine stays undetermined, never a number).

A candidate run is one the rig can make, built from a run it made (its schedule, its
cells and its noise model): the same rig and schedule at another mount angle (every
45 deg), plane or vertical axis; a tumble on another head axis; a thermal run at
set-points beyond the range; a repeat (more readings per level).  Its cost is the
duration of the run it repeats.  A lab's own list replaces them
(:func:`load_candidates`).

Ranking: for each target, the expected reduction of its variance (1 when the target
becomes determined), for a pair to separate the drop of |correlation| (and whether it
falls below :data:`SEPARATED`), per minute of rig time; greedy up to ``max_runs``, with
every pair of runs tried when no single run determines a target (45 deg and 135 deg
separate Kip and Kpp; neither alone does).

References: Fedorov, *Theory of Optimal Experiments* (1972), ch. 2 (information of
independent observations is additive); JCGM 100:2008 §5 (the covariance it predicts).
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .effects import EFFECTS, coefficient_spec, plausible_size, typical_size
from .fitting.blas import single_thread
from .fitting.core import information_root, lstsq_svd
from .fitting.data import RunCells, mean_variance, pooled_noise
from .fitting.identify import Why, aliased_with, holds, mixed_with
from .constants import G_STANDARD, MOUNT_ANGLE_TOLERANCE_RAD
from .estimators.joint import (CROSS_AXIS_ABSORBED, absorbed_cross_axis, held_type_b_directions,
                               rig_input_directions, rig_input_terms, type_b_terms)
from .fitting.model import CANDIDATE_SHARED, CampaignModel, processing_effects
from .fitting.procedure import fit_selected
from .physics.axes import AXES
from .physics.geometry import CentrifugeMount, geometry_of
from .physics.rigs import INSTRUMENT_EFFECTS

#: Instrument coefficients that are catalogue effects, unknown in every advice model.
INSTRUMENT_TERMS = tuple(INSTRUMENT_EFFECTS.values())
#: |correlation| below which a pair counts as separated.
SEPARATED = 0.9
#: Mount angles a candidate may take [deg].
ANGLES_DEG = tuple(range(0, 360, 45))
#: Planes a centrifuge candidate may use (first axis first, drop-format.md).
PLANES = ("IA-PA", "IA-OA", "PA-OA")
#: Set-up time of one run (mounting the unit, settling) where the lab states none in
#: ``[rigs."ID"] setup_min`` of accelcal.toml [min].
SETUP_MIN_DEFAULT = 15.0


#: Largest number of candidates whose pairs are all tried when a target is not yet
#: determined or a pair not separated (the default list of a 20-run campaign has about 70;
#: a lab's own list may have hundreds)
PAIR_POOL = 30


class DesignError(ValueError):
    """Bad input to the advice (one line naming the target, effect or candidate)."""


@dataclass(frozen=True)
class Candidate:
    """A run the rig can make.

    Attributes
    ----------
    test, rig_id : str
        Drop-format test kind and rig.
    spec : dict
        The run in drop-format terms (``mount_plane``, ``mount_angle_deg``,
        ``vertical_axis``, ``g_levels`` [g], ``reads_per_level``; tumble ``head_axis``,
        ``cos_axis``, ``sin_axis``, ``positions_deg`` [deg]; thermal ``temp_set_c`` [degC]).
    minutes : float
        Rig time [min].
    meta : dict
        Metadata of the run (the template's, with the spec's keys).
    template : int
        Index of the run whose schedule, cells and noise model it repeats.
    temp_shift_c : float
        Shift of the template's temperatures [degC] (thermal candidates).
    """
    test: str
    rig_id: str
    spec: dict
    minutes: float
    meta: dict
    template: int
    temp_shift_c: float = 0.0

    @property
    def label(self) -> str:
        """One line in drop-format words."""
        s = self.spec
        if "mount_plane" in s:
            return (f"{self.test} {self.rig_id} {s['mount_plane']} {s['mount_angle_deg']:g}° "
                    f"{s['vertical_axis']}" + (" (repeat)" if s.get("repeat") else ""))
        if "head_axis" in s:
            return f"tumble {self.rig_id} head {s['head_axis']} cos {s['cos_axis']} sin {s['sin_axis']}"
        if "temp_set_c" in s:
            return f"tilt_rotation {self.rig_id} at {', '.join(f'{t:g}' for t in s['temp_set_c'])} °C"
        return f"{self.test} {self.rig_id}"


@dataclass
class Prediction:
    """Standard uncertainties [SI] (None: not determined) and correlations of the targets;
    for a fit of runs made (:func:`fitted_uncertainty`) also their values [SI]."""
    std_uncertainty: dict[str, float | None]
    corr: dict[str, float | None] = field(default_factory=dict)
    value: dict[str, float] = field(default_factory=dict)


@dataclass
class Proposal:
    """Runs to add, what they are predicted to give, their cost and score."""
    runs: list[Candidate]
    predicted: Prediction
    minutes: float
    gain: float

    @property
    def score(self) -> float:
        """Gain per minute of rig time [1/min]."""
        return self.gain / max(self.minutes, 1e-9)


@dataclass
class Advice:
    """The advice: targets, the current prediction, the proposals (best first), notes; the
    noise model and set-up times it assumed; the targets' current values [SI] (a relative
    u, K1's in ppm, reads against them) and the typical size each counts from while it
    is not determined (its gain's prior)."""
    targets: list[str]
    separate: list[tuple[str, str]]
    current: Prediction
    proposals: list[Proposal]
    units: dict[str, str]
    plausible: dict[str, float | None]
    notes: list[str] = field(default_factory=list)
    candidates: int = 0
    noise: list[dict] = field(default_factory=list)
    setup_min: dict[str, float] = field(default_factory=dict)
    setup_stated: list[str] = field(default_factory=list)
    values: dict[str, float] = field(default_factory=dict)
    typical: dict[str, float | None] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The JSON form: current, proposals with runs in drop-format keys."""
        return {"targets": self.targets, "units": self.units,
                "current": {"std_uncertainty": self.current.std_uncertainty, "corr": self.current.corr},
                "proposals": [{"runs": [{"test": c.test, "rig_id": c.rig_id, **c.spec} for c in p.runs],
                               "predicted": {"std_uncertainty": p.predicted.std_uncertainty,
                                             "corr": p.predicted.corr},
                               "minutes": round(p.minutes, 1), "gain": round(p.gain, 4)}
                              for p in self.proposals],
                "candidates": self.candidates, "notes": self.notes, "noise": self.noise,
                "setup_min": self.setup_min, "values": self.values}


# ----------------------------------------------------------------------------- candidates

def _minutes(run: RunCells) -> float:
    t = run.cols.get("time_s")
    if t is None or t.size < 2:
        return 1.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max((float(np.nanmax(t) - np.nanmin(t)) + dt) / 60.0, 1e-3)


def _g_levels(run: RunCells) -> list[float]:
    g = float(run.meta.get("g_local_m_s2") or 9.80665)
    return sorted({round(float(v) / g, 1) for v in run.x if v > 0})


def _reads(run: RunCells) -> int:
    return int(np.median(run.n)) if run.n.size else 0


def _mount_spec(plane: str, angle: float, vertical: str, run: RunCells) -> dict:
    return {"mount_plane": plane, "mount_angle_deg": float(angle), "vertical_axis": vertical,
            "g_levels": _g_levels(run), "reads_per_level": _reads(run)}


def _verticals(plane: str) -> list[str]:
    a, b = plane.split("-")
    third = next(x for x in AXES if x not in (a, b))
    return [f"+{third}", f"-{third}"]


def candidate_runs(cells: Sequence[RunCells]) -> list[Candidate]:
    """The runs each rig of ``cells`` can make (module docstring), from the first run of each
    (rig, test) as template.

    Parameters
    ----------
    cells : sequence of RunCells
        The campaign's runs, with noise models.

    Returns
    -------
    list of Candidate
    """
    out: list[Candidate] = []
    made = {(r.rig_id, r.test, r.geometry.label) for r in cells}
    seen: set[tuple[str, str]] = set()
    for j, r in enumerate(cells):
        key = (r.rig_id, r.test)
        if key in seen:
            continue
        seen.add(key)
        mins = _minutes(r)
        if r.test in ("centrifuge", "sine_centrifuge"):
            for plane in PLANES:
                for vert in _verticals(plane):
                    for ang in ANGLES_DEG:
                        meta = {**r.meta, "mount_plane": plane, "mount_angle_deg": float(ang), "vertical_axis": vert}
                        try:
                            geo = geometry_of(meta)
                        except ValueError:
                            continue
                        spec = _mount_spec(plane, ang, vert, r)
                        if (r.rig_id, r.test, geo.label) in made:
                            if (plane, float(ang)) != (r.meta.get("mount_plane"), float(r.meta.get("mount_angle_deg", 0))):
                                continue
                            spec["repeat"] = True
                        out.append(Candidate(r.test, r.rig_id, spec, mins, meta, j))
        elif r.test == "tumble":
            for head in AXES:
                others = [a for a in AXES if a != head]
                for ca, sa in (others, others[::-1]):
                    meta = {**r.meta, "head_axis": head, "cos_axis": f"+{ca}", "sin_axis": f"+{sa}"}
                    try:
                        geo = geometry_of(meta)
                    except ValueError:
                        continue
                    spec = {"head_axis": head, "cos_axis": f"+{ca}", "sin_axis": f"+{sa}",
                            "positions_deg": sorted({round(float(a), 3) for a in r.cols.get("angle_deg", [])}),
                            "reads_per_level": _reads(r)}
                    if (r.rig_id, r.test, geo.label) in made:
                        spec["repeat"] = True
                    out.append(Candidate(r.test, r.rig_id, spec, mins, meta, j))
        elif r.test == "tilt_rotation":
            sets = np.unique(r.cols.get("temp_set_c", np.zeros(0)))
            span = float(np.ptp(sets)) if sets.size > 1 else 10.0
            for shift in (-span, span):
                spec = {"temp_set_c": [float(t + shift) for t in sets], "positions": int(r.meta.get("positions", 0))}
                out.append(Candidate(r.test, r.rig_id, spec, mins, dict(r.meta), j, temp_shift_c=shift))
    return out


def load_candidates(path, cells: Sequence[RunCells], rig_max_g: Mapping[str, float] | None = None
                    ) -> list[Candidate]:
    """The lab's own candidate runs from a TOML file: ``[[run]]`` tables with ``test``,
    ``rig_id``, the geometry keys of drop-format.md, optionally ``minutes``.

    Parameters
    ----------
    path : str or Path
        The TOML file.
    cells : sequence of RunCells
        The runs made: a candidate takes the schedule of a run of its rig and test.
    rig_max_g : mapping, optional
        Rig id -> highest g level it may run [g] (``accelcal.toml`` ``[rigs."ID"] max_g``).

    Returns
    -------
    list of Candidate

    Raises
    ------
    DesignError
        One line naming the file, the run and the rule it breaks.
    """
    import tomllib
    from pathlib import Path
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise DesignError(f"{p}: cannot read the candidates: {exc}") from None
    out = []
    for k, row in enumerate(doc.get("run", []), 1):
        where = f"{p}: [[run]] {k}"
        test, rig = str(row.get("test", "")), str(row.get("rig_id", ""))
        tmpl = next((j for j, r in enumerate(cells) if r.test == test and r.rig_id == rig), None)
        if tmpl is None:
            raise DesignError(f"{where}: no {test or '(no test)'} run of rig {rig or '(no rig_id)'} in these data "
                              "to take its schedule from")
        r = cells[tmpl]
        keys = {k2: v for k2, v in row.items() if k2 not in ("test", "rig_id", "minutes")}
        meta = {**r.meta, **keys}
        try:
            geometry_of(meta)
        except (ValueError, KeyError) as exc:
            raise DesignError(f"{where}: {exc}") from None
        levels = row.get("g_levels")
        top = max(_g_levels(r), default=0.0)
        lim = (rig_max_g or {}).get(rig)
        if levels:
            if lim is not None and max(levels) > lim:
                raise DesignError(f"{where}: g level {max(levels):g} beyond rig {rig}'s limit {lim:g} g")
            if max(levels) > top + 0.05:
                raise DesignError(f"{where}: g level {max(levels):g} above the {top:g} g these runs reached "
                                  "(no schedule to repeat)")
        spec = {**keys}
        if test in ("centrifuge", "sine_centrifuge"):
            spec = {**_mount_spec(str(meta["mount_plane"]), float(meta["mount_angle_deg"]),
                                  str(meta["vertical_axis"]), r), **keys}
        out.append(Candidate(test, rig, spec, float(row.get("minutes", _minutes(r))), meta, tmpl))
    if not out:
        raise DesignError(f"{p}: no [[run]] table")
    return out


def candidate_cells(c: Candidate, cells: Sequence[RunCells], index: int) -> RunCells:
    """The cells of a candidate: its template's schedule, cells and noise model on the
    candidate's geometry (and temperatures)."""
    r = cells[c.template]
    meta = {**c.meta, "run_id": f"proposed-{index}"}
    cols = r.cols
    if c.temp_shift_c:
        cols = dict(cols)
        for k in ("temp_c", "temp_set_c"):
            if k in cols:
                cols[k] = cols[k] + c.temp_shift_c
    out = replace(r, index=index, meta=meta, geometry=geometry_of(meta), cols=cols, sha256="", notes=[])
    peers = [x for x in cells if x.test == r.test and x.rig_id == r.rig_id]
    noise = pooled_noise(peers)
    if noise is not None:               # the rig's noise, not one run's estimate of it
        shares = [(_ia_share(x.geometry), x.noise) for x in peers if x.noise is not None
                  and math.isfinite(x.noise.a) and _ia_share(x.geometry) > 0.3]
        if shares and noise.b > 0:
            # the rate-proportional part is rate jitter seen through IA's share of the
            # centripetal direction: per unit share squared, then at the candidate's share
            w = [max(m.dof, 1) for _, m in shares]
            b1 = sum(wk * m.b / sh ** 2 for wk, (sh, m) in zip(w, shares)) / sum(w)
            noise = replace(noise, b=b1 * _ia_share(out.geometry) ** 2)
        out.noise, out.var_mean = noise, mean_variance(out, noise)
    return out


def _ia_share(geo) -> float:
    """|IA component| of the unit vector towards the spindle of a centrifuge mount [1]
    (drop-format.md: it makes angle phi with the first plane axis, towards the second);
    1 for other rigs (their level noise does not depend on the mount)."""
    if not isinstance(geo, CentrifugeMount):
        return 1.0
    c, s = math.cos(geo.phi_rad), math.sin(geo.phi_rad)
    return abs(c) if geo.e1 == 0 else (abs(s) if geo.e2 == 0 else 0.0)


# ----------------------------------------------------------------------------- targets

def _model(cells: Sequence[RunCells], effects: Sequence[str], extra: Sequence[str] = ()) -> CampaignModel:
    """The advice model: the effects, every instrument term; an effect the baseline leaves
    out (``extra``) in the form the diagnosis looks for it, a mount angle error as one angle
    shared by every mount (:meth:`accelcal.diagnosis.fits.Fitter.fit`)."""
    return CampaignModel(cells, effects, include=INSTRUMENT_TERMS,
                         shared=[e for e in CANDIDATE_SHARED if e in extra])


def resolve_targets(model: CampaignModel, targets: Sequence[str]) -> dict[str, list[int]]:
    """Target name -> parameter indices: a coefficient (K2, Kip) or an effect id.

    Raises
    ------
    DesignError
        For a name the model does not know.
    """
    out: dict[str, list[int]] = {}
    for t in targets:
        t_coef = INSTRUMENT_EFFECTS.get(t, t)
        idx = [i for i, role in enumerate(model.roles)
               if (role.kind == "coef" and role.key == t_coef) or (role.kind == "effect" and role.key == t)]
        if not idx:
            if t not in EFFECTS and coefficient_spec(t) is None:
                raise DesignError(f"target {t!r}: neither a coefficient nor an effects.md id")
            raise DesignError(f"target {t!r}: not a parameter of these runs' model (tests: "
                              f"{', '.join(sorted({r.test for r in model.runs}))})")
        out[t] = idx
    return out


# ----------------------------------------------------------------------------- prediction

class _Information:
    """The information of the runs made (square root) and of each candidate (rows), at the
    estimate and with the candidates' own unknown geometry (a new mount's angle, a new
    head's misalignment) at plus and minus its typical size: a run whose information hinges
    on a nuisance not yet measured is judged at the worse of the three."""

    def __init__(self, model: CampaignModel, n_made: int, p: np.ndarray,
                 stated: Mapping[str, Mapping[str, float]] | None = None):
        self.model = model
        self.n_made = n_made
        made_rows = slice(0, int(model.offsets[n_made]))
        self.cols_made = sorted({i for j in range(n_made) for i in model.run_params[j]})
        J = model.jacobian(p)
        self.R0 = information_root(J[made_rows][:, self.cols_made])
        # the radius rule of the rank decision matters only where the runs made leave the
        # radius to K1 (no gravity reference); a run added only adds information
        made = model.columns(self.cols_made)
        self.scale_rule = ({k: h.reason for k, h in holds(self.R0, made, name_aliases=False).items()}
                           != {k: h.reason for k, h in holds(self.R0, made, name_aliases=False,
                                                             scale_rule=False).items()})
        new = [i for i, r in enumerate(model.roles) if r.kind == "effect" and i not in set(self.cols_made)]
        self.Js = [J]
        for sign in (1.0, -1.0):
            if not new:
                break
            q = p.copy()
            for i in new:
                q[i] = p[i] + sign * typical_size(model.roles[i].key)
            # only the candidates' rows are read at these points (the runs made keep R0)
            Jq = np.zeros_like(J)
            for j in range(n_made, len(model.runs)):
                sl = model.rows(j)
                Jq[sl] = model.jacobian_run(q, j) / model.sig[sl, None]
            self.Js.append(Jq)
        # the type-B inputs the pipeline's budget adds (estimators.joint: the angles of
        # radial mounts, IA tilt, the stated rig inputs), as (u, direction) pairs; a
        # design's sensitivities follow from J^T d over its rows (made + proposed)
        fixed = [(uB, [d]) for _, d, uB, _ in held_type_b_directions(model, p, {})]
        fixed += [(u, dirs) for _, _, dirs, u, _ in rig_input_directions(model, p, stated or {})[0]]
        self.type_b = [(u, d) for u, dirs in fixed for d in dirs]
        self._g_made = [self.Js[0][made_rows].T @ d[made_rows] for _, d in self.type_b]
        self._g_run: dict[tuple[int, int], list[np.ndarray]] = {}
        self._solved: dict[tuple[tuple[int, ...], int], tuple] = {}

    def type_b_gradient(self, runs: Sequence[int], k: int) -> list[np.ndarray]:
        """J^T d of each type-B direction over the rows of the runs made plus ``runs``,
        candidate rows from ``self.Js[k]`` [1 per parameter unit per input unit]."""
        out = [g.copy() for g in self._g_made]
        for j in runs:
            key = (k, j)
            if key not in self._g_run:
                sl = self.model.rows(j)
                self._g_run[key] = [self.Js[k][sl].T @ d[sl] for _, d in self.type_b]
            for g, gj in zip(out, self._g_run[key]):
                g += gj
        return out

    def cols(self, runs: Sequence[int]) -> list[int]:
        extra = {i for j in runs for i in self.model.run_params[j]}
        return sorted(set(self.cols_made) | extra)

    def solve(self, runs: Sequence[int], k_J: int):
        """(columns, names held, lstsq_svd solution over the others, type-B variance of
        each) of the runs made plus ``runs`` (model indices) with candidate rows from
        ``self.Js[k_J]``: the parameters the joint fit of those runs would hold
        (:func:`accelcal.fitting.identify.holds` on the stacked square root) are held here
        too, and the type-B terms its budget would add
        (:func:`accelcal.estimators.joint.held_type_b_directions`,
        :func:`~accelcal.estimators.joint.rig_input_directions`) are added: the bias each
        input transfers, (J^T J)^+ J^T d u.  Kept per (runs, k_J): it depends on nothing
        else, and the questions of one advice session ask for the same designs."""
        key = (tuple(runs), k_J)
        if key not in self._solved:
            self._solved[key] = self._solve(runs, k_J)
        return self._solved[key]

    def _solve(self, runs: Sequence[int], k_J: int):
        J = self.Js[k_J]
        cols = self.cols(runs)
        pos = {c: k for k, c in enumerate(cols)}
        R = np.zeros((self.R0.shape[0], len(cols)))
        for k, c in enumerate(self.cols_made):
            R[:, pos[c]] = self.R0[:, k]
        A = np.vstack([R] + [J[self.model.rows(j)][:, cols] for j in runs])
        held = holds(A, self.model.columns(cols), name_aliases=False, scale_rule=self.scale_rule)
        free = [c for c in cols if self.model.candidates[c].name not in held]
        Af = A[:, [pos[c] for c in free]]
        sol = lstsq_svd(Af, np.zeros(A.shape[0]))
        ali = [pos[c] for c in cols if getattr(held.get(self.model.candidates[c].name), "why", None) is Why.ALIASED]
        mixed = {free[m] for m in np.flatnonzero(mixed_with(Af, A[:, ali], sol.cov))} if ali else set()
        var_b = np.zeros(len(free))
        for (u, _), g in zip(self.type_b, self.type_b_gradient(runs, k_J)):
            var_b += (u * (sol.cov @ g[free])) ** 2
        names = self.model.params.names
        kept = [pos[c] for c in free]
        # the aliases are named only for the holds the budget may add a term for
        index, roles = self.model.params.index, self.model.roles
        named = {n: replace(h, aliased_with=tuple(names[cols[m]] for m in aliased_with(A, pos[index[n]], kept)))
                 for n, h in held.items()
                 if h.why is Why.ALIASED and roles[index[n]].key in CROSS_AXIS_ABSORBED}
        for _, i, absorbers in absorbed_cross_axis(self.model, named):
            g = A[:, [pos[c] for c in free]].T @ A[:, pos[i]]
            sens = sol.cov @ g
            keep = np.array([names[c] not in absorbers for c in free])
            var_b += keep * (MOUNT_ANGLE_TOLERANCE_RAD / math.sqrt(3.0) * sens) ** 2
        return free, mixed, sol, var_b


def _predict(info: _Information, runs: Sequence[int], targets: Mapping[str, list[int]],
             pairs: Sequence[tuple[str, str]]) -> Prediction:
    """The prediction for the runs made plus ``runs``: the worst over the candidates'
    unknown geometry (:class:`_Information`), by the number of targets left undetermined,
    then the sum of the relative variances."""
    preds = [_predict_at(info, runs, targets, pairs, k) for k in range(len(info.Js) if runs else 1)]

    def badness(pr: Prediction):
        us = list(pr.std_uncertainty.values())
        ref = preds[0].std_uncertainty
        return (sum(u is None for u in us),
                sum((u / ref[k]) ** 2 for k, u in pr.std_uncertainty.items() if u is not None and ref.get(k)))
    return max(preds, key=badness)


def _determined(u: float, key: str) -> float | None:
    """A standard uncertainty [parameter unit] as a determination, or None: not finite or
    not positive, or beyond the parameter's plausible size, as the model's own selection
    says (:meth:`CampaignModel.select`)."""
    lim = plausible_size(key)
    return float(u) if math.isfinite(u) and u > 0 and (lim is None or u <= lim) else None


def _predict_at(info: _Information, runs: Sequence[int], targets: Mapping[str, list[int]],
                pairs: Sequence[tuple[str, str]], k_J: int) -> Prediction:
    cols, mixed, sol, var_b = info.solve(runs, k_J)
    pos = {c: k for k, c in enumerate(cols)}
    names = info.model.params.names
    std: dict[str, float | None] = {}
    for t, idx in targets.items():
        for i in idx:
            k = pos.get(i)
            u = (math.sqrt(sol.cov[k, k] + var_b[k]) if k is not None and i not in mixed and sol.estimable[k]
                 and sol.cov[k, k] > 0 else float("nan"))
            std[names[i] if len(idx) > 1 else t] = _determined(u, info.model.params[i].key)
    corr: dict[str, float | None] = {}
    for a, b in pairs:
        ia, ib = targets[a][0], targets[b][0]
        ka, kb = pos.get(ia), pos.get(ib)
        if ka is None or kb is None or ia in mixed or ib in mixed or not (sol.estimable[ka] and sol.estimable[kb]):
            corr[f"{a}|{b}"] = None
            continue
        d = math.sqrt(sol.cov[ka, ka] * sol.cov[kb, kb])
        corr[f"{a}|{b}"] = float(sol.cov[ka, kb] / d) if d > 0 else None
    return Prediction(std, corr)


def _gain(cur: Prediction, new: Prediction, prior: Mapping[str, float | None]) -> float:
    """Sum over the targets of the relative variance reduction, a target not determined now
    counting with its typical size as its uncertainty (what is known of it before any run,
    the catalogue's :func:`accelcal.effects.typical_size`), plus for each pair the drop of |correlation| and 1 when it falls below
    :data:`SEPARATED`."""
    g = 0.0
    for k, u0 in cur.std_uncertainty.items():
        u1 = new.std_uncertainty.get(k)
        if u1 is None:
            continue
        u0 = prior.get(k) if u0 is None else u0
        g += 1.0 if not u0 else max(0.0, 1.0 - (u1 / u0) ** 2)
    for k, r0 in cur.corr.items():
        r1 = new.corr.get(k)
        if r1 is None:
            continue
        a0 = 1.0 if r0 is None else abs(r0)
        g += max(0.0, a0 - abs(r1)) + (1.0 if abs(r1) < SEPARATED <= a0 else 0.0)
    return g


def _target_information(info: _Information, runs: Sequence[int], targets: Mapping[str, list[int]]
                        ) -> list[float]:
    """Squared norm of each run's whitened rows in the targets' columns [1, summed], each
    column scaled by its norm over every run of the model (made and candidate), so that
    units do not weigh."""
    idx = sorted({i for ix in targets.values() for i in ix})
    J = info.Js[0][:, idx]
    scale = np.linalg.norm(J, axis=0)
    J = J / np.where(scale > 0, scale, 1.0)
    return [float(np.sum(J[info.model.rows(j)] ** 2)) for j in runs]


def _touches(info: _Information, j: int, targets: Mapping[str, list[int]]) -> bool:
    rows = info.Js[0][info.model.rows(j)]
    return any(np.any(rows[:, i]) for idx in targets.values() for i in idx)


def advise(cells: Sequence[RunCells], baseline: Sequence[str], targets: Sequence[str] | None = None,
           separate: Sequence[tuple[str, str]] = (), max_runs: int = 2,
           candidates: Sequence[Candidate] | None = None, top: int = 5,
           stated: Mapping[str, Mapping[str, float]] | None = None,
           setup_min: Mapping[str, float] | None = None, session: dict | None = None) -> Advice:
    """Which runs to add to ``cells`` for the targets, best first.

    Each prediction is what the pipeline will report: the joint fit's type-A uncertainty
    with the noise model fitted to the campaign's runs (:attr:`Advice.noise`), plus every
    type-B term its budget adds (:func:`accelcal.estimators.joint.held_type_b_directions`,
    :func:`~accelcal.estimators.joint.rig_input_directions`).  A run costs its duration
    plus the rig's set-up time.

    Parameters
    ----------
    cells : sequence of RunCells
        The runs made, with noise models (:func:`accelcal.diagnosis.core.prepare_cells`).
    baseline : sequence of str
        Effects the model includes (effects.md ids).
    targets : sequence of str, optional
        Coefficients or effect ids; default every instrument coefficient of the model.
    separate : sequence of (str, str)
        Pairs whose correlation should fall below :data:`SEPARATED`.
    max_runs : int
        Largest set of runs proposed together.
    candidates : sequence of Candidate, optional
        Default :func:`candidate_runs`.
    top : int
        Proposals returned.
    stated : mapping, optional
        Rig id -> rig input id -> standard uncertainty the lab states
        (:func:`accelcal.config.rig_uncertainties`), as the pipeline's budget reads it.
    setup_min : mapping of str to float, optional
        Rig id -> set-up time of one run [min] (``[rigs."ID"] setup_min``); default
        :data:`SETUP_MIN_DEFAULT`.
    session : dict, optional
        Kept between calls on the same ``cells`` (one per question list,
        :func:`next_runs`): the fit of the runs made and the prediction of every design
        already judged, per model (baseline, added effects, candidates and stated rig
        inputs), so that questions sharing a model pay for it once; the answers are those
        of separate calls.

    Returns
    -------
    Advice
        Standard uncertainties in SI units of each target (None: not determined).

    Raises
    ------
    DesignError
        For an unknown target or effect id.
    """
    with single_thread():            # many small dense solves: one BLAS thread is the fast one
        return _advise(list(cells), baseline, targets, separate, max_runs, candidates, top, stated or {},
                       setup_min or {}, {} if session is None else session)


def _advise(cells, baseline, targets, separate, max_runs, candidates, top, stated, setup_min, session) -> Advice:
    for e in baseline:
        if e not in EFFECTS:
            raise DesignError(f"baseline effect {e!r}: not an effects.md id")
    targets = list(targets or [])
    for a, b in separate:
        targets += [x for x in (a, b) if x not in targets]
    extra = [t for t in targets if t in EFFECTS and t not in baseline and t not in INSTRUMENT_EFFECTS]
    effects = list(baseline) + extra
    cands = list(candidate_runs(cells) if candidates is None else candidates)
    # to see an effect the baseline leaves out, a run of a test it acts on (effects.md): a
    # tumble measures Kip as the unit's coefficient, not cross_coupling, the centrifuge
    # effect the diagnosis would then name
    seen = [t for t in targets if t in EFFECTS and t not in baseline]
    if seen:
        cands = [c for c in cands if any(c.test in EFFECTS[t].tests for t in seen)]
    # the runs made, fitted as the advice model (noise refitted to its residuals, which is
    # the noise a fit of the augmented campaign will see)
    # every field of every candidate, and the stated rig inputs the type-B terms read
    key = (tuple(effects), tuple(extra), repr(cands), repr(sorted(stated.items())))
    if key not in session:
        made = _model(cells, effects, extra)
        made_fit = fit_selected(made)
        made_cells, p_made = made_fit.model.runs, made_fit.fit.values
        cand_cells = [candidate_cells(c, made_cells, len(made_cells) + k) for k, c in enumerate(cands)]
        model = _model(made_cells + cand_cells, effects, extra)
        p = model.params.values()
        for i, prm in enumerate(model.params):
            k = made.params.index.get(prm.name)
            if k is not None:
                p[i] = p_made[k]
        session[key] = (made, made_cells, p_made, model, p, _Information(model, len(made_cells), p, stated))
    made, cells, p_made, model, p, info = session[key]
    if not targets:
        targets = list(dict.fromkeys(prm.key for prm, role in zip(made.params, made.roles) if role.kind == "coef"))
    tmap = resolve_targets(model, targets)
    setup = {c.rig_id: float(setup_min.get(c.rig_id, SETUP_MIN_DEFAULT)) for c in cands}
    cost = [c.minutes + setup[c.rig_id] for c in cands]
    cur = _predict(info, [], tmap, separate)
    n0 = len(cells)
    names = list(cur.std_uncertainty)
    units, plaus, prior = {}, {}, {}
    for n in names:
        base = n.split("[", 1)[0]
        spec = coefficient_spec(base)
        known = base in EFFECTS or spec is not None
        units[n] = spec.unit if spec is not None else (EFFECTS[base].unit if base in EFFECTS else "")
        plaus[n] = plausible_size(base) if known else None
        prior[n] = typical_size(base) if known else None
    singles = []
    for k in range(len(cands)):
        pred = _predict(info, [n0 + k], tmap, separate)
        singles.append(Proposal([cands[k]], pred, cost[k], _gain(cur, pred, prior)))
    props = list(singles)
    if max_runs >= 2 and cands:
        best = max(singles, key=lambda s: s.score)
        kb = cands.index(best.runs[0])
        for k in range(len(cands)):
            if k != kb:
                pred = _predict(info, [n0 + kb, n0 + k], tmap, separate)
                props.append(Proposal([cands[kb], cands[k]], pred, cost[kb] + cost[k],
                                      _gain(cur, pred, prior)))
        still = [t for t, u in cur.std_uncertainty.items() if u is None
                 and all(s.predicted.std_uncertainty.get(t) is None for s in singles)]
        if still or any(r is None or abs(r) >= SEPARATED for r in cur.corr.values()):
            near = [k for k in range(len(cands)) if _touches(info, n0 + k, tmap)]
            if len(near) > PAIR_POOL:
                # a lab's list of hundreds: pairs among the runs that carry the most
                # information on the targets per minute (each pair is a full prediction)
                weight = _target_information(info, [n0 + k for k in near], tmap)
                per_minute = {k: -w / max(cost[k], 1e-9) for k, w in zip(near, weight)}
                near = sorted(sorted(near, key=per_minute.__getitem__)[:PAIR_POOL])
            for a, b in itertools.combinations(near, 2):
                if (cands[a].rig_id, cands[a].test) != (cands[b].rig_id, cands[b].test):
                    continue
                pred = _predict(info, [n0 + a, n0 + b], tmap, separate)
                props.append(Proposal([cands[a], cands[b]], pred, cost[a] + cost[b],
                                      _gain(cur, pred, prior)))
    props = [q for q in props if q.gain > 1e-9]
    props.sort(key=lambda q: (-q.score, q.minutes, [c.label for c in q.runs]))
    out, seen = [], set()
    for q in props:
        key = frozenset(c.label for c in q.runs)
        if key in seen:
            continue
        seen.add(key)
        out.append(q)
        if len(out) >= top:
            break
    notes = [f"{n}: no run these rigs can make determines it (with every instrument coefficient unknown)"
             for n, u in cur.std_uncertainty.items()
             if u is None and all(q.predicted.std_uncertainty.get(n) is None for q in props)]
    if not out:
        notes.append("no candidate run improves the targets")
    return Advice(targets=list(tmap), separate=list(separate), current=cur, proposals=out, units=units,
                  plausible=plaus, notes=notes, candidates=len(cands),
                  noise=noise_statement(cells, _scale_factor(made, p_made)),
                  setup_min=setup, setup_stated=sorted(set(setup) & set(setup_min)), typical=prior, values={(model.params.names[i] if len(ix) > 1 else t): float(p[i])
                                           for t, ix in tmap.items() for i in ix})


def _scale_factor(model: CampaignModel, p: np.ndarray) -> float | None:
    """The campaign's fitted K1 [output unit per m/s2], None where the model has none."""
    k = model.params.index.get("K1")
    return float(p[k]) if k is not None and p[k] else None


def noise_statement(cells: Sequence[RunCells], k1: float | None = None) -> list[dict]:
    """The noise model behind every prediction, per rig and test: the runs' noise pooled
    (:func:`accelcal.fitting.data.pooled_noise`), fitted to the campaign's residuals.

    Returns
    -------
    list of dict
        ``rig_id``, ``test``, ``runs``, ``sigma`` (white noise of one reading
        [output unit]), ``rate_sigma_per_m_s2`` (the rate-proportional part's standard
        deviation per m/s2 of centripetal level [output unit / (m/s2)], 0 when none: rate
        jitter, which a proposed centrifuge mount sees through IA's share of the radius),
        ``rho`` (lag-1 autocorrelation [1]), ``output_unit``, ``source``, and with
        ``k1`` (the scale factor [output unit per m/s2]) ``sigma_ug``: the white noise as
        an input acceleration [µg].
    """
    out = []
    for rig, test in sorted({(c.rig_id, c.test) for c in cells}):
        peers = [c for c in cells if c.rig_id == rig and c.test == test]
        nm = pooled_noise(peers)
        if nm is None or not math.isfinite(nm.a):
            continue
        out.append({"rig_id": rig, "test": test, "runs": len(peers), "sigma": math.sqrt(max(nm.a, 0.0)),
                    "rate_sigma_per_m_s2": math.sqrt(max(nm.b, 0.0)), "rho": float(nm.rho),
                    "output_unit": str(peers[0].meta.get("output_unit", "out")), "source": nm.source})
        if k1:
            out[-1]["sigma_ug"] = out[-1]["sigma"] / abs(k1) / G_STANDARD * 1e6
    return out


def fitted_uncertainty(cells: Sequence[RunCells], baseline: Sequence[str], targets: Sequence[str],
                       separate: Sequence[tuple[str, str]] = (),
                       stated: Mapping[str, Mapping[str, float]] | None = None) -> Prediction:
    """The standard uncertainties the advice model gives when fitted to runs made: what a
    prediction of :func:`advise` is checked against once its runs exist.

    Parameters
    ----------
    cells : sequence of RunCells
        The runs, with noise models.
    baseline : sequence of str
        Effects of the model (as given to :func:`advise`).
    targets : sequence of str
        Coefficients or effect ids.

    separate : sequence of (str, str)
        Pairs whose correlation is wanted.

    stated : mapping, optional
        As for :func:`advise`.

    Returns
    -------
    Prediction
        Target -> standard uncertainty [SI] of the fit (noise model refitted to its
        residuals, lack-of-fit scaled; :func:`accelcal.fitting.procedure.fit_model`) with
        the type-B terms the pipeline's budget adds (:func:`accelcal.estimators.joint.type_b_terms`,
        :func:`~accelcal.estimators.joint.rig_input_terms`), None when not determined (as
        :func:`advise` says it); the pairs' correlations.
    """
    targets = list(targets) + [x for ab in separate for x in ab if x not in targets]
    extra = [t for t in targets if t in EFFECTS and t not in baseline and t not in INSTRUMENT_EFFECTS]
    model = _model(list(cells), list(baseline) + extra, extra)
    tmap = resolve_targets(model, targets)
    mf = fit_selected(model)
    out: dict[str, float | None] = {}
    values: dict[str, float] = {}
    mixed = {n for h in mf.held.values() if h.why is Why.ALIASED for n in h.aliased_with}
    type_b = {n: [c * u for _, c, u in v] for n, v in type_b_terms(mf).items()}
    for n, v in rig_input_terms(mf, stated or {})[0].items():
        type_b.setdefault(n, []).extend(c * u for _, c, u, _, _ in v)
    for t, idx in tmap.items():
        for i in idx:
            name = model.params.names[i]
            u = (math.sqrt(mf.fit.std(name) ** 2 + sum(x * x for x in type_b.get(name, [])))
                 if name not in mixed else float("nan"))
            out[name if len(idx) > 1 else t] = _determined(u, model.params[i].key)
            values[name if len(idx) > 1 else t] = float(mf.fit.values[i])
    corr: dict[str, float | None] = {}
    for a, b in separate:
        na, nb = model.params.names[tmap[a][0]], model.params.names[tmap[b][0]]
        if out.get(a) is None or out.get(b) is None:
            corr[f"{a}|{b}"] = None
            continue
        _, R = mf.fit.correlation([na, nb])
        corr[f"{a}|{b}"] = float(R[0, 1])
    return Prediction(out, corr, values)



#: Readings of a campaign above which the certificate leaves the separating run to
#: ``accelcal design``: the advice refits the runs made reading by reading, for every pair
SEPARATION_MAX_READINGS = 1_000_000


def separating_run_flag(cells: Sequence[RunCells], pair: tuple[str, str], session: dict | None = None,
                        **lab) -> str | None:
    """The certificate's line for a pair of coefficients the runs determine only together:
    ``accelcal design --separate A,B --max-runs 1``'s first proposal (:func:`advise` with
    the pipeline's processing model), asked when a person reads the result.

    Parameters
    ----------
    cells : sequence of RunCells
        The campaign's runs as ``accelcal design`` reads them
        (:func:`accelcal.diagnosis.core.prepare_cells`).
    pair : (str, str)
        The aliased pair (:func:`accelcal.estimators.joint.stored_aliased_pairs`).
    session : dict, optional
        :func:`advise`'s, shared by the pairs of one campaign.
    **lab
        The lab's statements (:func:`accelcal.config.advice_inputs`), as ``accelcal
        design`` passes them.

    Returns
    -------
    str or None
        ``"A, B: one more run would separate them: <run> (accelcal design --separate A,B
        --max-runs 1)"``, or that no single run does; None for a campaign above
        :data:`SEPARATION_MAX_READINGS` readings or advice that cannot judge the pair (the
        stored flag then names the command).
    """
    if not cells or sum(c.y_rows.size for c in cells) > SEPARATION_MAX_READINGS:
        return None
    try:
        adv = advise(cells, processing_effects(sorted({c.test for c in cells})), None, [pair], max_runs=1, top=1,
                     session=session, **lab)
    except (DesignError, ValueError, np.linalg.LinAlgError):
        return None
    ask = f"(accelcal design --separate {pair[0]},{pair[1]} --max-runs 1)"
    if not adv.proposals:
        return f"{pair[0]}, {pair[1]}: no single run these rigs can make separates them {ask}"
    run = " + ".join(c.label for c in adv.proposals[0].runs)
    return f"{pair[0]}, {pair[1]}: one more run would separate them: {run} {ask}"


def next_runs(runs, res, **lab) -> list[dict]:
    """For each effect the runs cannot see and each alias the diagnosis names, the best
    single run the rigs can make to fix it, or the best two where no single run does
    (:func:`advise`).

    Parameters
    ----------
    runs : list of RunFile
        The runs diagnosed.
    res : dict
        :func:`accelcal.diagnosis.core.diagnose`'s result (``unobservable``, ``ranking``
        with ``aliases``, ``baseline``).
    **lab
        The lab's statements (:func:`accelcal.config.advice_inputs`), as ``accelcal
        design`` passes them.

    Returns
    -------
    list of dict
        ``to`` (what it fixes), ``run`` (drop-format words) and ``runs`` (keys), ``minutes``
        [min], ``predicted`` (standard uncertainties [SI]); or ``note`` when no single run
        does.
    """
    from .diagnosis.core import prepare_cells
    asks = [(f"see {u['effect']}", [u["effect"]], []) for u in res.get("unobservable") or []]
    for r in res.get("ranking") or []:
        for a in r.get("aliases") or []:
            other = a if isinstance(a, str) else a.get("effect")
            if other:
                asks.append((f"separate {r['effect']} from {other}", [], [(r["effect"], other)]))
    if not asks:
        return []
    cells, _ = prepare_cells(runs)
    base = list((res.get("baseline") or {}).get("effects") or [])
    out, session = [], {}
    for what, targets, pairs in asks:
        try:
            adv = advise(cells, base, targets or None, pairs, max_runs=1, top=1, session=session, **lab)
            # seeing an effect may take two runs (Kip beside an unknown Kpp: 45 + 135 deg);
            # telling an effect from a coefficient by two runs of other planes leans on
            # second-order terms, and the plain answer is the gravity reference below
            if not adv.proposals and targets:
                adv = advise(cells, base, targets, pairs, max_runs=2, top=1, session=session, **lab)
        except (DesignError, ValueError, np.linalg.LinAlgError) as exc:
            out.append({"to": what, "note": f"no advice: {exc}"})
            continue
        if not adv.proposals:
            other = pairs[0][1] if pairs else None
            gravity = (other is not None and coefficient_spec(other) is not None
                       and not any(r.meta.get("test") == "tumble" for r in runs))
            out.append({"to": what, "note": ("no run or pair of runs these rigs can make does it" if targets
                                             else "no single run these rigs can make does it") + (
                f"; a tumble in the gravity field measures the unit's {other} on its own" if gravity else "")})
            continue
        p = adv.proposals[0]
        out.append({"to": what, "run": " + ".join(c.label for c in p.runs),
                    "runs": [{"test": c.test, "rig_id": c.rig_id, **c.spec} for c in p.runs],
                    "minutes": round(p.minutes, 1), "predicted": p.predicted.std_uncertainty})
    return out
