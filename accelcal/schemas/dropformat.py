"""Parser of lab data drops, format ``accelcal-drop/1`` (shared/spec/drop-format.md).

This module implements the *structural* half of the contract: everything the
spec says about "A drop" and "A run file", the metadata keys ("Metadata keys
every run has" and the per-test key tables), the columns of each test, and the
parser-level part of "What the pipeline must refuse". The semantic rules that
need the numbers (NaN/inf in ``output``, time going backwards, negative
centrifuge rates, header-vs-data consistency) live in :mod:`accelcal.schemas.suites`.

A refused file raises :class:`DropFormatError` whose ``str`` is
``"{path}:{line}: {rule}: {detail}"`` (``:{line}`` omitted when unknown).
Nothing read is ever modified or moved: the file is read once, as bytes.

Rule ids emitted here (short kebab-case, stable; tests and the warehouse use them):

==================  =========================================================
``empty-file``      zero bytes or only blank lines
``not-utf8``        a byte sequence that is not UTF-8 (line + byte offset)
``bad-line-end``    a lone ``\\r`` (line ends must be ``\\n`` or ``\\r\\n``)
``no-metadata``     the first line is not a ``# key: value`` metadata line
``format-not-first`` the metadata block does not start with ``# format``
``metadata-syntax`` a ``#`` line that is not ``# key: value``
``duplicate-key``   a metadata key given twice
``unknown-format``  ``format`` is not ``accelcal-drop/1``
``unknown-test``    ``test`` is not one of the four kinds
``missing-key``     a required metadata key is absent
``bad-value``       a value of the wrong kind (text for a number, bad time...)
``bad-axis``        an axis/plane that is not IA/PA/OA, repeats, or is inconsistent
``no-header``       metadata block but no CSV header line
``bad-columns``     missing, misspelt, extra or repeated columns (named)
``field-count``     a row with the wrong number of fields
``truncated``       the file ends mid-row (no final newline, incomplete row)
``non-numeric``     a cell that is not a number (column + line named)
``empty-value``     an empty cell in a column where the spec allows none
``not-integer``     a non-integral ``step``/``position``
``no-data``         a header but no data rows
``line-too-long``   a line longer than LINE_MAX bytes (64 KiB): no line of the
                    format is, and the file is never held whole in memory
``out-of-range``    a number written in full that a 64-bit float cannot hold
                    (``1e999``: the spec's numbers are finite unless written
                    ``inf``/``nan``, which the suites judge)
==================  =========================================================

Files are read as a stream (:func:`parse_run`): blocks of bytes, lines found with numpy,
numbers parsed a chunk of about CHUNK_BYTES at a time by pyarrow, no Python per row;
memory is a chunk plus the run's columns.  The first problem in file order is reported.
A ``detail`` is at most DETAIL_MAX characters, and text quoted from the file is repr()-ed
(control characters escaped) and cut.
"""
from __future__ import annotations

import hashlib
import io
import math
import os
import re
import stat as stat_mod
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from ..effects import TESTS
from ..physics.axes import AxisError, parse_plane, parse_signed_axis, plane_handedness

FORMAT = "accelcal-drop/1"

#: Keys every run has (drop-format.md, "Metadata keys every run has").
COMMON_KEYS: tuple[str, ...] = (
    "format", "run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id",
    "started_at", "site_latitude_deg", "g_local_m_s2", "output_unit", "sample_period_s",
)
_CENTRIFUGE_GEOMETRY = ("arm_radius_m", "rotation_sense", "mount_plane", "mount_angle_deg",
                        "vertical_axis")
#: Keys per test kind (drop-format.md, the ``test:`` sections).
TEST_KEYS: dict[str, tuple[str, ...]] = {
    "tumble": ("head_axis", "cos_axis", "sin_axis"),
    "centrifuge": _CENTRIFUGE_GEOMETRY + ("reading_window_s",),
    "tilt_rotation": ("tilt_deg", "sin_axis", "cos_axis", "normal_axis", "positions"),
    "sine_centrifuge": _CENTRIFUGE_GEOMETRY + ("rate_amplitude_rad_s", "rate_frequency_hz"),
}
#: Required keys per test kind: common + per test.
REQUIRED_KEYS: dict[str, tuple[str, ...]] = {t: COMMON_KEYS + TEST_KEYS[t] for t in TESTS}
#: Optional everywhere.
OPTIONAL_KEYS: tuple[str, ...] = ("operator", "notes", "daq_id", "ambient_temp_c")
#: Keys typed as float in ``RunFile.meta`` (``positions`` is int); all others are str.
FLOAT_KEYS = frozenset({
    "site_latitude_deg", "g_local_m_s2", "sample_period_s", "arm_radius_m", "mount_angle_deg",
    "reading_window_s", "tilt_deg", "rate_amplitude_rad_s", "rate_frequency_hz", "ambient_temp_c",
})
INT_KEYS = frozenset({"positions"})
OUTPUT_UNITS = ("mA", "V", "count", "m/s2")
ROTATION_SENSES = ("ccw", "cw")

