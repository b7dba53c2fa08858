"""Semantic validation of parsed runs with great-expectations 1.x (drop-format.md).

The parser (:mod:`accelcal.schemas.dropformat`) checks structure; this module
checks what needs the numbers, per test kind, with one Expectation Suite per
(test kind, table):

* ``<test>.rows`` on the runs' data (all runs of a kind in one batch) plus
  derived columns: column presence and types; finite values ("NaN or infinite
  numbers in ``output``"); time strictly increasing ("time that goes
  backwards"); ``table_rate_rad_s`` >= 0 for ``centrifuge``; plausible
  temperatures; angles in range; and the header's claims against the data
  (``sample_period_s``; tumble ``angle_deg`` constant per ``position``;
  centrifuge rest dwells at >= 2 equally spaced azimuths, azimuth present at
  rest, a step near 1 g; tilt_rotation ``positions`` equally spaced angles per
  temperature point; sine_centrifuge ``rate_amplitude_rad_s``/``rate_frequency_hz``).
  Run-level quantities sit on the run's first row (NaN elsewhere, which GE skips).
* ``<test>.meta`` on the metadata, one row per run: keys present, well typed,
  values in their sets and plausible ranges.

GE's unexpected row indices are mapped back to (file, ``line``); each failed
expectation of a run gives one :class:`Refusal` naming the first offending
line, the rule (``meta["rule"]`` of the expectation) and a detail. Rule ids:

``missing-column``, ``column-type``, ``output-not-finite``, ``not-finite``,
``time-not-increasing``, ``negative-rate``, ``temp-out-of-range``,
``angle-out-of-range``, ``sample-period``, ``angle-inconsistent``,
``angle-missing-at-rest``, ``rest-dwells``, ``no-1g-step``,
``positions-mismatch``, ``sine-amplitude``, ``sine-frequency``,
``missing-key``, ``unknown-format``, ``unknown-test``, ``bad-value``,
``bad-axis``, ``metadata-range``.

Data Docs (static HTML, offline: :mod:`accelcal.schemas.datadocs`) of each call go to
``docs_dir/<drop_name>/index.html``: every file with its verdict, the parser's refusals
passed in as ``parse_refusals`` included, and every expectation with its failures named
by file and line (the batch carries ``file`` and ``line`` columns).
"""
from __future__ import annotations

import os
import re
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .dropformat import RunFile
from .dropspec import (COLUMNS, FLOAT_KEYS, FORMAT, INT_COLUMNS, INT_KEYS, NULLABLE_COLUMNS,
                       OUTPUT_UNITS, REQUIRED_KEYS, ROTATION_SENSES, Refusal)
from ..effects import TESTS
from ..fitting.core import lstsq_min_norm

os.environ.setdefault("GX_ANALYTICS_ENABLED", "False")

__all__ = ["Refusal", "ValidationReport", "validate_runs", "validate_report", "build_suites",
           "TEMP_RANGE_C", "ANGLE_TOL_DEG"]

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
_ISO_OFFSET = r"^\d{4}-?\d{2}-?\d{2}[T ]\d{2}(:?\d{2}(:?\d{2}(\.\d+)?)?)?(Z|[+-]\d{2}(:?\d{2})?)$"
_SIGNED_AXIS = r"^\s*[+-]?\s*(IA|PA|OA)\s*$"
_PLANE = r"^\s*(IA|PA|OA)\s*-\s*(IA|PA|OA)\s*$"


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

    keys = REQUIRED_KEYS[test]
    meta: list = [
        _E("ExpectColumnValuesToBeBetween", "missing-key", "required keys missing (count)",
           column="missing_keys", max_value=0),
        _E("ExpectColumnValuesToBeBetween", "bad-value",
           "keys whose value is not of their type (count)", column="badly_typed_keys", max_value=0),
    ]
    meta.append(_E("ExpectColumnValuesToBeInSet", "unknown-format", f"format must be {FORMAT}",
                   column="format", value_set=[FORMAT]))
    meta.append(_E("ExpectColumnValuesToBeInSet", "unknown-test", f"test must be {test}",
                   column="test", value_set=[test]))
    meta.append(_E("ExpectColumnValuesToBeInSet", "bad-value", "output_unit not allowed",
                   column="output_unit", value_set=list(OUTPUT_UNITS)))
    meta.append(_E("ExpectColumnValuesToMatchRegex", "bad-value",
                   "started_at must be ISO 8601 with a UTC offset", column="started_at",
                   regex=_ISO_OFFSET))
    ranges = {
        "site_latitude_deg": (-90, 90), "g_local_m_s2": (9.7, 9.9), "sample_period_s": (1e-6, 3600),
        "arm_radius_m": (1e-3, 20), "mount_angle_deg": (-360, 360), "reading_window_s": (1e-6, 3600),
        "tilt_deg": (0, 90), "positions": (1, 100000), "rate_amplitude_rad_s": (1e-6, 1000),
        "rate_frequency_hz": (1e-6, 1000),
    }
    for k, (lo, hi) in ranges.items():
        if k in keys:
            meta.append(_E("ExpectColumnValuesToBeBetween", "metadata-range",
                           f"{k} outside plausible range {lo:g}..{hi:g}", column=k,
                           min_value=lo, max_value=hi))
    meta.append(_E("ExpectColumnValuesToBeBetween", "metadata-range",
                   "ambient_temp_c outside plausible range", column="ambient_temp_c",
                   min_value=TEMP_RANGE_C[0], max_value=TEMP_RANGE_C[1]))
    for k in ("head_axis", "cos_axis", "sin_axis", "normal_axis", "vertical_axis"):
        if k in keys:
            meta.append(_E("ExpectColumnValuesToMatchRegex", "bad-axis", f"{k} must be a signed axis",
                           column=k, regex=_SIGNED_AXIS))
    if "mount_plane" in keys:
        meta.append(_E("ExpectColumnValuesToMatchRegex", "bad-axis", "mount_plane must be like IA-PA",
                       column="mount_plane", regex=_PLANE))
    if "rotation_sense" in keys:
        meta.append(_E("ExpectColumnValuesToBeInSet", "bad-value", "rotation_sense must be ccw or cw",
                       column="rotation_sense", value_set=list(ROTATION_SENSES)))
    return {"rows": rows, "meta": meta}


