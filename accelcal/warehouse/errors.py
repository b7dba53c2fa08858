"""The warehouse's errors: each one line for the CLI, naming the file and what to do."""
from __future__ import annotations


class WarehouseError(RuntimeError):
    """The warehouse cannot be used (one-line message for the CLI)."""


class WarehouseBusy(WarehouseError):
    """Another process holds the warehouse lock."""


class ExtrasError(WarehouseError):
    """A result's extras file is missing or its bytes are not the ones its sha256 names."""


_DUCKDB_HINTS = (
    ("no space left", "the disk is full: free space, then run again; what was committed stays"),
    ("read-only file system", "a read-only file system: choose a writable place"),
    ("permission denied", "no permission: make the warehouse folder writable for this user"),
    ("not a valid duckdb database", "restore it from a backup or its -snapshot.duckdb copy"),
    ("serialization", "the file is damaged or from another DuckDB version: restore it from a "
                      "backup or its -snapshot.duckdb copy"),
    ("corrupt", "the file is damaged: restore it from a backup or its -snapshot.duckdb copy"),
    ("checksum", "the file is damaged: restore it from a backup or its -snapshot.duckdb copy"),
)


def duckdb_error_text(e: Exception, what: str, untouched: bool = False) -> str:
    """One line for a DuckDB error: what, DuckDB's first line (cut), what to do."""
    msg = " ".join(str(e).split())[:240]
    low = msg.lower()
    hint = next((h for k, h in _DUCKDB_HINTS if k in low), None)
    if hint is None and untouched:
        hint = "restore it from a backup or its -snapshot.duckdb copy"
    tail = "; it was not modified" if untouched else ""
    return f"{what}: {msg}{tail}" + (f" ({hint})" if hint else "")