#: Columns per test kind, in the spec's order (files may order them differently).
COLUMNS: dict[str, tuple[str, ...]] = {
    "tumble": ("time_s", "position", "angle_deg", "output", "temp_c"),
    "centrifuge": ("time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"),
    "tilt_rotation": ("time_s", "temp_set_c", "temp_c", "rotation_deg", "output"),
    "sine_centrifuge": ("time_s", "table_rate_rad_s", "table_angle_deg", "output"),
}
#: Columns read as int64 (all others float64).
INT_COLUMNS = frozenset({"step", "position"})
#: Columns whose cells may be empty (-> NaN): ``temp_c`` (case temperature, may be
#: missing) and the centrifuge's ``table_angle_deg`` (empty while turning).
NULLABLE_COLUMNS: dict[str, frozenset[str]] = {
    "tumble": frozenset({"temp_c"}),
    "centrifuge": frozenset({"table_angle_deg", "temp_c"}),
    "tilt_rotation": frozenset({"temp_c"}),
    "sine_centrifuge": frozenset(),
}

_META_LINE = re.compile(r"^#\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(.*)$")
_NUMBER = re.compile(r"^\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*$",
                     re.IGNORECASE | re.ASCII)
_INTEGER = re.compile(r"^\s*[+-]?\d+\s*$", re.ASCII)


#: Longest refusal detail kept (characters); longer ones are cut with "…".
DETAIL_MAX = 300


def cap_detail(text) -> str:
    text = str(text)
    return text if len(text) <= DETAIL_MAX else text[:DETAIL_MAX - 1] + "…"


class DropFormatError(ValueError):
    """A run file that breaks the drop format (drop-format.md, "What the pipeline must refuse").

    Attributes ``path``, ``line`` (1-based, or None), ``rule`` (short kebab id), ``detail``.
    """

    def __init__(self, path, line: int | None, rule: str, detail: str):
        self.path = str(path)
        self.line = None if line is None else int(line)
        self.rule = rule
        self.detail = cap_detail(detail)
        super().__init__(self.__str__())

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}" if self.detail else f"{where}: {self.rule}"

    def __reduce__(self):  # picklable across process/task boundaries
        return (type(self), (self.path, self.line, self.rule, self.detail))

    def as_refusal(self) -> Refusal:
        return Refusal(self.path, self.line, self.rule, self.detail)


@dataclass(frozen=True)
class Refusal:
    """Why a file (or one of its lines) is refused; same text form as DropFormatError."""

    path: str
    line: int | None
    rule: str
    detail: str

    def __post_init__(self):
        object.__setattr__(self, "detail", cap_detail(self.detail))

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}"


class _Frame:
    """``RunFile.data``: given as a DataFrame, or as a dict of column arrays (what the
    parser makes) from which the DataFrame is made when first asked for.  Ingest and
    validation read the arrays (:attr:`RunFile.arrays`) and never need the DataFrame:
    making it, and looking its columns up, cost about a tenth of a file's ingest."""

    def __get__(self, run, owner=None):
        if run is None:          # no default value for the dataclass field
            raise AttributeError("data")
        d = run.__dict__
        if d.get("_data") is None:
            d["_data"] = pd.DataFrame(d["_arrays"], copy=False)  # in one go: adding a column copies
        return d["_data"]

    def __set__(self, run, value) -> None:
        if isinstance(value, pd.DataFrame):
            run.__dict__.update(_data=value, _arrays=None)
        else:
            run.__dict__.update(_data=None, _arrays=dict(value))


@dataclass(frozen=True, eq=False)
class RunFile:
    """One parsed run file (docs/design.md, schemas.dropformat).

    ``meta``: typed metadata (FLOAT_KEYS float, ``positions`` int, the rest str);
    ``meta_raw``: the values exactly as written (stripped); ``data``: the test's
    columns in COLUMNS order (float64, ``step``/``position`` int64, empty cells NaN)
    plus ``line`` (int64), the 1-based line number of each row (a DataFrame; may be
    given as a dict of arrays, see :attr:`arrays`); ``header_line``: the line number
    of the CSV header; ``meta_lines``: the line of each metadata key (so later checks
    can name it; empty when unknown).
    """

    path: str
    sha256: str
    size_bytes: int
    meta: dict
    meta_raw: dict[str, str]
    data: pd.DataFrame = field(repr=False)
    header_line: int
    meta_lines: dict[str, int] = field(default_factory=dict)

    @property
    def arrays(self) -> dict[str, np.ndarray]:
        """The columns of ``data`` as numpy arrays, in its order (the parser's own arrays,
        without making the DataFrame; else taken out of the DataFrame once)."""
        d = self.__dict__
        if d.get("_arrays") is None:
            d["_arrays"] = {c: self._data[c].to_numpy() for c in self._data.columns}
        return d["_arrays"]

    @property
    def n_rows(self) -> int:
        return len(next(iter(self.arrays.values()), ()))

    @property
    def test(self) -> str:
        return str(self.meta["test"])

    @property
    def run_id(self) -> str:
        return str(self.meta["run_id"])

    def __eq__(self, other) -> bool:
        if not isinstance(other, RunFile):
            return NotImplemented
        return (self.path == other.path and self.sha256 == other.sha256
                and self.size_bytes == other.size_bytes and self.meta == other.meta
                and self.meta_raw == other.meta_raw and self.header_line == other.header_line
                and self.meta_lines == other.meta_lines
                and list(self.data.columns) == list(other.data.columns)
                and list(self.data.dtypes) == list(other.data.dtypes)
                and self.data.reset_index(drop=True).equals(other.data.reset_index(drop=True)))

    def __hash__(self) -> int:
        return hash((self.path, self.sha256))


RunFile.data = _Frame()     # after the dataclass is made: the field keeps no default


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


