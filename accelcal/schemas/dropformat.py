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
==================  =========================================================
"""
from __future__ import annotations

import hashlib
import math
import re
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
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


class DropFormatError(ValueError):
    """A run file that breaks the drop format (drop-format.md, "What the pipeline must refuse").

    Attributes ``path``, ``line`` (1-based, or None), ``rule`` (short kebab id), ``detail``.
    """

    def __init__(self, path, line: int | None, rule: str, detail: str):
        self.path = str(path)
        self.line = None if line is None else int(line)
        self.rule = rule
        self.detail = detail
        super().__init__(self.__str__())

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}"

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

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}"


@dataclass(frozen=True, eq=False)
class RunFile:
    """One parsed run file (docs/design.md, schemas.dropformat).

    ``meta``: typed metadata (FLOAT_KEYS float, ``positions`` int, the rest str);
    ``meta_raw``: the values exactly as written (stripped); ``data``: the test's
    columns in COLUMNS order (float64, ``step``/``position`` int64, empty cells NaN)
    plus ``line`` (int64), the 1-based line number of each row; ``header_line``: the
    line number of the CSV header; ``meta_lines``: the line of each metadata key
    (so later checks can name it; empty when unknown).
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


def discover(drop_dir) -> list[Path]:
    """Every run file of a drop (drop-format.md, "A drop"): ``*.csv`` at any depth, sorted.

    Other files (``*.log``, ``*.txt``, ``Thumbs.db``, partial copies ``*.csv.part``) are ignored;
    so are directories that happen to be named ``*.csv``.
    """
    root = Path(drop_dir)
    return sorted(p for p in root.rglob("*") if p.suffix.lower() == ".csv" and p.is_file())


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
# the file


def _decode(path, raw: bytes) -> str:
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise DropFormatError(path, line, "not-utf8",
                              f"byte 0x{raw[e.start]:02x} at byte offset {e.start} is not UTF-8 "
                              f"({e.reason})") from None
    if text.startswith("\ufeff"):  # a UTF-8 byte-order mark is still UTF-8
        text = text[1:]
    return text


