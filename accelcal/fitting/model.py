"""The campaign model: the one forward model (:func:`accelcal.physics.rig_output`) with its
parameters made free, over every reading of every run of one or more campaigns.

It is what the joint fit (the adopted calibration, :mod:`accelcal.estimators.joint`) and
the sim-to-real diagnosis (:mod:`accelcal.diagnosis`) both fit.  A model is defined by

* the runs (:class:`accelcal.fitting.data.RunCells`), grouped by campaign (one unit);
* ``effects``: the effects.md ids the model includes.  Instrument-term effects
  (``odd_quadratic`` -> Koq, ``cubic`` -> K3, ``cross_coupling`` -> Kip,
  ``bias_temperature`` -> K0T, ``scale_temperature`` -> K1T) add that coefficient;
  ``earth_rate`` is held at its physical size (1); ``initial_misalignment`` is theta0
  per dividing head; ``mount_angle_error`` is one angle per centrifuge mount (both
  polarities, effects.md) or one shared angle (``shared=("mount_angle_error",)``); every
  other effect is one parameter shared by the runs it applies to.

Parameters that are always there (they are not catalogue effects):

* the instrument coefficients the tests of a campaign are designed to determine
  (:data:`DESIGNED`): K0, K1, K2 and, by test, Kp, Ko, Kip, Kio, Kpo, Kpp, Koo (paper 000
  eq 1 / effects.md), shared by every run of the campaign, so eq 2 mixes them in each
  centrifuge mount exactly as the instrument does;
* per ``centrifuge`` run a bias K0[run] (rest offsets: tilt, the vertical axis' cross
  terms; paper 000 eq 9's K0±);
* per centrifuge rig the turning-centre radius R[rig] (paper 000 §2.1; the polarity radii
  follow from R and the mass-centre offset, effects.md ``mass_centre_offset``).

Which of these the data determine is decided from the design (:meth:`CampaignModel.select`):
in priority order, a parameter whose Jacobian column adds no new direction (theta0 and Ko
in one tumble, K2 and Koo, K1 and R without a gravity reference) is held and named as
aliased; an extension term whose design uncertainty exceeds its plausible size is held as
weakly determined.

Jacobian columns are derivatives of ``rig_output``: exact for the instrument coefficients
(:func:`accelcal.physics.instrument.output_derivative`, lagged like the output when a
sensor lag is in the model), central differences of ``rig_output`` for everything else.
"""
from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..effects import EFFECTS, si_unit, typical_size
from ..physics import instrument
from ..physics.geometry import CentrifugeMount
from ..physics.instrument import first_order_lag
from ..physics.rigs import INSTRUMENT_EFFECTS, POINT_COLUMNS, rig_output, rotation_sign, specific_force
from ..constants import T_REF_C
from .core import LackOfFit, Parameter, ParameterSet, lack_of_fit, lstsq_svd
from .identify import (ALIAS_TOL, PRIORITY, Column, Combination, Hold, absorbed, as_holds, combinations, holds,
                       structural_point)
from .data import NoiseModel, RunCells, ar1_mean_factor, ar1_scatter_dof, ar1_variance_factor, with_noise

CENTRIFUGES = ("centrifuge", "sine_centrifuge")
#: coefficient -> the catalogue effect that is it (effects.md)
COEFFICIENT_EFFECT = {v: k for k, v in INSTRUMENT_EFFECTS.items()}

#: Instrument coefficients each test kind is designed to determine (papers 000-003).
DESIGNED: dict[str, tuple[str, ...]] = {
    "tumble": ("K0", "K1", "K2", "Kip", "Kio", "Kp", "Ko", "Kpp", "Koo"),
    "centrifuge": ("K0", "K1", "K2", "K3", "Koq", "Kp", "Ko", "Kip", "Kio", "Kpo", "Kpp", "Koo"),
    "sine_centrifuge": ("K0", "K1", "K2", "K3", "Koq", "Kp", "Ko", "Kip", "Kio", "Kpo", "Kpp", "Koo"),
    "tilt_rotation": ("K0", "K1", "K0T", "K1T", "Kp", "Ko"),
}
#: Coefficients that act on a test's readings though it is not designed to determine them:
#: the fundamental of a tumble's IA input takes Koq g 8/(3 pi) and K3 g^2 3/4
#: (:func:`accelcal.estimators.tumble.k1_correction`).  The adopted fit holds them while the
#: designed model fits, names what they leave in its rows (:meth:`CampaignModel.combinations`),
#: and lets them in where they explain a lack of fit
#: (:func:`accelcal.estimators.joint.fit_campaign_model`).
ACTING: dict[str, tuple[str, ...]] = {
    "tumble": ("Koq", "K3"),
    # a tilted rotary table turns gravity through IA and PA at g sin(tilt) with OA at
    # g cos(tilt): every square and cross term acts (visible from about 10 deg of tilt)
    "tilt_rotation": ("K2", "Kip", "Kio", "Kpo", "Kpp", "Koo", "Koq", "K3"),
}
#: Effects a diagnosis or a test-design advice looks for, when the baseline leaves them out,
#: as one parameter shared by every run they apply to (a mount angle error: one angle, not
#: one per mount)
CANDIDATE_SHARED = ("mount_angle_error",)


def effect_claim(effect: str) -> str:
    """The :data:`PRIORITY` entry under which an effect claims a direction of the design: an
    instrument-term effect its coefficient's (``cross_coupling`` as Kip), the initial
    misalignment theta0's, the mass-centre offset and the mount angle their own, every
    other effect ``'effect'``.

    Parameters
    ----------
    effect : str
        effects.md id.

    Returns
    -------
    str
        An entry of :data:`PRIORITY`.
    """
    key = INSTRUMENT_EFFECTS.get(effect, "theta0" if effect == "initial_misalignment" else effect)
    return key if key in PRIORITY else "effect"


#: fewest effective pure-error dof a run's own noise estimate is counted with in the
#: lack-of-fit reference (:func:`lack_of_fit_reference`; the third moment of F(d, m) needs m > 6)
MIN_NOISE_DOF = 7.0

#: Effects the lab's processing models, per test kind (the default model; the diagnosis
#: uses the same list as its default baseline).
PROCESSING_EFFECTS: dict[str, tuple[str, ...]] = {
    "tumble": ("initial_misalignment",),
    "centrifuge": ("earth_rate", "odd_quadratic", "cubic", "cross_coupling", "mass_centre_offset",
                   "mount_angle_error"),
    "sine_centrifuge": ("earth_rate", "odd_quadratic", "cubic", "cross_coupling", "mass_centre_offset",
                        "spindle_tilt", "sensor_lag"),
    "tilt_rotation": ("bias_temperature", "scale_temperature"),
}
def processing_effects(tests: Sequence[str]) -> list[str]:
    """The union of :data:`PROCESSING_EFFECTS` over the test kinds present.

    Parameters
    ----------
    tests : sequence of str
        Test kinds of the runs (``'centrifuge'``, ``'sine_centrifuge'``, ``'tumble'``,
        ``'tilt_rotation'``); repeats are allowed, unknown kinds add nothing.

    Returns
    -------
    list of str
        effects.md ids, each once: the test kinds in sorted order, each kind's effects in
        :data:`PROCESSING_EFFECTS` order.
    """
    out: list[str] = []
    for t in sorted(set(tests)):
        for e in PROCESSING_EFFECTS.get(t, ()):
            if e not in out:
                out.append(e)
    return out