#: Rules of entries refused without being read (the file rules of issue 12).
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


# --------------------------------------------------------------------------------------
# metadata values ("Metadata keys every run has", per-test key tables)


def _parse_float(path, line, key, text) -> float:
    if not _NUMBER.match(text):
        raise DropFormatError(path, line, "bad-value", f"{key}: {text!r} is not a number")
    v = float(text)
    if not math.isfinite(v):
        raise DropFormatError(path, line, "bad-value", f"{key}: {text!r} is not a finite number")
    return v


def _parse_int(path, line, key, text) -> int:
    if _INTEGER.match(text):
        return int(text)
    v = _parse_float(path, line, key, text)
    if v != int(v):
        raise DropFormatError(path, line, "bad-value", f"{key}: {text!r} is not an integer")
    return int(v)


def _check_started_at(path, line, text) -> None:
    try:
        t = datetime.fromisoformat(text)
    except ValueError:
        raise DropFormatError(path, line, "bad-value",
                              f"started_at: {text!r} is not an ISO 8601 time") from None
    if t.tzinfo is None or t.utcoffset() is None or len(text) <= 10:
        raise DropFormatError(path, line, "bad-value",
                              f"started_at: {text!r} has no UTC offset (e.g. +08:00)")


def _typed_meta(path, raw: dict[str, str], lines: dict[str, int]) -> dict:
    """Type and check every value, in file order (first problem wins)."""
    test = raw["test"]
    meta: dict = {}
    for key in sorted(raw, key=lambda k: lines[k]):
        text, ln = raw[key], lines[key]
        if key in FLOAT_KEYS:
            meta[key] = _parse_float(path, ln, key, text)
        elif key in INT_KEYS:
            meta[key] = _parse_int(path, ln, key, text)
        else:
            meta[key] = text
            if key in REQUIRED_KEYS[test] and text == "":
                raise DropFormatError(path, ln, "bad-value", f"{key} is empty")
        if key == "started_at":
            _check_started_at(path, ln, text)
        elif key == "output_unit" and text not in OUTPUT_UNITS:
            raise DropFormatError(path, ln, "bad-value",
                                  f"output_unit {text!r} is not one of {', '.join(OUTPUT_UNITS)}")
        elif key == "rotation_sense" and text not in ROTATION_SENSES:
            raise DropFormatError(path, ln, "bad-value", f"rotation_sense {text!r} is not ccw or cw")
        elif key == "positions" and meta[key] < 1:
            raise DropFormatError(path, ln, "bad-value", f"positions {text!r} must be >= 1")
        elif key in ("sample_period_s", "arm_radius_m", "reading_window_s",
                     "rate_frequency_hz", "g_local_m_s2") and meta[key] <= 0:
            raise DropFormatError(path, ln, "bad-value", f"{key} {text!r} must be > 0")
    _check_axes(path, test, raw, lines)
    return meta


def _check_axes(path, test, raw, lines) -> None:
    """Axes via accelcal.physics.axes (drop-format.md, "Axes and angles" and the test sections)."""
    def axis(key):
        try:
            return parse_signed_axis(raw[key])[0]
        except AxisError as e:
            raise DropFormatError(path, lines[key], "bad-axis", f"{key}: {e}") from None

    if test in ("tumble", "tilt_rotation"):
        keys = ("head_axis", "cos_axis", "sin_axis") if test == "tumble" else \
               ("sin_axis", "cos_axis", "normal_axis")
        seen: dict[int, str] = {}
        for k in sorted(keys, key=lambda k: lines[k]):
            a = axis(k)
            if a in seen:
                raise DropFormatError(path, lines[k], "bad-axis",
                                      f"{k} {raw[k]!r} is the same axis as {seen[a]} {raw[seen[a]]!r}"
                                      f"; {', '.join(keys)} must be the three distinct axes")
            seen[a] = k
    else:  # centrifuge, sine_centrifuge
        try:
            parse_plane(raw["mount_plane"])
        except AxisError as e:
            raise DropFormatError(path, lines["mount_plane"], "bad-axis", f"mount_plane: {e}") from None
        axis("vertical_axis")
        try:
            plane_handedness(raw["mount_plane"], raw["vertical_axis"])
        except AxisError as e:
            raise DropFormatError(path, lines["vertical_axis"], "bad-axis",
                                  f"vertical_axis must be the third axis: {e}") from None


# --------------------------------------------------------------------------------------
# the file, read as a stream: memory is bounded by a chunk, not by the file

#: Bytes read at a time, and (about) the bytes of rows parsed at a time.
BLOCK_BYTES = 1 << 20
CHUNK_BYTES = 4 << 20
#: Longest line a run file may have.  The spec's lines are short (a key, a header of a few
#: names, a row of a few numbers); a longer one is refused (``line-too-long``) without
#: ever being held whole in memory.
LINE_MAX = 1 << 16
_BOM = b"\xef\xbb\xbf"
_IS_BLANK_BYTE = np.zeros(256, dtype=bool)
_IS_BLANK_BYTE[[0x20, 0x09, 0x0B, 0x0C]] = True        # \r is dealt with as part of \r\n
_LITERAL_INF = r"^\s*[+-]?inf(inity)?\s*$"


