"""Semantic validation of parsed runs with great-expectations 1.x (drop-format.md).

The parser (:mod:`accelcal.schemas.dropformat`) checks structure; this module
checks what needs the numbers, per test kind, with one Expectation Suite per
(test kind, table):

* ``<test>.rows`` on the runs' data (all runs of a kind in one batch) plus
  derived columns: column presence and types; finite values ("NaN or infinite
  numbers in ``output``"); time strictly increasing ("time that goes
  backwards"); ``table_rate_rad_s`` >= 0 for ``centrifuge``; plausible
  temperatures; angles in range; and the header's claims against the data
  (``sample_period_s``; tumble ``angle_deg`` constant per ``position``;
  centrifuge rest dwells at >= 2 equally spaced azimuths, azimuth present at
  rest, a step near 1 g; tilt_rotation ``positions`` equally spaced angles per
  temperature point; sine_centrifuge ``rate_amplitude_rad_s``/``rate_frequency_hz``).
  Run-level quantities sit on the run's first row (NaN elsewhere, which GE skips).
* ``<test>.meta`` on the metadata, one row per run: numeric values in their plausible
  ranges (``rules.METADATA_RANGES``).  That a key is present, well typed, in its set, a
  time or an axis is the parser's rule, checked there only: a run that breaks one never
  reaches a suite.

GE's unexpected row indices are mapped back to (file, ``line``); each failed
expectation of a run gives one :class:`Refusal` naming the first offending
line, the rule (``meta["rule"]`` of the expectation) and a detail. Rule ids:

``missing-column``, ``column-type``, ``output-not-finite``, ``not-finite``,
``time-not-increasing``, ``negative-rate``, ``temp-out-of-range``,
``angle-out-of-range``, ``sample-period``, ``angle-inconsistent``,
``angle-missing-at-rest``, ``rest-dwells``, ``no-1g-step``,
``positions-mismatch``, ``sine-amplitude``, ``sine-frequency``,
``metadata-range``; and ``unknown-test`` (through ``dropspec.check_test``, the parser's
rule) for a run made without the parser.

Data Docs (static HTML, offline: :mod:`accelcal.schemas.datadocs`) of each call go to
``docs_dir/<drop_name>/index.html``: every file with its verdict, the parser's refusals
passed in as ``parse_refusals`` included, and every expectation with its failures named
by file and line (the batch carries ``file`` and ``line`` columns).
"""
from __future__ import annotations

import gc
import os
import re
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from .derived import RowColumn, _derive, _meta_record
from .dropformat import RunFile
from .dropspec import COLUMNS, INT_COLUMNS, NULLABLE_COLUMNS, DropFormatError, Refusal, check_test
from .rules import ANGLE_TOL_DEG, TEMP_RANGE_C, ValidationReport, _expectation, _suite_specs, build_suites

os.environ.setdefault("GX_ANALYTICS_ENABLED", "False")

__all__ = ["Refusal", "ValidationReport", "validate_runs", "validate_report", "build_suites",
           "TEMP_RANGE_C", "ANGLE_TOL_DEG"]


# --------------------------------------------------------------------------------------
# running the suites



def _new_context():
    import great_expectations as gx
    from great_expectations.data_context.types.base import ProgressBarsConfig
    ctx = gx.get_context(mode="ephemeral")
    ctx.variables.progress_bars = ProgressBarsConfig(globally=False, metric_calculations=False)
    return ctx


#: Per thread: ``source``, the pandas data source of an ephemeral context, and ``defs``, one
#: whole-dataframe batch definition per table, made once and reused by every batch (each
#: batch still gets its own Batch of its own dataframe).  Per thread, as GE's objects are
#: not made to be shared.
_GE = threading.local()


