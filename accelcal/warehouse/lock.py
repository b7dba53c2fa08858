"""The cross-process write lock of a warehouse: ``fcntl.flock`` on ``<db>.lock``.

One writer at a time: every write session holds the lock exclusively (re-entrant within a
process); readers (``accelcal sql``) hold it shared, so they wait for a writer and a writer
waits for them, never half-way through a run.  The holder's pid is written in the file
and, on Linux, read from /proc/locks to name who holds it when a wait times out.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import threading
import time
from pathlib import Path
from typing import Iterator

from ..fileio import os_error_text
from .errors import WarehouseBusy, WarehouseError

_held_lock = threading.RLock()
_held: dict[str, list] = {}      # realpath of lock file -> [fd, depth]


def lock_path_for(db_path: str | Path) -> Path:
    return Path(str(db_path) + ".lock")


def _holder_pid(lock_path: Path) -> str:
    try:
        txt = lock_path.read_text().strip()
        return txt or "unknown"
    except OSError:
        return "unknown"


def lock_holders(lock_path: str | Path) -> list[tuple[int, str]]:
    """(pid, 'WRITE'|'READ') of the processes holding a flock on ``lock_path``, from
    /proc/locks (Linux; empty elsewhere)."""
    try:
        st = os.stat(lock_path)
        with open("/proc/locks") as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    want = (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino)
    out = []
    for line in lines:
        parts = line.split()
        if "->" in parts or len(parts) < 6 or parts[1] != "FLOCK":
            continue
        try:
            maj, mnr, ino = parts[5].split(":")
            if (int(maj, 16), int(mnr, 16), int(ino)) == want:
                out.append((int(parts[4]), parts[3]))
        except ValueError:
            continue
    return out


def describe_pid(pid: int) -> str:
    """'pid N (command line)' for a message."""
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            cmd = f.read().replace(b"\0", b" ").decode("utf-8", "replace").strip()
    except OSError:
        cmd = ""
    cmd = re.sub(r"^\S*python[0-9.]*\s+(-m\s+)?", "", " ".join(cmd.split()))
    return f"pid {pid}" + (f" ({cmd[:60]})" if cmd else "")


def _busy_text(db_path, lp: Path, timeout: float) -> str:
    holders = lock_holders(lp)
    if holders:
        who = ", ".join(describe_pid(p) + (", reading" if m == "READ" else "") for p, m in holders[:3])
    else:
        who = f"pid {_holder_pid(lp)}"
    return f"warehouse {db_path} is in use by {who} (waited {timeout:g} s; see {lp})"


@contextlib.contextmanager
def warehouse_lock(db_path: str | Path, timeout: float = 60.0,
                   poll: float = 0.1, shared: bool = False) -> Iterator[None]:
    """Exclusive OS lock on ``<db>.lock`` (``shared=True``: a reader's shared lock);
    waits up to ``timeout`` seconds.

    Re-entrant within one process.  Raises :class:`WarehouseBusy` naming the
    holder's pid when the wait times out.  A reader in a folder where the lock file
    cannot be created goes on without it (no writer can work there either).
    """
    lp = lock_path_for(db_path)
    key = os.path.realpath(lp)
    with _held_lock:
        if key in _held:
            _held[key][1] += 1
            reentered = True
        else:
            reentered = False
    if reentered:
        try:
            yield
        finally:
            with _held_lock:
                _held[key][1] -= 1
        return

    try:
        if not shared:
            lp.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lp, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as e:
        fd = None
        if shared:
            try:
                fd = os.open(lp, os.O_RDONLY | os.O_CLOEXEC)
            except OSError:
                pass
        if fd is None and not shared:
            raise WarehouseError(os_error_text(e, f"cannot use warehouse {db_path}: cannot "
                                                  "create its lock file")) from None
    if fd is None:                     # a reader, no lock file and none can be made
        yield
        return
    deadline = time.monotonic() + max(0.0, timeout)
    try:
        while True:
            try:
                fcntl.flock(fd, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | fcntl.LOCK_NB)
                break
            except OSError as e:
                if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                    raise
                if time.monotonic() >= deadline:
                    raise WarehouseBusy(_busy_text(db_path, lp, timeout)) from None
                time.sleep(poll)
    except BaseException:
        os.close(fd)
        raise
    if not shared:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    with _held_lock:
        _held[key] = [fd, 1]
    try:
        yield
    finally:
        with _held_lock:
            del _held[key]
        try:
            if not shared:
                os.ftruncate(fd, 0)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)


def holds_lock(db_path: str | Path) -> bool:
    with _held_lock:
        return os.path.realpath(lock_path_for(db_path)) in _held