def _at_rest():
    from great_expectations.expectations.row_conditions import Column
    rate = Column("table_rate_rad_s")
    return (rate < REST_RATE) & (rate > -REST_RATE)


# --------------------------------------------------------------------------------------
# derived columns (the header's claims made checkable row by row)


def _first_only(n: int, value: float) -> np.ndarray:
    out = np.full(n, np.nan)
    if n:
        out[0] = value
    return out


def _dwell_keys(test: str, d: dict[str, np.ndarray]) -> np.ndarray:
    """Consecutive rows of one dwell share a key (the DAQ logs at sample_period within it)."""
    if test == "tumble":
        k = d["position"].astype(np.float64)
    elif test == "centrifuge":
        k = d["step"].astype(np.float64)
    elif test == "tilt_rotation":
        k = d["temp_set_c"].astype(np.float64) * 1e4 + d["rotation_deg"].astype(np.float64)
    else:
        k = np.zeros(len(d["line"]))
    return k


def _segments(values: np.ndarray) -> np.ndarray:
    """Index of the run of equal consecutive values each row belongs to."""
    if len(values) == 0:
        return np.zeros(0, np.int64)
    change = np.r_[False, values[1:] != values[:-1]]
    return np.cumsum(change)


def _run_edges(values: np.ndarray) -> np.ndarray:
    """Where each run of equal consecutive values starts, then the end: run k is
    ``values[edges[k]:edges[k + 1]]`` (the slices of :func:`_segments`' labels)."""
    if len(values) == 0:
        return np.zeros(0, np.int64)
    return np.flatnonzero(np.r_[True, values[1:] != values[:-1], True])


