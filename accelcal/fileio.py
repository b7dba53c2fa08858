"""Atomic file writes: a killed writer leaves the old file or the new one, never a part."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def atomic_write(target: str | Path, write: Callable[[IO[Any]], None], mode: str = "wb",
                 fsync: bool = False, **open_kw) -> Path:
    """Call ``write(fh)`` on a temporary file in the target's folder, then ``os.replace``
    it onto ``target`` (atomic on one file system).  The temporary file is removed if
    anything fails.  fsync: flush to disk before the rename."""
    target = Path(target)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, mode, **open_kw) as fh:
            write(fh)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return target
