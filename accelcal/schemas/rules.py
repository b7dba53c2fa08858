"""The drop-format rules great-expectations checks (drop-format.md): the thresholds and
the declaration of every expectation of each (test kind, table) suite, with its rule id.
:mod:`accelcal.schemas.suites` runs them; :mod:`accelcal.schemas.derived` makes the
columns the rows suites read."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .dropspec import COLUMNS, INT_COLUMNS, REQUIRED_KEYS, Refusal

#: Plausible temperatures, degC.
TEMP_RANGE_C = (-60.0, 150.0)
#: Angle tolerance for "the same angle", degrees.
ANGLE_TOL_DEG = 0.5
#: Relative tolerance of the sample period.
PERIOD_RTOL = 0.01
#: A table turning slower than this (rad/s) is at rest.
REST_RATE = 1e-3
#: Largest |omega^2 R / g - 1| of the step "near 1 g".
ONE_G_RTOL = 0.15
#: sine: fitted rate amplitude / rate_amplitude_rad_s within 1 +- this.
SINE_AMP_RTOL = 0.1
#: sine: rms residual of the rate fit at rate_frequency_hz, relative to the amplitude.
SINE_RESID_MAX = 0.1
_BIG = 1e300
#: Plausible ranges of numeric metadata (rule ``metadata-range``).  This is the one check of
#: metadata the suites make: presence, types, sets, times and axes are the parser's
#: (:mod:`accelcal.schemas.dropformat`), which refuses a file before it reaches a suite.
METADATA_RANGES: dict[str, tuple[float, float]] = {
    "site_latitude_deg": (-90, 90), "g_local_m_s2": (9.7, 9.9), "sample_period_s": (1e-6, 3600),
    "arm_radius_m": (1e-3, 20), "mount_angle_deg": (-360, 360), "reading_window_s": (1e-6, 3600),
    "tilt_deg": (0, 90), "positions": (1, 100000), "rate_amplitude_rad_s": (1e-6, 1000),
    "rate_frequency_hz": (1e-6, 1000),
}


@dataclass
class ValidationReport:
    """Result of :func:`validate_report`: refusals per run path (empty list = accepted)."""

    refusals: dict[str, list[Refusal]]
    seconds: float
    seconds_per_kind: dict[str, float] = field(default_factory=dict)
    docs_index: Path | None = None

    @property
    def accepted(self) -> list[str]:
        return [p for p, r in self.refusals.items() if not r]


# --------------------------------------------------------------------------------------
# suites


def _E(cls_name: str, rule: str, what: str, **kw) -> tuple[str, str, str, dict]:
    """An expectation as a spec: (GE class name, rule, what, keyword arguments)."""
    return cls_name, rule, what, kw


def _expectation(spec: tuple[str, str, str, dict], **meta):
    import great_expectations.expectations as gxe
    cls_name, rule, what, kw = spec
    return getattr(gxe, cls_name)(meta={"rule": rule, "what": what, **meta}, **kw)


def build_suites(test: str) -> dict[str, list]:
    """The expectations of ``<test>.rows`` and ``<test>.meta`` (not yet in a suite)."""
    return {t: [_expectation(x) for x in specs] for t, specs in _suite_specs(test).items()}


def _suite_specs(test: str) -> dict[str, list[tuple[str, str, str, dict]]]:
    """The expectations of one test kind: on its rows, and on its metadata."""
    cols = COLUMNS[test]
    rows: list = [_E("ExpectTableColumnsToMatchSet", "missing-column",
                     f"the columns of a {test} run", column_set=list(cols), exact_match=False)]
    for c in cols:
        rows.append(_E("ExpectColumnValuesToBeInTypeList", "column-type",
                       f"{c} must be {'int64' if c in INT_COLUMNS else 'float64'}", column=c,
                       type_list=["int64"] if c in INT_COLUMNS else ["float64"]))
    rows.append(_E("ExpectColumnValuesToNotBeNull", "output-not-finite", "output must not be NaN",
                   column="output"))
    rows.append(_E("ExpectColumnValuesToBeBetween", "output-not-finite", "output must be finite",
                   column="output", min_value=-_BIG, max_value=_BIG))
    rows.append(_E("ExpectColumnValuesToBeBetween", "not-finite",
                   "NaN or infinite value (count of such cells in the row)",
                   column="nonfinite_cells", max_value=0))
    rows.append(_E("ExpectColumnValuesToBeBetween", "time-not-increasing",
                   "time_s must increase strictly (goes back or repeats here)",
                   column="d_time_s", min_value=0.0, strict_min=True))
    rows.append(_E("ExpectColumnValuesToBeBetween", "sample-period",
                   "rows closer in time than sample_period_s",
                   column="dt_over_period", min_value=1.0 - PERIOD_RTOL))
    rows.append(_E("ExpectColumnValuesToBeBetween", "sample-period",
                   "median time step within a dwell differs from sample_period_s",
                   column="period_error", min_value=0.0, max_value=PERIOD_RTOL))
    for c in ("temp_c", "temp_set_c"):
        if c in cols:
            rows.append(_E("ExpectColumnValuesToBeBetween", "temp-out-of-range",
                           f"{c} outside {TEMP_RANGE_C[0]:g}..{TEMP_RANGE_C[1]:g} degC",
                           column=c, min_value=TEMP_RANGE_C[0], max_value=TEMP_RANGE_C[1]))
    for c in ("angle_deg", "rotation_deg") + (("table_angle_deg",) if test == "centrifuge" else ()):
        if c in cols:
            rows.append(_E("ExpectColumnValuesToBeBetween", "angle-out-of-range",
                           f"{c} outside -360..360 deg", column=c, min_value=-360.0, max_value=360.0))
    for c in ("position", "step"):
        if c in cols:
            rows.append(_E("ExpectColumnValuesToBeBetween", "bad-value", f"{c} must be >= 0",
                           column=c, min_value=0))
    if test == "tumble":
        rows.append(_E("ExpectColumnValuesToBeBetween", "angle-inconsistent",
                       f"angle_deg differs by more than {ANGLE_TOL_DEG} deg from the other rows "
                       "of its position", column="angle_dev_deg", max_value=ANGLE_TOL_DEG))
    if test == "centrifuge":
        rows.append(_E("ExpectColumnValuesToBeBetween", "negative-rate",
                       "table_rate_rad_s must be >= 0 in a centrifuge run",
                       column="table_rate_rad_s", min_value=0.0))
        rows.append(_E("ExpectColumnValuesToNotBeNull", "angle-missing-at-rest",
                       "table_angle_deg must be given while the table is at rest",
                       column="table_angle_deg", row_condition=_at_rest()))
        rows.append(_E("ExpectColumnValuesToBeBetween", "rest-dwells",
                       "the run must start with rest dwells at >= 2 equally spaced azimuths "
                       "(worst azimuth spacing error, deg)",
                       column="rest_dwell_error_deg", min_value=0.0, max_value=ANGLE_TOL_DEG))
        rows.append(_E("ExpectColumnValuesToBeBetween", "no-1g-step",
                       "no dwell rate near 1 g (min |omega^2 R / g - 1|)",
                       column="one_g_error", min_value=0.0, max_value=ONE_G_RTOL))
    if test == "tilt_rotation":
        rows.append(_E("ExpectColumnValuesToBeBetween", "positions-mismatch",
                       "rotation_deg is not one of the 360*k/positions angles (off by, deg)",
                       column="rotation_grid_dev_deg", max_value=ANGLE_TOL_DEG))
        rows.append(_E("ExpectColumnValuesToBeBetween", "positions-mismatch",
                       "number of distinct rotation angles at this temperature point minus positions",
                       column="positions_error", min_value=0, max_value=0))
    if test == "sine_centrifuge":
        rows.append(_E("ExpectColumnValuesToBeBetween", "sine-amplitude",
                       "fitted |rate| amplitude / rate_amplitude_rad_s",
                       column="rate_amplitude_ratio", min_value=1 - SINE_AMP_RTOL,
                       max_value=1 + SINE_AMP_RTOL))
        rows.append(_E("ExpectColumnValuesToBeBetween", "sine-frequency",
                       "rms residual of a sine fit at rate_frequency_hz / amplitude",
                       column="rate_fit_residual", min_value=0.0, max_value=SINE_RESID_MAX))

    meta = [_E("ExpectColumnValuesToBeBetween", "metadata-range",
                  f"{k} outside plausible range {lo:g}..{hi:g}", column=k, min_value=lo,
                  max_value=hi)
            for k, (lo, hi) in METADATA_RANGES.items() if k in REQUIRED_KEYS[test]]
    meta.append(_E("ExpectColumnValuesToBeBetween", "metadata-range",
                   "ambient_temp_c outside plausible range", column="ambient_temp_c",
                   min_value=TEMP_RANGE_C[0], max_value=TEMP_RANGE_C[1]))
    return {"rows": rows, "meta": meta}


def _at_rest():
    from great_expectations.expectations.row_conditions import Column
    rate = Column("table_rate_rad_s")
    return (rate < REST_RATE) & (rate > -REST_RATE)