def _derive(test: str, run: RunFile, step_means: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The run's columns plus the derived columns the suite checks, as numpy arrays of the
    run's length (no DataFrame per run: the batch is one table, made once).  The run's
    columns are its arrays (RunFile.arrays): a pandas column lookup costs more than most
    of the arithmetic here.  ``step_means``: for a centrifuge run, its mean turning rate
    per step when already known (:func:`_turning_step_means`)."""
    d = dict(run.arrays)
    n = run.n_rows
    d.setdefault("line", np.full(n, -1))
    cols = [c for c in COLUMNS[test] if c in d]
    out: dict[str, np.ndarray] = {c: d[c] for c in cols}
    meta = run.meta
    nullable = NULLABLE_COLUMNS[test]
    bad = np.zeros(n, np.int64)
    for c in cols:
        if c == "output" or c in INT_COLUMNS:
            continue
        v = d[c].astype(np.float64, copy=False)
        bad += np.isinf(v) if c in nullable else ~np.isfinite(v)
    out["nonfinite_cells"] = bad
    with np.errstate(all="ignore"):
        t = d["time_s"].astype(np.float64, copy=False) if "time_s" in d else np.full(n, np.nan)
        dt = np.r_[np.nan, np.diff(t)] if n else np.zeros(0)
        out["d_time_s"] = dt
        period = float(meta.get("sample_period_s", np.nan) or np.nan)
        # only forward steps here; a step back is time-not-increasing's alone
        out["dt_over_period"] = np.where(dt > 0, dt / period, np.nan) if period > 0 else np.nan
        try:
            keys = _dwell_keys(test, d)
            same = np.r_[False, keys[1:] == keys[:-1]] & np.isfinite(dt) & (dt > 0)
            within = dt[same]
            perr = abs(float(np.median(within)) / period - 1.0) if within.size and period > 0 else np.nan
        except KeyError:
            perr = np.nan
        out["period_error"] = _first_only(n, perr)

        if test == "tumble" and {"position", "angle_deg"} <= d.keys():
            ang = d["angle_deg"].astype(np.float64, copy=False)
            med = pd.Series(ang).groupby(d["position"]).transform("median").to_numpy(np.float64)
            out["angle_dev_deg"] = np.abs(ang - med)
        if test == "centrifuge" and {"step", "table_rate_rad_s", "table_angle_deg"} <= d.keys():
            out["rest_dwell_error_deg"] = _first_only(n, _rest_dwell_error(d))
            out["one_g_error"] = _one_g(d, meta, n, step_means)
        if test == "tilt_rotation" and {"temp_set_c", "rotation_deg"} <= d.keys():
            npos = int(meta.get("positions", 0) or 0)
            rot = d["rotation_deg"].astype(np.float64, copy=False)
            if npos >= 1:
                step = 360.0 / npos
                r = np.mod(rot, step)
                out["rotation_grid_dev_deg"] = np.minimum(r, step - r)
            else:
                out["rotation_grid_dev_deg"] = np.nan
            seg = _segments(d["temp_set_c"].astype(np.float64, copy=False))
            rk = np.round(np.mod(rot, 360.0) / ANGLE_TOL_DEG)
            distinct = pd.Series(rk).groupby(seg).transform("nunique").to_numpy(np.float64)
            first = np.r_[True, seg[1:] != seg[:-1]] if n else np.zeros(0, bool)
            out["positions_error"] = np.where(first, distinct - npos, np.nan)
        if test == "sine_centrifuge" and "table_rate_rad_s" in d:
            ratio, resid = _sine_fit(t, d["table_rate_rad_s"].astype(np.float64, copy=False), meta)
            out["rate_amplitude_ratio"] = _first_only(n, ratio)
            out["rate_fit_residual"] = _first_only(n, resid)
    for k, v in out.items():         # a scalar stands for every row (as a column would)
        if np.ndim(v) == 0:
            out[k] = np.full(n, v, dtype=np.float64)
    return out


def _rest_dwell_error(d: dict[str, np.ndarray]) -> float:
    """Worst spacing error (deg) of the leading rest dwells' azimuths; 999 if < 2 of them."""
    rate = d["table_rate_rad_s"].astype(np.float64, copy=False)
    step = d["step"]
    ang = d["table_angle_deg"].astype(np.float64, copy=False)
    # the dwells (runs of equal steps) as slices: the same rows, in order, as a mask each
    edges = _run_edges(step)
    az = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = slice(lo, hi)
        if not np.all(np.abs(rate[m]) < REST_RATE):
            break
        a = ang[m]
        a = a[np.isfinite(a)]
        if a.size == 0:
            return 999.0
        az.append(float(np.median(np.mod(a, 360.0))))
    az = sorted(set(round(a, 6) for a in az))
    if len(az) < 2:
        return 999.0
    gaps = np.diff(np.r_[az, az[0] + 360.0])
    return float(np.max(np.abs(gaps - 360.0 / len(az))))


def _one_g(d: dict[str, np.ndarray], meta: dict, n: int,
           means: np.ndarray | None = None) -> np.ndarray:
    """min over turning dwells of |omega^2 R / g - 1|, placed on the first turning row.
    ``means``: the mean turning rate [rad/s] per step, ascending steps (see
    :func:`_turning_step_means`), or None to compute them here."""
    rate = d["table_rate_rad_s"].astype(np.float64, copy=False)
    R = float(meta.get("arm_radius_m", np.nan))
    g = float(meta.get("g_local_m_s2", np.nan))
    turning = rate >= REST_RATE
    out = np.full(n, np.nan)
    if not turning.any() or not (R > 0 and g > 0):
        out[0] = 999.0 if n else np.nan
        return out
    if means is None:
        means = pd.Series(rate[turning]).groupby(d["step"][turning]).mean().to_numpy()
    err = np.abs(means ** 2 * R / g - 1.0)
    out[int(np.flatnonzero(turning)[0])] = float(np.nanmin(err)) if np.isfinite(err).any() else 999.0
    return out


def _turning_step_means(runs: list[RunFile]) -> dict[int, np.ndarray]:
    """What :func:`_one_g` needs of each centrifuge run ``runs[j]`` -- the mean rate [rad/s]
    of its turning rows per step, ascending steps -- for all of them in one pandas groupby
    (one per run cost a quarter of a run's derived columns).  The same numbers as a
    groupby per run, bit for bit: each group here is one run's step, its rows in the run's
    order, and pandas sums a group from its values alone -- but how depends on the whole
    key: rows sorted by group (and no NaN) are summed with ``np.add.reduceat``, others by
    a compensated sum.  So only runs whose turning steps never go down are taken (the
    batch is then sorted too, as each of them is alone; a turning rate is never NaN);
    the others, and runs whose columns are not the parser's dtypes, are left out
    (computed per run)."""
    rates, steps, js = [], [], []
    for j, r in enumerate(runs):
        a = r.arrays
        if r.test != "centrifuge" or not {"step", "table_rate_rad_s", "table_angle_deg"} <= a.keys():
            continue
        rate, step = a["table_rate_rad_s"], a["step"]
        if rate.dtype != np.float64 or step.dtype != np.int64:
            continue
        turning = rate >= REST_RATE
        s = step[turning]
        if len(s) > 1 and not (s[1:] >= s[:-1]).all():
            continue
        rates.append(rate[turning])
        steps.append(s)
        js.append(np.full(len(rates[-1]), j, np.int64))
    if not rates:
        return {}
    means = pd.Series(np.concatenate(rates)).groupby([np.concatenate(js),
                                                      np.concatenate(steps)]).mean()
    run_of = means.index.get_level_values(0).to_numpy()
    values = means.to_numpy()
    out: dict[int, np.ndarray] = {}
    bounds = _run_edges(run_of)
    for a, b in zip(bounds[:-1], bounds[1:]):
        out[int(run_of[a])] = values[a:b]
    return out


def _sine_fit(t: np.ndarray, rate: np.ndarray, meta: dict) -> tuple[float, float]:
    """Least-squares a*sin + b*cos + c at rate_frequency_hz: (amplitude/Omega, rms resid/Omega)."""
    Om = float(meta.get("rate_amplitude_rad_s", np.nan))
    f = float(meta.get("rate_frequency_hz", np.nan))
    ok = np.isfinite(t) & np.isfinite(rate)
    if ok.sum() < 4 or not (Om > 0 and f > 0):
        return np.nan, np.nan
    w = 2 * np.pi * f * t[ok]
    A = np.column_stack([np.sin(w), np.cos(w), np.ones_like(w)])
    try:
        coef = lstsq_min_norm(A, rate[ok])
    except np.linalg.LinAlgError:
        return np.nan, np.nan
    resid = rate[ok] - A @ coef
    rel_resid = float(np.sqrt(np.mean(resid ** 2)) / Om)
    if rel_resid <= SINE_RESID_MAX:
        amp = float(np.hypot(coef[0], coef[1]))
    else:  # wrong frequency: the fit says nothing about the amplitude; use the rms instead
        amp = float(np.sqrt(2.0) * np.std(rate[ok]))
    return amp / Om, rel_resid


def _meta_record(test: str, r: RunFile) -> tuple[dict, dict[str, str]]:
    """The run's typed metadata for the ``meta`` expectations, plus counts of missing and
    badly typed keys; and the names behind those counts (for the refusal's detail)."""
    keys = list(REQUIRED_KEYS[test]) + ["ambient_temp_c"]
    rec = {k: r.meta.get(k) for k in keys}
    missing = [k for k in REQUIRED_KEYS[test] if r.meta.get(k) in (None, "")]
    badtype = [k for k in keys if k in r.meta and (
        (k in FLOAT_KEYS and (isinstance(r.meta[k], bool) or not isinstance(r.meta[k], (float, int))))
        or (k in INT_KEYS and (isinstance(r.meta[k], bool) or not isinstance(r.meta[k], int)))
        or (k not in FLOAT_KEYS and k not in INT_KEYS and not isinstance(r.meta[k], str)))]
    rec["missing_keys"] = len(missing)
    rec["badly_typed_keys"] = len(badtype)
    for k in badtype:
        rec[k] = None  # keep the range checks from choking on a wrong kind
    return rec, {"missing_keys": ", ".join(missing), "badly_typed_keys": ", ".join(badtype)}


# --------------------------------------------------------------------------------------
# running the suites



def _new_context():
    import great_expectations as gx
    from great_expectations.data_context.types.base import ProgressBarsConfig
    ctx = gx.get_context(mode="ephemeral")
    ctx.variables.progress_bars = ProgressBarsConfig(globally=False, metric_calculations=False)
    return ctx


#: Per thread: ``source``, the pandas data source of an ephemeral context, and ``defs``, one
#: whole-dataframe batch definition per table, made once and reused by every batch (each
#: batch still gets its own Batch of its own dataframe).  Per thread, as GE's objects are
#: not made to be shared.
_GE = threading.local()


def _batch_definition(table: str):
    """The batch definition of ``table`` ('rows' or 'meta') in this thread's context."""
    if getattr(_GE, "source", None) is None:
        _GE.source = _new_context().data_sources.add_pandas("accelcal")
        _GE.defs = {}
    if table not in _GE.defs:
        _GE.defs[table] = _GE.source.add_dataframe_asset(table) \
            .add_batch_definition_whole_dataframe("all")
    return _GE.defs[table]


def _forget_batches() -> None:
    """Let go of the batches this thread's data source holds (its execution engine keeps
    every batch it loaded, and with it the batch's table): the table of a batch is
    freed when the batch is done, not when the next batch replaces it."""
    if getattr(_GE, "source", None) is None:
        return
    manager = _GE.source.get_execution_engine().batch_manager
    manager.reset_batch_cache()
    manager.batch_data_cache.clear()


#: Set (to a dict) while this thread runs a validation: see _configurations_memo.
_MEMO = threading.local()


def _memoize_configurations() -> None:
    """Make ``Expectation.configuration`` computed once per expectation object while a
    validation of ours runs (:func:`_configurations_memo`), the same value otherwise.

    GE 1.x recomputes that property -- a pydantic ``.dict()`` of the whole expectation,
    then a new ExpectationConfiguration -- for every keyword it looks up, ~80 times per
    expectation per validation: a third of a batch's validation CPU, for a value that
    cannot change while the expectation is only read (GE validates objects it creates
    from the suite's configurations, and does not change them).  Outside our validations
    (no memo set in this thread) the original property runs, untouched."""
    from great_expectations.expectations.expectation import Expectation
    prop = Expectation.__dict__.get("configuration")
    if not isinstance(prop, property) or getattr(prop.fget, "_accelcal_memo", False):
        return
    compute = prop.fget

    def configuration(self):
        memo = getattr(_MEMO, "memo", None)
        if memo is None:
            return compute(self)
        hit = memo.get(id(self))
        if hit is None or hit[0] is not self:     # (a new object may reuse a dead one's id)
            hit = memo[id(self)] = (self, compute(self))
        return hit[1]
    configuration._accelcal_memo = True
    Expectation.configuration = property(configuration, doc=prop.__doc__)


class _configurations_memo:
    """While inside: each expectation's configuration is computed once (this thread)."""

    def __enter__(self):
        _memoize_configurations()
        self.outer = getattr(_MEMO, "memo", None)
        _MEMO.memo = {}

    def __exit__(self, *exc):
        _MEMO.memo = self.outer     # the objects it held (and their ids) are let go


def _fmt(v) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return repr(v) if isinstance(v, str) else str(v)


def docs_folder_name(drop_name: str | None) -> str:
    """The folder under ``docs_dir`` that holds a drop's Data Docs."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", drop_name or "drop")


#: Columns that name where a row of a batch came from (GE reports them for each failure).
WHERE_COLUMNS = ["file", "line", "_row"]


#: Name of the one suite (and Data Docs page) that validates a batch.
BATCH_SUITE = "batch"


def _batch_specs(kinds: list[str], columns: dict[str, set[str]]) -> list[tuple[tuple, str, list[str]]]:
    """The expectations of every kind present, merged into one suite for one table:
    (spec, table 'rows'|'meta', kinds it applies to).  An expectation shared by several
    kinds is there once; each kind's own keep their order (so a file's refusals come in
    the same order as from its kind's suite).  One that is a kind's own, on a column other
    kinds' rows also fill, is limited to that kind's rows (row condition on ``test``)."""
    from great_expectations.expectations.row_conditions import Column
    merged: list[list] = []      # [key, spec, table, kinds]
    for k in kinds:
        prev = -1
        specs = _suite_specs(k)
        for table in ("rows", "meta"):
            for spec in specs[table]:
                key = (table, spec[0], spec[1], spec[2], repr(sorted(spec[3].items())))
                pos = next((i for i, m in enumerate(merged) if m[0] == key), -1)
                if pos > prev:
                    merged[pos][3].append(k)
                    prev = pos
                else:
                    merged.insert(prev + 1, [key, spec, table, [k]])
                    prev += 1
    out = []
    for _, (cls_name, rule, what, kw), table, ks in merged:
        col = kw.get("column")
        if col is not None and any(col in columns[o] for o in kinds if o not in ks):
            cond = Column("test").is_in(ks) if len(ks) > 1 else Column("test") == ks[0]
            kw = dict(kw, row_condition=cond if "row_condition" not in kw
                      else kw["row_condition"] & cond)
        out.append(((cls_name, rule, what, kw), table, ks))
    return out


#: Rows of the ``rows`` table validated by one great-expectations call.  A batch with more
#: rows (a big run file) is validated a slice of rows at a time and the slices' results
#: merged (:func:`_validate_batch`): GE copies the whole table for each metric, so a 5 M-row
#: table cost ~2 GB.  Every expectation on ``rows`` looks at one row at a time (or at the
#: table's columns and dtypes, the same in every slice), so the merged verdicts, failing
#: rows and messages are those of the whole table.
VALIDATE_ROWS = 1 << 19


class _Rows:
    """The ``rows`` table of a batch, made a slice of rows at a time (:meth:`frame`): every
    run's rows (its columns and derived columns; a column a kind does not have is empty on
    its rows -- NaN, or 0 in an int column) and where each row came from (``test``,
    ``file``, ``line``, ``_row``).  The whole table is never held: only the runs' own
    arrays, and the slice being validated."""

    def __init__(self, items: list[tuple[RunFile, str, dict]], lens: np.ndarray,
                 names: list[str], dtypes: dict[str, np.dtype], kinds, files, kind_code, file_code):
        self.items, self.lens, self.names, self.dtypes = items, lens, names, dtypes
        self.starts = np.r_[0, np.cumsum(lens)[:-1]].astype(np.int64)
        self.n = int(lens.sum())
        self.kinds, self.files = kinds, files          # category names
        self.kind_code, self.file_code = kind_code, file_code   # per run

    def run_of(self, rows) -> np.ndarray:
        """The run (index into the items) of each global row index."""
        return np.searchsorted(self.starts, np.asarray(rows, np.int64), side="right") - 1

    def _line(self, j: int) -> np.ndarray:
        r, _, d = self.items[j]
        if "line" in d:
            return d["line"]
        if "line" in r.arrays:
            return np.asarray(r.arrays["line"], dtype=np.int64)
        return np.full(self.lens[j], -1)

    def line(self, k: int) -> int:
        j = int(self.run_of(k))
        return int(self._line(j)[k - self.starts[j]])

    def cell(self, c: str, k: int):
        """The value of column ``c`` at global row ``k``, as the whole table holds it."""
        j = int(self.run_of(k))
        v = self.items[j][2].get(c)
        dt = self.dtypes[c]
        if v is None:
            return dt.type(0) if dt.kind in "iu" else dt.type(np.nan)
        return dt.type(v[k - self.starts[j]])

    def frame(self, a: int = 0, b: int | None = None) -> pd.DataFrame:
        """Rows ``a`` to ``b`` of the table (global row numbers kept in ``_row``)."""
        b = self.n if b is None else b
        js = [j for j in range(len(self.items))
              if self.starts[j] < b and self.starts[j] + self.lens[j] > a]
        cuts = [(j, max(a - self.starts[j], 0), min(b - self.starts[j], self.lens[j])) for j in js]
        m = b - a
        data: dict[str, object] = {}
        for c in self.names:
            dt = self.dtypes[c]
            parts = [self.items[j][2].get(c) for j, _, _ in cuts]
            if all(p is not None for p in parts):
                data[c] = np.concatenate([p[lo:hi] for p, (_, lo, hi) in zip(parts, cuts)]) \
                    if len(parts) != 1 or cuts[0][1] != 0 or cuts[0][2] != len(parts[0]) \
                    else parts[0]
                if data[c].dtype != dt:
                    data[c] = data[c].astype(dt)
                continue
            vals = np.zeros(m, np.int64) if dt.kind in "iu" else np.full(m, np.nan)
            pos = 0
            for p, (_, lo, hi) in zip(parts, cuts):
                if p is not None:
                    vals[pos:pos + hi - lo] = p[lo:hi]
                pos += hi - lo
            data[c] = vals
        run_ix = np.repeat(np.asarray(js, np.int64), [hi - lo for _, lo, hi in cuts])
        data["test"] = pd.Categorical.from_codes(self.kind_code[run_ix], self.kinds)
        data["file"] = pd.Categorical.from_codes(self.file_code[run_ix], self.files)
        data["line"] = np.concatenate([self._line(j)[lo:hi] for j, lo, hi in cuts])
        data["_row"] = np.arange(a, b)
        return pd.DataFrame(data, copy=False)

    def slices(self, rows: int = 0):
        """(a, b) row ranges of at most ``rows`` rows (default VALIDATE_ROWS) covering it."""
        rows = rows or VALIDATE_ROWS
        return [(a, min(a + rows, self.n)) for a in range(0, max(self.n, 1), rows)]


def _batch_parts(items: list[tuple[RunFile, str, dict]]) -> tuple[_Rows, pd.DataFrame, dict,
                                                                  list[dict]]:
    """The batch as two tables: ``rows`` (a :class:`_Rows`, made a slice at a time), and
    ``meta``, one row per run with its metadata; both say where each row came from
    (``test``, ``file``, ``line``, ``_row``; a run's meta row carries the ``_row`` and
    ``line`` of its first data row).  Two tables, not one, because great-expectations
    copies the whole table for every column it checks: metadata columns spread over every
    data row cost that copy without holding anything.  Also: the columns each kind fills,
    and each run's meta 'why'."""
    lens = np.array([len(next(iter(d.values()))) if d else 0 for _, _, d in items], np.int64)
    for j, (r, t, d) in enumerate(items):
        if lens[j] == 0:      # nothing to hold its metadata: one empty row (not a file's)
            items[j] = (r, t, {**{c: np.full(1, np.nan) if v.dtype.kind == "f" else
                                  np.zeros(1, v.dtype) for c, v in d.items()},
                               "line": np.full(1, -1)})
            lens[j] = 1
    columns: dict[str, set[str]] = {}
    names: dict[str, None] = {}
    for _, t, d in items:
        columns.setdefault(t, set()).update(c for c in d if c != "line")
        names.update(dict.fromkeys(c for c in d if c != "line"))
    dtypes: dict[str, np.dtype] = {}
    for c in names:
        parts = [d.get(c) for _, _, d in items]
        dt = np.result_type(*[p.dtype for p in parts if p is not None])
        if any(p is None for p in parts):
            if dt.kind in "iu":
                # an int column stays int64 (GE checks a nullable one row by row, in Python):
                # the other kinds' rows hold 0, and count as having the column, so its
                # expectations are limited to the kinds whose column it is (_batch_specs)
                dt = np.dtype(np.int64)
                for _, t, _ in items:
                    columns[t].add(c)
            else:
                dt = np.dtype(np.float64)
        dtypes[c] = dt
    # the metadata, one row per run
    whys, recs = [], []
    meta: dict[str, object] = {}
    for r, t, _ in items:
        rec, why = _meta_record(t, r)
        recs.append(rec)
        whys.append(why)
        columns[t].update(rec)
    for k in dict.fromkeys(k for rec in recs for k in rec):
        numeric = k in FLOAT_KEYS or k in INT_KEYS or k in ("missing_keys", "badly_typed_keys")
        if numeric:
            meta[k] = pd.to_numeric(pd.Series([rec.get(k) for rec in recs], dtype=object),
                                    errors="coerce").astype("float64").to_numpy()
        else:
            vals = np.empty(len(recs), dtype=object)
            vals[:] = [rec.get(k) for rec in recs]
            meta[k] = pd.Series(vals, dtype=object)
    tests = np.asarray([t for _, t, _ in items], dtype=object)
    files = np.asarray([r.path for r, _, _ in items], dtype=object)
    # on the data rows, ``test`` and ``file`` are categorical (a code per row): GE copies the
    # whole table for each metric of an expectation with a row condition, and a copy of
    # strings per row cost a fifth of a large batch's validation; the values are the same
    kind_names, kind_code = np.unique(tests.astype(str), return_inverse=True)
    file_names, file_code = np.unique(files.astype(str), return_inverse=True)
    rows = _Rows(items, lens, list(names), dtypes, kind_names.astype(object),
                 file_names.astype(object), kind_code, file_code)
    meta["test"] = pd.Series(tests, dtype=object)
    meta["file"] = files
    meta["line"] = np.asarray([rows._line(j)[0] for j in range(len(items))], np.int64)
    meta["_row"] = rows.starts
    return rows, pd.DataFrame(meta, copy=False), columns, whys


