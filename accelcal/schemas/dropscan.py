"""A drop, scanned (drop-format.md, "A drop"), and the drop-format file rules: which
entries of a drop are run files, which are refused as they stand without being opened
(:data:`ENTRY_RULES`: links, FIFOs, devices, unreadable folders, bad names), and when a
file being written has settled (:func:`settle_wait`).  The run files themselves are read
by :mod:`accelcal.schemas.dropformat`.
"""
from __future__ import annotations

import os
import re
import stat as stat_mod
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Entry:
    """One thing in a drop that is, or looks like, a run file (see :func:`scan_drop`).

    ``path`` is the path as the OS gives it (a name that is not UTF-8 holds surrogate
    escapes); ``size``/``mtime_ns`` are from lstat at the scan; ``refusal`` is
    ``(rule, detail)`` when the entry is refused as it stands, without being opened.
    """

    path: str
    size: int = -1
    mtime_ns: int = -1
    refusal: tuple[str, str] | None = None


#: Rules of entries refused without being read (the drop-format file rules).
ENTRY_RULES = {
    "link": "a symbolic link: links are not followed (copy the file into the drop)",
    "not-a-file": "a FIFO, socket or device named *.csv: not a regular file",
    "unreadable": "the OS refuses to open or read it (the reason is named)",
    "bad-file-name": "a name that is not UTF-8 or holds a control character",
}

_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def bad_name(name: str) -> str | None:
    """Why a file or folder name is refused, or None.  A name must be UTF-8 (a lineage
    that names the raw file must name it exactly) and hold no control character (every
    message naming it is one line)."""
    try:
        name.encode("utf-8")
    except UnicodeEncodeError as e:
        b = os.fsencode(name)
        k = len(name[:e.start].encode("utf-8", "surrogateescape"))
        return f"the name is not UTF-8 (byte 0x{b[k]:02x} at byte {k} of the name)"
    m = _CONTROL.search(name)
    if m:
        return f"the name holds a control character (U+{ord(m.group()):04X})"
    return None


def _is_csv(name: str) -> bool:
    return name[-4:].lower() == ".csv"


def scan_drop(drop_dir) -> list[Entry]:
    """Every run file of a drop, and every entry refused as a run file, sorted by path.

    A drop's run files are its regular ``*.csv`` files at any depth (drop-format.md, "A
    drop"); other files (``*.log``, ``*.txt``, ``Thumbs.db``, ``*.csv.part``) are ignored,
    and so are folders named ``*.csv`` (their files are looked at).  Nothing is followed
    out of the drop and nothing is opened here.  Refused, with a reason
    (:data:`ENTRY_RULES`): a symbolic link named ``*.csv`` or to a folder (dangling,
    inside or out of the drop); a FIFO, socket or device named ``*.csv``; a sub-folder
    that cannot be listed; a ``*.csv`` file or a folder whose name is not UTF-8 or holds
    a control character (its files are not looked at).  Raises OSError when the drop
    folder itself cannot be listed.
    """
    root = os.fspath(drop_dir)
    out: list[Entry] = []
    stack = [root]
    while stack:
        folder = stack.pop()
        try:
            with os.scandir(folder) as it:
                items = list(it)
        except OSError as e:
            if folder == root:
                raise
            out.append(Entry(folder, 0, 0, ("unreadable", f"cannot list this folder: "
                                                          f"{e.strerror or e}; its files are not read")))
            continue
        for de in items:
            path, name = de.path, de.name
            try:
                st = de.stat(follow_symlinks=False)
            except FileNotFoundError:          # gone since the listing
                continue
            except OSError as e:
                if _is_csv(name):
                    out.append(Entry(path, 0, 0, ("unreadable", f"cannot stat: {e.strerror or e}")))
                continue
            mode = st.st_mode
            if stat_mod.S_ISLNK(mode):
                why = _link_refusal(root, path, name)
                if why is not None:
                    out.append(Entry(path, 0, 0, ("link", why)))
                continue
            why = bad_name(name)
            if stat_mod.S_ISDIR(mode):
                if why is not None:
                    out.append(Entry(path, 0, 0, ("bad-file-name", f"a folder: {why}; its files "
                                                                   "are not read (rename it)")))
                else:
                    stack.append(path)
                continue
            if not _is_csv(name):
                continue
            if why is not None:
                out.append(Entry(path, st.st_size, st.st_mtime_ns, ("bad-file-name", f"{why} (rename it)")))
            elif not stat_mod.S_ISREG(mode):
                kind = ("a FIFO (named pipe)" if stat_mod.S_ISFIFO(mode) else
                        "a socket" if stat_mod.S_ISSOCK(mode) else "a device")
                out.append(Entry(path, 0, st.st_mtime_ns, ("not-a-file", f"{kind}, not a regular file")))
            else:
                out.append(Entry(path, st.st_size, st.st_mtime_ns))
    out.sort(key=lambda e: e.path.split(os.sep))
    return out


