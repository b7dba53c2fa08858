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
from ..provenance import SIMULATED_KEY
from .engine import COLUMNS, DIGITS, INT_COLUMNS, SimRun

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
    for i in range(len(data)):
        lines.append(",".join(_cell(c, a[i]) for c, a in zip(cols, arrays)))
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
    paths = []
    for r in runs:
        sub = getattr(r, "subdir", "") or ""
        paths.append(write_run_file(r.meta, r.data, out / sub / f"{r.meta['run_id']}.csv"))
    return paths
