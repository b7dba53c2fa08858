"""Parser of lab data drops, format ``accelcal-drop/1`` (shared/spec/drop-format.md).

This module implements the *structural* half of the contract: everything the
spec says about "A drop" and "A run file", the metadata keys ("Metadata keys
every run has" and the per-test key tables), the columns of each test, and the
parser-level part of "What the pipeline must refuse". The semantic rules that
need the numbers (NaN/inf in ``output``, time going backwards, negative
centrifuge rates, header-vs-data consistency) live in :mod:`accelcal.schemas.suites`.
Which entries of a drop are run files, and which are refused without being opened, is
:mod:`accelcal.schemas.dropscan`; the keys, columns and the refusal itself are
:mod:`accelcal.schemas.dropspec`; the data rows are parsed by :mod:`accelcal.schemas.runbody`.

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
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np
import pandas as pd
import pyarrow as pa

from ..physics.axes import AxisError, parse_plane, parse_signed_axis, plane_handedness
from .dropspec import (BLOCK_BYTES, CHUNK_BYTES, COLUMNS, FLOAT_KEYS, FORMAT, INT_KEYS, LINE_MAX,
                       NULLABLE_COLUMNS, OUTPUT_UNITS, REQUIRED_KEYS, ROTATION_SENSES, _INTEGER,
                       _META_LINE, _NUMBER, DropFormatError, check_test)
from .runbody import _Body, _plain_arrays, _plain_rows, _rows_of


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
            a = d["_arrays"]
            if hasattr(a, "rows"):      # a run in its Parquet file: read whole, not kept
                return pd.DataFrame({c: a[c] for c in a}, copy=False)
            d["_data"] = pd.DataFrame(a, copy=False)  # in one go: adding a column copies
        return d["_data"]

    def __set__(self, run, value) -> None:
        if isinstance(value, pd.DataFrame):
            run.__dict__.update(_data=value, _arrays=None)
        elif hasattr(value, "rows"):    # columns in a Parquet file, read when asked for
            run.__dict__.update(_data=None, _arrays=value)
        else:
            run.__dict__.update(_data=None, _arrays=dict(value))


@dataclass(frozen=True, eq=False)
class RunFile:
    """One parsed run file (docs/design.md, schemas.dropformat).

    ``meta``: typed metadata (FLOAT_KEYS float, ``positions`` int, the rest str);
    ``meta_raw``: the values exactly as written (stripped); ``data``: the test's
    columns in COLUMNS order (float64, ``step``/``position`` int64, empty cells NaN)
    plus ``line`` (int64), the 1-based line number of each row (a DataFrame; may be
    given as a dict of arrays, see :attr:`arrays`, or as the columns of the run's Parquet
    file, :class:`accelcal.schemas.tables.ParquetColumns`, read when asked for and never
    kept: a run parsed into that file); ``header_line``: the line number
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
        a = self.arrays
        if hasattr(a, "n_rows"):        # columns in a Parquet file: counted there
            return int(a.n_rows)
        return len(next(iter(a.values()), ()))

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

_BOM = b"\xef\xbb\xbf"


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


def parse_run(fh, path, stream=None) -> RunFile:
    """:func:`read_run` on an open binary file object (or ``io.BytesIO``); ``path`` names
    it in messages.  ``RunFile.sha256`` and ``size_bytes`` are those of the bytes read.

    ``stream``: a :class:`accelcal.schemas.tables.RunParquetStream` that takes the rows as
    they are parsed: it is opened with the run's metadata once the head is read,
    gets every chunk's rows, and the RunFile's columns are then those of its Parquet file,
    read when asked for.  The caller commits or aborts it."""
    spath = str(path)
    st = _Stream(fh, spath)
    meta, raw_meta, key_line, names, header_line, hterm = _parse_head(st, spath)
    test = meta["test"]
    if stream is not None:
        stream.open(RunFile(path=spath, sha256=stream.sha256, size_bytes=stream.size_bytes,
                            meta=meta, meta_raw=raw_meta, data={}, header_line=header_line,
                            meta_lines=key_line))

    # ---- rows, a chunk at a time (numpy finds the lines, pyarrow parses the numbers)
    try:
        size_hint = os.fstat(fh.fileno()).st_size
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        size_hint = len(fh.getbuffer()) if hasattr(fh, "getbuffer") else None
    body = _Body(spath, test, names, size_hint, sink=stream)
    if hterm:
        for chunk, first, offset, last in st.chunks():
            body.add(chunk, first, offset, last)
    if body.n_rows == 0:
        raise DropFormatError(spath, header_line, "no-data", "a header but no data rows")
    if stream is not None:
        data = stream.columns((*COLUMNS[test], "line"), body.n_rows)
    else:
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
    test = check_test(spath, key_line["test"], raw_meta["test"])
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

