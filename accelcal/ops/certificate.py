"""What a certificate and its machine-readable twin (the DCC) share: the coverage words,
the method texts from the estimator registry, the certificate number, which values are
adopted and how their coverage factor is read (:mod:`accelcal.ops.report` renders the HTML
and PDF, :mod:`accelcal.ops.dcc` the DCC XML)."""
from __future__ import annotations

import math
from typing import Any

from .plots import K_COVERAGE

#: Coverage probability of U = 2u for a normal distribution (EA-4/02 wording).
COVERAGE_PROBABILITY = "≈ 95 %"

#: What each test kind is, in the certificate's words (../shared/docs/methods.md); how each
#: is evaluated is the method's own text (:mod:`accelcal.estimators.registry`).
TEST_TITLES = {
    "tumble": "Multi-position tumble in the gravity field on a dividing head",
    "centrifuge": "Precision centrifuge at stepped constant rates",
    "tilt_rotation": "Tilted rotary table in a thermal chamber",
    "sine_centrifuge": "Disc centrifuge at a sinusoidal rate",
}


def method_text(test: str) -> tuple[str, str]:
    """(what the test is, how its runs are evaluated) for the certificate's method section:
    the texts of the registered estimators that take the test, joined."""
    from ..estimators import registry
    return TEST_TITLES.get(test, test), "; ".join(e.certificate for e in registry.for_test(test))


class ReportError(RuntimeError):
    """The report cannot be made (one-line reason)."""


def _k(c) -> float:
    k = c.get("coverage_factor")
    return float(k) if k is not None and math.isfinite(float(k)) else K_COVERAGE


def _u_unknown(c) -> bool:
    u = c.get("std_uncertainty")
    return u is None or (isinstance(u, float) and math.isnan(u))


def certificate_number(result_id: str, prefix: str) -> str:
    """Unique per result: the lab's prefix and the first 12 hex of the result id (the id
    the CLI prints).  A re-issue of the same result carries the same number."""
    return f"{prefix}-{result_id[:12].upper()}"


def _adopted(d) -> list[dict[str, Any]]:
    return [c for c in d["coefficients"] if c.get("adopted")]