def _link_refusal(root: str, path: str, name: str) -> str | None:
    """Why a symbolic link in a drop is refused, or None (a link to something that is not
    a folder, with a name that is not ``*.csv``: ignored like any other non-run file)."""
    try:
        target = os.readlink(path)
    except OSError:
        target = "?"
    try:
        is_dir = stat_mod.S_ISDIR(os.stat(path).st_mode)
        dangling = False
    except OSError:
        is_dir, dangling = False, True
    if not (_is_csv(name) or is_dir):
        return None
    what = "a symbolic link to a folder" if is_dir else "a symbolic link"
    real = os.path.realpath(path)
    root_real = os.path.realpath(root)
    if dangling:
        where = "that points nowhere (dangling)"
    elif real == root_real or real.startswith(root_real.rstrip(os.sep) + os.sep):
        where = "inside the drop (what it points to is read under its own name)"
    else:
        where = "out of the drop"
    return (f"{what} to {target!r}, {where}: links are not followed; copy the "
            f"{'files' if is_dir else 'file'} into the drop")


def discover(drop_dir) -> list[Path]:
    """The run files of a drop (drop-format.md, "A drop"): the regular ``*.csv`` files at
    any depth, sorted; see :func:`scan_drop` for what is refused and why."""
    return [Path(e.path) for e in scan_drop(drop_dir) if e.refusal is None]


def settle_wait(entries: list[Entry], settle: float, max_wait: float | None = None,
                sleep=time.sleep, clock=time.time) -> tuple[list[Entry], list[tuple[Entry, str]]]:
    """Wait until every run file's size and mtime have been stable for ``settle`` seconds
    -- its mtime is that old, or two looks that far apart saw the same (size, mtime), which
    also copes with a clock that is off -- looking again at the others for at most
    ``max_wait`` seconds (default ``2 * settle + 5``).  Returns (settled entries with their
    latest stat, held back [(entry, why)]): a file still being written is not read.

    Shared by ``run`` and ``serve``: a DAQ copying into the drop is never read half-way.
    Entries refused as they stand pass through; files gone meanwhile are dropped.
    """
    ready = [e for e in entries if e.refusal is not None]
    pending = [e for e in entries if e.refusal is None]
    if settle <= 0:
        return ready + pending, []
    max_wait = 2 * settle + 5 if max_wait is None else max_wait
    t_end = clock() + max_wait
    since: dict[str, tuple[tuple[int, int], float]] = {}     # path -> (stat, first seen)
    left: list[Entry] = []
    while pending:
        now = clock()
        left = []
        for e in pending:
            sig = (e.size, e.mtime_ns)
            if since.get(e.path, (None,))[0] != sig:
                since[e.path] = (sig, now)
            if now - e.mtime_ns / 1e9 >= settle or now - since[e.path][1] >= settle:
                ready.append(e)
            else:
                left.append(e)
        if not left:
            break
        wake = min(min(e.mtime_ns / 1e9, since[e.path][1]) + settle for e in left)
        if wake > t_end:
            break
        sleep(max(wake - now, 0.01))
        pending = []
        for e in left:
            try:
                st = os.lstat(e.path)
            except FileNotFoundError:
                continue
            except OSError:
                ready.append(e)                  # reading it will say why
                continue
            pending.append(Entry(e.path, st.st_size, st.st_mtime_ns))
        left = []
    now = clock()
    held = [(e, f"still being written (modified {max(now - e.mtime_ns / 1e9, 0):.1f} s ago, "
                f"settle time {settle:g} s): not read this time") for e in left]
    ready.sort(key=lambda e: e.path.split(os.sep))
    return ready, held
