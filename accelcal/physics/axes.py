"""Instrument axes and signed-axis notation (drop-format.md, "Axes and angles").

IA, PA, OA form a right-handed set (IA x PA = OA). Vectors of specific force
are stored as arrays [..., 3] with columns in the order IA, PA, OA.
"""
from __future__ import annotations

import re

AXES = ("IA", "PA", "OA")
AXIS_INDEX = {a: i for i, a in enumerate(AXES)}
_SIGNED = re.compile(r"^\s*([+-]?)\s*(IA|PA|OA)\s*$")


class AxisError(ValueError):
    """An axis or plane name that is not IA/PA/OA, or a plane whose axes repeat."""


def parse_signed_axis(text: str) -> tuple[int, int]:
    """'+IA' -> (0, +1); '-OA' -> (2, -1); 'PA' -> (1, +1)."""
    m = _SIGNED.match(str(text))
    if not m:
        raise AxisError(f"{text!r} is not a signed axis (+IA, -PA, OA, ...)")
    return AXIS_INDEX[m.group(2)], (-1 if m.group(1) == "-" else 1)


def parse_plane(text: str) -> tuple[int, int]:
    """'IA-PA' -> (0, 1): the first and second plane axes."""
    parts = str(text).strip().split("-")
    if len(parts) != 2 or any(p.strip() not in AXIS_INDEX for p in parts):
        raise AxisError(f"{text!r} is not a plane of two axes such as IA-PA")
    a, b = (AXIS_INDEX[p.strip()] for p in parts)
    if a == b:
        raise AxisError(f"plane {text!r} repeats an axis")
    return a, b


def cross_sign(first: int, second: int) -> tuple[int, int]:
    """e_first x e_second = sign * e_third; returns (third, sign)."""
    third = 3 - first - second
    sign = 1 if (second - first) % 3 == 1 else -1
    return third, sign


def plane_handedness(plane: str, vertical_axis: str) -> int:
    """+1 when first x second plane axes points up, -1 when down (drop-format.md, sine_centrifuge).

    Raises AxisError when the vertical axis lies in the plane.
    """
    e1, e2 = parse_plane(plane)
    v, vs = parse_signed_axis(vertical_axis)
    third, s = cross_sign(e1, e2)
    if v != third:
        raise AxisError(f"vertical_axis {vertical_axis!r} lies in the mount plane {plane!r}")
    return s * vs