def _batch_table(items: list[tuple[RunFile, str, dict]]) -> tuple[dict[str, pd.DataFrame], dict,
                                                                  np.ndarray, np.ndarray, list[dict]]:
    """:func:`_batch_parts` with the ``rows`` table made whole (benchmarks/
    bench_intake_budget.py times it): the two tables, the columns each kind fills, the run
    and the line of each row, and each run's meta 'why'."""
    rows, meta, columns, whys = _batch_parts(items)
    df = rows.frame()
    run_ix = np.repeat(np.arange(len(items)), rows.lens)
    return {"rows": df, "meta": meta}, columns, run_ix, df["line"].to_numpy(), whys


def validate_report(runs: list[RunFile], docs_dir: Path | None = None,
                    drop_name: str = "drop",
                    parse_refusals: list[Refusal] | None = None) -> ValidationReport:
    """Validate parsed runs with the GE suites: the batch is one table (every run's rows,
    derived columns and metadata, with ``file`` and ``line`` columns), validated by one
    suite -- the suites of the test kinds present, merged -- in one great-expectations
    call, in an ephemeral context.  Writes Data Docs to ``docs_dir/<drop_name>/`` when
    docs_dir is given, listing ``parse_refusals`` (files the parser refused) beside the
    suite's verdicts.
    """
    t0 = time.perf_counter()
    suite_results: list[tuple[str, dict]] = []
    refusals: dict[str, list[Refusal]] = {r.path: [] for r in runs}
    items: list[tuple[RunFile, str, dict]] = []
    todo: list[tuple[RunFile, str]] = []
    for r in runs:
        test = str(r.meta.get("test", ""))
        if test not in TESTS:
            refusals[r.path].append(Refusal(r.path, r.meta_lines.get("test"), "unknown-test",
                                            f"test {test!r} is not one of {', '.join(TESTS)}"))
            continue
        miss = [c for c in list(COLUMNS[test]) + ["line"] if c not in r.arrays]
        if miss:
            refusals[r.path].append(Refusal(r.path, r.header_line, "missing-column",
                                            f"columns missing: {', '.join(miss)}"))
            continue
        todo.append((r, test))
    try:
        step_means = _turning_step_means([r for r, _ in todo])
    except Exception:       # then each run's own, so that only its run is refused
        step_means = {}
    for j, (r, test) in enumerate(todo):
        try:
            items.append((r, test, _derive(test, r, step_means.get(j))))
        except Exception as e:  # a bug or data beyond the checks: refuse, don't stop the drop
            refusals[r.path].append(Refusal(r.path, None, "validation-error",
                                            f"{type(e).__name__}: {e}"[:300]))
    docs_root = None if docs_dir is None else Path(docs_dir) / docs_folder_name(drop_name)
    per_kind: dict[str, float] = {}
    if items:
        tk = time.perf_counter()
        kinds = list(dict.fromkeys(t for _, t, _ in items))
        rows, dfm, columns, meta_why = _batch_parts(items)
        specs = _batch_specs(kinds, columns)
        results, res_json = _validate_batch({"rows": rows, "meta": dfm}, specs,
                                            docs_root is not None)
        if docs_root is not None:
            suite_results.append((BATCH_SUITE, res_json))
        kind_runs = [r for r, _, _ in items]
        test_of = [t for _, t, _ in items]
        for er in results:
            if er.success:
                continue
            cfg = er.expectation_config
            rule = cfg.meta.get("rule", "validation")
            what = cfg.meta.get("what", cfg.type)
            table = cfg.meta.get("table", "rows")
            ks = set(cfg.meta.get("kinds") or kinds)
            col = cfg.kwargs.get("column")
            idx = er.result.get("unexpected_index_list") if er.result else None
            if idx and isinstance(idx[0], dict):      # {file, line, _row, value}
                idx = [e["_row"] for e in idx]
            if er.exception_info and er.exception_info.get("raised_exception"):
                idx = None
            if not idx:  # whole-table failure (column missing, wrong type, error)
                msg = what
                if er.result and "observed_value" in er.result:
                    msg += f" (observed {_fmt(er.result['observed_value'])})"
                if er.exception_info and er.exception_info.get("raised_exception"):
                    msg += f" ({str(er.exception_info.get('exception_message'))[:120]})"
                for r, t in zip(kind_runs, test_of):
                    if t in ks:
                        ln = r.meta_lines.get(col) if table == "meta" else r.header_line
                        refusals[r.path].append(Refusal(r.path, ln, rule, msg))
                continue
            idx = np.asarray(sorted(int(i) for i in idx))
            ri = rows.run_of(idx)
            for i in np.unique(ri):
                sel = idx[ri == i]
                k = int(sel[0])
                r = kind_runs[int(i)]
                if table == "meta":
                    why = meta_why[int(i)]
                    if col in why:
                        names = why[col]
                        ln = r.meta_lines.get(names.split(", ")[0]) if names else None
                        detail = f"{what}: {names}"
                    else:
                        ln = r.meta_lines.get(col)
                        detail = f"{what}: {col} = {_fmt(r.meta.get(col, dfm[col].iloc[int(i)]))}"
                    refusals[r.path].append(Refusal(r.path, ln, rule, detail))
                    continue
                test = test_of[int(i)]
                ln = rows.line(k)
                more = f" ({len(sel)} rows, first here)" if len(sel) > 1 else ""
                shown = [c for c in (col, "time_s") if c and c in columns[test]]
                if col == "nonfinite_cells":
                    shown = [c for c in COLUMNS[test] if c not in INT_COLUMNS
                             and not np.isfinite(rows.cell(c, k))
                             and not (np.isnan(rows.cell(c, k)) and c in NULLABLE_COLUMNS[test])]
                vals = ", ".join(f"{c} = {_fmt(rows.cell(c, k))}" for c in dict.fromkeys(shown))
                refusals[r.path].append(Refusal(r.path, ln if ln > 0 else None, rule,
                                                f"{what}: {vals}{more}"))
        per_kind["+".join(kinds)] = time.perf_counter() - tk
    for p in refusals:
        refusals[p].sort(key=lambda x: (x.line is None, x.line or 0, x.rule))
    index = _docs(docs_root, drop_name, runs, refusals, parse_refusals, suite_results)
    return ValidationReport(refusals, time.perf_counter() - t0, per_kind, index)


