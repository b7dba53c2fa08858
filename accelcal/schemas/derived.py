"""The derived columns the rows suites check (:mod:`accelcal.schemas.rules`): dwell keys,
run-level figures on each run's first row (sample period, rest-dwell spread, the 1 g
step, the sine drive's amplitude and frequency), and the metadata record of a run."""
from __future__ import annotations

import numpy as np
import pandas as pd

from ..fitting.core import lstsq_min_norm
from ..fitting.data import Groups, dwell_starts
from .dropformat import RunFile
from .dropspec import COLUMNS, INT_COLUMNS, NULLABLE_COLUMNS, REQUIRED_KEYS
from .rules import ANGLE_TOL_DEG, METADATA_RANGES, REST_RATE, SINE_RESID_MAX

# --------------------------------------------------------------------------------------
# derived columns (the header's claims made checkable row by row)


class RowColumn:
    """A derived column made a slice of rows at a time, never whole (a day-long
    run's derived columns were hundreds of MB beside its own).  ``rows(lo, hi)`` gives
    rows ``lo`` to ``hi`` as an array of ``dtype``, element by element the numbers the
    whole column would hold.  It reads like the array it stands for where the rows table
    reads one (:class:`accelcal.schemas.suites._Rows`): ``len``, ``dtype``, a slice, a row.
    """

    def __init__(self, n: int, dtype, rows):
        self.n, self.dtype, self._rows = int(n), np.dtype(dtype), rows

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k):
        if isinstance(k, slice):
            lo, hi, step = k.indices(self.n)
            if step != 1:
                raise IndexError("a RowColumn is read in slices of consecutive rows")
            return np.asarray(self._rows(lo, max(hi, lo)), self.dtype)
        k = int(k) + (self.n if int(k) < 0 else 0)
        if not 0 <= k < self.n:
            raise IndexError(k)
        return self[k:k + 1][0]


def _sparse(n: int, at: np.ndarray, values: np.ndarray, fill: float = np.nan, dtype=np.float64) -> RowColumn:
    """A column that is ``fill`` but at the rows ``at`` (ascending), where it is ``values``."""
    at = np.asarray(at, np.int64)
    values = np.asarray(values, dtype)

    def rows(lo, hi):
        out = np.full(hi - lo, fill, dtype)
        a, b = np.searchsorted(at, lo), np.searchsorted(at, hi)
        out[at[a:b] - lo] = values[a:b]
        return out
    return RowColumn(n, dtype, rows)


def _first_only(n: int, value: float) -> RowColumn:
    return _sparse(n, np.zeros(1 if n else 0, np.int64), np.array([value] if n else []))


def _elementwise(n: int, dtype, fn, *cols: np.ndarray) -> RowColumn:
    """``fn`` of the columns, row by row, made for a slice at a time."""
    return RowColumn(n, dtype, lambda lo, hi: fn(*(c[lo:hi] for c in cols)))


def _segments(values: np.ndarray) -> np.ndarray:
    """Index of the run of equal consecutive values each row belongs to."""
    if len(values) == 0:
        return np.zeros(0, np.int64)
    change = np.r_[False, values[1:] != values[:-1]]
    return np.cumsum(change)


