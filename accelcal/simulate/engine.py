"""Scenario -> in-memory runs.  All kinematics and the instrument model come from
:mod:`accelcal.physics` (``rig_output``); this module only lays out the test plan
(times, steps, angles, rates, temperatures) and adds the noise.

Noise model (per run, from the run's own random stream):
- rate jitter: the true rate of a reading is ``logged * sqrt(1 + delta)``, delta ~ N(0, rate_jitter_rel),
  i.e. true omega^2 = logged omega^2 (1 + delta) (centrifuge: per reading; sine: per sample);
- logged-rate noise: logged rate = level rate (centrifuge) or drive (sine) times (1 + nu),
  nu ~ N(0, rate_log_rel), plus N(0, rate_log_abs) rad/s; the true rate does not see it;
- temperature: temp_c = plan temperature + N(0, temp_noise_c); the output is computed from the
  temp_c that is written (the instrument's own sensor), as the physics does;
- bias random walk: K1(T) * b(t), b a Wiener process with b(t0) = 0, sigma bias_walk_m_s2_rt_s;
- white noise: K1(T) * N(0, white_m_s2) per row; with white_ar1_rho, AR(1) between
  consecutive rows of one run (lag-1 correlation rho, the same marginal sd: a DAQ's
  anti-alias filter or a slowly wandering environment);
- centripetal noise: K1(T) * N(0, centripetal_rel * omega_z^2 R) per row of a centrifuge or
  sine run, in every mount (what the lab's centrifuge data show: std/a_c ~ 2e-6 at 0, 45 and
  90 deg alike);
- logged-angle noise: the logged angle (tumble ``angle_deg``, tilt ``rotation_deg``, the
  centrifuges' ``table_angle_deg``) = true angle + N(0, angle_log_deg); the physics sees the
  true angle;
- rare spikes: with probability spike_rate per row the output gains
  K1(T) * s * spike_m_s2 * (1 + |N(0, 1)|), s = +-1;
- output counts: the output is rounded to a multiple of output_quantum (output_unit), last.

The optional noise keys draw random numbers only when they are above 0, so a scenario
without them gives the same bytes as one that sets them to 0.

Disturbances (``[disturbance]``): effects outside the catalogue (effects.md), for testing that
the diagnosis says a gap is unexplained: a sweep hysteresis (a centrifuge's rising steps read
K1(T) * sweep_hysteresis_rel * a_IA higher, its falling steps as much lower), a bias quadratic
in temperature
K1(T) * bias_temp_quadratic_m_s2_c2 * (T - T_ref)^2 and a periodic bias
K1(T) * bias_periodic_m_s2 * sin(2 pi t / bias_periodic_period_s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from ..constants import OMEGA_EARTH, T_REF_C
from ..effects import EFFECTS
from ..physics import rig_output, scale_factor
from ..physics.rigs import (centripetal_level, instrument_coefficients, sine_drive, sine_drive_angle,
                            specific_force)
from .scenario import DISTURBANCE_DEFAULTS, Scenario, load_scenario

COLUMNS = {
    "tumble": ["time_s", "position", "angle_deg", "output", "temp_c"],
    "centrifuge": ["time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"],
    "tilt_rotation": ["time_s", "temp_set_c", "temp_c", "rotation_deg", "output"],
    "sine_centrifuge": ["time_s", "table_rate_rad_s", "table_angle_deg", "output"],
}
INT_COLUMNS = {"step", "position"}
#: significant digits written (and kept in memory, so file and DataFrame agree)
DIGITS = {"time_s": 12, "table_rate_rad_s": 10, "table_angle_deg": 10, "angle_deg": 10,
          "rotation_deg": 10, "temp_set_c": 10, "temp_c": 9, "output": 11}


@dataclass
class SimRun:
    """One simulated run: ``meta`` typed like the parser's (floats for numbers, ``positions``
    int, the rest str), ``data`` the drop-format columns, ``truth`` what made it."""
    meta: dict
    data: pd.DataFrame
    truth: dict
    subdir: str = ""


def quantize(values, digits: int) -> np.ndarray:
    """Round to ``digits`` significant digits exactly as the file writer prints them."""
    v = np.asarray(values, float)
    return np.array([float(format(x, f".{digits}g")) if np.isfinite(x) else np.nan for x in v])


def acting_effects(kind: str, *layers) -> dict[str, float]:
    """The effects of the layers (later ones override) that act in a ``kind`` test (effects.md)."""
    out: dict[str, float] = {}
    for layer in layers:
        out.update(layer or {})
    return {k: v for k, v in out.items() if kind in EFFECTS[k].tests}


def _base_meta(sc: Scenario, t: dict, run_id: str, started_at: str, sample_period: float) -> dict:
    u = sc.unit
    return {"format": "accelcal-drop/1", "run_id": run_id, "test": t["kind"],
            "unit_serial": str(u["serial"]), "unit_model": str(u["model"]),
            "campaign": str(u["campaign"]), "rig_id": str(t["rig_id"]), "started_at": started_at,
            "site_latitude_deg": float(sc.site["latitude_deg"]),
            "g_local_m_s2": float(sc.site["g_local_m_s2"]),
            "output_unit": str(u["output_unit"]), "sample_period_s": float(sample_period)}


def _optional_meta(meta: dict, *sources) -> dict:
    for key in ("operator", "notes", "daq_id", "ambient_temp_c"):
        for s in sources:
            if s and s.get(key) not in (None, ""):
                meta[key] = float(s[key]) if key == "ambient_temp_c" else str(s[key])
                break
    return meta


def _started_at(t: dict, k: int) -> str:
    start = t.get("started_at", "2026-01-01T08:00:00+00:00")
    dt = start if isinstance(start, datetime) else datetime.fromisoformat(str(start))
    return (dt + timedelta(seconds=float(t.get("run_interval_s", 3600.0)) * k)).isoformat()


def _output(kind, meta, cols, angle, coeffs, effects, noise, rng, true_rate=None, radius=None, down=None):
    """Write the logged angle and the output into ``cols``; returns the noise-free output.

    The physics sees the columns as they will be written, the true angle, and ``true_rate``
    (centrifuges) in place of the logged rate.  The output is the noise-free
    :func:`~accelcal.physics.rigs.rig_output`, then bias walk, white noise and (centrifuges:
    the centripetal level omega_z^2 R of each reading from ``true_rate`` and ``radius`` [m])
    noise proportional to it, the disturbances, spikes and counts [output_unit]; ``down``: the
    readings of a centrifuge's falling steps (the sweep hysteresis).
    """
    phys = _frame_phys(cols if true_rate is None else {**cols, "table_rate_rad_s": true_rate})
    cols[angle] = _logged_angle(cols[angle], noise, rng)
    level = None if true_rate is None else centripetal_level(meta, true_rate, radius)
    E0 = rig_output(kind, meta, phys, coeffs, effects)
    n = len(E0)
    temp = np.asarray(phys["temp_c"], float) if "temp_c" in phys else None
    K1 = scale_factor(instrument_coefficients(coeffs, effects), temp)
    t = np.asarray(phys["time_s"], float)
    E = E0.copy()
    walk = noise["bias_walk_m_s2_rt_s"]
    if walk > 0 and n > 1:
        steps = rng.standard_normal(n - 1) * walk * np.sqrt(np.maximum(np.diff(t), 0.0))
        E = E + K1 * np.concatenate([[0.0], np.cumsum(steps)])
    if noise["white_m_s2"] > 0:
        w = rng.standard_normal(n)
        rho = noise.get("white_ar1_rho", 0.0)
        if rho:                         # AR(1) between consecutive rows, the same marginal sd
            w[1:] *= math.sqrt(1.0 - rho * rho)
            w = lfilter([1.0], [1.0, -rho], w)
        E = E + K1 * noise["white_m_s2"] * w
    if level is not None and noise.get("centripetal_rel", 0.0) > 0:
        E = E + K1 * noise["centripetal_rel"] * np.abs(level) * rng.standard_normal(n)
    hyst = noise.get("sweep_hysteresis_rel", 0.0)
    if hyst and down is not None:       # rising steps read h a_IA higher, falling ones lower
        a_ia = specific_force(kind, meta, phys, effects)[:, 0]
        E = E + K1 * hyst * a_ia * np.where(down, -1.0, 1.0)
    quad = noise.get("bias_temp_quadratic_m_s2_c2", 0.0)
    if quad and temp is not None:
        E = E + K1 * quad * (temp - T_REF_C) ** 2
    amp, period = noise.get("bias_periodic_m_s2", 0.0), noise.get("bias_periodic_period_s", 0.0)
    if amp and period > 0:
        E = E + K1 * amp * np.sin(2 * np.pi * t / period)
    if noise.get("spike_rate", 0.0) > 0 and noise.get("spike_m_s2", 0.0) > 0:
        hit = rng.random(n) < noise["spike_rate"]
        sign = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        size = noise["spike_m_s2"] * (1.0 + np.abs(rng.standard_normal(n)))
        E = E + K1 * np.where(hit, sign * size, 0.0)
    q = noise.get("output_quantum", 0.0)
    if q > 0:
        E = np.round(E / q) * q
    cols["output"] = E
    return E0


def _logged_angle(angle: np.ndarray, noise: dict, rng: np.random.Generator) -> np.ndarray:
    """The angle as logged: the true angle plus its reading noise (only drawn when
    ``angle_log_deg`` > 0; NaN stays NaN)."""
    sd = noise.get("angle_log_deg", 0.0)
    if sd <= 0:
        return angle
    return np.asarray(angle, float) + sd * rng.standard_normal(np.shape(angle))


def _frame(kind: str, cols: dict) -> pd.DataFrame:
    df = pd.DataFrame({c: cols[c] for c in COLUMNS[kind]})
    for c in df.columns:
        if c in INT_COLUMNS:
            df[c] = df[c].astype("int64")
        else:
            df[c] = quantize(df[c].to_numpy(float), DIGITS[c])
    return df


def _rng(seed: int | None, index: int) -> np.random.Generator:
    """Run ``index``'s generator: its own stream of the campaign's seed (fresh entropy without one)."""
    return np.random.default_rng() if seed is None else np.random.default_rng([int(seed) & 0xFFFFFFFF, index])


# ---------------------------------------------------------------- per test kind
def _tumble_run(sc, t, head, meta, effects, noise, rng):
    n_pos = int(t.get("positions", 24))
    n_read = int(t.get("readings", 10))
    dt = meta["sample_period_s"]
    period = float(t.get("dwell_period_s", 40.0))
    pos = np.repeat(np.arange(n_pos), n_read)
    j = np.tile(np.arange(n_read), n_pos)
    time = pos * period + j * dt
    angle = 360.0 * pos / n_pos
    temp = _case_temperature(t, time) + noise["temp_noise_c"] * rng.standard_normal(time.size)
    meta.update({"head_axis": head["head_axis"], "cos_axis": head["cos_axis"], "sin_axis": head["sin_axis"]})
    cols = {"time_s": time, "position": pos, "angle_deg": angle, "temp_c": temp}
    E0 = _output("tumble", meta, cols, "angle_deg", sc.coefficients, effects, noise, rng)
    return cols, {"noise_free_output": E0}


def _case_temperature(t: dict, time: np.ndarray) -> np.ndarray:
    """Case temperature of a tumble or centrifuge run: ``temp_c``; with ``temp_tau_s`` an
    exponential approach to it from ``temp_start_c`` (a unit warming up on the rig); with
    ``temp_cycle_c`` a sinusoidal swing of that amplitude and ``temp_cycle_period_s`` (the
    room's air conditioning)."""
    time = np.asarray(time, float)
    T = np.full(time.shape, float(t.get("temp_c", 23.0)))
    t0 = float(np.min(time)) if time.size else 0.0
    tau = float(t.get("temp_tau_s", 0.0))
    if tau > 0:
        T = T + (float(t.get("temp_start_c", T[0] if T.size else 0.0)) - T) * np.exp(-(time - t0) / tau)
    amp, period = float(t.get("temp_cycle_c", 0.0)), float(t.get("temp_cycle_period_s", 0.0))
    if amp and period > 0:
        T = T + amp * np.sin(2 * np.pi * (time - t0) / period)
    return T


def _frame_phys(cols: dict) -> pd.DataFrame:
    """The columns the physics reads, quantized as they will be written (so the file is
    self-consistent: the logged time, angles and temperatures are the ones that were used)."""
    return pd.DataFrame({k: (quantize(v, DIGITS[k]) if k in DIGITS and k not in INT_COLUMNS else v)
                         for k, v in cols.items()})


def level_rates(levels, g: float, radius: float, latitude_deg: float, sense: str,
                earth: bool = True) -> np.ndarray:
    """Logged table rate of each g level: omega with omega_z^2 R = L g (earth rate included
    when ``earth``), i.e. sqrt(L g / R) - s Omega_e sin(lat)."""
    w = np.sqrt(np.asarray(levels, float) * g / radius)
    if earth:
        s = 1 if sense == "ccw" else -1
        w = w - s * OMEGA_EARTH * np.sin(np.radians(latitude_deg))
    return w


def _centrifuge_run(sc, t, mount, meta, effects, noise, rng):
    g = float(sc.site["g_local_m_s2"])
    R = float(t["arm_radius_m"])
    sense = str(t.get("rotation_sense", "ccw"))
    az = [float(a) for a in t.get("rest_azimuths_deg", [0, 90, 180, 270])]
    levels = [float(x) for x in t.get("g_levels", [1, 2, 3, 5, 7, 10, 14, 18, 21, 25])]
    sweep = str(t.get("sweep", "up_down"))
    if sweep not in ("up", "up_down"):
        raise ValueError(f"sweep {sweep!r} is not 'up' or 'up_down'")
    seq = levels + (levels[-2::-1] if sweep == "up_down" else [])
    rates = level_rates(seq, g, float(t.get("level_radius_m", R)), sc.site["latitude_deg"], sense,
                        bool(t.get("level_earth_rate", True)))
    n_read = int(t.get("readings", 8))
    dt = meta["sample_period_s"]
    p_rest = float(t.get("rest_dwell_period_s", 36.0))
    p_rate = float(t.get("rate_dwell_period_s", 76.0))
    dwell_rate = [0.0] * len(az) + list(rates)
    dwell_angle = az + [np.nan] * len(rates)
    starts = np.cumsum([0.0] + [p_rest] * len(az) + [p_rate] * (len(rates) - 1))
    step = np.repeat(np.arange(len(dwell_rate)), n_read)
    j = np.tile(np.arange(n_read), len(dwell_rate))
    time = np.asarray(starts)[step] + j * dt
    nominal = np.asarray(dwell_rate)[step]
    moving = nominal > 0
    logged = nominal * (1.0 + noise["rate_log_rel"] * rng.standard_normal(time.size))
    logged = np.where(moving, np.abs(logged + noise["rate_log_abs"] * rng.standard_normal(time.size)), 0.0)
    logged = quantize(logged, DIGITS["table_rate_rad_s"])
    delta = noise["rate_jitter_rel"] * rng.standard_normal(time.size)
    true_rate = np.where(moving, logged * np.sqrt(1.0 + delta), 0.0)
    angle = np.asarray(dwell_angle)[step]
    temp = _case_temperature(t, time) + noise["temp_noise_c"] * rng.standard_normal(time.size)
    meta.update({"arm_radius_m": R, "rotation_sense": sense, "mount_plane": str(mount["plane"]),
                 "mount_angle_deg": float(mount.get("angle_deg", 0.0)),
                 "vertical_axis": str(mount["vertical"]),
                 "reading_window_s": float(t.get("reading_window_s", dt))})
    cols = {"time_s": time, "step": step, "table_rate_rad_s": logged, "table_angle_deg": angle,
            "temp_c": temp}
    E0 = _output("centrifuge", meta, cols, "table_angle_deg", sc.coefficients, effects, noise, rng,
                 true_rate, R, down=step >= len(az) + len(levels))
    return cols, {"noise_free_output": E0, "true_rate_rad_s": true_rate, "g_levels": seq}


def _tilt_run(sc, t, _item, meta, effects, noise, rng):
    n_pos = int(t.get("positions", 12))
    sets = [float(x) for x in t.get("temp_set_c", [20, 25, 30, 35, 40])]
    sweeps = int(t.get("sweeps", 1))
    n_read = int(t.get("readings", 20))
    dt = meta["sample_period_s"]
    period = float(t.get("dwell_period_s", 50.0))
    soak = float(t.get("soak_s", 3600.0))
    off = float(t.get("temp_offset_c", 0.0))
    tau = float(t.get("temp_tau_s", 600.0))
    T_prev = float(t.get("start_temp_c", sets[0])) + off
    time, tset, tplan, rot = [], [], [], []
    t_cmd = 0.0
    for _ in range(sweeps):
        for sp in sets:
            target = sp + off
            for k in range(n_pos):
                tt = t_cmd + soak + k * period + np.arange(n_read) * dt
                time.append(tt)
                tset.append(np.full(n_read, sp))
                tplan.append(target + (T_prev - target) * np.exp(-(tt - t_cmd) / tau) if tau > 0
                             else np.full(n_read, target))
                rot.append(np.full(n_read, 360.0 * k / n_pos))
            T_prev = float(tplan[-1][-1])
            t_cmd = t_cmd + soak + n_pos * period
    time = np.concatenate(time)
    temp = np.concatenate(tplan) + noise["temp_noise_c"] * rng.standard_normal(time.size)
    meta.update({"tilt_deg": float(t["tilt_deg"]), "sin_axis": str(t.get("sin_axis", "+IA")),
                 "cos_axis": str(t.get("cos_axis", "+PA")), "normal_axis": str(t.get("normal_axis", "+OA")),
                 "positions": n_pos})
    cols = {"time_s": time, "temp_set_c": np.concatenate(tset), "temp_c": temp,
            "rotation_deg": np.concatenate(rot)}
    E0 = _output("tilt_rotation", meta, cols, "rotation_deg", sc.coefficients, effects, noise, rng)
    return cols, {"noise_free_output": E0}


def _sine_run(sc, t, att, meta, effects, noise, rng):
    Om = float(t["rate_amplitude_rad_s"])
    f = float(t["rate_frequency_hz"])
    fs = float(t.get("sample_rate_hz", 50.0))
    n = int(t.get("samples", 1000))
    time = quantize(np.arange(n) / fs, DIGITS["time_s"])
    drive = sine_drive(t, time)
    angle = sine_drive_angle(t, time)
    logged = (drive * (1.0 + noise["rate_log_rel"] * rng.standard_normal(n))
              + noise["rate_log_abs"] * rng.standard_normal(n))
    delta = noise["rate_jitter_rel"] * rng.standard_normal(n)
    true_rate = drive * np.sqrt(1.0 + delta)
    meta.update({"arm_radius_m": float(t["arm_radius_m"]),
                 "rotation_sense": str(t.get("rotation_sense", "ccw")),
                 "mount_plane": str(att["plane"]), "mount_angle_deg": float(att.get("angle_deg", 0.0)),
                 "vertical_axis": str(att["vertical"]), "rate_amplitude_rad_s": Om, "rate_frequency_hz": f})
    cols = {"time_s": time, "table_rate_rad_s": logged, "table_angle_deg": angle}
    E0 = _output("sine_centrifuge", meta, cols, "table_angle_deg", sc.coefficients, effects, noise, rng,
                 true_rate, float(t["arm_radius_m"]))
    return cols, {"noise_free_output": E0, "true_rate_rad_s": true_rate}


# ---------------------------------------------------------------- campaign
_RUN = {"tumble": _tumble_run, "centrifuge": _centrifuge_run, "tilt_rotation": _tilt_run,
        "sine_centrifuge": _sine_run}
#: default sample period of a tumble, centrifuge or tilt run [s]
SAMPLE_PERIOD_S = {"tumble": 1.0, "centrifuge": 2.0, "tilt_rotation": 1.0}


def _plan(sc: Scenario):
    """Yield (test, item, k) for every run: item is the head/mount/attitude, k its index in the test."""
    for t in sc.tests:
        kind = t["kind"]
        if kind == "tumble":
            items = t["heads"]
        elif kind == "centrifuge":
            items = [m for m in t["mounts"] for _ in range(int(t.get("replicates", 1)))]
        elif kind == "sine_centrifuge":
            items = t["attitudes"]
        else:
            items = [None] * int(t.get("runs", 1))
        for k, item in enumerate(items):
            yield t, item, k


def simulate_campaign(scenario, seed: int | None = None) -> list[SimRun]:
    """Simulate every run of a scenario in memory.  ``seed`` overrides the scenario's seed;
    with neither, the noise is fresh.  The same seed gives the same runs (and bytes)."""
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    seed = sc.seed if seed is None else int(seed)
    counters: dict[str, int] = {}
    runs: list[SimRun] = []
    for index, (t, item, k) in enumerate(_plan(sc)):
        kind = t["kind"]
        prefix = str(t.get("run_id_prefix", f"{t['rig_id'].replace('-', '')}-SIM"))
        if k == 0 and "first_number" in t:
            counters[prefix] = int(t["first_number"])
        num = counters.get(prefix, 1)
        counters[prefix] = num + 1
        run_id = f"{prefix}-{num:04d}"
        item_effects = item.get("effects", {}) if isinstance(item, dict) else {}
        effects = acting_effects(kind, sc.effects, t["effects"], item_effects)
        noise = {**sc.noise, **t["noise"], **sc.disturbance, **t["disturbance"]}
        rng = _rng(seed, index)
        period = (1.0 / float(t.get("sample_rate_hz", 50.0)) if kind == "sine_centrifuge"
                  else float(t.get("sample_period_s", SAMPLE_PERIOD_S[kind])))
        meta = _base_meta(sc, t, run_id, _started_at(t, k), period)
        cols, extra = _RUN[kind](sc, t, item, meta, effects, noise, rng)
        _optional_meta(meta, item if isinstance(item, dict) else None, t)
        dist = {k: noise.pop(k) for k in list(noise) if k in DISTURBANCE_DEFAULTS}
        truth: dict[str, Any] = {"scenario": sc.name, "coefficients": dict(sc.coefficients),
                                 "effects": effects, "noise": noise, "seed": seed, "run_index": index}
        if any(dist.values()):
            truth["disturbance"] = dist
        if kind == "centrifuge":
            truth["mount"] = {k2: v for k2, v in item.items() if k2 != "effects"}
        truth.update(extra)
        runs.append(SimRun(meta=meta, data=_frame(kind, cols), truth=truth,
                           subdir=str(t.get("subdir", ""))))
    return runs
