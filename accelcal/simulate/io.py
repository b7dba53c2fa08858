"""Writing runs in the drop format (drop-format.md, ``accelcal-drop/1``): the metadata
block (``# key: value``), one CSV header line, the rows; ``\\n`` line ends; UTF-8.
Files are written atomically (a temporary file in the same folder, then renamed)."""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from ..fileio import atomic_write
from ..provenance import SIM_PREFIX, SIMULATED_KEY
from .engine import COLUMNS, DIGITS, INT_COLUMNS, SimRun, simulate_campaign
from .scenario import load_scenario

#: metadata keys in the order they are written (then any others, in the dict's order)
META_ORDER = ["format", SIMULATED_KEY, "run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id",
              "started_at", "site_latitude_deg", "g_local_m_s2", "output_unit", "sample_period_s"]


def _meta_value(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            raise ValueError(f"metadata value {v!r} is not finite")
        return repr(float(v))
    s = str(v)
    if "\n" in s or "\r" in s:
        raise ValueError(f"metadata value {s!r} spans lines")
    return s


def _cell(col: str, x) -> str:
    if col in INT_COLUMNS:
        return str(int(x))
    x = float(x)
    if not math.isfinite(x):
        return ""
    s = format(x, f".{DIGITS.get(col, 12)}g")
    return "0" if s == "-0" else s


def format_run(meta: Mapping, data: pd.DataFrame) -> str:
    """The text of a run file."""
    test = str(meta["test"])
    cols = COLUMNS.get(test)
    if cols is None:
        raise ValueError(f"unknown test {test!r}")
    missing = [c for c in cols if c not in data.columns]
    if missing:
        raise ValueError(f"data lacks columns {missing} for a {test} run")
    meta = {**meta, SIMULATED_KEY: True}        # whatever the caller passed: simulated
    keys = [k for k in META_ORDER if k in meta] + [k for k in meta if k not in META_ORDER]
    lines = []
    for k in keys:
        if ":" in k or not k.strip():
            raise ValueError(f"bad metadata key {k!r}")
        lines.append(f"# {k}: {_meta_value(meta[k])}")
    lines.append(",".join(cols))
    arrays = [data[c].to_numpy() for c in cols]
    lines += [",".join(_cell(c, a[i]) for c, a in zip(cols, arrays)) for i in range(len(data))]
    return "\n".join(lines) + "\n"


def write_run_file(meta: Mapping, data: pd.DataFrame, path) -> Path:
    """Write one run file, exactly in the drop format, atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = format_run(meta, data)
    atomic_write(path, lambda fh: fh.write(text), "w", encoding="utf-8", newline="\n")
    return path


def write_drop(runs: Iterable[SimRun], out_dir) -> list[Path]:
    """Write every run as ``out_dir/[subdir/]run_id.csv``; returns the paths in run order."""
    out = Path(out_dir)
    return [write_run_file(r.meta, r.data, out / (getattr(r, "subdir", "") or "") / f"{r.meta['run_id']}.csv")
            for r in runs]


def sim_ids(runs, prefix: str = SIM_PREFIX):
    """Mark run_id and campaign as simulated (``SIM-...``), so a simulated campaign never
    shares a real campaign's label or run ids.  The unit serial stays: it names the unit
    whose truth was simulated (a simulated result is never current for a unit with a real
    calibration, accelcal.warehouse).

    Parameters
    ----------
    runs : list of SimRun
        Simulated runs; their ``meta`` is changed in place.
    prefix : str
        The mark (:data:`accelcal.provenance.SIM_PREFIX`).

    Returns
    -------
    list of SimRun
        ``runs``, each id prefixed once.
    """
    for r in runs:
        for key in ("run_id", "campaign"):
            v = str(r.meta[key])
            if not v.startswith(prefix):
                r.meta[key] = prefix + v
    return runs


def simulate_to_drop(scenario_path, out_dir, seed: int | None = None,
                     keep_ids: bool = False) -> list[Path]:
    """Load a scenario, simulate it and write the drop.  Every file carries
    ``# simulated: true``; run ids and the campaign get the ``SIM-`` prefix unless
    ``keep_ids`` (the scenario's own ids, e.g. to compare with a sample drop).

    Parameters
    ----------
    scenario_path : str or Path
        Scenario TOML, or the name of a shipped scenario (:func:`load_scenario`).
    out_dir : str or Path
        Drop folder to write into.
    seed : int, optional
        Random seed (default: the scenario's).
    keep_ids : bool
        Keep the scenario's run ids and campaign label.

    Returns
    -------
    list of Path
        The written run files, in run order.
    """
    runs = simulate_campaign(load_scenario(scenario_path), seed=seed)
    return write_drop(runs if keep_ids else sim_ids(runs), out_dir)