def read_run(path) -> RunFile:
    """Read and structurally check one run file (drop-format.md, "A run file").

    Raises DropFormatError naming the file, the line and the rule broken.
    """
    p = Path(path)
    spath = str(path)
    raw = p.read_bytes()
    sha = hashlib.sha256(raw).hexdigest()
    if not raw.strip():
        raise DropFormatError(spath, None, "empty-file", f"the file is empty ({len(raw)} bytes)")
    text = _decode(spath, raw)
    if not text.strip():
        raise DropFormatError(spath, None, "empty-file", f"the file holds only blank lines ({len(raw)} bytes)")
    if "\r" in text:
        text = text.replace("\r\n", "\n")
        if "\r" in text:
            ln = text.count("\n", 0, text.index("\r")) + 1
            raise DropFormatError(spath, ln, "bad-line-end",
                                  "a lone carriage return; line ends must be \\n or \\r\\n")
    ends_nl = text.endswith("\n")
    lines = text.split("\n")
    if ends_nl:
        lines.pop()
    nlines = len(lines)

    def cut_short(rule_if_not: str) -> str:
        return "truncated" if not ends_nl else rule_if_not

    # ---- metadata block
    raw_meta: dict[str, str] = {}
    key_line: dict[str, int] = {}
    i = 0
    header_idx = None
    while i < nlines:
        s = lines[i].strip()
        if not s:
            i += 1
            continue
        if not s.startswith("#"):
            header_idx = i
            break
        m = _META_LINE.match(s)
        if not m:
            if not raw_meta:
                raise DropFormatError(spath, i + 1, "no-metadata",
                                      f"the file must start with '# format: {FORMAT}', found {s[:60]!r}")
            raise DropFormatError(spath, i + 1, cut_short("metadata-syntax") if i == nlines - 1
                                  else "metadata-syntax", f"{s[:60]!r} is not '# key: value'")
        key, value = m.group(1), m.group(2).strip()
        if not raw_meta and key != "format":
            raise DropFormatError(spath, i + 1, "format-not-first",
                                  f"the first metadata line must be '# format: {FORMAT}', found key {key!r}")
        if key in raw_meta:
            raise DropFormatError(spath, i + 1, "duplicate-key",
                                  f"{key} given again (first on line {key_line[key]})")
        raw_meta[key] = value
        key_line[key] = i + 1
        i += 1
    if not raw_meta:
        first = next(j for j in range(nlines) if lines[j].strip())
        raise DropFormatError(spath, first + 1, "no-metadata",
                              f"the file must start with '# format: {FORMAT}', found "
                              f"{lines[first].strip()[:60]!r}")
    if raw_meta["format"] != FORMAT:
        raise DropFormatError(spath, key_line["format"], "unknown-format",
                              f"format {raw_meta['format']!r} is not {FORMAT!r}")
    if "test" not in raw_meta:
        raise DropFormatError(spath, None, cut_short("missing-key"),
                              "required key 'test' is missing")
    test = raw_meta["test"]
    if test not in TESTS:
        raise DropFormatError(spath, key_line["test"], "unknown-test",
                              f"test {test!r} is not one of {', '.join(TESTS)}")
    missing = [k for k in REQUIRED_KEYS[test] if k not in raw_meta]
    if missing:
        if header_idx is None and not ends_nl:
            raise DropFormatError(spath, nlines, "truncated",
                                  f"the file ends inside the metadata block (missing {', '.join(missing)})")
        raise DropFormatError(spath, None, "missing-key",
                              f"required key{'s' if len(missing) > 1 else ''} "
                              f"{', '.join(missing)} missing for test {test}")
    if header_idx is None:
        raise DropFormatError(spath, nlines if not ends_nl else None, cut_short("no-header"),
                              "the metadata block is not followed by a CSV header line")
    meta = _typed_meta(spath, raw_meta, key_line)

    # ---- header
    header_line = header_idx + 1
    names = [c.strip() for c in lines[header_idx].split(",")]
    want = COLUMNS[test]
    dup = sorted({c for c in names if names.count(c) > 1})
    miss = [c for c in want if c not in names]
    extra = [c for c in names if c not in want]
    if dup or miss or extra:
        parts = []
        if miss:
            parts.append("missing " + ", ".join(miss))
        if extra:
            parts.append("unexpected " + ", ".join(repr(c) for c in extra))
        if dup:
            parts.append("repeated " + ", ".join(dup))
        rule = "truncated" if (header_idx == nlines - 1 and not ends_nl) else "bad-columns"
        raise DropFormatError(spath, header_line, rule,
                              f"columns for {test} must be {', '.join(want)}: {'; '.join(parts)}")

    # ---- rows. Fast path: the body has no blank lines -> pyarrow parses it as it is (it
    # refuses ragged rows itself). Otherwise, or when pyarrow refuses, check the structure
    # line by line in Python to name the line, then parse the numbers.
    n_body = nlines - header_idx - 1
    if n_body > 0 and not ends_nl and lines[-1].rstrip().endswith(","):
        raise DropFormatError(spath, nlines, "truncated",
                              "the file ends mid-row: the last line ends with an empty field "
                              "and no line end")
    tbl = None
    rows: list[str] | None = None
    if n_body > 0:
        body = text[sum(len(s) + 1 for s in lines[:header_idx + 1]):]
        if not body.startswith("\n") and "\n\n" not in body:
            tbl = _arrow_table(body.encode("utf-8"), names, n_body)
    if tbl is not None:
        line_no = header_line + 1 + np.arange(n_body, dtype=np.int64)
    else:
        rows, line_no = _structure(spath, lines[header_idx + 1:], header_line, names, ends_nl)
        tbl = _arrow_table("\n".join(rows).encode("utf-8"), names, len(rows))

    def get_rows() -> list[str]:
        return rows if rows is not None else lines[header_idx + 1:]

    cols = _parse_numbers(spath, test, names, tbl, get_rows, line_no, ends_nl)
    data = pd.DataFrame({c: cols[c] for c in want})
    data["line"] = line_no
    return RunFile(path=spath, sha256=sha, size_bytes=len(raw), meta=meta, meta_raw=raw_meta,
                   data=data, header_line=header_line, meta_lines=key_line)


