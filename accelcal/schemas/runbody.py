"""The data rows of a run file, parsed (drop-format.md, "A run file"): a chunk at a time
into per-column arrays for :func:`accelcal.schemas.dropformat.parse_run` (:class:`_Body`),
and the joint fast path of :func:`accelcal.schemas.dropformat.parse_runs` over many files'
plain rows (:func:`_plain_rows`, :func:`_rows_of`, :func:`_plain_arrays`).  Numpy finds
the lines, pyarrow's CSV reader parses the numbers, no Python per row.
"""
from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from .dropspec import (CHUNK_BYTES, COLUMNS, INT_COLUMNS, LINE_MAX, NULLABLE_COLUMNS, _NUMBER,
                       DropFormatError)


_IS_BLANK_BYTE = np.zeros(256, dtype=bool)
_IS_BLANK_BYTE[[0x20, 0x09, 0x0B, 0x0C]] = True        # \r is dealt with as part of \r\n
_LITERAL_INF = r"^\s*[+-]?inf(inity)?\s*$"


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

    def __init__(self, path: str, test: str, names: list[str], size_hint: int | None = None,
                 sink=None):
        self.path, self.test, self.names = path, test, names
        self.size_hint = size_hint          # bytes of the file, to size the arrays once
        #: where each chunk's rows go instead of these arrays (tables.RunParquetStream)
        self.sink = sink
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
        if self.sink is not None:           # handed over, not kept
            self.sink.write(cols, m)
            self.n_rows = n + m
            return
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