@dataclass(frozen=True)
class Role:
    """How a parameter enters a run: kind 'coef' (instrument coefficient ``key``), 'bias'
    (the run's own K0), 'radius' (arm radius), 'effect' (effects.md id ``key``)."""
    kind: str
    key: str


class CampaignModel:
    """Parameters and predictions of the forward model over cells of runs (module doc).

    Parameters
    ----------
    runs : sequence of RunCells
    effects : sequence of str
        effects.md ids in the model.
    shared : sequence of str
        Effects to fit as one parameter even where their natural scope is narrower
        (``mount_angle_error``).
    per_run_bias : bool or None
        K0 per run for every run (True), for ``centrifuge`` runs only (None, default) or
        never (False).
    per_run_scale : bool
        K1 per run (a heterogeneity check; not for adopted values).
    include : sequence of str
        Instrument coefficients that are catalogue effects (K0T, K1T, Koq, K3, Kip) to include
        wherever a campaign's tests are designed to determine them (:data:`DESIGNED`), even
        when their effect is not in ``effects`` (the diagnosis' bare model: the
        tilt-rotation test measures K0T and K1T).
    acting : mapping of str to sequence of str, optional
        Test kind -> coefficients of ``include`` that come in where a test of that kind acts
        on them, though it is not designed to determine them (:data:`ACTING`: a tumble's K1
        takes up Koq and K3, so the adopted fit of a tumble-only campaign names K1 with them).
    fixed : sequence of str
        Effects held at their physical size when in ``effects`` (default: ``earth_rate`` at 1);
        an effect in ``effects`` but not here is a fitted parameter (the diagnosis estimates
        the earth-rate scale when the baseline omits it).
    """

    def __init__(self, runs: Sequence[RunCells], effects: Sequence[str] = (), *,
                 shared: Sequence[str] = (), per_run_bias: bool | None = None,
                 per_run_scale: bool = False, include: Sequence[str] = (),
                 fixed: Sequence[str] = ("earth_rate",), acting: Mapping[str, Sequence[str]] | None = None):
        self.runs = list(runs)
        acting = acting or {}
        self.effects = [e for e in dict.fromkeys(effects)]
        for e in self.effects:
            if e not in EFFECTS:
                raise ValueError(f"unknown effect id {e!r} (effects.md ids: {sorted(EFFECTS)})")
        self.fixed = {"earth_rate": 1.0} if "earth_rate" in self.effects and "earth_rate" in fixed else {}
        #: mount angles the design cannot separate (IA radial): label -> runs
        self.unseparable_angles: dict[str, list[int]] = {}
        self.campaigns = list(dict.fromkeys(r.campaign for r in self.runs))
        multi = len(self.campaigns) > 1
        ps = ParameterSet()
        self.roles: list[Role] = []
        self.priority: list[int] = []

        def add(name, key, unit, scale, runs_, group, role, prio, value=0.0):
            ps.add(Parameter(name, key, unit, scale, tuple(runs_), group, True, value))
            self.roles.append(role)
            self.priority.append(PRIORITY.index(prio))

        coef_names = {}
        #: coefficients that are here only because a test acts on them (:data:`ACTING`)
        self.acting_only: list[str] = []
        for c in self.campaigns:
            idx = [j for j, r in enumerate(self.runs) if r.campaign == c]
            tests = {self.runs[j].test for j in idx}
            # an instrument-term effect in the model adds its coefficient wherever the effect
            # applies (bias_temperature to a centrifuge campaign too), not only where a test
            # is designed to measure it
            designed = [k for k in instrument.DEFAULTS
                        if (k not in COEFFICIENT_EFFECT and any(k in DESIGNED[t] for t in tests))
                        or (k in COEFFICIENT_EFFECT and COEFFICIENT_EFFECT[k] in self.effects
                            and any(t in EFFECTS[COEFFICIENT_EFFECT[k]].tests for t in tests))
                        or (k in include and any(k in DESIGNED[t] for t in tests))]
            only_acting = [k for k in instrument.DEFAULTS if k not in designed and k in include
                           and any(k in acting.get(t, ()) for t in tests)]
            wanted = [k for k in instrument.DEFAULTS if k in designed or k in only_acting]
            bias_runs = {j for j in idx if self._has_bias(self.runs[j], per_run_bias)}
            for k in wanted:
                acts = [j for j in idx if not (k == "K0" and j in bias_runs)]
                if not acts:
                    continue
                name = f"{k}[{c}]" if multi else k
                coef_names[(c, k)] = name
                if k in only_acting:
                    self.acting_only.append(name)
                add(name, k, si_unit(k), typical_size(k), acts, "instrument", Role("coef", k), k,
                    1.0 if k == "K1" else 0.0)
            for j in sorted(bias_runs):
                r = self.runs[j]
                add(f"K0[{r.run_id}]", "K0", "m/s2", typical_size("K0"), [j], "per-run bias",
                    Role("bias", "K0"), "bias")
            if per_run_scale:
                for j in idx[1:]:
                    add(f"dK1[{self.runs[j].run_id}]", "K1", "1", 1e-4, [j], "per-run scale",
                        Role("scale", "K1"), "effect")
        # radius per centrifuge rig
        rigs = {}
        for j, r in enumerate(self.runs):
            if r.test in CENTRIFUGES:
                rigs.setdefault(r.rig_id, []).append(j)
        for rig, idx in rigs.items():
            R0 = float(np.median([self.runs[j].geometry.arm_radius_m for j in idx]))
            add(f"R[{rig}]", "radius", "m", typical_size("radius"), idx, "turning-centre radius",
                Role("radius", "radius"), "radius", R0)
        # effects
        for e in self.effects:
            if e in self.fixed or e in INSTRUMENT_EFFECTS:
                continue
            idx = [j for j, r in enumerate(self.runs) if r.test in EFFECTS[e].tests]
            if not idx:
                continue
            for label, group in self._scopes(e, idx, shared):
                name = f"{e}[{label}]" if label else e
                add(name, e, EFFECTS[e].unit, typical_size(e), group, f"effect {e}", Role("effect", e),
                    effect_claim(e))
        self.params = ps
        #: every candidate parameter, before :meth:`select` held any
        self.candidates = ps
        self.coef_names = coef_names
        self.run_params = [[i for i, p in enumerate(ps) if p.acts_on(j)] for j in range(len(self.runs))]
        self._acting = [frozenset(idx) for idx in self.run_params]     # the same, for membership
        # per run: how each parameter acting on it enters rig_output, and the fixed effects
        self._plan = [[(i, self.roles[i].kind, self.roles[i].key) for i in idx] for idx in self.run_params]
        self._fixed_of = [{k: v for k, v in self.fixed.items() if r.test in EFFECTS[k].tests} for r in self.runs]
        self.offsets = np.concatenate([[0], np.cumsum([r.ncell for r in self.runs])]).astype(int)
        self.N = int(self.offsets[-1])
        self.y = np.concatenate([r.y for r in self.runs]) if self.runs else np.zeros(0)
        self.refresh_noise()

    # ----------------------------------------------------------------- structure
    @staticmethod
    def _has_bias(run: RunCells, per_run_bias: bool | None) -> bool:
        if per_run_bias is None:
            return run.test == "centrifuge"
        return bool(per_run_bias)

    def _scopes(self, e: str, idx: list[int], shared: Sequence[str]):
        """(label, runs) groups of an effect's parameters."""
        if e == "initial_misalignment":
            heads: dict[str, list[int]] = {}
            for j in idx:
                r = self.runs[j]
                heads.setdefault(f"{r.campaign}|{r.rig_id} {r.geometry.label}", []).append(j)
            if len(heads) == 1:
                return [("", next(iter(heads.values())))]
            return [(k if len(self.campaigns) > 1 else k.split("|", 1)[1], v) for k, v in heads.items()]
        if e == "mount_angle_error" and e not in shared:
            mounts: dict[str, list[int]] = {}
            radial: dict[str, list[int]] = {}
            for j in idx:
                r = self.runs[j]
                plane, phi = r.geometry.mount_key
                label = f"{r.rig_id} {plane} {phi:g}/{phi + 180:g}"
                # IA along the centripetal force senses the angle only at second order, where
                # it is one with K2 (eq 8 at phi0 = 0: dc2 = Kip dphi): not a parameter of the
                # fit, but a type-B term of the budget (fixture tolerance)
                (radial if r.geometry.ia_polarity is not None else mounts).setdefault(label, []).append(j)
            self.unseparable_angles.update(radial)
            return list(mounts.items())
        return [("", idx)]

    def with_noise(self, noise: Sequence[NoiseModel]) -> "CampaignModel":
        """The same model on copies of its runs that carry ``noise`` (one per run), whitened
        by it; this model and its runs are not changed.

        Parameters
        ----------
        noise : sequence of NoiseModel

        Returns
        -------
        CampaignModel
            Sharing the parameters, roles and kept predictions (which do not depend on the
            noise).
        """
        out = copy.copy(self)
        out.runs = [with_noise(r, m) for r, m in zip(self.runs, noise)]
        out.refresh_noise()
        return out

    def refresh_noise(self) -> None:
        """Whiten by each run's ``var_mean``."""
        if self.runs and all(r.var_mean is not None for r in self.runs):
            self.sig = np.sqrt(np.concatenate([r.var_mean for r in self.runs]))
        else:
            self.sig = np.ones(self.N)

    def rows(self, j: int) -> slice:
        """Rows of run j in the stacked cell vectors (``y``, ``sig``, :meth:`predict`,
        :meth:`residual`, :meth:`jacobian`).

        Parameters
        ----------
        j : int
            Index of the run in the model.

        Returns
        -------
        slice
            ``offsets[j]:offsets[j + 1]``, one row per cell of the run.
        """
        return slice(int(self.offsets[j]), int(self.offsets[j + 1]))

    def name(self, campaign: str, coefficient: str) -> str | None:
        """Name of the parameter of an instrument coefficient of one campaign.

        Parameters
        ----------
        campaign : str
            Campaign id (``RunCells.campaign``).
        coefficient : str
            Instrument coefficient, effects.md notation (``'K1'``, ``'Kip'``, ...).

        Returns
        -------
        str or None
            ``'K1'``, or ``'K1[<campaign>]'`` when the model has more than one campaign
            (held or not); None when the model has no such candidate for the campaign (not
            designed for its tests nor added by an effect, or K0 replaced by a per-run bias
            in every run).
        """
        return self.coef_names.get((campaign, coefficient))

    # ----------------------------------------------------------------- evaluation
    def inputs(self, p: np.ndarray, j: int, extra: Mapping[str, float] | None = None
               ) -> tuple[dict, dict, dict]:
        """Inputs of ``rig_output`` for run j at the parameter vector p.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        j : int
            Index of the run in the model.
        extra : mapping of str to float, optional
            Effects (effects.md ids) added on top of the model's own values [effect unit];
            an instrument-term effect (``odd_quadratic``, ...) adds to its coefficient
            [coefficient unit]; effects that do not apply to the run's test are ignored.

        Returns
        -------
        coefficients : dict of str to float
            Instrument coefficients acting on the run [effects.md units]: K1 [output_unit
            per m/s2] (1 when it is not a parameter of the run, times 1 + dK1 with a per-run
            scale), K0 (the campaign's, or the run's own bias) [m/s2], ...
        effects : dict of str to float
            effects.md id -> parameter [effect unit]: the fixed ones (``earth_rate`` at 1)
            and the fitted ones acting on the run.
        kwargs : dict
            ``radius_m``: the rig's turning-centre radius R [m] (centrifuge runs);
            ``rate_derivative``: d(omega)/dt of a sine run's drive [rad/s2], times the
            rotation sign and 1 + ``rate_scale_error``.
        """
        r = self.runs[j]
        co: dict[str, float] = {"K1": 1.0}
        eff: dict[str, float] = dict(self._fixed_of[j])
        kw: dict = {}
        pv = p.tolist() if isinstance(p, np.ndarray) else list(p)
        for i, kind, key in self._plan[j]:
            v = pv[i]
            if kind == "coef" or kind == "bias":
                co[key] = co.get(key, 0.0) + v if key != "K1" else v
            elif kind == "scale":
                co["_dK1"] = v
            elif kind == "radius":
                kw["radius_m"] = v
            else:
                eff[key] = eff.get(key, 0.0) + v
        if "_dK1" in co:
            co["K1"] = co.get("K1", 1.0) * (1.0 + co.pop("_dK1"))
        for k, v in (extra or {}).items():
            if r.test not in EFFECTS[k].tests:
                continue
            if k in INSTRUMENT_EFFECTS:
                co[INSTRUMENT_EFFECTS[k]] = co.get(INSTRUMENT_EFFECTS[k], 0.0) + v
            else:
                eff[k] = eff.get(k, 0.0) + v
        if r.rate_derivative is not None:
            eps = float(eff.get("rate_scale_error", 0.0))
            kw["rate_derivative"] = rotation_sign(r.meta) * (1.0 + eps) * r.rate_derivative
        return co, eff, kw

    #: points whose model outputs are kept (the most recent): a fit evaluates the model at
    #: its solution again and again (its last step, the noise refit, the next fit's start,
    #: the pure error), each time at the same point
    PREDICTION_CACHE = 8
    #: and at most this many bytes of them, the newest point always kept: a big run's outputs
    #: at eight points would be hundreds of MB
    PREDICTION_CACHE_BYTES = 64 * 2 ** 20

    def predict_rows(self, p: np.ndarray, j: int, extra: Mapping[str, float] | None = None) -> np.ndarray:
        """The model's output at every reading of run j.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        j : int
            Index of the run in the model.
        extra : mapping of str to float, optional
            Effects added on top of the model's values [effect unit] (:meth:`inputs`).

        Returns
        -------
        (nrow,) ndarray
            ``rig_output`` at each reading [output_unit]; read-only when kept in the
            prediction cache (:attr:`PREDICTION_CACHE`: a float64 ``p`` and no ``extra``).
        """
        if extra or type(p) is not np.ndarray or p.dtype != np.float64:
            return self._rows(p, j, extra)
        # keyed by value: the point (bytes) is all the output depends on besides the runs'
        # metadata and columns, which do not change while a model lives on them
        cache = self.__dict__.setdefault("_predictions", {})
        size = self.__dict__.setdefault("_prediction_bytes", {})     # point -> bytes of its rows
        key = (p.shape, p.tobytes())
        rows = cache.get(key)
        if rows is None:
            rows = cache[key] = {}
            size[key] = 0
            while len(cache) > self.PREDICTION_CACHE:
                old = next(iter(cache))
                del cache[old], size[old]
        E = rows.get(j)
        if E is None:
            E = rows[j] = self._rows(p, j)
            E.setflags(write=False)
            size[key] += E.nbytes
            held = sum(size.values())
            while held > self.PREDICTION_CACHE_BYTES and len(cache) > 1:
                old = next(iter(cache))
                if old == key:
                    break
                del cache[old]
                held -= size.pop(old)
        return E

    def _rows(self, p: np.ndarray, j: int, extra: Mapping[str, float] | None = None) -> np.ndarray:
        """:meth:`predict_rows` itself: ``rig_output`` at the inputs of run j."""
        r = self.runs[j]
        co, eff, kw = self.inputs(p, j, extra)
        return rig_output(r.test, r.meta, r.cols, co, eff, geometry=r.geometry, **kw)

    def _rows_at(self, points: Sequence[np.ndarray], j: int) -> np.ndarray:
        """:meth:`_rows` at several points that differ only in parameters of
        :meth:`_point_column`, in one evaluation of the model: row k, element for element,
        is ``_rows(points[k], j)`` (the forward model takes those values as columns)."""
        r = self.runs[j]
        co, eff, kw = self.inputs(points[0], j)
        P = np.array(points)
        # each point's value of each point parameter, as inputs() adds them up
        for i, kind, key in self._plan[j]:
            if kind == "radius":
                kw["radius_m"] = P[:, [i]]
            elif kind == "effect" and key in POINT_COLUMNS[r.test]:
                eff[key] = (eff[key] if isinstance(eff[key], np.ndarray)
                            else self._fixed_of[j].get(key, 0.0)) + P[:, [i]]
        return rig_output(r.test, r.meta, r.cols, co, eff, geometry=r.geometry, **kw)

    def _point_column(self, i: int, j: int) -> bool:
        """Whether run j's forward model takes parameter i as a column of points
        (:meth:`_rows_at`, :data:`~accelcal.physics.rigs.POINT_COLUMNS`)."""
        role = self.roles[i]
        return role.kind in ("radius", "effect") and role.key in POINT_COLUMNS.get(self.runs[j].test, ())

    def predict_run(self, p: np.ndarray, j: int, extra: Mapping[str, float] | None = None) -> np.ndarray:
        """Cell means of the model's output for run j.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        j : int
            Index of the run in the model.
        extra : mapping of str to float, optional
            Effects added on top of the model's values [effect unit] (:meth:`inputs`).

        Returns
        -------
        (ncell,) ndarray
            :meth:`predict_rows` averaged over each cell of the run [output_unit].
        """
        return self.runs[j].cell_mean(self.predict_rows(p, j, extra))

    def predict(self, p: np.ndarray) -> np.ndarray:
        """Cell means of the model's output over all runs.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].

        Returns
        -------
        (N,) ndarray
            :meth:`predict_run` of every run, stacked in run order [output_unit].
        """
        return np.concatenate([self.predict_run(p, j) for j in range(len(self.runs))])

    def residual(self, p: np.ndarray) -> np.ndarray:
        """Whitened cell residuals z = (ybar - model) / sigma_mean.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].

        Returns
        -------
        (N,) ndarray
            z [1]: sigma_mean is the standard deviation of each cell mean from its run's
            noise model (``var_mean``, :meth:`refresh_noise`); 1 [output_unit] for every
            cell while a run has no noise model.
        """
        return (self.y - self.predict(p)) / self.sig

    def _temp(self, r: RunCells):
        if "temp_c" not in r.cols:
            return None
        T = r.cols["temp_c"]
        return np.where(np.isfinite(T), T, T_REF_C)

    #: bytes of the block of exact columns of readings :meth:`jacobian_run` builds and lags at
    #: once: a long run's readings times every instrument coefficient would be hundreds of MB
    LAG_BLOCK_BYTES = 16 * 2 ** 20

    def jacobian_run(self, p: np.ndarray, j: int, params: Sequence[int] | None = None) -> np.ndarray:
        """Jacobian of the cell means of run j, not whitened.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        j : int
            Index of the run in the model.
        params : sequence of int, optional
            Parameter indices of the columns; None = every parameter.

        Returns
        -------
        (ncell, len(params)) ndarray
            d(cell-mean model)/dp [output_unit per parameter unit]; 0 in the columns of
            parameters that do not act on the run.  Instrument coefficients and run biases
            are exact (:func:`accelcal.physics.instrument.output_derivative`, lagged like the
            output when the run has a sensor lag); every other column is a central difference
            of ``rig_output`` with step 1e-3 ``Parameter.scale`` (a forward one for a sensor
            lag the backward point would make negative).
        """
        r = self.runs[j]
        cols = list(range(len(self.params))) if params is None else list(params)
        J = np.zeros((r.ncell, len(cols)))
        co, eff, kw = self.inputs(p, j)
        tau = float(eff.get("sensor_lag", 0.0))
        acting = self._acting[j]
        exact = [(c, i) for c, i in enumerate(cols) if i in acting
                 and self.roles[i].kind in ("coef", "bias") and self.roles[i].key in instrument.DEFAULTS]
        if exact:
            F = specific_force(r.test, r.meta, r.cols, eff, geometry=r.geometry, **kw)
            T, t = self._temp(r), r.cols.get("time_s")
            drift = float(eff.get("bias_drift", 0.0))
            # the columns of readings side by side, in blocks of at most LAG_BLOCK_BYTES
            width = max(1, self.LAG_BLOCK_BYTES // (8 * max(r.cid.size, 1)))
            for b in range(0, len(exact), width):
                block = exact[b:b + width]
                X = np.empty((r.cid.size, len(block)))
                for k, (_, i) in enumerate(block):
                    X[:, k] = instrument.output_derivative(self.roles[i].key, co, F, T, t, drift)
                if tau > 0:               # lagged like the output (the lag is linear), each column alone
                    X = first_order_lag(X, t, tau)
                J[:, [c for c, _ in block]] = r.cell_means(X)
        done = {c for c, _ in exact}
        # the central differences the model evaluates as columns of points, a block of
        # points (at most LAG_BLOCK_BYTES of force and output) per evaluation: each row is
        # what the point alone gives, the Python around the model paid once per block
        together = [(c, i) for c, i in enumerate(cols)
                    if i in acting and c not in done and self._point_column(i, j)]
        width = max(1, self.LAG_BLOCK_BYTES // (8 * 8 * max(r.cid.size, 1)))
        for b in range(0, len(together), width):
            block = [(c, *self._difference_points(p, i)) for c, i in together[b:b + width]]
            E = self._rows_at([q for _, _, pp, pm in block for q in (pp, pm)], j)
            for k, (c, h, _, _) in enumerate(block):
                J[:, c] = (r.cell_mean(E[2 * k]) - r.cell_mean(E[2 * k + 1])) / (2 * h)
                done.add(c)
        base = None
        for c, i in enumerate(cols):
            if i not in acting or c in done:
                continue
            h, pp, pm = self._difference_points(p, i)
            # the points of the differences are not kept (each is used once)
            plus = r.cell_mean(self._rows(pp, j))
            if self.roles[i].key == "sensor_lag" and pm[i] < 0:
                if base is None:
                    base = self.predict_run(p, j)
                J[:, c] = (plus - base) / h
                continue
            J[:, c] = (plus - r.cell_mean(self._rows(pm, j))) / (2 * h)
        return J

    def _difference_points(self, p: np.ndarray, i: int) -> tuple[float, np.ndarray, np.ndarray]:
        """(h, p + h e_i, p - h e_i): the step of parameter i's central difference, 1e-3
        ``Parameter.scale``, and its two points."""
        h = 1e-3 * self.params[i].scale
        pp, pm = p.copy(), p.copy()
        pp[i] += h
        pm[i] -= h
        return h, pp, pm

    #: points whose unwhitened Jacobian columns are kept per model (the most recent ones): a
    #: fit asks for the same columns again at the same point (model selection with every
    #: column, then the Gauss–Newton start with the free ones; the combinations with the
    #: free, then the held ones)
    JACOBIAN_CACHE = 2

    def jacobian(self, p: np.ndarray, params: Sequence[int] | None = None) -> np.ndarray:
        """Whitened Jacobian over all cells.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        params : sequence of int, optional
            Parameter indices of the columns; None = every parameter.

        Returns
        -------
        (N, len(params)) ndarray
            :meth:`jacobian_run` of every run stacked, each row divided by its cell's sigma
            [1 per parameter unit].  Each unwhitened column is kept (:attr:`JACOBIAN_CACHE`)
            by the point, the parameter and its difference step: a column is worked out
            alone, whichever others are asked for with it.
        """
        cols = list(range(len(self.params))) if params is None else list(params)
        # keyed by value: the point (bytes), the column and its difference step (the
        # parameter's scale), which is all jacobian_run depends on besides the runs' cells,
        # which do not change while a model lives on them
        pa = np.asarray(p)
        cache = self.__dict__.setdefault("_jacobians", {})
        have = cache.setdefault((pa.dtype.str, pa.shape, pa.tobytes()), {})
        while len(cache) > self.JACOBIAN_CACHE:
            del cache[next(iter(cache))]
        keys = [(i, self.params[i].scale) for i in cols]
        new = list(dict.fromkeys(i for i, k in zip(cols, keys) if k not in have))
        if new:
            J = np.zeros((self.N, len(new)))
            for j in range(len(self.runs)):
                J[self.rows(j)] = self.jacobian_run(p, j, new)
            J.setflags(write=False)
            have.update(((i, self.params[i].scale), J[:, c]) for c, i in enumerate(new))
        J = np.column_stack([have[k] for k in keys]) if keys else np.zeros((self.N, 0))
        return J / self.sig[:, None]

    def signature(self, p: np.ndarray, effect: str, h: float | None = None,
                  runs: Sequence[int] | None = None) -> np.ndarray:
        """Whitened derivative of the model with respect to an effect *not* in it (a
        candidate of the diagnosis; a parameter the design cannot separate, e.g. the angle
        of a radial mount, :attr:`unseparable_angles`: a type-B term), on top of the
        model's own value: central differences of ``rig_output``.

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        effect : str
            effects.md id.
        h : float, optional
            Difference step [effect unit]; None (or 0) = 1e-3 times the effect's typical
            size.
        runs : sequence of int, optional
            Indices of the runs the effect acts on; None = every run whose test it applies
            to.

        Returns
        -------
        (N,) ndarray
            Difference of the cell means (:meth:`predict_run` with the effect at +-h on top
            of the model) divided by sigma [1 per effect unit]; a forward difference for
            ``sensor_lag`` (a time constant is >= 0); 0 in every other row.
        """
        h = h or 1e-3 * typical_size(effect)
        out = np.zeros(self.N)
        if runs is None:
            runs = [j for j, r in enumerate(self.runs) if r.test in EFFECTS[effect].tests]
        for j in runs:
            sl = self.rows(j)
            if effect == "sensor_lag":
                out[sl] = (self.predict_run(p, j, {effect: h}) - self.predict_run(p, j)) / h
            else:
                out[sl] = (self.predict_run(p, j, {effect: h}) - self.predict_run(p, j, {effect: -h})) / (2 * h)
        return out / self.sig

    def input_direction(self, p: np.ndarray, rig_input: str, runs: Sequence[int],
                        rows: Mapping[int, np.ndarray] | None = None, h: float | None = None
                        ) -> np.ndarray:
        """Whitened derivative of the model with respect to a rig input the drop gives as
        known (:data:`accelcal.effects.RIG_INPUTS`: ``g_local``, ``table_tilt``,
        ``temperature``), moved by the same amount in ``runs``: the direction a stated
        uncertainty of that input takes the fit (a type-B term, JCGM 100 §5.1.3).

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        rig_input : str
            Its id in :data:`~accelcal.effects.RIG_INPUTS`.
        runs : sequence of int
            Indices of the runs whose input moves together.
        rows : mapping of int to ndarray of bool, optional
            Per run, the readings whose logged column moves (a set point); all of them
            when not given.  Only for an input read from a column.
        h : float, optional
            Difference step [the input's unit]; default the catalogue's
            (:attr:`accelcal.effects.RigInput.step`).

        Returns
        -------
        (N,) ndarray
            Central difference of the cell means of ``runs`` divided by sigma, 0 in every
            other row [1 per input unit].
        """
        from ..effects import RIG_INPUTS
        spec = RIG_INPUTS[rig_input]
        h = h or spec.step
        out = np.zeros(self.N)
        for j in runs:
            r = self.runs[j]
            co, eff, kw = self.inputs(p, j)
            E = []
            for step in (h, -h):
                if spec.meta_key is None and spec.column not in r.cols:
                    break

                meta, cols = r.meta, r.cols
                if spec.meta_key is not None:
                    meta = {**meta, spec.meta_key: float(meta[spec.meta_key]) + step}
                else:
                    on = None if rows is None or j not in rows else rows[j]
                    cols = {**cols, spec.column: np.asarray(cols[spec.column], float) + (
                        step if on is None else np.where(on, step, 0.0))}
                E.append(r.cell_mean(rig_output(r.test, meta, cols, co, eff, **kw)))
            if len(E) == 2:
                out[self.rows(j)] = (E[0] - E[1]) / (2 * h)
        return out / self.sig

    def lower_bounds(self) -> np.ndarray:
        """Lower bound of each parameter.

        Returns
        -------
        (p,) ndarray
            0 for a time constant (``sensor_lag``) [s], -inf for every other parameter, in
            parameter order.
        """
        return np.array([0.0 if r.key == "sensor_lag" else -np.inf for r in self.roles])

    # ----------------------------------------------------------------- start, selection
    def start(self, profile_lag: bool = True) -> np.ndarray:
        """Start values: K1 by regression of each campaign's outputs on the nominal input
        (the amplitude of the data, paper 003 starts from the nominal sensitivity), K0 and
        the run biases from the mean residual, radii at the nominal arm radius; a sensor lag
        profiled (:meth:`start_lag`) unless ``profile_lag`` is False (a start given).

        The nominal input is the model's cell means at the parameters' start values (K1 = 1,
        the other coefficients and the effects 0); the regression is of the centred outputs
        on it (K1 = 1 when it has no amplitude).  The model is not changed.

        Parameters
        ----------
        profile_lag : bool
            Profile the start of ``sensor_lag`` (:meth:`start_lag`).

        Returns
        -------
        (p,) ndarray
            Start vector [parameter units].
        """
        p = self.params.values()
        for c in self.campaigns:
            i1 = self.params.index.get(self.name(c, "K1"))
            num = den = 0.0
            for j, r in enumerate(self.runs):
                if r.campaign != c:
                    continue
                a = self.predict_run(p, j)
                a = a - a.mean()
                num += float(np.sum(a * (r.y - r.y.mean())))
                den += float(np.sum(a * a))
            K1 = num / den if den > 0 and num != 0 else 1.0
            if i1 is not None:
                p[i1] = K1
            for j, r in enumerate(self.runs):
                if r.campaign != c:
                    continue
                off = float(np.mean(r.y - self.predict_run(p, j))) / K1
                for i in self.run_params[j]:
                    if self.roles[i].kind == "bias":
                        p[i] = off
            i0 = self.params.index.get(self.name(c, "K0"))
            if i0 is not None:
                offs = [float(np.mean(r.y - self.predict_run(p, j))) / K1 for j, r in enumerate(self.runs)
                        if r.campaign == c and i0 in self.run_params[j]]
                p[i0] += float(np.mean(offs)) if offs else 0.0
        return self.start_lag(p) if profile_lag else p

    def start_lag(self, p: np.ndarray) -> np.ndarray:
        """Start of ``sensor_lag`` (when it is a parameter): a sampled first-order lag shows
        nothing of a tau far below the sample period, its derivative vanishing at 0
        (:func:`accelcal.physics.instrument.first_order_lag`); the start is the best of 0 and
        lags whose delays dt a / (1 - a) span 1e-8 to 3 sample periods, by the weighted
        residual of a linear refit of the instrument coefficients.

        dt is the median sample period of the runs the lag acts on, a = exp(-dt / tau); 12
        delays are tried, spaced geometrically; the refit is one linear least-squares step
        on the instrument coefficients and run biases.

        Parameters
        ----------
        p : ndarray
            Start vector [parameter units].

        Returns
        -------
        ndarray
            The best trial: a copy of ``p`` with tau [s] and the refitted coefficients; ``p``
            itself when the model has no sensor lag.
        """
        i = next((k for k, r in enumerate(self.roles) if r.key == "sensor_lag"), None)
        if i is None:
            return p
        dt = float(np.median(np.concatenate([np.diff(self.runs[j].cols["time_s"])
                                             for j in (self.params[i].runs or range(len(self.runs)))])))
        lin = [k for k, r in enumerate(self.roles) if r.kind in ("coef", "bias")]
        best, p_best = None, p
        for tau in [0.0] + [dt / math.log1p(1.0 / d) for d in np.geomspace(1e-8, 3.0, 12)]:
            q = p.copy()
            q[i] = tau
            z = self.residual(q)
            q[lin] += lstsq_svd(self.jacobian(q, lin), z).x
            c = float(np.sum(self.residual(q) ** 2))
            if best is None or c < best:
                best, p_best = c, q
        return p_best

    def columns(self, cols: Sequence[int] | None = None, p: np.ndarray | None = None) -> list[Column]:
        """The candidate parameters ``cols`` as the rank decision sees them
        (:class:`accelcal.fitting.identify.Column`).

        Parameters
        ----------
        cols : sequence of int, optional
            Indices into :attr:`candidates`; None = every one.
        p : ndarray, optional
            Point whose values the columns take [parameter units]; None = the candidates'
            own values.

        Returns
        -------
        list of Column
        """
        cols = range(len(self.candidates)) if cols is None else cols
        return [Column(self.candidates[i].name, self.roles[i].kind, self.roles[i].key, self.candidates[i].unit,
                       self.priority[i], float(self.candidates[i].value if p is None else p[i])) for i in cols]

    def select(self, p: np.ndarray, tol: float = ALIAS_TOL, keep: Sequence[str] = (),
               hold: Mapping[str, Hold | str] | None = None) -> dict[str, Hold]:
        """The parameters the design cannot determine at p
        (:func:`accelcal.fitting.identify.holds`).  Every candidate is considered afresh (a
        parameter held at the start, where the instrument coefficients are still 0, may be
        determined at the estimate); the model is not changed (:meth:`with_holds` makes the
        model that holds them).

        Parameters
        ----------
        p : ndarray
            Point at which the design is judged [parameter units].
        tol : float
            :data:`~accelcal.fitting.identify.ALIAS_TOL` [1].
        keep : sequence of str
            Parameter names never held for being weakly determined.
        hold : mapping of str to Hold or str, optional
            Parameters held whatever the design (name -> hold, or the caller's words),
            before it is judged.

        Returns
        -------
        dict of str to Hold
        """
        hold = as_holds(hold)
        cols = [i for i, prm in enumerate(self.candidates) if prm.name not in hold]
        q = structural_point(p, self.columns())
        J = self.jacobian(p, cols)
        return {**holds(J, self.columns(cols), tol, keep,
                        structural=None if np.array_equal(q, p) else self.jacobian(q, cols)), **hold}

    def with_holds(self, held: Mapping[str, Hold]) -> "CampaignModel":
        """The same model with ``params`` the :attr:`candidates` with ``held`` held (at their
        candidate values); this model is not changed.

        Parameters
        ----------
        held : mapping of str to Hold
            :meth:`select`.

        Returns
        -------
        CampaignModel
        """
        out = copy.copy(self)
        out.params = self.candidates.held(held)
        return out

    def combinations(self, p: np.ndarray, u: Mapping[str, float] | None = None) -> dict[str, Combination]:
        """What each free parameter measures besides itself: the held parameters it absorbs
        (:func:`accelcal.fitting.identify.absorbed`, :func:`~accelcal.fitting.identify.combinations`).

        A parameter held where the data cannot determine it (:meth:`select`) is not gone
        from the readings: the free parameters take up its part.  A held parameter counts
        when a size of it typical of an ordinary unit (:func:`accelcal.effects.typical_size`)
        would move the estimate by more than its uncertainty.

        Parameters
        ----------
        p : ndarray
            Parameter vector, held parameters at their held values [parameter units].
        u : mapping of str to float, optional
            Standard uncertainty of each free parameter [parameter unit] (default: the
            design's).

        Returns
        -------
        dict of str to Combination
            Free parameter name -> what it measures, only for those that take something up.
        """
        free = [i for i, prm in enumerate(self.params) if prm.vary]
        held = [i for i, prm in enumerate(self.params) if not prm.vary]
        if not free or not held:
            return {}
        u_f = None if u is None else np.array([u.get(self.params[i].name, np.nan) for i in free])
        A = absorbed(self.jacobian(p, free), self.jacobian(p, held), u_f,
                     np.array([typical_size(self.roles[i].key) for i in held]))
        return combinations(self.columns(free, p), self.columns(held, p), A,
                            [self.roles[i].kind == "coef" for i in held])

    # ----------------------------------------------------------------- derived geometry
    def polarity_radius(self, p: np.ndarray, j: int) -> float:
        """Distance [m] of the effective mass centre from the spindle in run j (a centrifuge
        run): |R u - r e1| for its mount (effects.md mass_centre_offset).

        Parameters
        ----------
        p : ndarray
            Parameter vector [parameter units].
        j : int
            Index of the run in the model (a centrifuge run).

        Returns
        -------
        float
            rho [m], with R the rig's turning-centre radius, u at the mount angle phi plus
            ``mount_angle_error`` and r the ``mass_centre_offset`` (paper 000 §2.2).
        """
        r = self.runs[j]
        g = r.geometry
        co, eff, kw = self.inputs(p, j)
        R = kw.get("radius_m", g.arm_radius_m)
        phi = g.phi_rad + float(eff.get("mount_angle_error", 0.0))
        off = float(eff.get("mass_centre_offset", 0.0))
        return float(math.hypot(R * math.cos(phi) - off, R * math.sin(phi)))


def mount_runs(model: CampaignModel) -> dict[tuple[str, str, float], list[int]]:
    """Centrifuge runs grouped by (rig, plane, phi mod 180).

    Parameters
    ----------
    model : CampaignModel
        The model whose runs are grouped.

    Returns
    -------
    dict of tuple to list of int
        ``(rig_id, plane, phi mod 180 [deg])`` -> indices of its runs in the model (both
        polarities of a mount), in run order.
    """
    out: dict[tuple[str, str, float], list[int]] = {}
    for j, r in enumerate(model.runs):
        if isinstance(r.geometry, CentrifugeMount):
            out.setdefault((r.rig_id, *r.geometry.mount_key), []).append(j)
    return out


def residual_cell_variance(model: "CampaignModel", p: np.ndarray) -> list[np.ndarray]:
    """Each run's within-cell sample variance of the residual readings at ``p``
    (:meth:`RunCells.cell_variance` of output minus model): what the pure error of
    :func:`pure_error_runs` rests on, worked out once for both its rho variants.

    Parameters
    ----------
    model : CampaignModel
    p : ndarray
        Parameter vector [parameter units].

    Returns
    -------
    list of (ncell,) ndarray
        Per run [output_unit^2]; nan for 1-reading cells.
    """
    return [r.cell_variance(r.y_rows - model.predict_rows(p, j)) for j, r in enumerate(model.runs)]


def pure_error_runs(model: "CampaignModel", scatter: Sequence[np.ndarray],
                    at_rho_hi: bool = False) -> list[tuple[float, int]]:
    """Each run's weighted pure-error chi-square and its degrees of freedom (Draper &
    Smith §2.1); the lack of fit tests against their sums.

    Parameters
    ----------
    model : CampaignModel
    scatter : sequence of ndarray
        Each run's within-cell residual variance (:func:`residual_cell_variance`).
    at_rho_hi : bool
        Count the dof at the upper end of each run's rho interval (``NoiseModel.rho_hi``;
        the scatter's scale is the noise model's, refitted at that rho it is the same).

    Returns
    -------
    list of (chi2, dof) : (float [1], int)
        Per run of the model: the within-cell scatter of the residuals against the run's
        noise model (reading variance times the AR(1) factor of a cell of n readings); the
        dof are the Satterthwaite dof of correlated readings (:func:`ar1_scatter_dof`).
        (0.0, 0) for a run without replicates or noise model.
    """
    out = []
    for r, s2 in zip(model.runs, scatter):
        ok = (r.n >= 2) & np.isfinite(s2)
        if not ok.any() or r.noise is None or not math.isfinite(r.noise.a):
            out.append((0.0, 0))
            continue
        sig2 = r.noise.reading_variance(r.x[ok]) * ar1_variance_factor(r.n[ok], r.noise.rho)
        rho = max(r.noise.rho_hi, r.noise.rho) if at_rho_hi else r.noise.rho
        if rho == 0.0:
            out.append((float(np.sum((r.n[ok] - 1) * s2[ok] / sig2)), int(np.sum(r.n[ok] - 1))))
            continue
        # correlated readings: nu s^2 / E[s^2] ~ chi2(nu) with fewer dof than n - 1
        # (Satterthwaite, :func:`ar1_scatter_dof`)
        nu = ar1_scatter_dof(r.n[ok], rho)
        out.append((float(np.sum(nu * s2[ok] / sig2)), int(round(float(np.sum(nu))))))
    return out


def residual_dof_runs(model: "CampaignModel", J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Each run's share of the lack-of-fit degrees of freedom: its cells less the
    leverage they carry, N_j - sum_i h_ii (they add up to N - rank).

    Parameters
    ----------
    model : CampaignModel
    J : (N, P) ndarray
        Whitened Jacobian at the solution [1 / parameter unit].
    cov : (P, P) ndarray
        Noise-model covariance, zero on held parameters (``FitResult.cov_noise``).

    Returns
    -------
    (runs,) ndarray
        Residual dof per run [1].
    """
    h = np.einsum("ij,jk,ik->i", J, cov, J) if J.size else np.zeros(J.shape[0])
    return np.array([float(model.rows(j).stop - model.rows(j).start) - float(np.sum(h[model.rows(j)]))
                     for j in range(len(model.runs))])


def lack_of_fit_reference(model: "CampaignModel", dof_runs: np.ndarray,
                          pe_runs: Sequence[tuple[float, int]]) -> tuple[float, float, float] | None:
    """First three cumulants of the lack-of-fit statistic times its dof, F dof_lof, under
    the model, when each run's cell means are weighted by a noise model estimated from that
    run's own scatter.

    With the noise known, F dof_lof would be chi-square(dof_lof).  A run whose variance is
    read from nu pure-error dof with q variance parameters (:attr:`NoiseModel.n_params`)
    contributes d_j F(d_j, m_j), m_j = nu/q, instead (d_j its share of the dof,
    :func:`residual_dof_runs`): its weights are too large as often as too small, and the
    inverse of a variance estimate is high on average (m/(m - 2)), so the sum of the
    runs' chi-squares is larger and wider than the F(dof_lof, dof_pe) of one pooled
    variance says.  On clean full-set centrifuge campaigns (eight runs of 161 pure-error
    dof) the F reference put 8-10 % of them below p = 0.05.  Runs whose noise
    is not their own estimate count as known.

    Parameters
    ----------
    model : CampaignModel
    dof_runs : (runs,) ndarray
        Residual dof per run [1].
    pe_runs : sequence of (chi2, dof)
        :func:`pure_error_runs`.

    Returns
    -------
    (k1, k2, k3) : (float, float, float) or None
        None when no run's noise is its own estimate (F(dof_lof, dof_pe) holds); else the
        cumulants of sum_j d_j F(d_j, m_j) [1], from the raw moments E[(d F)^r] =
        m^r Gamma(d/2 + r) Gamma(m/2 - r) / (Gamma(d/2) Gamma(m/2)) (the ratio of
        independent chi-squares; Johnson, Kotz & Balakrishnan, *Continuous Univariate
        Distributions* 2, ch. 27); :func:`accelcal.fitting.core.lack_of_fit` matches a
        shifted, scaled chi-square to them.
    """
    k1 = k2 = k3 = 0.0
    owned = False
    for r, d, (_, nu) in zip(model.runs, dof_runs, pe_runs):
        if d <= 0:
            continue
        own = r.noise is not None and r.noise.source in ("residuals", "outputs") and nu > 0
        owned |= own
        if not own:                       # chi-square(d): cumulants d, 2d, 8d
            k1, k2, k3 = k1 + d, k2 + 2.0 * d, k3 + 8.0 * d
            continue
        m = max(nu / max(r.noise.n_params, 1), MIN_NOISE_DOF)
        lg = math.lgamma
        mu = [math.exp(rr * math.log(m) + lg(d / 2 + rr) + lg(m / 2 - rr) - lg(d / 2) - lg(m / 2))
              for rr in (1, 2, 3)]
        c2 = mu[1] - mu[0] ** 2
        k1, k2, k3 = k1 + mu[0], k2 + c2, k3 + mu[2] - 3.0 * mu[0] * mu[1] + 2.0 * mu[0] ** 3
    return (k1, k2, k3) if owned else None


def lack_of_fit_at_rho_hi(model: "CampaignModel", scatter: Sequence[np.ndarray], z: np.ndarray, dof_lof: int,
                          alpha: float, dof_runs: np.ndarray | None = None) -> LackOfFit | None:
    """The lack-of-fit test with each run's AR(1) correlation at the upper end of its
    sampling interval (``NoiseModel.rho_hi``), or None when every run is white.

    A rho read from short cells is uncertain (in 24 ten-reading cells at rho = 0.6 it reads
    0.4-0.7), and a cell mean's noise grows fast with it (:func:`ar1_mean_factor`); the
    model is called inadequate only if it is inadequate at that end too.  At
    rho_hi the reading variance refitted to the same scatter is sigma^2 vf(rho) / vf(rho_hi)
    (vf = :func:`ar1_variance_factor`), so each cell's whitened residual squared scales by
    vf(rho_hi) mf(rho) / (vf(rho) mf(rho_hi)) (mf = :func:`ar1_mean_factor`).

    Parameters
    ----------
    model : CampaignModel
    scatter : sequence of ndarray
        Each run's within-cell residual variance at the fit (:func:`residual_cell_variance`).
    z : (N,) ndarray
        Whitened cell residuals at p [1].
    dof_lof : int
        Cells minus fitted parameters [1].
    alpha : float
        Level of the test [1].
    dof_runs : (runs,) ndarray, optional
        Residual dof per run (:func:`residual_dof_runs`): the p-value then allows for the
        runs' noise models being estimates (:func:`lack_of_fit_reference`).

    Returns
    -------
    LackOfFit or None
    """
    if not any(r.noise is not None and r.noise.rho_hi > r.noise.rho for r in model.runs):
        return None
    chi = 0.0
    for j, r in enumerate(model.runs):
        zj = z[model.rows(j)]
        if r.noise is None or not r.noise.rho_hi > r.noise.rho:
            chi += float(zj @ zj)
            continue
        lo, hi = r.noise.rho, r.noise.rho_hi
        k = (ar1_variance_factor(r.n, hi) * ar1_mean_factor(r.n, lo)
             / (ar1_variance_factor(r.n, lo) * ar1_mean_factor(r.n, hi)))
        chi += float(np.sum(zj * zj * k))
    pe_runs = pure_error_runs(model, scatter, at_rho_hi=True)
    chi_pe, dof_pe = sum(c for c, _ in pe_runs), sum(d for _, d in pe_runs)
    return lack_of_fit(chi, dof_lof, chi_pe if dof_pe > 0 else None, dof_pe, alpha=alpha,
                       reference=lack_of_fit_reference(model, dof_runs, pe_runs) if dof_runs is not None else None)