def _batch_definition(table: str):
    """The batch definition of ``table`` ('rows' or 'meta') in this thread's context."""
    if getattr(_GE, "source", None) is None:
        _GE.source = _new_context().data_sources.add_pandas("accelcal")
        _GE.defs = {}
    if table not in _GE.defs:
        _GE.defs[table] = _GE.source.add_dataframe_asset(table) \
            .add_batch_definition_whole_dataframe("all")
    return _GE.defs[table]


def _forget_batches() -> None:
    """Let go of the batches this thread's data source holds (its execution engine keeps
    every batch it loaded, and with it the batch's table): the table of a batch is
    freed when the batch is done, not when the next batch replaces it."""
    if getattr(_GE, "source", None) is None:
        return
    manager = _GE.source.get_execution_engine().batch_manager
    manager.reset_batch_cache()
    manager.batch_data_cache.clear()


#: Set (to a dict) while this thread runs a validation: see _configurations_memo.
_MEMO = threading.local()


def _memoize_configurations() -> None:
    """Make ``Expectation.configuration`` computed once per expectation object while a
    validation of ours runs (:func:`_configurations_memo`), the same value otherwise.

    GE 1.x recomputes that property -- a pydantic ``.dict()`` of the whole expectation,
    then a new ExpectationConfiguration -- for every keyword it looks up, ~80 times per
    expectation per validation: a third of a batch's validation CPU, for a value that
    cannot change while the expectation is only read (GE validates objects it creates
    from the suite's configurations, and does not change them).  Outside our validations
    (no memo set in this thread) the original property runs, untouched."""
    from great_expectations.expectations.expectation import Expectation
    prop = Expectation.__dict__.get("configuration")
    if not isinstance(prop, property) or getattr(prop.fget, "_accelcal_memo", False):
        return
    compute = prop.fget

    def configuration(self):
        memo = getattr(_MEMO, "memo", None)
        if memo is None:
            return compute(self)
        hit = memo.get(id(self))
        if hit is None or hit[0] is not self:     # (a new object may reuse a dead one's id)
            hit = memo[id(self)] = (self, compute(self))
        return hit[1]
    configuration._accelcal_memo = True
    Expectation.configuration = property(configuration, doc=prop.__doc__)


class _configurations_memo:
    """While inside: each expectation's configuration is computed once (this thread)."""

    def __enter__(self):
        _memoize_configurations()
        self.outer = getattr(_MEMO, "memo", None)
        _MEMO.memo = {}

    def __exit__(self, *exc):
        _MEMO.memo = self.outer     # the objects it held (and their ids) are let go


def _fmt(v) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return repr(v) if isinstance(v, str) else str(v)


