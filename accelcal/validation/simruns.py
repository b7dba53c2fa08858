"""Simulated runs as the pipeline's science sees a parsed run file (``meta``, ``data``,
``sha256``): what the Monte Carlo study and the diagnosis benchmark feed the science."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class SimRunFile:
    """A simulated run as process_campaign sees a parsed file: meta, data, sha256."""
    meta: dict
    data: Any
    sha256: str

    @classmethod
    def from_simrun(cls, run) -> "SimRunFile":
        h = hashlib.sha256()
        h.update(json.dumps(run.meta, sort_keys=True, default=str).encode())
        h.update(",".join(map(str, run.data.columns)).encode())
        h.update(np.ascontiguousarray(run.data.to_numpy(dtype=float)).tobytes())
        return cls(meta=run.meta, data=run.data, sha256=h.hexdigest())
