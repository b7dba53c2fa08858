"""How the certificate prints a number, a date, a table cell: the display helpers of
:mod:`accelcal.ops.report` (GUM 7.2.6 rounding through :mod:`accelcal.rounding`, display
units through the catalogue)."""
from __future__ import annotations

import datetime as _dt
import html
import math
import re
from typing import Any

from ..results import display_number
from .certificate import K_COVERAGE

PLACEHOLDER_CLASS = "placeholder"


# ------------------------------------------------------------------ display --

def display_value(name: str, value: float | None, std_u: float | None,
                  unit: str | None, k: float | None = None) -> tuple[str, str, str]:
    """(value, U = k u, display unit) for one coefficient, rounded per GUM 7.2.6; k = 2
    unless the coefficient carries its own coverage factor (few degrees of freedom)."""
    from ..effects import display_coefficient
    return display_coefficient(name, value, std_u, unit, k or K_COVERAGE)


def _to_second(t) -> str:
    """A stored timestamp as people read it: to the second, with its UTC offset."""
    import datetime as _dt
    if isinstance(t, _dt.datetime):
        return t.replace(microsecond=0).isoformat(sep=" ")
    return re.sub(r"(\d{2}:\d{2}:\d{2})\.\d+", r"\1", str(t))


def _coefficient_scale(name: str, unit: str | None) -> tuple[float, str]:
    """(factor, display unit) of a coefficient: display value = SI value / factor, the unit
    of the results table (effects.md "usual display"; K1 in <output unit>/g)."""
    from ..effects import coefficient_spec, to_display
    spec = coefficient_spec(name)
    if spec is None:
        return 1.0, unit or ""
    return spec.display_factor, to_display(name, 1.0, None, unit or "out")[2]


def _at_digit(x: float | None, exp: int | None) -> str:
    """x written to the decimal place 10**exp (a GUM-rounded quantity's last digit)."""
    from decimal import ROUND_HALF_UP, Decimal
    if x is None or not math.isfinite(x):
        return "—"
    if exp is None:
        return _fmt(x, ".6g")
    s = format(Decimal(repr(float(x))).quantize(Decimal(1).scaleb(exp), rounding=ROUND_HALF_UP), "f")
    return s[1:] if s.startswith("-") and float(s) == 0 else s


_fmt = display_number


def _e(x: Any) -> str:
    return html.escape("" if x is None else str(x))


def _ph(what: str) -> str:
    """A marked placeholder for a fact the lab has not configured."""
    return f"<span class='{PLACEHOLDER_CLASS}'>[{_e(what)}]</span>"


def _table(headers: list[str], rows: list[list[Any]], cls: str = "") -> str:
    th = "".join(f"<th>{_e(h)}</th>" for h in headers)
    body = []
    for row in rows:
        tds = []
        for c in row:
            if isinstance(c, tuple):        # (text, css class)
                tds.append(f'<td class="{c[1]}">{_e(c[0])}</td>')
            else:
                tds.append(f"<td>{_e(c)}</td>")
        body.append("<tr>" + "".join(tds) + "</tr>")
    return (f'<table class="{cls}"><thead><tr>{th}</tr></thead>'
            f"<tbody>{''.join(body)}</tbody></table>")


def _kv(pairs: list[tuple[str, str]]) -> str:
    """A key/value table whose values are already HTML."""
    return "<table class='kv'>" + "".join(
        f"<tr><th>{_e(k)}</th><td>{v}</td></tr>" for k, v in pairs) + "</table>"


def _when(t: _dt.datetime | None, seconds: bool = False) -> str:
    """A time as the certificate prints it, to the minute (to the second with ``seconds``),
    with its UTC offset."""
    if t is None:
        return "—"
    off = t.strftime("%z")
    off = f"UTC{off[:3]}:{off[3:]}" if off else "no offset"
    return f"{t:%Y-%m-%d %H:%M:%S} ({off})" if seconds else f"{t:%Y-%m-%d %H:%M} ({off})"


def _same_minute(a, b) -> bool:
    return a is not None and b is not None and a.replace(second=0, microsecond=0) == b.replace(
        second=0, microsecond=0)


#: A section body shorter than this [characters of HTML, no image] is kept on one page.
KEEP_SECTION_CHARS = 4000


def _keep(body: str) -> str:
    return " class='keep'" if len(body) < KEEP_SECTION_CHARS and "<img" not in body else ""


def _img(b64: str | None, alt: str) -> str:
    return f"<img alt='{_e(alt)}' src='data:image/png;base64,{b64}'>" if b64 else ""
