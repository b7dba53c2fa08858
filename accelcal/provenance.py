"""Where a run file comes from: the lab's DAQ, or the simulator.

``accelcal simulate`` writes ``# simulated: true`` as the second metadata line of every
file.  drop-format.md lists the keys a run has and four optional ones; it does not
forbid others, and the parser keeps an unknown key as text (``RunFile.meta_raw``), so a
real DAQ file is read exactly as before while a simulated one says what it is in its
own bytes (the sha256 covers the mark, and no file name, folder or run-id convention has
to be trusted).  Any value but ``false``/``no``/``0`` counts as simulated: when in
doubt, a file is not taken for real data.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping

SIMULATED_KEY = "simulated"
#: run_id and campaign prefix the simulator uses unless told to keep the scenario's ids.
SIM_PREFIX = "SIM-"
_NOT_SIMULATED = ("false", "no", "0")


def is_simulated(meta: Mapping) -> bool:
    """True when a run's metadata carries the simulator's mark."""
    if SIMULATED_KEY not in meta:
        return False
    return str(meta[SIMULATED_KEY]).strip().lower() not in _NOT_SIMULATED


def metadata_lines(raw: bytes, limit: int = 65536) -> Iterator[tuple[int, str, str]]:
    """(line number, key, value) of the ``# key: value`` block at the top of a file, read
    best-effort from its first ``limit`` bytes (for files the parser may refuse)."""
    text = raw[:limit].decode("utf-8", errors="replace")
    for n, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s:
            continue
        if not s.startswith("#"):
            return
        key, sep, value = s[1:].partition(":")
        if sep:
            yield n, key.strip(), value.strip()


def simulated_line(raw: bytes) -> int | None:
    """The line of the simulator's mark in a file's bytes, or None for a real file."""
    for n, key, value in metadata_lines(raw):
        if key == SIMULATED_KEY and is_simulated({key: value}):
            return n
    return None