class _Stream:
    """Lines, then chunks of whole lines, of a binary file object; hashes every byte read."""

    def __init__(self, fh, path: str):
        self.fh, self.path = fh, path
        self.hash = hashlib.sha256()
        self.size = 0
        self.buf = b""
        self.pos = 0           # next unread byte of buf
        self.offset = 0        # file offset of buf[0]
        self.line = 0          # lines handed out so far
        self.eof = False

    def _block(self) -> bytes:
        if self.eof:
            return b""
        data = self.fh.read(BLOCK_BYTES)
        if not data:
            self.eof = True
            return b""
        self.hash.update(data)
        self.size += len(data)
        return data

    def _too_long(self, line: int, n: int) -> DropFormatError:
        return DropFormatError(self.path, line, "line-too-long",
                               f"more than {LINE_MAX} bytes ({n:,} read) without a line end; "
                               "no line of a run file is that long")

    def readline(self):
        """(line bytes without its \\n, line number, file offset, ends with \\n) or None at EOF."""
        while True:
            k = self.buf.find(b"\n", self.pos)
            if k >= 0:
                term = True
                break
            if len(self.buf) - self.pos > LINE_MAX:
                raise self._too_long(self.line + 1, len(self.buf) - self.pos)
            data = self._block()
            if not data:
                if self.pos >= len(self.buf):
                    return None
                k, term = len(self.buf), False
                break
            self.offset += self.pos
            self.buf, self.pos = self.buf[self.pos:] + data, 0
        line = self.buf[self.pos:k]
        if len(line) > LINE_MAX:
            raise self._too_long(self.line + 1, len(line))
        self.line += 1
        off = self.offset + self.pos
        self.pos = k + 1 if term else k
        return line, self.line, off, term

    def chunks(self):
        """The rest of the file as (bytes, number of its first line, file offset, is last):
        whole lines of about CHUNK_BYTES, the last chunk possibly without a final \\n."""
        pending = self.buf[self.pos:]
        offset = self.offset + self.pos
        first = self.line + 1
        self.buf, self.pos = b"", 0
        grow = False               # the pending bytes hold no line end yet: read on
        while True:
            blocks, n = [pending], len(pending)
            while n < CHUNK_BYTES or grow:
                grow = False
                data = self._block()
                if not data:
                    break
                blocks.append(data)
                n += len(data)
            buf = b"".join(blocks) if len(blocks) > 1 else blocks[0]
            del blocks
            if self.eof:
                if buf:
                    yield buf, first, offset, True
                return
            k = buf.rfind(b"\n")
            if k < 0:
                if len(buf) > LINE_MAX:
                    raise self._too_long(first, len(buf))
                pending, grow = buf, True
                continue
            chunk, pending = buf[:k + 1], buf[k + 1:]
            del buf
            if len(pending) > LINE_MAX:
                raise self._too_long(first + chunk.count(b"\n"), len(pending))
            yield chunk, first, offset, False
            first += chunk.count(b"\n")
            offset += len(chunk)


def _decode_line(path, line: bytes, ln: int, off: int) -> str:
    try:
        return line.decode("utf-8")
    except UnicodeDecodeError as e:
        raise DropFormatError(path, ln, "not-utf8",
                              f"byte 0x{line[e.start]:02x} at byte offset {off + e.start} is not "
                              f"UTF-8 ({e.reason})") from None


def read_run(path) -> RunFile:
    """Read and structurally check one run file (drop-format.md, "A run file").

    Raises DropFormatError naming the file, the line and the rule broken.  The file is
    read once, in blocks; memory is bounded by a chunk of rows plus the parsed columns.
    """
    with open(path, "rb", buffering=0) as fh:
        return parse_run(fh, path)


def parse_run(fh, path) -> RunFile:
    """:func:`read_run` on an open binary file object (or ``io.BytesIO``); ``path`` names
    it in messages.  ``RunFile.sha256`` and ``size_bytes`` are those of the bytes read."""
    spath = str(path)
    st = _Stream(fh, spath)
    meta, raw_meta, key_line, names, header_line, hterm = _parse_head(st, spath)
    test = meta["test"]

    # ---- rows, a chunk at a time (numpy finds the lines, pyarrow parses the numbers)
    try:
        size_hint = os.fstat(fh.fileno()).st_size
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        size_hint = len(fh.getbuffer()) if hasattr(fh, "getbuffer") else None
    body = _Body(spath, test, names, size_hint)
    if hterm:
        for chunk, first, offset, last in st.chunks():
            body.add(chunk, first, offset, last)
    if body.n_rows == 0:
        raise DropFormatError(spath, header_line, "no-data", "a header but no data rows")
    data = body.columns()       # RunFile.data makes the DataFrame when it is asked for
    return RunFile(path=spath, sha256=st.hash.hexdigest(), size_bytes=st.size, meta=meta,
                   meta_raw=raw_meta, data=data, header_line=header_line, meta_lines=key_line)