def run_suite(name: str, table: str, df: pd.DataFrame, specs: list, which: list[int],
              result_format: dict):
    """The expectations ``specs[i]`` (i in ``which``) of ``table`` ('rows' or 'meta') as one
    suite on ``df``, in this thread's context: GE's validation result.  Each expectation
    carries its index ``i`` in its meta."""
    import great_expectations as gx
    exps = [_expectation(specs[i][0], table=specs[i][1], kinds=specs[i][2], i=i) for i in which]
    # validated as is: a suite is added to a context only to be stored, and nothing here
    # is stored (that cost a serialisation of every expectation per batch)
    suite = gx.ExpectationSuite(name=name, expectations=exps)
    batch = _batch_definition(table).get_batch(batch_parameters={"dataframe": df})
    try:
        with warnings.catch_warnings(), _configurations_memo():
            warnings.simplefilter("ignore")
            return batch.validate(suite, result_format=result_format)
    finally:
        _forget_batches()


def _validate_batch(tables: dict[str, "pd.DataFrame | _Rows"], specs: list,
                    want_json: bool) -> tuple[list, dict | None]:
    """The batch's suite on its tables (``rows`` and ``meta``, each expectation on the
    table its spec names): GE's results, in the suite's order, and (``want_json``) one
    validation result as JSON for the Data Docs.

    Every expectation is run once with result format BOOLEAN_ONLY (passed or not: the
    cheap metrics); only those that failed are run again, COMPLETE, for the rows to name
    (their file and line: WHERE_COLUMNS) and the observed values.  A clean batch costs one
    validation per table; the failures' results replace theirs, so the Data Docs show them
    whole.

    A ``rows`` table given as :class:`_Rows` of more than VALIDATE_ROWS rows is validated a
    slice at a time (:func:`_validate_slices`), each slice made only while it is checked."""
    def run(name: str, table: str, which: list[int], result_format: dict):
        df = tables[table]
        if isinstance(df, _Rows):
            df = df.frame()
        return run_suite(name, table, df, specs, which, result_format)

    def key(er) -> int:
        return int(er.expectation_config.meta["i"])

    results: dict[int, object] = {}
    docs: dict[int, dict] = {}
    stats = {"evaluated_expectations": 0, "successful_expectations": 0,
             "unsuccessful_expectations": 0}
    for table in tables:
        which = [i for i, sp in enumerate(specs) if sp[1] == table]
        if not which:
            continue
        name = f"{BATCH_SUITE}.{table}"
        if isinstance(tables[table], _Rows) and len(tables[table].slices()) > 1:
            merged, merged_json = _validate_slices(name, table, tables[table], specs, which,
                                                   want_json)
            results.update(merged)
            if want_json:
                docs.update(merged_json)
                ok = sum(1 for i in which if merged[i].success)
                stats["evaluated_expectations"] += len(which)
                stats["successful_expectations"] += ok
                stats["unsuccessful_expectations"] += len(which) - ok
            continue
        first = run(name, table, which, {"result_format": "BOOLEAN_ONLY"})
        failed = [key(er) for er in first.results if not er.success]
        again = run(f"{name}.failed", table, failed, {
            "result_format": "COMPLETE", "unexpected_index_column_names": WHERE_COLUMNS}) \
            if failed else None
        full = {key(er): er for er in again.results} if again is not None else {}
        results.update({key(er): full.get(key(er), er) for er in first.results})
        if want_json:
            doc = first.to_json_dict()
            full_json = {int(r["expectation_config"]["meta"]["i"]): r
                         for r in (again.to_json_dict()["results"] if again is not None else [])}
            for r in doc["results"]:
                i = int(r["expectation_config"]["meta"]["i"])
                docs[i] = full_json.get(i, r)
            for k in stats:
                stats[k] += int((doc.get("statistics") or {}).get(k) or 0)
    ordered = [results[i] for i in sorted(results)]
    if not want_json:
        return ordered, None
    n = stats["evaluated_expectations"]
    stats["success_percent"] = 100.0 * stats["successful_expectations"] / n if n else None
    doc = {"success": all(er.success for er in ordered), "statistics": stats,
           "suite_name": BATCH_SUITE, "results": [docs[i] for i in sorted(docs)],
           "tables": {t: [i for i, sp in enumerate(specs) if sp[1] == t] for t in tables}}
    return ordered, doc