def _derive(test: str, run: RunFile) -> dict[str, np.ndarray]:
    """The run's columns plus the derived columns the suite checks, as numpy arrays of the
    run's length (no DataFrame per run: the batch is one table, made once).  The run's
    columns are its arrays (RunFile.arrays): a pandas column lookup costs more than most
    of the arithmetic here.  A dwell is :func:`accelcal.fitting.data.dwell_starts`' (the
    science's)."""
    src = run.arrays
    n = run.n_rows
    lazy = hasattr(src, "rows")     # the run is in its Parquet file: read when needed
    if lazy:
        # every column is read for the rows table a slice at a time; a whole column only
        # while a run-level figure is made from it
        d = src
        out: dict[str, np.ndarray] = {c: _stored(src, c) for c in (*COLUMNS[test], "line")
                                      if c in src}
        cols = [c for c in COLUMNS[test] if c in out]
    else:
        d = dict(src)
        d.setdefault("line", np.full(n, -1))
        cols = [c for c in COLUMNS[test] if c in d]
        out = {c: d[c] for c in cols}
    meta = run.meta
    nullable = NULLABLE_COLUMNS[test]
    checked = [(out[c], c in nullable) for c in cols if c != "output" and c not in INT_COLUMNS]

    def nonfinite(*vs):
        bad = np.zeros(len(vs[0]) if vs else 0, np.int64)
        for v, (_, null) in zip(vs, checked):
            v = v.astype(np.float64, copy=False)
            bad += np.isinf(v) if null else ~np.isfinite(v)
        return bad
    out["nonfinite_cells"] = (_elementwise(n, np.int64, nonfinite, *[v for v, _ in checked]) if checked
                              else np.zeros(n, np.int64))
    with np.errstate(all="ignore"):
        if lazy:
            t = out["time_s"] if "time_s" in out else RowColumn(n, np.float64,
                                                                 lambda lo, hi: np.full(hi - lo, np.nan))
        else:
            t = d["time_s"].astype(np.float64, copy=False) if "time_s" in d else np.full(n, np.nan)
        period = float(meta.get("sample_period_s", np.nan) or np.nan)

        def d_time(lo, hi):
            # rows lo..hi of np.r_[nan, np.diff(t)]: the same differences
            return np.r_[np.nan, np.diff(t[lo:hi])] if lo == 0 else np.diff(t[lo - 1:hi])

        def dt_over_period(lo, hi):
            # only forward steps here; a step back is time-not-increasing's alone
            dt = d_time(lo, hi)
            return np.where(dt > 0, dt / period, np.nan) if period > 0 else np.full(hi - lo, np.nan)
        out["d_time_s"] = RowColumn(n, np.float64, d_time)
        out["dt_over_period"] = RowColumn(n, np.float64, dt_over_period)
        try:
            if lazy:
                vals, counts = _within_dwell_steps(test, src, d_time, n)
                med = _median_of_counts(vals, counts) if counts.sum() else None
            else:
                dt = d_time(0, n) if n else np.zeros(0)
                same = np.isfinite(dt) & (dt > 0)
                same[dwell_starts(test, d, n)] = False
                within = dt[same]
                del dt
                med = float(np.median(within)) if within.size else None
            perr = abs(med / period - 1.0) if med is not None and period > 0 else np.nan
        except KeyError:
            perr = np.nan
        out["period_error"] = _first_only(n, perr)

        if test == "tumble" and {"position", "angle_deg"} <= d.keys():
            ang = d["angle_deg"].astype(np.float64, copy=False)
            med = pd.Series(ang).groupby(d["position"]).transform("median").to_numpy(np.float64)
            out["angle_dev_deg"] = np.abs(ang - med)
        if test == "centrifuge" and {"step", "table_rate_rad_s", "table_angle_deg"} <= d.keys():
            scan = _centrifuge_dwells(src, n) if lazy else None
            out["rest_dwell_error_deg"] = _first_only(n, _rest_dwell_error(d, scan and scan.edges))
            out["one_g_error"] = _sparse(n, *_one_g(d, meta, n, scan))
        if test == "tilt_rotation" and {"temp_set_c", "rotation_deg"} <= d.keys():
            npos = int(meta.get("positions", 0) or 0)
            rot = None if lazy else d["rotation_deg"].astype(np.float64, copy=False)
            if npos >= 1:
                step = 360.0 / npos

                def grid_dev(rot):
                    r = np.mod(rot.astype(np.float64, copy=False), step)
                    return np.minimum(r, step - r)
                out["rotation_grid_dev_deg"] = _elementwise(n, np.float64, grid_dev,
                                                            out["rotation_deg"] if lazy else rot)
            else:
                out["rotation_grid_dev_deg"] = _sparse(n, np.zeros(0), np.zeros(0))
            if lazy:
                first, count = _positions_by_slices(src, n)
            else:
                seg = _segments(d["temp_set_c"].astype(np.float64, copy=False))
                rk = np.round(np.mod(rot, 360.0) / ANGLE_TOL_DEG)
                first = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]]) if n else np.zeros(0, np.int64)
                count = _distinct_per_segment(seg, rk)[seg[first]]
                del seg, rk
            out["positions_error"] = _sparse(n, first, count - npos)
        if test == "sine_centrifuge" and "table_rate_rad_s" in d:
            ratio, resid = _sine_fit(t[:] if lazy else t, d["table_rate_rad_s"].astype(np.float64, copy=False), meta)
            out["rate_amplitude_ratio"] = _first_only(n, ratio)
            out["rate_fit_residual"] = _first_only(n, resid)
    for k, v in out.items():         # a scalar stands for every row (as a column would)
        if not isinstance(v, RowColumn) and np.ndim(v) == 0:
            out[k] = np.full(n, v, dtype=np.float64)
    return out


