"""Handing freed memory back to the OS between the stages of a big run.

A stage that worked on a long run leaves free memory the process keeps: Python objects in
reference cycles until the next collection, Arrow's pool what a conversion freed, glibc's
heap the slices and temporaries below its mmap threshold.  The next stage would start that
much higher, and a run's peak is the sum.  Stages call :func:`give_back` when what they
worked on was big (:data:`BIG_ROWS`); a small run is left alone (a collection costs tens
of milliseconds).
"""
from __future__ import annotations

#: Rows (readings) of a stage's data after which its freed memory is handed back.
BIG_ROWS = 1 << 20


def give_back() -> None:
    """Collect cycles, release Arrow's unused pool and trim glibc's heap (best effort:
    nothing on a libc without ``malloc_trim``)."""
    import gc
    gc.collect()
    try:
        import pyarrow as pa
        pa.default_memory_pool().release_unused()
    except Exception:
        pass
    try:
        import ctypes
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass
