"""Files accelcal writes: atomic writes (a killed writer leaves the old file or the new
one, never a part) and the clean-up of what a killed writer leaves; paths and OS errors
as one line of text."""
from __future__ import annotations

import errno
import hashlib
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def current_umask() -> int:
    """The process's file-mode creation mask, read without changing it.

    Linux gives it in ``/proc/self/status``; elsewhere it is read by setting and restoring
    it, which is not safe while other threads create files, so it is read once and kept.
    """
    global _UMASK
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    if _UMASK is None:
        _UMASK = os.umask(0o022)
        os.umask(_UMASK)
    return _UMASK


_UMASK: int | None = None


def atomic_write(target: str | Path, write: Callable[[IO[Any]], None], mode: str = "wb",
                 fsync: bool = False, **open_kw) -> Path:
    """Call ``write(fh)`` on a temporary file in the target's folder, then ``os.replace``
    it onto ``target`` (atomic on one file system).  The temporary file is removed if
    anything fails.  fsync: flush to disk before the rename.  The file gets the mode an
    ordinary ``open`` would give it (0666 less the umask): a lab shares what we write,
    where ``mkstemp`` alone would leave it 0600."""
    f = AtomicFile(target, mode, **open_kw)
    try:
        write(f.fh)
        if fsync:
            f.fh.flush()
            os.fsync(f.fh.fileno())
        return f.commit()
    except BaseException:
        f.abort()
        raise


class AtomicFile:
    """:func:`atomic_write`'s temporary file kept open across calls, for a file written
    while something else is read (a run's Parquet file as its raw file is parsed, issue
    28): write to ``fh``, then :meth:`commit` (renamed onto the target) or :meth:`abort`
    (removed).  Either may be called again, and abort after commit does nothing."""

    def __init__(self, target: str | Path, mode: str = "wb", **open_kw):
        self.target = Path(target)
        fd, self.tmp = tempfile.mkstemp(prefix=f".{self.target.name}.", suffix=".tmp",
                                        dir=self.target.parent)
        try:
            os.fchmod(fd, 0o666 & ~current_umask())
            self.fh = os.fdopen(fd, mode, **open_kw)
        except BaseException:
            os.close(fd)
            os.unlink(self.tmp)
            raise
        self.done = False

    def commit(self) -> Path:
        if not self.done:
            self.fh.close()
            os.replace(self.tmp, self.target)
            self.done = True
        return self.target

    def abort(self) -> None:
        if self.done:
            return
        self.done = True
        try:
            self.fh.close()
        except OSError:
            pass
        try:
            os.unlink(self.tmp)
        except FileNotFoundError:
            pass


def sha256_fd(fd: int) -> tuple[str, int]:
    """sha256 (hex) and size [byte] of what is read from ``fd`` to its end, 1 MiB at a time
    (a big run file is hashed in a pass of its own before it is parsed)."""
    h, n = hashlib.sha256(), 0
    while True:
        b = os.read(fd, 1 << 20)
        if not b:
            return h.hexdigest(), n
        h.update(b)
        n += len(b)


def sync_files(paths: list[str | Path]) -> None:
    """Make files written without an fsync durable, names included: one ``syncfs`` of each
    file system they are on (Linux), else an ``fsync`` of each file and of each folder
    holding them.  One flush for a batch of files: an fsync per file cost ~3.5 ms a file on
    this lab's disks, one syncfs after 500 files 0.15-0.5 ms a file.  Raises OSError."""
    paths = [os.fspath(p) for p in paths]
    if not paths:
        return
    syncfs = _syncfs()
    folders = sorted({os.path.dirname(p) or "." for p in paths})
    if syncfs is not None:
        seen: set[int] = set()
        for d in folders:
            dev = os.stat(d).st_dev
            if dev in seen:
                continue
            seen.add(dev)
            fd = os.open(d, os.O_RDONLY)
            try:
                if syncfs(fd) != 0:
                    err = ctypes_errno()
                    raise OSError(err, os.strerror(err), d)
            finally:
                os.close(fd)
        return
    for p in paths + folders:
        fd = os.open(p, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _syncfs():
    """libc's syncfs, or None where there is none (not Linux)."""
    global _SYNCFS
    if _SYNCFS is False:
        import ctypes
        try:
            f = ctypes.CDLL(None, use_errno=True).syncfs
            f.argtypes, f.restype = [ctypes.c_int], ctypes.c_int
            _SYNCFS = f
        except (AttributeError, OSError):
            _SYNCFS = None
    return _SYNCFS


_SYNCFS: Any = False


def ctypes_errno() -> int:
    import ctypes
    return ctypes.get_errno() or errno.EIO


_TEMP = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp(\.wal)?$")


def is_temp_name(name: str) -> bool:
    """A name :func:`atomic_write` gives its temporary files (``.<target>.XXXXXXXX.tmp``;
    with ``.wal``: DuckDB's log of a warehouse being created under a temporary name)."""
    return bool(_TEMP.match(name))


def remove_stale_temps(folder: str | Path, recursive: bool = True) -> list[str]:
    """Remove the temporary files of :func:`atomic_write` under ``folder`` (left by a
    writer that was killed); returns their paths.  Call it only while no writer of that
    folder can be running (the pipeline holds the warehouse lock)."""
    removed: list[str] = []
    stack = [os.fspath(folder)]
    while stack:
        d = stack.pop()
        try:
            with os.scandir(d) as it:
                items = list(it)
        except OSError:
            continue
        for de in items:
            try:
                if de.is_dir(follow_symlinks=False):
                    if recursive:
                        stack.append(de.path)
                elif is_temp_name(de.name) and de.is_file(follow_symlinks=False):
                    os.unlink(de.path)
                    removed.append(de.path)
            except OSError:
                pass
    return removed


def path_text(path) -> str:
    """A path as text that is always valid UTF-8: bytes of a name that are not UTF-8 are
    shown as ``\\xNN`` (os.fsencode, then backslashreplace).  For valid names it is the
    path itself."""
    p = os.fspath(path)
    if isinstance(p, bytes):
        return p.decode("utf-8", "backslashreplace")
    try:
        p.encode("utf-8")
        return p
    except UnicodeEncodeError:
        return os.fsencode(p).decode("utf-8", "backslashreplace")


class StoreError(RuntimeError):
    """A place accelcal writes (the Parquet store, Data Docs, the snapshot) cannot be
    written: a one-line message naming it and what to do.  Not a verdict on any file."""


_HINTS = {
    errno.ENOSPC: "the disk is full: free space there, then run again",
    errno.EDQUOT: "the disk quota is used up: free space, then run again",
    errno.EROFS: "a read-only file system: choose a writable place",
    errno.EACCES: "no permission: make it writable for this user, or choose another place",
    errno.EPERM: "not permitted: make it writable for this user, or choose another place",
    errno.ENAMETOOLONG: "the path is too long",
    errno.ENOTDIR: "a part of the path is not a folder",
    errno.EIO: "the device reports an input/output error: check the disk",
}


def os_error_text(e: OSError, what: str | None = None) -> str:
    """One line for an OSError: what, the path, the OS's reason and what to do."""
    parts = [what] if what else []
    if e.filename is not None:
        parts.append(path_text(e.filename))
    reason = e.strerror or str(e) or type(e).__name__
    hint = _HINTS.get(e.errno)
    return ": ".join(parts + [reason]) + (f" ({hint})" if hint else "")