def _parse_head(st: _Stream, spath: str):
    """The metadata block and the CSV header of a run file read by ``st``, checked (the
    first problem raised, as :func:`parse_run` does): (typed meta, raw meta, line of each
    key, column names, header line number, header ends with a line end)."""
    # ---- metadata block, line by line
    raw_meta: dict[str, str] = {}
    key_line: dict[str, int] = {}
    header = None                       # (text, line number, ends with \n)
    last_term, last_ln, seen_text = True, 0, False
    while True:
        got = st.readline()
        if got is None:
            break
        line, ln, off, term = got
        last_term, last_ln = term, ln
        if ln == 1 and line.startswith(_BOM):      # a UTF-8 byte-order mark is still UTF-8
            line, off = line[3:], off + 3
        text = _decode_line(spath, line, ln, off)
        if text.endswith("\r") and term:
            text = text[:-1]
        if "\r" in text:
            raise DropFormatError(spath, ln, "bad-line-end",
                                  "a lone carriage return; line ends must be \\n or \\r\\n")
        s = text.strip()
        if not s:
            continue
        seen_text = True
        if not s.startswith("#"):
            header = (text, ln, term)
            break
        m = _META_LINE.match(s)
        if not m:
            if not raw_meta:
                raise DropFormatError(spath, ln, "no-metadata",
                                      f"the file must start with '# format: {FORMAT}', found {s[:60]!r}")
            raise DropFormatError(spath, ln, "metadata-syntax" if term else "truncated",
                                  f"{s[:60]!r} is not '# key: value'")
        key, value = m.group(1), m.group(2).strip()
        if not raw_meta and key != "format":
            raise DropFormatError(spath, ln, "format-not-first",
                                  f"the first metadata line must be '# format: {FORMAT}', found key {key!r}")
        if key in raw_meta:
            raise DropFormatError(spath, ln, "duplicate-key",
                                  f"{key} given again (first on line {key_line[key]})")
        raw_meta[key] = value
        key_line[key] = ln
    if not seen_text:
        what = "is empty" if st.size == 0 else "holds only blank lines"
        raise DropFormatError(spath, None, "empty-file", f"the file {what} ({st.size} bytes)")
    if not raw_meta:
        raise DropFormatError(spath, header[1], "no-metadata",
                              f"the file must start with '# format: {FORMAT}', found "
                              f"{header[0].strip()[:60]!r}")
    cut = header is None and not last_term      # the file ends inside the metadata block
    if raw_meta["format"] != FORMAT:
        raise DropFormatError(spath, key_line["format"], "unknown-format",
                              f"format {raw_meta['format']!r} is not {FORMAT!r}")
    if "test" not in raw_meta:
        raise DropFormatError(spath, None, "truncated" if cut else "missing-key",
                              "required key 'test' is missing")
    test = raw_meta["test"]
    if test not in TESTS:
        raise DropFormatError(spath, key_line["test"], "unknown-test",
                              f"test {test!r} is not one of {', '.join(TESTS)}")
    missing = [k for k in REQUIRED_KEYS[test] if k not in raw_meta]
    if missing:
        if cut:
            raise DropFormatError(spath, last_ln, "truncated",
                                  f"the file ends inside the metadata block (missing {', '.join(missing)})")
        raise DropFormatError(spath, None, "missing-key",
                              f"required key{'s' if len(missing) > 1 else ''} "
                              f"{', '.join(missing)} missing for test {test}")
    if header is None:
        raise DropFormatError(spath, last_ln if cut else None, "truncated" if cut else "no-header",
                              "the metadata block is not followed by a CSV header line")
    meta = _typed_meta(spath, raw_meta, key_line)

    # ---- header
    htext, header_line, hterm = header
    names = [c.strip() for c in htext.split(",")]
    want = COLUMNS[test]
    dup = sorted({c for c in names if names.count(c) > 1})
    miss = [c for c in want if c not in names]
    extra = [c for c in names if c not in want]
    if dup or miss or extra:
        parts = []
        if miss:
            parts.append("missing " + ", ".join(miss))
        if extra:
            parts.append("unexpected " + ", ".join(repr(c[:40]) for c in extra[:5])
                         + (f" and {len(extra) - 5} more" if len(extra) > 5 else ""))
        if dup:
            parts.append("repeated " + ", ".join(dup))
        raise DropFormatError(spath, header_line, "bad-columns" if hterm else "truncated",
                              f"columns for {test} must be {', '.join(want)}: {'; '.join(parts)}")
    return meta, raw_meta, key_line, names, header_line, hterm


def parse_runs(items) -> list:
    """:func:`parse_run` on many small files held as bytes, ``items`` [(bytes, path)]: for
    each, the RunFile that parse_run gives, or the DropFormatError it raises (returned,
    not raised), in order.

    Why: pyarrow's CSV reader costs ~0.2 ms a call whatever the size, a run file's rows
    ~0.04 ms.  The metadata block and header of each file are read and checked by
    parse_run's own code; the rows of every file whose rows are plain (only ASCII digits,
    signs, points, exponents and commas -- no space, CR, blank line or byte >= 0x80 --
    ending with a line end, under LINE_MAX) are parsed together, one pyarrow call for the
    files of one header line, and cut back per file by their row counts.  Whenever that
    leaves any doubt -- the joint parse fails, a file's rows hold an empty cell where none
    may be, an infinity, a non-integral step -- the file (or the header line's files) is
    parsed alone by parse_run, so every refusal is parse_run's, word for word, and every
    RunFile equals parse_run's (tests/test_dropformat_batch.py)."""
    out: list = [None] * len(items)
    groups: dict[tuple, list] = {}        # (test, header names) -> [(index, head, body, rows)]
    for i, (raw, path) in enumerate(items):
        spath = str(path)
        st = _Stream(io.BytesIO(raw), spath)
        try:
            head = _parse_head(st, spath)
        except DropFormatError as e:
            out[i] = e
            continue
        body = st.buf[st.pos:]
        rows = body.count(b"\n")
        if not (head[5] and st.size == len(raw) and rows and body.endswith(b"\n")
                and _plain_rows(body)):
            out[i] = _parse_one(raw, spath)
            continue
        groups.setdefault((head[0]["test"], tuple(head[3])), []).append((i, head, st, body, rows))
    for (test, names), files in groups.items():
        try:
            tbl = _rows_of(list(names), b"".join(f[3] for f in files))
        except pa.ArrowException:
            tbl = None
        if tbl is None or tbl.num_rows != sum(f[4] for f in files):
            for i, *_ in files:
                out[i] = _parse_one(*items[i])
            continue
        cols = {c: tbl.column(c) for c in COLUMNS[test]}
        whole = {c: col.to_numpy() for c, col in cols.items()}
        nullable = NULLABLE_COLUMNS[test]
        start = 0
        for i, head, st, body, m in files:
            arrays = _plain_arrays(test, whole, cols, nullable, start, m)
            start += m
            if arrays is None:
                out[i] = _parse_one(*items[i])
                continue
            meta, raw_meta, key_line, _, header_line, _ = head
            arrays["line"] = np.arange(header_line + 1, header_line + 1 + m, dtype=np.int64)
            out[i] = RunFile(path=st.path, sha256=st.hash.hexdigest(), size_bytes=st.size,
                             meta=meta, meta_raw=raw_meta, data=arrays, header_line=header_line,
                             meta_lines=key_line)
    return out


