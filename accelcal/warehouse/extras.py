"""The extras store: a result's extras as immutable, content-addressed files.

A result's extras (per-pair fits, residual series, the Monte Carlo check: what the
certificate's plots and checks read, ~48 KB of JSON a result) are files, not a column.
In the results table they made the flow process's memory grow with the fleet: DuckDB
rewrites a table's whole row group at a checkpoint, and with 91 MB of extras at 2,000
campaigns, appending 32 results and checkpointing took the process from 167 to 334 MB.
One immutable file per distinct extras, named by the sha256 of its bytes, costs the same
at any fleet size; ``results.extras_sha256`` names it, and anyone can check the bytes
(``sha256sum``) against it.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from ..fileio import StoreError, atomic_write, os_error_text, path_text, sync_files
from .errors import ExtrasError

#: schema_info key: the folder of the extras files, relative to the warehouse's folder.
#: The snapshot (same folder, a copy of schema_info) finds them through it too.
EXTRAS_DIR_KEY = "extras_dir"


def extras_file(extras_root: str | Path, sha256: str) -> Path:
    """``<extras_root>/<sha256[:2]>/<sha256>.json``: where the extras of that sha256 are."""
    return Path(extras_root) / sha256[:2] / f"{sha256}.json"


def _holds(path: Path, data: bytes) -> bool:
    """The file exists with exactly these bytes (a file a power loss cut short does not)."""
    try:
        if os.stat(path).st_size != len(data):
            return False
        with open(path, "rb") as f:
            return f.read() == data
    except OSError:
        return False


def write_extras(extras_root: str | Path, texts: list[str]) -> list[str]:
    """Store each JSON text as the UTF-8 file :func:`extras_file` names by the sha256 of
    its bytes, unless that file already holds them; return the sha256s, in order.

    Each file is written atomically (temporary file + rename) and the batch made durable
    by one flush before returning: the caller commits the rows naming them afterwards, so
    a run killed at any point leaves at most a file nothing names yet, with the content
    its name says, which the next run finds in place.  Raises StoreError (one line).
    """
    root = Path(extras_root)
    shas: list[str] = []
    written: list[Path] = []
    try:
        for text in texts:
            data = text.encode("utf-8")
            sha = hashlib.sha256(data).hexdigest()
            shas.append(sha)
            target = extras_file(root, sha)
            if _holds(target, data):
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(target, lambda fh, data=data: fh.write(data), "wb")
            written.append(target)
        sync_files(written)
    except OSError as e:        # name the store, not our temporary file in it
        raise StoreError(os_error_text(OSError(e.errno, e.strerror, str(root)),
                                       "cannot write the extras store")) from None
    return shas


def read_extras_text(extras_root: str | Path, sha256: str) -> str:
    """The JSON text of the extras ``sha256`` names, its bytes checked against it.
    Raises ExtrasError (one line) when the file is missing, unreadable or altered."""
    path = extras_file(extras_root, sha256)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ExtrasError(os_error_text(e, f"cannot read the extras {sha256[:12]} of a result")
                          + " (restore the warehouse's extras folder from a backup)") from None
    if hashlib.sha256(data).hexdigest() != sha256:
        raise ExtrasError(f"extras file {path_text(path)} does not hold the bytes its name "
                          "(results.extras_sha256) says: restore it from a backup")
    return data.decode("utf-8")


def load_extras(extras_root: str | Path, sha256: str | None) -> Any:
    """A result's extras (``CampaignResult.extras``) from its ``results.extras_sha256``;
    None for None.  ExtrasError when the file is missing or its bytes are not these."""
    if sha256 is None:
        return None
    return json.loads(read_extras_text(extras_root, sha256))


def extras_root_of(con, db_path: str | Path) -> Path:
    """The extras folder of the warehouse (or snapshot) open on ``con`` at ``db_path``:
    schema_info's ``extras_dir`` under the file's folder."""
    db_path = Path(db_path).expanduser().resolve()
    row = con.execute("SELECT value FROM schema_info WHERE key = ?", [EXTRAS_DIR_KEY]).fetchall()
    return db_path.parent / (row[0][0] if row else f"{db_path.stem}-extras")
