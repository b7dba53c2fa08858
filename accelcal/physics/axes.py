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
    """A signed axis of drop-format.md as (axis index, sign).

    Parameters
    ----------
    text : str
        '+IA', '-OA', 'PA', ...

    Returns
    -------
    (int, int)
        Index into (IA, PA, OA) and +1/-1: '+IA' -> (0, +1), '-OA' -> (2, -1).

    Raises
    ------
    AxisError
        Not a signed axis.
    """
    m = _SIGNED.match(str(text))
    if not m:
        raise AxisError(f"{text!r} is not a signed axis (+IA, -PA, OA, ...)")
    return AXIS_INDEX[m.group(2)], (-1 if m.group(1) == "-" else 1)


def parse_plane(text: str) -> tuple[int, int]:
    """A mount plane of drop-format.md as (first, second) axis indices.

    Parameters
    ----------
    text : str
        'IA-PA', 'OA-IA', ...

    Returns
    -------
    (int, int)
        'IA-PA' -> (0, 1).

    Raises
    ------
    AxisError
        Not two distinct axes.
    """
    parts = str(text).strip().split("-")
    if len(parts) != 2 or any(p.strip() not in AXIS_INDEX for p in parts):
        raise AxisError(f"{text!r} is not a plane of two axes such as IA-PA")
    a, b = (AXIS_INDEX[p.strip()] for p in parts)
    if a == b:
        raise AxisError(f"plane {text!r} repeats an axis")
    return a, b


def cross_sign(first: int, second: int) -> tuple[int, int]:
    """The third axis of a pair and the sign of their cross product.

    Parameters
    ----------
    first, second : int
        Axis indices (IA x PA = OA, drop-format.md).

    Returns
    -------
    (int, int)
        (third, sign) with e_first x e_second = sign e_third.
    """
    third = 3 - first - second
    sign = 1 if (second - first) % 3 == 1 else -1
    return third, sign


def plane_handedness(plane: str, vertical_axis: str) -> int:
    """Handedness h of a mount plane (drop-format.md, ``sine_centrifuge``).

    Parameters
    ----------
    plane : str
        'IA-PA', ...
    vertical_axis : str
        The signed vertical axis, e.g. '+OA'.

    Returns
    -------
    int
        +1 when e1 x e2 points up, -1 when down.

    Raises
    ------
    AxisError
        The vertical axis lies in the plane.
    """
    e1, e2 = parse_plane(plane)
    v, vs = parse_signed_axis(vertical_axis)
    third, s = cross_sign(e1, e2)
    if v != third:
        raise AxisError(f"vertical_axis {vertical_axis!r} lies in the mount plane {plane!r}")
    return s * vs
