"""How results are written down: GUM (JCGM 100) 7.2.6.

An expanded uncertainty U is given to two significant digits, and the value is rounded
to the same decimal place as U.  :func:`round_gum` is the one place this is done; the
CLI summary, the certificate and the README tables use it.

Rounding is decimal (the shortest repr of the float, then ROUND_HALF_UP), so 0.0299899
becomes ``0.030`` (the trailing zero is a significant digit and is kept), 9.96 becomes
``10``, and the value follows U's last digit: K1T -119.98691 with U 0.02999 is
``-119.987`` ± ``0.030``.
"""
from __future__ import annotations

import math
from decimal import ROUND_HALF_UP, Decimal, InvalidOperation
from typing import NamedTuple

#: Significant digits of an uncertainty (GUM 7.2.6: "at most two").
SIG_DIGITS = 2


class Rounded(NamedTuple):
    value: str
    uncertainty: str
    exponent: int | None     # power of ten of the last digit shown (None: U unknown)


def _finite(x) -> bool:
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def _plain(d: Decimal) -> str:
    s = format(d, "f")
    if s.startswith("-") and Decimal(s) == 0:
        s = s[1:]
    return s


def round_sig(x: float, sig: int = SIG_DIGITS) -> tuple[Decimal, int]:
    """x to ``sig`` significant digits: (rounded Decimal, exponent of its last digit)."""
    d = Decimal(repr(float(x)))
    exp = d.adjusted() - (sig - 1)
    r = d.quantize(Decimal(1).scaleb(exp), rounding=ROUND_HALF_UP)
    if r != 0 and r.adjusted() > d.adjusted():        # 9.96 -> 10.0: one digit too many
        exp += 1
        r = d.quantize(Decimal(1).scaleb(exp), rounding=ROUND_HALF_UP)
    return r, exp


def format_sig(x: float | None, sig: int = SIG_DIGITS) -> str:
    """x to ``sig`` significant digits, trailing zeros kept ("—" when not a number)."""
    if not _finite(x):
        return "—"
    if x == 0:
        return "0"
    return _plain(round_sig(x, sig)[0])


def round_gum(value: float | None, U: float | None, sig: int = SIG_DIGITS,
              fallback_sig: int = 6) -> Rounded:
    """Value and expanded uncertainty as written on a certificate (GUM 7.2.6).

    U to ``sig`` significant digits; the value rounded to the decimal place of U's last
    digit.  Without a usable U (None, NaN, <= 0) the value keeps ``fallback_sig``
    significant digits and U is "—".
    """
    if not _finite(value):
        return Rounded("—", format_sig(U, sig) if _finite(U) and U > 0 else "—", None)
    if not _finite(U) or U <= 0:
        return Rounded(_plain(round_sig(value, fallback_sig)[0]) if value else "0", "—", None)
    Ur, exp = round_sig(U, sig)
    try:
        v = Decimal(repr(float(value))).quantize(Decimal(1).scaleb(exp), rounding=ROUND_HALF_UP)
    except InvalidOperation:        # more than 28 digits between value and U: not a result
        return Rounded(_plain(round_sig(value, fallback_sig)[0]), _plain(Ur), None)
    return Rounded(_plain(v), _plain(Ur), exp)


def round_gum_sci(value: float | None, u: float | None) -> tuple[str, str]:
    """(value, u) as people read them: u to two significant digits, the value to u's last
    digit (GUM 7.2.6); outside 0.001-99999 both in powers of ten with the value's exponent."""
    if value is None or not math.isfinite(value):
        return "—", format_sig(u)
    if value == 0:
        return "0", format_sig_sci(u)
    ref = abs(value)
    e = math.floor(math.log10(ref)) if ref and math.isfinite(ref) else 0
    if -3 <= e <= 4:
        r = round_gum(value, u)
        return r.value, r.uncertainty
    r = round_gum(value / 10 ** e, None if u is None else u / 10 ** e)
    return f"{r.value}e{e}", "—" if r.uncertainty == "—" else f"{r.uncertainty}e{e}"


def format_sig_sci(x: float | None, sig: int = SIG_DIGITS) -> str:
    """x to ``sig`` significant digits; outside 0.001-99999 in powers of ten (``1.7e-4``)."""
    if not _finite(x) or x == 0:
        return format_sig(x, sig)
    e = math.floor(math.log10(abs(x)))
    return format_sig(x, sig) if -3 <= e <= 4 else f"{format_sig(x / 10 ** e, sig)}e{e}"