#: Counts in a result that add up over slices of rows (the rest is the first failing slice's).
_SUMMED = ("element_count", "unexpected_count", "missing_count")


def _validate_slices(name: str, table: str, rows: _Rows, specs: list, which: list[int],
                     want_json: bool) -> tuple[dict[int, object], dict[int, dict]]:
    """:func:`_validate_batch` on a ``rows`` table too big for one call: each slice of rows
    (:meth:`_Rows.slices`) made, checked BOOLEAN_ONLY, its failures checked again COMPLETE,
    and let go.  An expectation passes when it passes on every slice; one that fails keeps
    the COMPLETE result of the first slice it fails on, with the failing rows of the later
    slices appended (``_row`` is the row's number in the whole table) and the counts of
    :data:`_SUMMED` added up -- so the refusals made from it (first failing row, how many)
    are those of the whole table.  Results and their JSON (``want_json``) by expectation."""
    def key(er) -> int:
        return int(er.expectation_config.meta["i"])

    out: dict[int, object] = {}
    out_json: dict[int, dict] = {}
    for a, b in rows.slices():
        df = rows.frame(a, b)
        first = run_suite(name, table, df, specs, which, {"result_format": "BOOLEAN_ONLY"})
        failed = [key(er) for er in first.results if not er.success]
        again = run_suite(f"{name}.failed", table, df, specs, failed, {
            "result_format": "COMPLETE", "unexpected_index_column_names": WHERE_COLUMNS}) \
            if failed else None
        del df
        full = {key(er): er for er in again.results} if again is not None else {}
        full_json = ({int(r["expectation_config"]["meta"]["i"]): r
                      for r in again.to_json_dict()["results"]}
                     if want_json and again is not None else {})
        first_json = ({int(r["expectation_config"]["meta"]["i"]): r
                       for r in first.to_json_dict()["results"]} if want_json else {})
        for er in first.results:
            i = key(er)
            er = full.get(i, er)
            prev = out.get(i)
            if prev is None or (prev.success and not er.success):
                out[i] = er
                if want_json:
                    out_json[i] = full_json.get(i, first_json.get(i))
                continue
            if er.success or prev.success:
                continue
            _merge_result(prev.result, er.result)
            if want_json and i in full_json:
                _merge_result(out_json[i].get("result"), full_json[i].get("result"))
    return out, out_json