class _RowsOf:
    """Rows ``lo`` to ``hi`` of every column of a run in its Parquet file, each read when
    asked for (the dwell keys of a slice)."""

    def __init__(self, src, lo: int, hi: int):
        self.src, self.lo, self.hi = src, lo, hi

    def __getitem__(self, c: str) -> np.ndarray:
        return self.src.rows(c, self.lo, self.hi)


#: Rows of a run in its Parquet file whose time steps are looked at together.
_STEP_ROWS = 1 << 22


def _within_dwell_steps(test: str, src, d_time, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The forward time steps between consecutive rows of one dwell, of a run in its
    Parquet file, found a slice of rows at a time, as their distinct values (ascending)
    and how often each occurs: the multiset the whole run's ``dt[same]`` holds
    (:func:`_derive`), in memory of the order of its distinct steps -- a DAQ's clock
    gives a handful -- not of its rows."""
    vals, counts = np.zeros(0), np.zeros(0, np.int64)
    for lo in range(0, n, _STEP_ROWS):
        hi = min(lo + _STEP_ROWS, n)
        a = max(lo - 1, 0)
        same = np.ones(hi - a, bool)
        same[dwell_starts(test, _RowsOf(src, a, hi), hi - a)] = False
        if lo > 0:
            same = same[1:]
        dt = d_time(lo, hi)
        u, c = np.unique(dt[same & np.isfinite(dt) & (dt > 0)], return_counts=True)
        vals, inv = np.unique(np.r_[vals, u], return_inverse=True)
        counts = np.bincount(inv, weights=np.r_[counts, c], minlength=vals.size).astype(np.int64)
    return vals, counts


def _median_of_counts(vals: np.ndarray, counts: np.ndarray) -> float:
    """``np.median`` of the multiset holding each of the ascending ``vals`` ``counts`` times:
    its middle element, or the mean of its two middle ones (the same float np.median
    gives: their sum halved)."""
    total = int(counts.sum())
    cum = np.cumsum(counts)

    def kth(k: int) -> float:
        return vals[int(np.searchsorted(cum, k, side="right"))]
    if total % 2:
        return float(kth(total // 2))
    return float(np.mean([kth(total // 2 - 1), kth(total // 2)]))


def _positions_by_slices(src, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A tilt-rotation run in its Parquet file: the first row of each temperature point
    (segment of equal ``temp_set_c``) and the number of distinct rotation keys in it --
    what :func:`_derive` finds from the whole run's columns, found a slice of rows at a
    time (each with the row before it): the same rows and counts."""
    rows, new_seg, keys = [], [], []
    for lo in range(0, n, _STEP_ROWS):
        hi = min(lo + _STEP_ROWS, n)
        a = max(lo - 1, 0)
        ts = src.rows("temp_set_c", a, hi).astype(np.float64, copy=False)
        rk = np.round(np.mod(src.rows("rotation_deg", a, hi).astype(np.float64, copy=False), 360.0)
                      / ANGLE_TOL_DEG)
        t_ch, k_ch = ts[1:] != ts[:-1], rk[1:] != rk[:-1]
        if lo == 0:
            t_ch, k_ch = np.r_[True, t_ch], np.r_[True, k_ch]
        else:
            rk = rk[1:]
        at = np.flatnonzero(t_ch | k_ch)
        rows.append(at + lo)
        new_seg.append(t_ch[at])
        keys.append(rk[at])
    rows_, new_ = np.concatenate(rows), np.concatenate(new_seg)
    bs = np.cumsum(new_) - 1                  # the segment of each block's first row
    nseg = int(bs[-1]) + 1 if bs.size else 0
    return rows_[new_], _distinct_of_blocks(bs, np.concatenate(keys), nseg)


def _stored(src, c: str) -> RowColumn:
    """Column ``c`` of a run in its Parquet file (tables.ParquetColumns), read a slice of
    rows at a time."""
    return RowColumn(src.n_rows, src.dtype(c), lambda lo, hi: src.rows(c, lo, hi))


def _distinct_per_segment(seg: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Number of distinct non-NaN ``values`` in each segment (``seg``: 0, 1, ... per row,
    from :func:`_segments`): a groupby ``nunique``, found over the blocks of consecutive
    equal (segment, value) rows, so no table of the run's length is made."""
    if seg.size == 0:
        return np.zeros(0, np.int64)
    starts = np.flatnonzero(np.r_[True, (seg[1:] != seg[:-1]) | (values[1:] != values[:-1])])
    return _distinct_of_blocks(seg[starts], values[starts], int(seg[-1]) + 1)


def _distinct_of_blocks(bs: np.ndarray, bv: np.ndarray, nseg: int) -> np.ndarray:
    """:func:`_distinct_per_segment` from the segment ``bs`` and value ``bv`` of the first
    row of each block of consecutive equal (segment, value) rows; ``nseg`` segments."""
    ok = ~np.isnan(bv)
    bs, bv = bs[ok], bv[ok]
    order = np.lexsort((bv, bs))
    bs, bv = bs[order], bv[order]
    new = np.r_[True, (bs[1:] != bs[:-1]) | (bv[1:] != bv[:-1])] if bs.size else np.zeros(0, bool)
    return np.bincount(bs[new], minlength=nseg)


def _rest_dwell_error(d: dict[str, np.ndarray], edges: np.ndarray | None = None) -> float:
    """Worst spacing error (deg) of the leading rest dwells' azimuths; 999 if < 2 of them.
    ``edges``: the first row of each dwell, then the run's length, when already found."""
    # the dwells (runs of equal steps) as slices: the same rows, in order, as a mask each;
    # only the leading ones' rates and azimuths are read (a run in its Parquet file is read
    # a dwell at a time)
    rows = d.rows if hasattr(d, "rows") else (lambda c, lo, hi: d[c][lo:hi])
    if edges is None:
        edges = np.r_[dwell_starts("centrifuge", d, len(d["step"])), len(d["step"])]
    az = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if not np.all(np.abs(rows("table_rate_rad_s", lo, hi).astype(np.float64, copy=False)) < REST_RATE):
            break
        a = rows("table_angle_deg", lo, hi).astype(np.float64, copy=False)
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
           scan: "_Dwells | None" = None) -> tuple[np.ndarray, np.ndarray]:
    """min over turning steps of |omega^2 R / g - 1|, omega the step's mean turning rate
    [rad/s], placed on the first turning row (999 on row 0 when no dwell turns or R or g is
    not positive): (rows, values), the one row and its value, or none (no rows); not a
    column of the run's length.  ``scan``: the run's dwells read one at a time
    (:func:`_centrifuge_dwells`), whose first turning row and means are used when it has
    them."""
    R = float(meta.get("arm_radius_m", np.nan))
    g = float(meta.get("g_local_m_s2", np.nan))
    if scan is not None and (scan.means is not None or scan.first_turning is None):
        first, means = scan.first_turning, scan.means
    else:
        rate = d["table_rate_rad_s"].astype(np.float64, copy=False)
        turning = rate >= REST_RATE
        first = int(np.argmax(turning)) if turning.any() else None
        if first is not None:
            means = Groups(d["step"][turning]).mean(rate[turning])
        del rate, turning
    if first is None or not (R > 0 and g > 0):
        return (np.zeros(1, np.int64), np.array([999.0])) if n else (np.zeros(0, np.int64), np.zeros(0))
    err = np.abs(means ** 2 * R / g - 1.0)
    value = float(np.nanmin(err)) if np.isfinite(err).any() else 999.0
    return np.array([first], np.int64), np.array([value])


class _Dwells:
    """A centrifuge run's dwells read one at a time (:func:`_centrifuge_dwells`):
    ``edges`` (the first row of each dwell, then the run's length), ``first_turning`` (the
    first row turning at REST_RATE or more, None when none does) and ``means`` (the mean
    turning rate of each step, None when the turning steps go down)."""

    def __init__(self, edges, first_turning, means):
        self.edges, self.first_turning, self.means = edges, first_turning, means


def _centrifuge_dwells(src, n: int) -> _Dwells:
    """What the 1 g and rest-dwell checks need of a centrifuge run in its Parquet file,
    read a slice of steps and a dwell of rates at a time: the same edges, first
    turning row and per-step means, bit for bit, as the whole run's columns give (each
    step's turning rates are summed as one ``np.add.reduceat`` segment, as there)."""
    parts, steps = [], []
    for lo in range(0, n, _STEP_ROWS):
        hi = min(lo + _STEP_ROWS, n)
        a = max(lo - 1, 0)
        st = src.rows("step", a, hi)
        at = dwell_starts("centrifuge", {"step": st}, hi - a)
        if lo > 0:
            at = at[1:]
        parts.append(at + a)
        steps.append(st[at])
    edges = np.r_[np.concatenate(parts), n].astype(np.int64) if n else np.zeros(0, np.int64)
    step_at = np.concatenate(steps) if n else np.zeros(0, np.int64)
    first, means, monotone = None, [], True
    group, step_of = [], None

    def flush():
        if group:
            x = group[0] if len(group) == 1 else np.concatenate(group)
            means.append(np.add.reduceat(x, [0])[0] / x.size)
            group.clear()
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        rate = src.rows("table_rate_rad_s", int(lo), int(hi))
        turning = rate >= REST_RATE
        if not turning.any():
            continue
        if first is None:
            first = int(lo) + int(np.argmax(turning))
        s = int(step_at[k])
        if step_of is not None and s < step_of:
            monotone = False
            break
        if s != step_of:
            flush()
        group.append(rate[turning])
        step_of = s
    flush()
    return _Dwells(edges, first, np.asarray(means, np.float64) if monotone and first is not None else None)


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


def _meta_record(test: str, r: RunFile) -> dict:
    """The run's numeric metadata the ``meta`` suite checks for plausible ranges
    (:data:`accelcal.schemas.rules.METADATA_RANGES` and ``ambient_temp_c``).  A value that is
    not a number is None here (the parser refuses it before; a run made by code that skips
    the parser is then checked on the rest)."""
    keys = [k for k in METADATA_RANGES if k in REQUIRED_KEYS[test]] + ["ambient_temp_c"]
    rec = {k: r.meta.get(k) for k in keys}
    for k, v in rec.items():
        if isinstance(v, bool) or not isinstance(v, (float, int)):
            rec[k] = None
    return rec