def _structure(path, body: list[str], header_line: int, names, ends_nl):
    """Non-blank rows and their line numbers; refuses rows with the wrong number of fields."""
    row_idx = [j for j, s in enumerate(body) if s and not s.isspace()]
    if not row_idx:
        raise DropFormatError(path, header_line, "no-data", "a header but no data rows")
    rows = [body[j] for j in row_idx]
    ncomma = len(names) - 1
    counts = np.fromiter((s.count(",") for s in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(counts != ncomma)
    if bad.size:
        k = int(bad[0])
        ln = header_line + 1 + row_idx[k]
        last = k == len(rows) - 1 and not ends_nl
        raise DropFormatError(path, ln, "truncated" if last else "field-count",
                              f"{'the file ends mid-row: ' if last else ''}"
                              f"{int(counts[k]) + 1} fields, the header has {len(names)}")
    return rows, header_line + 1 + np.asarray(row_idx, dtype=np.int64)


def _arrow_table(buf: bytes, names, n_rows: int) -> pa.Table | None:
    """All columns as float64 with pyarrow; None when pyarrow refuses or counts other rows."""
    try:
        tbl = pacsv.read_csv(
            pa.py_buffer(buf),
            read_options=pacsv.ReadOptions(column_names=names, use_threads=False),
            parse_options=pacsv.ParseOptions(quote_char=False, double_quote=False,
                                              escape_char=False, ignore_empty_lines=False),
            convert_options=pacsv.ConvertOptions(
                column_types={c: pa.float64() for c in names}, null_values=[""],
                strings_can_be_null=False, quoted_strings_can_be_null=False))
    except pa.ArrowException:
        return None
    return tbl if tbl.num_rows == n_rows else None


def _parse_numbers(path, test, names, tbl, get_rows, line_no, ends_nl) -> dict[str, np.ndarray]:
    """Columns as arrays (int columns int64) from the pyarrow table, or from the exact
    Python fallback (which names the first non-numeric cell) when pyarrow refused."""
    if tbl is not None:
        values = {c: tbl.column(c).to_numpy(zero_copy_only=False) for c in names}
        empty = {c: (tbl.column(c).null_count > 0) and
                 np.asarray(tbl.column(c).is_null().to_numpy(zero_copy_only=False)) for c in names}
    else:
        values, empty = _parse_numbers_slow(path, names, get_rows(), line_no, ends_nl)
    out: dict[str, np.ndarray] = {}
    nullable = NULLABLE_COLUMNS[test]
    for c in COLUMNS[test]:
        e = empty[c]
        if c not in nullable and e is not False and e.any():
            k = int(np.flatnonzero(e)[0])
            last = k == len(line_no) - 1 and not ends_nl
            raise DropFormatError(path, int(line_no[k]), "truncated" if last else "empty-value",
                                  f"{c} is empty; the spec allows empty cells only in "
                                  f"{', '.join(sorted(nullable)) or 'no column'} for {test}")
        v = np.asarray(values[c], dtype=np.float64)
        if c in INT_COLUMNS:
            okv = np.isfinite(v) & (v == np.round(v)) & (np.abs(v) < 2.0 ** 53)
            if not okv.all():
                k = int(np.flatnonzero(~okv)[0])
                raise DropFormatError(path, int(line_no[k]), "not-integer",
                                      f"{c} value {get_rows()[k].split(',')[names.index(c)].strip()!r} "
                                      "is not an integer")
            v = v.astype(np.int64)
        out[c] = v
    return out


def _parse_numbers_slow(path, names, rows, line_no, ends_nl):
    """Exact cell-by-column check, used only when pyarrow refuses: names the first bad cell."""
    cells = pd.DataFrame([s.split(",") for s in rows], columns=range(len(names)), dtype=object)
    values, empty = {}, {}
    first_bad = None
    for j, c in enumerate(names):
        col = cells[j].astype(str).str.strip()
        e = (col == "").to_numpy()
        ok = col.str.fullmatch(_NUMBER.pattern, flags=_NUMBER.flags).to_numpy(dtype=bool) | e
        if not ok.all():
            k = int(np.flatnonzero(~ok)[0])
            if first_bad is None or k < first_bad[0]:
                first_bad = (k, c, cells[j].iloc[k])
            continue
        v = np.full(len(rows), np.nan)
        v[~e] = col[~e].astype(np.float64).to_numpy()
        values[c], empty[c] = v, e
    if first_bad is not None:
        k, c, cell = first_bad
        last = k == len(rows) - 1 and not ends_nl
        raise DropFormatError(path, int(line_no[k]), "truncated" if last else "non-numeric",
                              f"{'the file ends mid-row: ' if last else ''}"
                              f"column {c}: {str(cell)[:40]!r} is not a number")
    return values, empty