def _parse_one(raw: bytes, path):
    try:
        return parse_run(io.BytesIO(raw), path)
    except DropFormatError as e:
        return e


#: The bytes of plain rows: digits, ``+-.eE`` and commas (``nan``/``inf`` and spaces are
#: left to parse_run); line ends are \n only.
_PLAIN_BYTE = np.zeros(256, dtype=bool)
_PLAIN_BYTE[np.frombuffer(b"0123456789+-.eE,\n", dtype=np.uint8)] = True


def _plain_rows(body: bytes) -> bool:
    """Rows parse_run would read as they are: only plain bytes, no blank line, no line
    longer than LINE_MAX (``body`` ends with a line end)."""
    b = np.frombuffer(body, dtype=np.uint8)
    if not _PLAIN_BYTE[b].all() or body.startswith(b"\n") or b"\n\n" in body:
        return False
    return len(body) <= LINE_MAX or int(np.diff(np.flatnonzero(b == 10), prepend=-1).max()) <= LINE_MAX


def _rows_of(names: list[str], buf: bytes) -> pa.Table:
    """The rows of files sharing a header, read as parse_run reads them (float64, empty
    cells null), in one call."""
    return pacsv.read_csv(pa.py_buffer(buf),
                          read_options=_csv_read_options(names, max(len(buf), 1) + 1),
                          parse_options=_CSV_PARSE,
                          convert_options=_csv_convert_options(names, pa.float64()))


#: How a run file's rows are split into cells: no quoting or escapes (drop-format.md), and
#: an empty line is a row (refused as such), not skipped.  parse_run and parse_runs alike.
_CSV_PARSE = pacsv.ParseOptions(quote_char=False, double_quote=False, escape_char=False,
                                ignore_empty_lines=False)


def _csv_read_options(names: list[str], block_size: int) -> pacsv.ReadOptions:
    return pacsv.ReadOptions(column_names=names, use_threads=False, block_size=block_size)


def _csv_convert_options(names: list[str], typ, columns=None) -> pacsv.ConvertOptions:
    """Every column as ``typ``, an empty cell null and nothing else."""
    return pacsv.ConvertOptions(
        column_types={c: typ for c in names}, include_columns=columns, null_values=[""],
        strings_can_be_null=False, quoted_strings_can_be_null=False, check_utf8=False)


def _plain_arrays(test, whole, cols, nullable, start: int, m: int) -> dict | None:
    """One file's rows cut out of the joint parse, typed as parse_run types them, or None
    when parse_run must judge them (an empty cell where none may be, an infinity, a
    non-integral step/position)."""
    arrays = {}
    for c in COLUMNS[test]:
        v = whole[c][start:start + m]
        if c not in nullable and cols[c].null_count and np.isnan(v).any():
            return None     # NaN here is an empty cell: ``nan`` is not a plain row
        if np.isinf(v).any():
            return None
        if c in INT_COLUMNS:
            ok = np.isnan(v) if c in nullable else np.zeros(len(v), dtype=bool)
            ok |= np.isfinite(v) & (v == np.round(v)) & (np.abs(v) < 2.0 ** 53)
            if not ok.all():
                return None
            v = v.astype(np.int64)
        else:
            v = v.copy()    # its own array: a run kept does not keep the whole joint parse
        arrays[c] = v
    return arrays


def _excerpt(text: str, n: int = 40) -> str:
    """A cell or line quoted for a message: repr (escapes control characters), at most n
    characters of it, and its length when cut."""
    text = text.strip()
    if len(text) <= n:
        return repr(text)
    return f"{text[:n]!r}… ({len(text):,} characters)"


class _BadCell(Exception):
    def __init__(self, row: int, error: DropFormatError):
        self.row, self.error = row, error


#: A parsed column buffer of at least this many bytes is handed out as a view, not copied
#: to its exact length (_Body.columns).
VIEW_BYTES = 16 << 20


