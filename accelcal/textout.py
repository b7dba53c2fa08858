"""Everything the CLI prints goes through here, so that nothing that came from a file (a
name, a metadata value, an excerpt in a refusal) is ever taken as rich markup (``[/x]``),
an emoji code (``:x:``), a terminal control sequence or a line break, and no file name
that is not UTF-8 can make printing fail.

The whole API:

``plain(x, limit=None)``
    ``str(x)`` as one printable line: control characters, line breaks, bidi overrides
    and the undecodable bytes of a file name (surrogate escapes) become ``\\xNN`` /
    ``\\uNNNN`` escapes and a backslash ``\\\\`` (so the text is unambiguous, as
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

# C0/C1 controls, DEL, lone surrogates (undecodable bytes of names), line/paragraph
# separators, bidi embeddings/overrides/isolates, BOM/zero-width no-break space.
_UNSAFE = re.compile("[\\\\\x00-\x1f\x7f-\x9f\ud800-\udfff\u2028\u2029\u200e\u200f"
                     "\u202a-\u202e\u2066-\u2069\ufeff]")


def _escape(m: re.Match) -> str:
    c = ord(m.group())
    if 0xDC80 <= c <= 0xDCFF:           # a byte that was not UTF-8 (surrogateescape)
        return f"\\x{c - 0xDC00:02x}"
    if c < 0x100:
        return {0x5C: "\\\\", 0x09: "\\t", 0x0A: "\\n", 0x0D: "\\r"}.get(c, f"\\x{c:02x}")
    return f"\\u{c:04x}"


def plain(x, limit: int | None = None) -> str:
    s = x if isinstance(x, str) else str(x)
    if limit is not None and len(s) > limit:
        s = s[:limit]
        cut = True
    else:
        cut = False
    s = _UNSAFE.sub(_escape, s)
    if limit is not None and (cut or len(s) > limit):
        s = s[:max(limit - 1, 0)] + "…"
    return s


def esc(x, limit: int | None = None) -> str:
    from rich.markup import escape
    return escape(plain(x, limit))


def console(stderr: bool = False):
    from rich.console import Console
    return Console(stderr=stderr, highlight=False, emoji=False)


def error(msg) -> None:
    print(f"accelcal: error: {plain(msg)}", file=sys.stderr)


def warn(msg) -> None:
    print(f"accelcal: warning: {plain(msg)}", file=sys.stderr)