def _merge_result(into: dict | None, more: dict | None) -> None:
    """Add a later slice's failing rows and counts to a failed expectation's result."""
    if not into or not more:
        return
    for k in ("unexpected_index_list",):
        if isinstance(into.get(k), list) and isinstance(more.get(k), list):
            into[k] = into[k] + more[k]
    for k in _SUMMED:
        if isinstance(into.get(k), (int, np.integer)) and isinstance(more.get(k), (int, np.integer)):
            into[k] = int(into[k]) + int(more[k])


def _docs(docs_root: Path | None, title: str, runs: list[RunFile],
          refusals: dict[str, list[Refusal]], parse_refusals: list[Refusal] | None,
          suite_results: list[tuple[str, dict]]) -> Path | None:
    """Data Docs of this call: the parser's and the suites' verdicts on every file."""
    if docs_root is None:
        return None
    from .datadocs import write_data_docs

    def reason(x):
        return {"line": x.line, "rule": x.rule, "detail": x.detail}
    files = [{"path": r.path, "verdict": "refused" if refusals[r.path] else "accepted",
              "stage": "suites" if refusals[r.path] else "",
              "reasons": [reason(x) for x in refusals[r.path]]} for r in runs]
    by_path: dict[str, list[Refusal]] = {}
    for x in parse_refusals or []:
        by_path.setdefault(str(x.path), []).append(x)
    files += [{"path": p, "verdict": "refused", "stage": "parse",
               "reasons": [reason(x) for x in xs]} for p, xs in by_path.items()]
    return write_data_docs(docs_root, title, files, suite_results)


def validate_runs(runs: list[RunFile], docs_dir: Path | None = None,
                  drop_name: str = "drop",
                  parse_refusals: list[Refusal] | None = None) -> dict[str, list[Refusal]]:
    """Refusals per run path (empty list: the run passed every suite). See validate_report."""
    return validate_report(runs, docs_dir, drop_name, parse_refusals).refusals
