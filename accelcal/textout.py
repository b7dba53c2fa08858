"""Everything the CLI prints goes through here, so that nothing that came from a file (a
name, a metadata value, an excerpt in a refusal) is ever taken as rich markup (``[/x]``),
an emoji code (``:x:``), a terminal control sequence or a line break, and no file name
that is not UTF-8 can make printing fail.

The whole API:

``plain(x, limit=None)``
    ``str(x)`` as one printable line: every character ``str.isprintable`` refuses
    (controls, line breaks, bidi overrides, zero-width and private-use characters) and
    the undecodable bytes of a file name (surrogate escapes) become ``\\xNN`` /
    ``\\uNNNN`` escapes, and a backslash ``\\\\`` (so the text is unambiguous, as
    repr() is); cut to ``limit`` characters with "…".
``esc(x, limit=None)``
    ``plain(x)`` escaped for rich markup: safe to put inside a markup string.
``console(stderr=False)``
    a rich Console with emoji codes and highlighting off.
``error(msg)``, ``warn(msg)``
    one line ``accelcal: error: …`` / ``accelcal: warning: …`` on stderr.
"""
from __future__ import annotations

import re
import sys

__all__ = ["plain", "esc", "console", "error", "warn"]


def _escape(c: str) -> str:
    o = ord(c)
    if 0xDC80 <= o <= 0xDCFF:           # a byte that was not UTF-8 (surrogateescape)
        return f"\\x{o - 0xDC00:02x}"
    if o < 0x100:
        return {0x5C: "\\\\", 0x09: "\\t", 0x0A: "\\n", 0x0D: "\\r"}.get(o, f"\\x{o:02x}")
    return f"\\u{o:04x}" if o < 0x10000 else f"\\U{o:08x}"


def plain(x, limit: int | None = None) -> str:
    s = x if isinstance(x, str) else str(x)
    cut = limit is not None and len(s) > limit
    if cut:
        s = s[:limit]
    if not s.isprintable() or "\\" in s:
        # everything str.isprintable() calls unprintable: controls, line and paragraph
        # separators, format characters (bidi overrides, zero-width), unassigned and
        # private-use code points, lone surrogates
        s = "".join(c if c.isprintable() and c != "\\" else _escape(c) for c in s)
    if limit is not None and (cut or len(s) > limit):
        s = s[:max(limit - 1, 0)] + "…"
    return s


#: a "[" that does not open a rich tag: rich.markup.escape leaves it, and rich's renderer
#: then reads a backslash before it as an escape ("\\[" would print as "\[")
_BARE_BRACKET = re.compile(r"\[(?![a-z#/@][^\[]*?\])")


def esc(x, limit: int | None = None) -> str:
    """:func:`plain`, escaped for rich markup: printed by rich it is exactly the plain text
    (tag-like brackets by rich's escape, every other bracket with one more backslash)."""
    from rich.markup import escape
    return _BARE_BRACKET.sub(r"\\[", escape(plain(x, limit)))


def console(stderr: bool = False):
    from rich.console import Console
    return Console(stderr=stderr, highlight=False, emoji=False)


def error(msg) -> None:
    print(f"accelcal: error: {plain(msg)}", file=sys.stderr)


def warn(msg) -> None:
    print(f"accelcal: warning: {plain(msg)}", file=sys.stderr)
