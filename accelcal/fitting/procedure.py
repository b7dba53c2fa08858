"""The one fit procedure of a campaign model: start -> Gauss–Newton -> noise-model refit ->
(re-selection) -> Gauss–Newton -> pure error -> lack of fit.

Both the adopted calibration (:func:`accelcal.estimators.joint.fit_campaign_model`) and the
sim-to-real diagnosis (:class:`accelcal.diagnosis.fits.Fitter`) fit a
:class:`~accelcal.fitting.model.CampaignModel` through :func:`fit_model`; what differs
between them is a handful of options, named here, not a second driver:

* ``bounded``: a time constant (``sensor_lag``) is kept >= 0 (the adopted fit); the
  diagnosis compares nested models and leaves it unbounded;
* ``reselect``: after the first noise pass the design is judged again at the estimate
  (terms that act only through the instrument coefficients are 0 at the start);
* ``noise_level``: which runs fit the rate-proportional noise term (``"design"``:
  centrifuge mounts whose rate varies, :func:`accelcal.fitting.data.fit_noise`;
  ``"spread"``: every run whose regressor varies);
* ``alpha``: level of the lack-of-fit test.

The fit changes neither the model nor the runs it is given: a new hold or a refitted noise
model makes a new model value (:meth:`CampaignModel.with_holds`,
:meth:`CampaignModel.with_noise`), which the result carries.

References: Draper & Smith, *Applied Regression Analysis*, §2.1 (pure error, lack of fit);
Marquardt 1963 (the damped Gauss–Newton step).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from .core import ALPHA, FitResult, NestedTest, finish_fit, gauss_newton, lack_of_fit, nested_test
from .data import NoiseModel, fit_noise, pool_missing_noise
from .identify import Hold, as_holds
from .model import (CampaignModel, lack_of_fit_at_rho_hi, lack_of_fit_reference, pure_error_runs,
                    residual_cell_variance, residual_dof_runs)


@dataclass
class ModelFit:
    """A fitted campaign model: the model, its :class:`~accelcal.fitting.core.FitResult`
    and what the procedure decided on the way.

    Attributes
    ----------
    model : CampaignModel
        The model at the solution: its parameters carry the holds, its runs (copies of the
        caller's) the noise models refitted to its residuals (:attr:`noise`).
    fit : FitResult
        Values [parameter units], covariance, chi-square [1], dof, lack of fit, whitened
        residual and Jacobian, Fisher information.
    held : dict of str to Hold
        Parameter name -> why it is held (:class:`~accelcal.fitting.identify.Hold`).
    iterations : int
        Gauss–Newton iterations over all passes.
    pure_error : dict
        ``{"chi2": [1], "dof": int}`` of the within-cell scatter (the sums of
        :func:`~accelcal.fitting.model.pure_error_runs`).
    active : ndarray of bool
        Free parameters whose Jacobian column acts on the data at the solution.
    effects : list of str
        The effects.md ids the model was built with.
    notes : list of str
        What a reader of the result should know (duplicate cells dropped, ...).
    """
    model: CampaignModel
    fit: FitResult
    held: dict[str, Hold]
    iterations: int
    pure_error: dict[str, float] = field(default_factory=dict)
    active: np.ndarray | None = None
    effects: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def value(self, name: str) -> float:
        """Estimate of one parameter (:meth:`accelcal.fitting.core.FitResult.value`).

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float
            Estimate, or the held value when held [parameter unit].
        """
        return self.fit.value(name)

    @property
    def noise(self) -> list[NoiseModel]:
        """Each run's noise model as the fit whitened it (refitted to its residuals)."""
        return [r.noise for r in self.model.runs]

    def reason(self, name: str) -> str | None:
        """Why one parameter is held, in words (:attr:`~accelcal.fitting.identify.Hold.reason`);
        None when it is free."""
        h = self.held.get(name)
        return None if h is None else h.reason

    def compare(self, smaller: "ModelFit", always_scaled: bool = False) -> NestedTest:
        """The nested test (:func:`~accelcal.fitting.core.nested_test`) of this fit against a
        smaller model it extends.

        Parameters
        ----------
        smaller : ModelFit
            The fit of the model this one extends.
        always_scaled : bool
            Scale by this fit's s2 = chi2 / dof whatever its size (the F test); False: only
            when s2 exceeds 1 (a gap the larger model leaves), else the chi-square test with
            the noise model taken as known.

        Returns
        -------
        NestedTest
            Untestable (statistic and p None) without dof, or with chi2 = 0 when always scaled.
        """
        return nested_test(smaller.fit.chi2, self.fit.chi2, max(self.fit.rank - smaller.fit.rank, 1),
                           int(self.fit.dof), always_scaled)

    def std(self, name: str) -> float:
        """Standard uncertainty of one parameter, lack-of-fit scaled
        (:meth:`accelcal.fitting.core.FitResult.std`).

        Parameters
        ----------
        name : str
            Parameter name.

        Returns
        -------
        float
            sqrt of the diagonal of ``fit.cov`` [parameter unit]; nan when the parameter is
            held or not estimable.
        """
        return self.fit.std(name)


def refit_noise(model: CampaignModel, p: np.ndarray, noise_level: str = "design",
                cautious: bool = False) -> list[NoiseModel]:
    """Every run's noise model refitted to the residual readings of the model at ``p``
    (:func:`accelcal.fitting.data.fit_noise`); the runs are not changed.

    Parameters
    ----------
    model : CampaignModel
    p : ndarray
        Parameter vector [parameter units].
    noise_level : {'design', 'spread'}
        Runs that fit the rate-proportional term b x^2: ``'design'`` leaves the choice to
        :func:`~accelcal.fitting.data.fit_noise` (centrifuge mounts whose rate varies);
        ``'spread'``: every run whose regressor x varies.
    cautious : bool
        AR(1) correlation at the upper end of its interval (:func:`fit_noise`).

    Returns
    -------
    list of NoiseModel
        One per run of the model, runs without replicates pooled
        (:func:`~accelcal.fitting.data.pool_missing_noise`).
    """
    return pool_missing_noise(model.runs, [
        fit_noise(r, r.y_rows - model.predict_rows(p, j), cautious=cautious,
                  use_level=None if noise_level == "design" else bool(r.x.size and np.ptp(r.x) > 0))
        for j, r in enumerate(model.runs)])


def fit_model(model: CampaignModel, p: np.ndarray, held: Mapping[str, Hold | str], *,
              keep: Sequence[str] = (), noise_passes: int = 1, reselect: bool = True,
              bounded: bool = True, noise_level: str = "design", max_iter: int = 40,
              alpha: float = ALPHA, effects: Sequence[str] = (),
              hold: Mapping[str, Hold | str] | None = None, cautious: bool = False) -> ModelFit:
    """Fit a campaign model whose holds are decided (:meth:`CampaignModel.select`).

    Parameters
    ----------
    model : CampaignModel
        With ``model.params`` holding what ``held`` names (:meth:`CampaignModel.with_holds`).
    p : ndarray
        Start [parameter units] (:meth:`CampaignModel.start`), held parameters at their
        held values.
    held : mapping of str to Hold or str
        Name -> hold of the parameters held (the caller's words for a given one).
    keep : sequence of str
        Names never held for being weakly determined (at the re-selection).
    noise_passes : int
        Times the noise model is refitted to the residuals and the model fitted again, so
        that regressor noise and a lack of fit of nothing but noise are told apart.
    reselect : bool
        Judge what the design determines again at the estimate after the first noise pass.
    bounded : bool
        Project each trial point onto the lower bounds (:meth:`CampaignModel.lower_bounds`).
    noise_level : {'design', 'spread'}
        :func:`refit_noise`.
    max_iter : int
        Gauss–Newton iterations per pass.
    alpha : float
        Level of the lack-of-fit test (:func:`accelcal.fitting.core.lack_of_fit`).
    effects : sequence of str
        Kept in the result (the effects.md ids the model was built with).
    hold : mapping of str to Hold or str, optional
        Parameters held whatever the design, at the re-selection too
        (:meth:`CampaignModel.select`).
    cautious : bool
        Noise refits take each run's AR(1) correlation at the upper end of its interval
        (:func:`~accelcal.fitting.data.fit_noise`).

    Returns
    -------
    ModelFit
        The covariance is the noise-model covariance scaled by the lack-of-fit factor; the
        lack of fit tests the cell means against the pure error (Draper & Smith §2.1).
    """
    held = as_holds(held)
    free = model.params.free()
    lower = model.lower_bounds() if bounded else None
    gn = gauss_newton(model.residual, model.jacobian, p, free, max_iter=max_iter, lower=lower)
    its = gn.iterations
    for k in range(noise_passes):
        model = model.with_noise(refit_noise(model, gn.p, noise_level, cautious))
        if k == 0 and reselect:
            held2 = model.select(gn.p, keep=keep, hold=hold)
            if set(held2) != set(held):
                held, model = held2, model.with_holds(held2)
                free = model.params.free()
                gn = replace(gn, p=np.where(free, gn.p, model.params.values()))
        gn = gauss_newton(model.residual, model.jacobian, gn.p, free, max_iter=max_iter, lower=lower)
        its += gn.iterations
    scatter = residual_cell_variance(model, gn.p)          # once, for both rho variants
    pe_runs = pure_error_runs(model, scatter)
    chi_pe, dof_pe = sum(c for c, _ in pe_runs), sum(d for _, d in pe_runs)
    plain = finish_fit(model.params, gn)
    rank = plain.rank
    # each run's weights are its own noise estimate: the p-value allows for it
    dof_runs = residual_dof_runs(model, gn.J, plain.cov_noise)
    lof = lack_of_fit(gn.chi2, model.N - rank, chi_pe if dof_pe > 0 else None, dof_pe, alpha=alpha,
                      reference=lack_of_fit_reference(model, dof_runs, pe_runs))
    # coloured noise: inadequate only if inadequate at the upper end of rho's interval too
    hi = (lack_of_fit_at_rho_hi(model, scatter, gn.z, model.N - rank, alpha, dof_runs)
          if lof.p_value is not None else None)
    if hi is not None and hi.p_value is not None and hi.p_value > lof.p_value:
        lof = hi
    # the covariance finish_fit gives with this lack of fit, from the one SVD already done
    fit = replace(plain, lof=lof, cov=plain.cov_noise * lof.factor ** 2)
    active = model.params.free() & (np.linalg.norm(gn.J, axis=0) > 0)
    return ModelFit(model, fit, held, its, {"chi2": chi_pe, "dof": dof_pe}, active, list(effects))


def fit_selected(model: CampaignModel, *, keep: Sequence[str] = (), noise_passes: int = 1,
                 effects: Sequence[str] = (), hold: Mapping[str, Hold | str] | None = None) -> ModelFit:
    """Fit a campaign model as the adopted calibration does: from its start
    (:meth:`CampaignModel.start`), with what the design cannot determine held
    (:meth:`CampaignModel.select`), judged again after the first noise pass, a time
    constant bounded at 0.

    Parameters
    ----------
    model : CampaignModel
    keep : sequence of str
        Parameters never held for being weakly determined.
    noise_passes : int
        :func:`fit_model`.
    effects : sequence of str
        Kept in the result (the effects.md ids the model was built with).
    hold : mapping of str to Hold or str, optional
        Parameters held whatever the design (name -> hold, or the caller's words).

    Returns
    -------
    ModelFit
    """
    p = model.start()
    held = model.select(p, keep=keep, hold=hold)
    model = model.with_holds(held)
    # the start's linear refit (:meth:`CampaignModel.start_lag`) spreads a minimum-norm
    # solution over aliased coefficients too: those held start at their held values
    p = np.where(model.params.free(), p, model.params.values())
    return fit_model(model, p, held, keep=keep, noise_passes=noise_passes, reselect=True, bounded=True,
                     effects=effects, hold=hold)