def docs_folder_name(drop_name: str | None) -> str:
    """The folder under ``docs_dir`` that holds a drop's Data Docs."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", drop_name or "drop")


#: Columns that name where a row of a batch came from (GE reports them for each failure).
WHERE_COLUMNS = ["file", "line", "_row"]


#: Name of the one suite (and Data Docs page) that validates a batch.
BATCH_SUITE = "batch"


def _batch_specs(kinds: list[str], columns: dict[str, set[str]]) -> list[tuple[tuple, str, list[str]]]:
    """The expectations of every kind present, merged into one suite for one table:
    (spec, table 'rows'|'meta', kinds it applies to).  An expectation shared by several
    kinds is there once; each kind's own keep their order (so a file's refusals come in
    the same order as from its kind's suite).  One that is a kind's own, on a column other
    kinds' rows also fill, is limited to that kind's rows (row condition on ``test``)."""
    from great_expectations.expectations.row_conditions import Column
    merged: list[list] = []      # [key, spec, table, kinds]
    for k in kinds:
        prev = -1
        specs = _suite_specs(k)
        for table in ("rows", "meta"):
            for spec in specs[table]:
                key = (table, spec[0], spec[1], spec[2], repr(sorted(spec[3].items())))
                pos = next((i for i, m in enumerate(merged) if m[0] == key), -1)
                if pos > prev:
                    merged[pos][3].append(k)
                    prev = pos
                else:
                    merged.insert(prev + 1, [key, spec, table, [k]])
                    prev += 1
    out = []
    for _, (cls_name, rule, what, kw), table, ks in merged:
        col = kw.get("column")
        if col is not None and any(col in columns[o] for o in kinds if o not in ks):
            cond = Column("test").is_in(ks) if len(ks) > 1 else Column("test") == ks[0]
            kw = dict(kw, row_condition=cond if "row_condition" not in kw
                      else kw["row_condition"] & cond)
        out.append(((cls_name, rule, what, kw), table, ks))
    return out


#: Rows of the ``rows`` table validated by one great-expectations call.  A batch with more
#: rows (a big run file) is validated a slice of rows at a time and the slices' results
#: merged (:func:`_validate_batch`): GE copies the whole table for each metric, so a 5 M-row
#: table cost ~2 GB.  Every expectation on ``rows`` looks at one row at a time (or at the
#: table's columns and dtypes, the same in every slice), so the merged verdicts, failing
#: rows and messages are those of the whole table.
VALIDATE_ROWS = 1 << 19


class _Rows:
    """The ``rows`` table of a batch, made a slice of rows at a time (:meth:`frame`): every
    run's rows (its columns and derived columns; a column a kind does not have is empty on
    its rows -- NaN, or 0 in an int column) and where each row came from (``test``,
    ``file``, ``line``, ``_row``).  The whole table is never held: only the runs' own
    arrays, and the slice being validated."""

    def __init__(self, items: list[tuple[RunFile, str, dict]], lens: np.ndarray,
                 names: list[str], dtypes: dict[str, np.dtype], kinds, files, kind_code, file_code):
        self.items, self.lens, self.names, self.dtypes = items, lens, names, dtypes
        self.starts = np.r_[0, np.cumsum(lens)[:-1]].astype(np.int64)
        self.n = int(lens.sum())
        self.kinds, self.files = kinds, files          # category names
        self.kind_code, self.file_code = kind_code, file_code   # per run

    def run_of(self, rows) -> np.ndarray:
        """The run (index into the items) of each global row index."""
        return np.searchsorted(self.starts, np.asarray(rows, np.int64), side="right") - 1

    def _line(self, j: int) -> np.ndarray:
        r, _, d = self.items[j]
        if "line" in d:
            return d["line"]
        if "line" in r.arrays:
            return np.asarray(r.arrays["line"], dtype=np.int64)
        return np.full(self.lens[j], -1)

    def line(self, k: int) -> int:
        j = int(self.run_of(k))
        return int(self._line(j)[k - self.starts[j]])

    def cell(self, c: str, k: int):
        """The value of column ``c`` at global row ``k``, as the whole table holds it."""
        j = int(self.run_of(k))
        v = self.items[j][2].get(c)
        dt = self.dtypes[c]
        if v is None:
            return dt.type(0) if dt.kind in "iu" else dt.type(np.nan)
        return dt.type(v[k - self.starts[j]])

    def frame(self, a: int = 0, b: int | None = None) -> pd.DataFrame:
        """Rows ``a`` to ``b`` of the table (global row numbers kept in ``_row``)."""
        b = self.n if b is None else b
        js = [j for j in range(len(self.items))
              if self.starts[j] < b and self.starts[j] + self.lens[j] > a]
        cuts = [(j, max(a - self.starts[j], 0), min(b - self.starts[j], self.lens[j])) for j in js]
        m = b - a
        data: dict[str, object] = {}
        for c in self.names:
            dt = self.dtypes[c]
            parts = [self.items[j][2].get(c) for j, _, _ in cuts]
            if all(p is not None for p in parts):
                # a column made a slice at a time (RowColumn) makes only the rows asked for
                if len(parts) != 1 or cuts[0][1] != 0 or cuts[0][2] != len(parts[0]):
                    data[c] = np.concatenate([p[lo:hi] for p, (_, lo, hi) in zip(parts, cuts)])
                else:
                    data[c] = parts[0][:] if isinstance(parts[0], RowColumn) else parts[0]
                if data[c].dtype != dt:
                    data[c] = data[c].astype(dt)
                continue
            vals = np.zeros(m, np.int64) if dt.kind in "iu" else np.full(m, np.nan)
            pos = 0
            for p, (_, lo, hi) in zip(parts, cuts):
                if p is not None:
                    vals[pos:pos + hi - lo] = p[lo:hi]
                pos += hi - lo
            data[c] = vals
        run_ix = np.repeat(np.asarray(js, np.int64), [hi - lo for _, lo, hi in cuts])
        data["test"] = pd.Categorical.from_codes(self.kind_code[run_ix], self.kinds)
        data["file"] = pd.Categorical.from_codes(self.file_code[run_ix], self.files)
        data["line"] = np.concatenate([self._line(j)[lo:hi] for j, lo, hi in cuts])
        data["_row"] = np.arange(a, b)
        return pd.DataFrame(data, copy=False)

    def slices(self, rows: int = 0):
        """(a, b) row ranges of at most ``rows`` rows (default VALIDATE_ROWS) covering it."""
        rows = rows or VALIDATE_ROWS
        return [(a, min(a + rows, self.n)) for a in range(0, max(self.n, 1), rows)]


def _batch_parts(items: list[tuple[RunFile, str, dict]]) -> tuple[_Rows, pd.DataFrame, dict]:
    """The batch as two tables: ``rows`` (a :class:`_Rows`, made a slice at a time), and
    ``meta``, one row per run with its metadata; both say where each row came from
    (``test``, ``file``, ``line``, ``_row``; a run's meta row carries the ``_row`` and
    ``line`` of its first data row).  Two tables, not one, because great-expectations
    copies the whole table for every column it checks: metadata columns spread over every
    data row cost that copy without holding anything.  Also: the columns each kind fills."""
    lens = np.array([len(next(iter(d.values()))) if d else 0 for _, _, d in items], np.int64)
    for j, (r, t, d) in enumerate(items):
        if lens[j] == 0:      # nothing to hold its metadata: one empty row (not a file's)
            items[j] = (r, t, {**{c: np.full(1, np.nan) if v.dtype.kind == "f" else
                                  np.zeros(1, v.dtype) for c, v in d.items()},
                               "line": np.full(1, -1)})
            lens[j] = 1
    columns: dict[str, set[str]] = {}
    names: dict[str, None] = {}
    for _, t, d in items:
        columns.setdefault(t, set()).update(c for c in d if c != "line")
        names.update(dict.fromkeys(c for c in d if c != "line"))
    dtypes: dict[str, np.dtype] = {}
    for c in names:
        parts = [d.get(c) for _, _, d in items]
        dt = np.result_type(*[p.dtype for p in parts if p is not None])
        if any(p is None for p in parts):
            if dt.kind in "iu":
                # an int column stays int64 (GE checks a nullable one row by row, in Python):
                # the other kinds' rows hold 0, and count as having the column, so its
                # expectations are limited to the kinds whose column it is (_batch_specs)
                dt = np.dtype(np.int64)
                for _, t, _ in items:
                    columns[t].add(c)
            else:
                dt = np.dtype(np.float64)
        dtypes[c] = dt
    # the metadata, one row per run
    recs = []
    meta: dict[str, object] = {}
    for r, t, _ in items:
        recs.append(_meta_record(t, r))
        columns[t].update(recs[-1])
    for k in dict.fromkeys(k for rec in recs for k in rec):
        meta[k] = pd.to_numeric(pd.Series([rec.get(k) for rec in recs], dtype=object),
                                errors="coerce").astype("float64").to_numpy()
    tests = np.asarray([t for _, t, _ in items], dtype=object)
    files = np.asarray([r.path for r, _, _ in items], dtype=object)
    # on the data rows, ``test`` and ``file`` are categorical (a code per row): GE copies the
    # whole table for each metric of an expectation with a row condition, and a copy of
    # strings per row cost a fifth of a large batch's validation; the values are the same
    kind_names, kind_code = np.unique(tests.astype(str), return_inverse=True)
    file_names, file_code = np.unique(files.astype(str), return_inverse=True)
    rows = _Rows(items, lens, list(names), dtypes, kind_names.astype(object),
                 file_names.astype(object), kind_code, file_code)
    meta["test"] = pd.Series(tests, dtype=object)
    meta["file"] = files
    meta["line"] = np.asarray([rows._line(j)[0] for j in range(len(items))], np.int64)
    meta["_row"] = rows.starts
    return rows, pd.DataFrame(meta, copy=False), columns


def _batch_table(items: list[tuple[RunFile, str, dict]]) -> tuple[dict[str, pd.DataFrame], dict,
                                                                  np.ndarray, np.ndarray]:
    """:func:`_batch_parts` with the ``rows`` table made whole (benchmarks/
    bench_intake_budget.py times it): the two tables, the columns each kind fills, the run
    and the line of each row."""
    rows, meta, columns = _batch_parts(items)
    df = rows.frame()
    run_ix = np.repeat(np.arange(len(items)), rows.lens)
    return {"rows": df, "meta": meta}, columns, run_ix, df["line"].to_numpy()


def validate_report(runs: list[RunFile], docs_dir: Path | None = None,
                    drop_name: str = "drop",
                    parse_refusals: list[Refusal] | None = None) -> ValidationReport:
    """Validate parsed runs with the GE suites: the batch is one table (every run's rows,
    derived columns and metadata, with ``file`` and ``line`` columns), validated by one
    suite -- the suites of the test kinds present, merged -- in one great-expectations
    call, in an ephemeral context.  Writes Data Docs to ``docs_dir/<drop_name>/`` when
    docs_dir is given, listing ``parse_refusals`` (files the parser refused) beside the
    suite's verdicts.
    """
    t0 = time.perf_counter()
    suite_results: list[tuple[str, dict]] = []
    refusals: dict[str, list[Refusal]] = {r.path: [] for r in runs}
    items: list[tuple[RunFile, str, dict]] = []
    todo: list[tuple[RunFile, str]] = []
    for r in runs:
        try:
            test = check_test(r.path, r.meta_lines.get("test"), str(r.meta.get("test", "")))
        except DropFormatError as e:    # a run made without the parser
            refusals[r.path].append(e.as_refusal())
            continue
        miss = [c for c in list(COLUMNS[test]) + ["line"] if c not in r.arrays]
        if miss:
            refusals[r.path].append(Refusal(r.path, r.header_line, "missing-column",
                                            f"columns missing: {', '.join(miss)}"))
            continue
        todo.append((r, test))
    for r, test in todo:
        try:
            items.append((r, test, _derive(test, r)))
        except Exception as e:  # a bug or data beyond the checks: refuse, don't stop the drop
            refusals[r.path].append(Refusal(r.path, None, "validation-error",
                                            f"{type(e).__name__}: {e}"[:300]))
    docs_root = None if docs_dir is None else Path(docs_dir) / docs_folder_name(drop_name)
    per_kind: dict[str, float] = {}
    if items:
        tk = time.perf_counter()
        kinds = list(dict.fromkeys(t for _, t, _ in items))
        rows, dfm, columns = _batch_parts(items)
        specs = _batch_specs(kinds, columns)
        results, res_json = _validate_batch({"rows": rows, "meta": dfm}, specs,
                                            docs_root is not None)
        if docs_root is not None:
            suite_results.append((BATCH_SUITE, res_json))
        kind_runs = [r for r, _, _ in items]
        test_of = [t for _, t, _ in items]
        for er in results:
            if er.success:
                continue
            cfg = er.expectation_config
            rule = cfg.meta.get("rule", "validation")
            what = cfg.meta.get("what", cfg.type)
            table = cfg.meta.get("table", "rows")
            ks = set(cfg.meta.get("kinds") or kinds)
            col = cfg.kwargs.get("column")
            idx = er.result.get("unexpected_index_list") if er.result else None
            if idx and isinstance(idx[0], dict):      # {file, line, _row, value}
                idx = [e["_row"] for e in idx]
            if er.exception_info and er.exception_info.get("raised_exception"):
                idx = None
            if not idx:  # whole-table failure (column missing, wrong type, error)
                msg = what
                if er.result and "observed_value" in er.result:
                    msg += f" (observed {_fmt(er.result['observed_value'])})"
                if er.exception_info and er.exception_info.get("raised_exception"):
                    msg += f" ({str(er.exception_info.get('exception_message'))[:120]})"
                for r, t in zip(kind_runs, test_of):
                    if t in ks:
                        ln = r.meta_lines.get(col) if table == "meta" else r.header_line
                        refusals[r.path].append(Refusal(r.path, ln, rule, msg))
                continue
            idx = np.asarray(sorted(int(i) for i in idx))
            ri = rows.run_of(idx)
            for i in np.unique(ri):
                sel = idx[ri == i]
                k = int(sel[0])
                r = kind_runs[int(i)]
                if table == "meta":
                    detail = f"{what}: {col} = {_fmt(r.meta.get(col, dfm[col].iloc[int(i)]))}"
                    refusals[r.path].append(Refusal(r.path, r.meta_lines.get(col), rule, detail))
                    continue
                test = test_of[int(i)]
                ln = rows.line(k)
                more = f" ({len(sel)} rows, first here)" if len(sel) > 1 else ""
                shown = [c for c in (col, "time_s") if c and c in columns[test]]
                if col == "nonfinite_cells":
                    shown = [c for c in COLUMNS[test] if c not in INT_COLUMNS
                             and not np.isfinite(rows.cell(c, k))
                             and not (np.isnan(rows.cell(c, k)) and c in NULLABLE_COLUMNS[test])]
                vals = ", ".join(f"{c} = {_fmt(rows.cell(c, k))}" for c in dict.fromkeys(shown))
                refusals[r.path].append(Refusal(r.path, ln if ln > 0 else None, rule,
                                                f"{what}: {vals}{more}"))
        per_kind["+".join(kinds)] = time.perf_counter() - tk
    for p in refusals:
        refusals[p].sort(key=lambda x: (x.line is None, x.line or 0, x.rule))
    index = _docs(docs_root, drop_name, runs, refusals, parse_refusals, suite_results)
    return ValidationReport(refusals, time.perf_counter() - t0, per_kind, index)


def run_suite(name: str, table: str, df: pd.DataFrame, specs: list, which: list[int],
              result_format: dict):
    """The expectations ``specs[i]`` (i in ``which``) of ``table`` ('rows' or 'meta') as one
    suite on ``df``, in this thread's context: GE's validation result.  Each expectation
    carries its index ``i`` in its meta."""
    import great_expectations as gx
    exps = [_expectation(specs[i][0], table=specs[i][1], kinds=specs[i][2], i=i) for i in which]
    # validated as is: a suite is added to a context only to be stored, and nothing here
    # is stored (that cost a serialisation of every expectation per batch)
    suite = gx.ExpectationSuite(name=name, expectations=exps)
    batch = _batch_definition(table).get_batch(batch_parameters={"dataframe": df})
    try:
        with warnings.catch_warnings(), _configurations_memo():
            warnings.simplefilter("ignore")
            return batch.validate(suite, result_format=result_format)
    finally:
        _forget_batches()


def _validate_batch(tables: dict[str, "pd.DataFrame | _Rows"], specs: list,
                    want_json: bool) -> tuple[list, dict | None]:
    """The batch's suite on its tables (``rows`` and ``meta``, each expectation on the
    table its spec names): GE's results, in the suite's order, and (``want_json``) one
    validation result as JSON for the Data Docs.

    Every expectation is run once with result format BOOLEAN_ONLY (passed or not: the
    cheap metrics); only those that failed are run again, COMPLETE, for the rows to name
    (their file and line: WHERE_COLUMNS) and the observed values.  A clean batch costs one
    validation per table; the failures' results replace theirs, so the Data Docs show them
    whole.

    A ``rows`` table given as :class:`_Rows` of more than VALIDATE_ROWS rows is validated a
    slice at a time (:func:`_validate_slices`), each slice made only while it is checked."""
    def run(name: str, table: str, which: list[int], result_format: dict):
        df = tables[table]
        if isinstance(df, _Rows):
            df = df.frame()
        return run_suite(name, table, df, specs, which, result_format)

    def key(er) -> int:
        return int(er.expectation_config.meta["i"])

    results: dict[int, object] = {}
    docs: dict[int, dict] = {}
    stats = {"evaluated_expectations": 0, "successful_expectations": 0,
             "unsuccessful_expectations": 0}
    for table in tables:
        which = [i for i, sp in enumerate(specs) if sp[1] == table]
        if not which:
            continue
        name = f"{BATCH_SUITE}.{table}"
        if isinstance(tables[table], _Rows) and len(tables[table].slices()) > 1:
            merged, merged_json = _validate_slices(name, table, tables[table], specs, which,
                                                   want_json)
            results.update(merged)
            if want_json:
                docs.update(merged_json)
                ok = sum(1 for i in which if merged[i].success)
                stats["evaluated_expectations"] += len(which)
                stats["successful_expectations"] += ok
                stats["unsuccessful_expectations"] += len(which) - ok
            continue
        first = run(name, table, which, {"result_format": "BOOLEAN_ONLY"})
        failed = [key(er) for er in first.results if not er.success]
        again = run(f"{name}.failed", table, failed, {
            "result_format": "COMPLETE", "unexpected_index_column_names": WHERE_COLUMNS}) \
            if failed else None
        full = {key(er): er for er in again.results} if again is not None else {}
        results.update({key(er): full.get(key(er), er) for er in first.results})
        if want_json:
            doc = first.to_json_dict()
            full_json = {int(r["expectation_config"]["meta"]["i"]): r
                         for r in (again.to_json_dict()["results"] if again is not None else [])}
            for r in doc["results"]:
                i = int(r["expectation_config"]["meta"]["i"])
                docs[i] = full_json.get(i, r)
            for k in stats:
                stats[k] += int((doc.get("statistics") or {}).get(k) or 0)
    ordered = [results[i] for i in sorted(results)]
    if not want_json:
        return ordered, None
    n = stats["evaluated_expectations"]
    stats["success_percent"] = 100.0 * stats["successful_expectations"] / n if n else None
    doc = {"success": all(er.success for er in ordered), "statistics": stats,
           "suite_name": BATCH_SUITE, "results": [docs[i] for i in sorted(docs)],
           "tables": {t: [i for i, sp in enumerate(specs) if sp[1] == t] for t in tables}}
    return ordered, doc


#: Counts in a result that add up over slices of rows (the rest is the first failing slice's).
_SUMMED = ("element_count", "unexpected_count", "missing_count")


def _validate_slices(name: str, table: str, rows: _Rows, specs: list, which: list[int],
                     want_json: bool) -> tuple[dict[int, object], dict[int, dict]]:
    """:func:`_validate_batch` on a ``rows`` table too big for one call: each slice of rows
    (:meth:`_Rows.slices`) made, checked BOOLEAN_ONLY, its failures checked again COMPLETE,
    and let go.  An expectation passes when it passes on every slice; one that fails keeps
    the COMPLETE result of the first slice it fails on, with the failing rows of the later
    slices appended (``_row`` is the row's number in the whole table) and the counts of
    :data:`_SUMMED` added up -- so the refusals made from it (first failing row, how many)
    are those of the whole table.  Results and their JSON (``want_json``) by expectation."""
    def key(er) -> int:
        return int(er.expectation_config.meta["i"])

    out: dict[int, object] = {}
    out_json: dict[int, dict] = {}
    for a, b in rows.slices():
        df = rows.frame(a, b)
        first = run_suite(name, table, df, specs, which, {"result_format": "BOOLEAN_ONLY"})
        failed = [key(er) for er in first.results if not er.success]
        again = run_suite(f"{name}.failed", table, df, specs, failed, {
            "result_format": "COMPLETE", "unexpected_index_column_names": WHERE_COLUMNS}) \
            if failed else None
        del df
        full = {key(er): er for er in again.results} if again is not None else {}
        full_json = ({int(r["expectation_config"]["meta"]["i"]): r
                      for r in again.to_json_dict()["results"]}
                     if want_json and again is not None else {})
        first_json = ({int(r["expectation_config"]["meta"]["i"]): r
                       for r in first.to_json_dict()["results"]} if want_json else {})
        for er in first.results:
            i = key(er)
            er = full.get(i, er)
            prev = out.get(i)
            if prev is None or (prev.success and not er.success):
                out[i] = er
                if want_json:
                    out_json[i] = full_json.get(i, first_json.get(i))
                continue
            if er.success or prev.success:
                continue
            _merge_result(prev.result, er.result)
            if want_json and i in full_json:
                _merge_result(out_json[i].get("result"), full_json[i].get("result"))
        # a slice's table sits in great-expectations' reference cycles: collected here, the
        # next slice reuses its memory (a 3 GB run's validation peaked 556 MB without this,
        # 449 MB with it, in the same time; the young generations only -- a full collection
        # per slice cost 50 ms)
        gc.collect(1)
    return out, out_json


def _merge_result(into: dict | None, more: dict | None) -> None:
    """Add a later slice's failing rows and counts to a failed expectation's result."""
    if not into or not more:
        return
    for k in ("unexpected_index_list",):
        if isinstance(into.get(k), list) and isinstance(more.get(k), list):
            into[k] = into[k] + more[k]
    for k in _SUMMED:
        if isinstance(into.get(k), (int, np.integer)) and isinstance(more.get(k), (int, np.integer)):
            into[k] = int(into[k]) + int(more[k])


def _docs(docs_root: Path | None, title: str, runs: list[RunFile],
          refusals: dict[str, list[Refusal]], parse_refusals: list[Refusal] | None,
          suite_results: list[tuple[str, dict]]) -> Path | None:
    """Data Docs of this call: the parser's and the suites' verdicts on every file."""
    if docs_root is None:
        return None
    from .datadocs import write_data_docs

    def reason(x):
        return {"line": x.line, "rule": x.rule, "detail": x.detail}
    files = [{"path": r.path, "verdict": "refused" if refusals[r.path] else "accepted",
              "stage": "suites" if refusals[r.path] else "",
              "reasons": [reason(x) for x in refusals[r.path]]} for r in runs]
    by_path: dict[str, list[Refusal]] = {}
    for x in parse_refusals or []:
        by_path.setdefault(str(x.path), []).append(x)
    files += [{"path": p, "verdict": "refused", "stage": "parse",
               "reasons": [reason(x) for x in xs]} for p, xs in by_path.items()]
    return write_data_docs(docs_root, title, files, suite_results)


def validate_runs(runs: list[RunFile], docs_dir: Path | None = None,
                  drop_name: str = "drop",
                  parse_refusals: list[Refusal] | None = None) -> dict[str, list[Refusal]]:
    """Refusals per run path (empty list: the run passed every suite). See validate_report."""
    return validate_report(runs, docs_dir, drop_name, parse_refusals).refusals