class _Body:
    """The data rows of one run, parsed a chunk at a time into per-column arrays."""

    def __init__(self, path: str, test: str, names: list[str], size_hint: int | None = None):
        self.path, self.test, self.names = path, test, names
        self.size_hint = size_hint          # bytes of the file, to size the arrays once
        self.cols: dict[str, np.ndarray] = {}
        self.n_rows = 0
        self.bytes_seen = 0
        self._read = _csv_read_options(names, CHUNK_BYTES + LINE_MAX + 1)

    # -- one chunk --------------------------------------------------------------------
    def add(self, chunk: bytes, first: int, offset: int, last: bool) -> None:
        b = np.frombuffer(chunk, dtype=np.uint8)
        n = len(b)
        nl = np.flatnonzero(b == 10)
        ends_nl = n > 0 and chunk[-1] == 10
        starts = np.concatenate(([0], nl + 1))
        ends = np.concatenate((nl, [n]))
        if ends_nl:
            starts, ends = starts[:-1], ends[:-1]
        line_no = first + np.arange(len(starts), dtype=np.int64)
        problems: list[tuple[int, int, str, str]] = []     # (line, order, rule, detail)

        def line_of(pos: int) -> int:
            return first + int(np.searchsorted(nl, pos))

        if n and int(b.max()) >= 0x80:
            try:
                chunk.decode("utf-8")
            except UnicodeDecodeError as e:
                problems.append((line_of(e.start), 0, "not-utf8",
                                 f"byte 0x{chunk[e.start]:02x} at byte offset {offset + e.start} "
                                 f"is not UTF-8 ({e.reason})"))
        raw_ends = ends
        cr = np.flatnonzero(b == 13)
        if cr.size:
            nxt = np.minimum(cr + 1, n - 1)
            lone = cr[(cr + 1 >= n) | (b[nxt] != 10)]
            if lone.size:
                problems.append((line_of(int(lone[0])), 1, "bad-line-end",
                                 "a lone carriage return; line ends must be \\n or \\r\\n"))
            has_cr = (ends > starts) & (b[np.maximum(ends - 1, 0)] == 13)
            ends = ends - has_cr
        lens = ends - starts
        long_ = np.flatnonzero(lens > LINE_MAX)
        if long_.size:
            i = int(long_[0])
            problems.append((int(line_no[i]), 2, "line-too-long",
                             f"a line of {int(lens[i]):,} bytes; no line of a run file is longer "
                             f"than {LINE_MAX}"))
        blanks = np.flatnonzero(_IS_BLANK_BYTE[b])
        blank = lens == (np.searchsorted(blanks, ends) - np.searchsorted(blanks, starts))
        commas = np.flatnonzero(b == 44)
        nfields = np.searchsorted(commas, ends) - np.searchsorted(commas, starts) + 1
        cut = last and not ends_nl           # the chunk's last line is the file's, unfinished
        bad = np.flatnonzero(~blank & (nfields != len(self.names)))
        if bad.size:
            i = int(bad[0])
            short = cut and i == len(starts) - 1
            problems.append((int(line_no[i]), 3, "truncated" if short else "field-count",
                             f"{'the file ends mid-row: ' if short else ''}"
                             f"{int(nfields[i])} fields, the header has {len(self.names)}"))
        if cut and len(starts) and not blank[-1] and chunk[starts[-1]:ends[-1]].rstrip().endswith(b","):
            problems.append((int(line_no[-1]), 3, "truncated",
                             "the file ends mid-row: the last line ends with an empty field "
                             "and no line end"))
        limit = min(problems)[0] if problems else None
        rows = np.flatnonzero(~blank if limit is None else (~blank & (line_no < limit)))
        if rows.size:
            self._numbers(chunk, b, starts, ends, raw_ends, rows, line_no, cut)
        if problems:
            ln, _, rule, detail = min(problems)
            raise DropFormatError(self.path, ln, rule, detail)

    def _numbers(self, chunk, b, starts, ends, raw_ends, rows, line_no, cut) -> None:
        """Parse the non-blank rows ``rows`` of the chunk; raise the first bad cell."""
        n = len(b)
        k = int(rows[-1])
        stop = min(int(raw_ends[k]) + 1, n)      # through row k's line end
        if rows.size == k + 1:                   # rows 0..k, none blank: the bytes as they are
            buf = pa.py_buffer(chunk)
            if stop < n:
                buf = buf.slice(0, stop)
        else:                                    # leave the blank lines out
            mark = np.zeros(n + 1, dtype=np.int8)
            mark[starts[rows]] += 1
            mark[np.minimum(raw_ends[rows] + 1, n)] -= 1
            buf = pa.py_buffer(b[np.cumsum(mark[:n], dtype=np.int8) > 0].tobytes())
        rlines = line_no[rows]
        last_row = len(rows) - 1 if cut and k == len(starts) - 1 else -1

        def row_text(j: int) -> str:
            i = int(rows[j])
            return chunk[int(starts[i]):int(ends[i])].decode("utf-8", "replace")

        def cell(j: int, c: str) -> str:
            return row_text(j).split(",")[self.names.index(c)]

        found: list[tuple[int, int, str, str]] = []     # (row, column order, rule, detail)
        try:
            tbl = self._csv(buf, pa.float64())
        except pa.ArrowException:
            try:
                tbl = self._floats_via_text(buf, rlines, last_row)
            except _BadCell as bad:
                if bad.row > 0:      # a problem in the rows before it comes first
                    self._numbers(chunk, b, starts, ends, raw_ends, rows[:bad.row], line_no, cut)
                raise bad.error from None
        nullable = NULLABLE_COLUMNS[self.test]
        cols: dict[str, np.ndarray] = {}
        for o, c in enumerate(COLUMNS[self.test]):
            col = tbl.column(c)
            v = col.to_numpy(zero_copy_only=False)
            if col.null_count and c not in nullable:
                j = int(np.flatnonzero(col.is_null().to_numpy(zero_copy_only=False))[0])
                found.append((j, o, "truncated" if j == last_row else "empty-value",
                              f"{c} is empty; the spec allows empty cells only in "
                              f"{', '.join(sorted(nullable)) or 'no column'} for {self.test}"))
            inf = np.flatnonzero(np.isinf(v))
            if inf.size:
                lit = self._csv(buf, pa.string(), [c]).column(c)
                lit = np.asarray(pc.match_substring_regex(lit, _LITERAL_INF, ignore_case=True)
                                 .to_numpy(zero_copy_only=False), dtype=bool)
                over = inf[~lit[inf]]
                if over.size:
                    j = int(over[0])
                    found.append((j, o, "out-of-range",
                                  f"{c}: {_excerpt(cell(j, c))} is a number too large for a "
                                  "64-bit float"))
            if c in INT_COLUMNS:
                ok = np.isnan(v) if c in nullable else np.zeros(len(v), dtype=bool)
                ok |= np.isfinite(v) & (v == np.round(v)) & (np.abs(v) < 2.0 ** 53)
                if not ok.all():
                    j = int(np.flatnonzero(~ok)[0])
                    found.append((j, o, "not-integer",
                                  f"{c} value {_excerpt(cell(j, c))} is not an integer"))
                    continue
                v = v.astype(np.int64)
            cols[c] = v
        if found:
            j, _, rule, detail = min(found)
            raise DropFormatError(self.path, int(rlines[j]), rule, detail)
        cols["line"] = rlines
        self._store(cols, len(rows), stop)

    def _store(self, cols: dict[str, np.ndarray], m: int, nbytes: int) -> None:
        """Append m rows.  The arrays are allocated once, sized from the rows per byte of the
        first chunk and the file's size (pages never written cost no memory), and grown
        only when later rows are denser: no list of pieces to concatenate at the end."""
        n = self.n_rows
        self.bytes_seen += nbytes
        cap = len(self.cols["line"]) if self.cols else 0
        if n + m > cap:
            est = (n + m) * (self.size_hint or 0) / max(self.bytes_seen, 1)
            new_cap = int(max(n + m, 1.1 * est, 1.25 * cap)) + 1024
            for c, v in cols.items():
                a = np.empty(new_cap, dtype=v.dtype)
                if n:
                    a[:n] = self.cols[c][:n]
                self.cols[c] = a
        for c, v in cols.items():
            self.cols[c][n:n + m] = v
        self.n_rows = n + m

    def _csv(self, buf, typ, columns=None) -> pa.Table:
        return pacsv.read_csv(buf, read_options=self._read, parse_options=_CSV_PARSE,
                              convert_options=_csv_convert_options(self.names, typ, columns))

    def _floats_via_text(self, buf, rlines, last_row) -> pa.Table:
        """When pyarrow refuses a cell: find the first cell that is not a number in the
        spec's form (and refuse it), or convert the cells pyarrow refused but the spec
        allows (blank cells: spaces only, which are empty)."""
        tbl = self._csv(buf, pa.string())
        best = None
        for c in self.names:
            col = tbl.column(c)
            ok = pc.or_(pc.match_substring_regex(col, _NUMBER.pattern, ignore_case=True),
                        pc.equal(pc.utf8_trim_whitespace(col), ""))
            bad = np.flatnonzero(~np.asarray(ok.to_numpy(zero_copy_only=False), dtype=bool))
            if bad.size and (best is None or bad[0] < best[0]):
                best = (int(bad[0]), c, col[int(bad[0])].as_py())
        if best is not None:
            j, c, text = best
            short = j == last_row
            raise _BadCell(j, DropFormatError(
                self.path, int(rlines[j]), "truncated" if short else "non-numeric",
                f"{'the file ends mid-row: ' if short else ''}"
                f"column {c}: {_excerpt(text)} is not a number"))
        cols = []
        for c in self.names:
            t = pc.utf8_trim_whitespace(tbl.column(c))
            cols.append(pc.cast(pc.if_else(pc.equal(t, ""), pa.scalar(None, pa.string()), t),
                                pa.float64()))
        return pa.table(cols, names=self.names)

    # -- the run ----------------------------------------------------------------------
    def columns(self) -> dict[str, np.ndarray]:
        """The run's columns (COLUMNS order, then ``line``), each an array of n_rows.

        Copied out of the growing buffers when those are larger (their capacity is an
        estimate plus 1,024 rows: ~3x a 500-row run): a batch holds its parsed runs until
        validation, and views would keep every buffer whole (a worker's peak grew by ~80 MB
        over batches of 550 files).  A big run's buffers are not copied (VIEW_BYTES): that
        copy doubled its columns for a moment (a 5 M-row run: +280 MB), while the pages of
        the unused tail, never written, hold no memory."""
        n = self.n_rows
        cols = {c: self.cols[c][:n] if len(self.cols[c]) == n or self.cols[c].nbytes >= VIEW_BYTES
                else self.cols[c][:n].copy() for c in (*COLUMNS[self.test], "line")}
        self.cols = {}
        return cols
