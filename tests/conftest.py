"""Shared fixtures: where the lab's example drops are, and the truth they were made from."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("ACCELCAL_SHARED", REPO.parent / "shared"))
EXAMPLES = SHARED / "examples"

#: Truth behind ../shared/examples/drop-2026-11-20 (quoted in issues 2 and 4).
TRUTH_20 = {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8, "Koq": 3.0e-8,
            "K3": 2.0e-10, "R+": 0.714775, "R-": 0.705794}


@pytest.fixture(scope="session")
def examples() -> Path:
    if not EXAMPLES.is_dir():
        pytest.skip(f"example drops not found at {EXAMPLES}")
    return EXAMPLES
