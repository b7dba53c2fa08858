"""Runs -> cells: replicate groups (dwells) with their mean, the variance of the mean
from a noise model fitted to the replicate scatter, and the dimensions the gap is
localised along.

A *cell* is a group of rows that repeat the same nominal input: a centrifuge dwell
(``step``), a tumble position, a tilt-rotation (set-point, angle) dwell, or, for the
sine centrifuge (which has no dwells), a drive-phase bin within one half of the run
(its periods are replicates of each other).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from ..physics.axes import parse_plane


@dataclass
class RunCells:
    meta: dict
    test: str
    run_id: str
    campaign: str
    cols: dict                     # raw columns (numpy) for rig_output
    cid: np.ndarray                # row -> cell index
    n: np.ndarray                  # rows per cell
    y: np.ndarray                  # cell mean output (output_unit)
    var: np.ndarray                # variance of the cell mean (noise model)
    s2: np.ndarray                 # raw sample variance of the rows of a cell (nan if n < 2)
    attrs: dict = field(default_factory=dict)   # dimension -> array of labels/values per cell
    noise_note: str = ""

    @property
    def ncell(self) -> int:
        return int(self.n.size)

    def cell_mean(self, rows: np.ndarray) -> np.ndarray:
        return np.bincount(self.cid, weights=rows, minlength=self.ncell) / self.n


# ---------------------------------------------------------------- reading
def _local_read(path: Path):
    import pandas as pd
    meta = {}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            if line.startswith("#"):
                k, v = line[1:].split(":", 1)
                meta[k.strip()] = v.strip()
    for k in list(meta):
        try:
            if k not in ("run_id", "campaign", "unit_serial", "started_at", "rig_id"):
                meta[k] = float(meta[k])
        except ValueError:
            pass
    data = pd.read_csv(path, comment="#")
    return meta, data


def read_paths(paths) -> list[tuple[dict, object, str]]:
    """Run files or folders -> [(meta, data, path)]; unreadable/refused files are skipped
    with a message on stderr (they are not ours to diagnose)."""
    import sys
    files: list[Path] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            files += sorted(q for q in p.rglob("*.csv") if q.is_file())
        else:
            files.append(p)
    out = []
    try:
        from ..schemas.dropformat import read_run
    except Exception:                                   # pragma: no cover - parser absent
        read_run = None
    for f in files:
        try:
            if read_run is not None:
                rf = read_run(f)
                out.append((dict(rf.meta), rf.data, str(f)))
            else:
                m, d = _local_read(f)
                out.append((m, d, str(f)))
        except Exception as e:   # a refused file: say so, diagnose the rest
            print(f"diagnose: skipping {f}: {e}", file=sys.stderr)
    return out


# ---------------------------------------------------------------- cells
def _blocks(keys: list[np.ndarray]) -> np.ndarray:
    """Consecutive rows with equal keys form one block; returns block index per row."""
    n = len(keys[0])
    change = np.zeros(n, bool)
    for k in keys:
        k = np.asarray(k, float)
        kk = np.where(np.isfinite(k), k, -1e300)
        change[1:] |= kk[1:] != kk[:-1]
    return np.cumsum(change)


def _fit_noise(s2, n, x, ybar):
    """sigma^2 (per row) = a + b x^2 + c ybar^2, all >= 0, by the Gamma likelihood of the
    replicate sample variances ((n-1) s^2 / sigma^2 ~ chi^2_{n-1})."""
    ok = (n >= 2) & np.isfinite(s2)
    if ok.sum() < 2:
        v = np.nanmean(s2[ok]) if ok.any() else 1.0
        return (lambda xx, yy: np.full(np.shape(xx), v)), "pooled"
    S, N, X, Y = s2[ok], n[ok], x[ok], ybar[ok]
    nu = N - 1.0
    base = max(np.min(S[S > 0]) if (S > 0).any() else 1e-30, 1e-300)
    sx = max(np.max(np.abs(X)), 1e-30)
    sy = max(np.max(np.abs(Y)), 1e-30)

    def model(q, xx, yy):
        a, b, c = np.exp(np.clip(q, -60, 60))
        return base * (a + b * (xx / sx) ** 2 + c * (yy / sy) ** 2)

    def nll(q):
        v = model(q, X, Y)
        return float(np.sum(nu * (S / v + np.log(v))))

    best = None
    for q0 in ([0, 0, -20], [0, -20, 0], [np.log(np.median(S) / base), -20, -20]):
        r = minimize(nll, np.array(q0, float), method="Nelder-Mead",
                     options={"xatol": 1e-3, "fatol": 1e-4, "maxiter": 600})
        if best is None or r.fun < best.fun:
            best = r
    q = best.x
    return (lambda xx, yy: model(q, np.asarray(xx, float), np.asarray(yy, float))), "a+b*x^2+c*y^2"


def make_cells(meta: dict, data, path: str = "") -> RunCells:
    test = str(meta["test"])
    cols = {c: np.asarray(data[c], float) for c in data.columns if c != "line"}
    nrow = len(cols["output"])
    t = cols.get("time_s", np.arange(nrow, dtype=float))
    attrs: dict[str, np.ndarray] = {}
    if test == "centrifuge":
        cid = _blocks([cols["step"]])
    elif test == "tumble":
        cid = _blocks([cols["position"], cols["angle_deg"]])
    elif test == "tilt_rotation":
        cid = _blocks([cols["temp_set_c"], cols["rotation_deg"]])
    elif test == "sine_centrifuge":
        f = float(meta["rate_frequency_hz"])
        dt = float(np.median(np.diff(t))) if nrow > 1 else 1.0
        nb = max(int(round(1.0 / (f * dt))), 1)
        ph = np.floor(((t * f) % 1.0) * nb + 0.5).astype(int) % nb
        half = (t > 0.5 * (t.min() + t.max())).astype(int)
        raw = half * nb + ph
        _, cid = np.unique(raw, return_inverse=True)
    else:
        raise ValueError(f"unknown test {test!r}")
    _, cid = np.unique(cid, return_inverse=True)
    k = int(cid.max()) + 1
    n = np.bincount(cid, minlength=k).astype(float)
    y_rows = cols["output"]
    y = np.bincount(cid, weights=y_rows, minlength=k) / n
    dev = y_rows - y[cid]
    s2 = np.where(n >= 2, np.bincount(cid, weights=dev ** 2, minlength=k) / np.maximum(n - 1, 1), np.nan)

    def cm(v):
        return np.bincount(cid, weights=np.nan_to_num(v), minlength=k) / n

    tm = cm(t)
    attrs["time"] = tm
    attrs["time_frac"] = (tm - tm.min()) / max(tm.max() - tm.min(), 1e-12)
    if "temp_c" in cols:
        attrs["temperature"] = cm(cols["temp_c"])
    g = float(meta["g_local_m_s2"])
    x = np.zeros(k)
    if test in ("centrifuge", "sine_centrifuge"):
        R = float(meta["arm_radius_m"])
        w2 = cm(cols["table_rate_rad_s"] ** 2)
        x = w2 * R
        attrs["g_level"] = x / g
        phi = float(meta["mount_angle_deg"]) % 360.0
        c = np.cos(np.radians(phi))
        pol = "+" if c > 1e-6 else ("-" if c < -1e-6 else "0")
        attrs["polarity"] = np.array([pol] * k, object)
        attrs["mount"] = np.array([f"{meta['mount_plane']}@{phi:g}"] * k, object)
        if test == "centrifuge":
            rate = cm(cols["table_rate_rad_s"])
            imax = int(np.argmax(rate))
            sweep = np.where(rate <= 0, "rest", np.where(np.arange(k) <= imax, "up", "down"))
            attrs["sweep"] = sweep.astype(object)
        else:
            attrs["position"] = cm(((t * float(meta["rate_frequency_hz"])) % 1.0) * 360.0)
    elif test == "tumble":
        attrs["position"] = cm(cols["angle_deg"]) % 360.0
        attrs["mount"] = np.array([f"head {meta['head_axis']} cos {meta['cos_axis']}"] * k, object)
    elif test == "tilt_rotation":
        attrs["position"] = cm(cols["rotation_deg"]) % 360.0
        attrs["temperature"] = cm(cols["temp_set_c"])
    sigma2_fn, note = _fit_noise(s2, n, x, y - np.median(y))
    var = sigma2_fn(x, y - np.median(y)) / n
    var = np.maximum(var, 1e-300)
    return RunCells(meta=dict(meta), test=test, run_id=str(meta.get("run_id", Path(path).stem)),
                    campaign=str(meta.get("campaign", "")), cols=cols, cid=cid, n=n, y=y, var=var,
                    s2=s2, attrs=attrs, noise_note=note)


def mount_cos(meta: dict) -> float:
    if "mount_angle_deg" not in meta:
        return np.nan
    return float(np.cos(np.radians(float(meta["mount_angle_deg"]))))


def first_plane_axis(meta: dict) -> int:
    return parse_plane(meta["mount_plane"])[0]
