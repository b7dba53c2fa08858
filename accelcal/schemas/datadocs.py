"""Data Docs that work offline: static HTML written from the great-expectations results.

great-expectations' own site pulls bootstrap, jQuery, font-awesome and vega from CDNs, so
without a network its index page is empty; and it names a failure by its row index in
the concatenated batch ("Data asset: None").  These pages have inline CSS, no scripts and
no external references, and name every failure by file and line: the validated batch
carries ``file`` and ``line`` columns (GE's ``unexpected_index_column_names``).  The
parser's refusals (files that never became a batch: not UTF-8, cut short, ...) are on
the same index page, so every refused file of a drop is there with its rule.

Layout of ``<docs_dir>/<drop>/``::

    index.html                   every file with its verdict and reasons; the suites
    validations/<suite>.html     every expectation of a suite: passed or failed, where
    validations/<suite>.json     GE's validation result, as GE writes it (machine-readable)
    part-NNNN/...                the same per batch when a drop is streamed in batches,
    parts.html                   ... and then a list of the batches' pages
"""
from __future__ import annotations

import datetime as _dt
import html
import json
import os
import re
from pathlib import Path
from typing import Any, Iterable

from ..fileio import atomic_write

#: Failures listed per expectation (all are counted; the JSON holds them all).
SHOWN_PER_EXPECTATION = 20

_CSS = """
body{font-family:"DejaVu Sans",Arial,Helvetica,sans-serif;color:#111;margin:20px auto;
     max-width:1150px;font-size:13px;line-height:1.35}
h1{font-size:20px;margin:0 0 4px 0} h2{font-size:15px;border-bottom:2px solid #1f3f6e;
     color:#1f3f6e;margin-top:22px} h3{font-size:13px;margin:14px 0 4px 0}
table{border-collapse:collapse;margin:6px 0 12px 0;width:100%}
th,td{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#e9eef5} .ok{color:#176b2c;font-weight:700} .bad{color:#a61b1b;font-weight:700}
.mono{font-family:"DejaVu Sans Mono",monospace;font-size:12px;word-break:break-all}
.note{color:#555;font-size:12px} a{color:#1f3f6e}
"""


def _e(x: Any) -> str:
    return html.escape("" if x is None else str(x))


def _page(title: str, body: str) -> str:
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_e(title)}"
            f"</title><style>{_CSS}</style></head><body>{body}<p class='note'>Written "
            f"{_dt.datetime.now(_dt.timezone.utc):%Y-%m-%d %H:%M:%S} UTC by accelcal from "
            f"great-expectations results; static, no scripts, no network.</p></body></html>")


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda fh: fh.write(text), "w", encoding="utf-8")


def _slug(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def short_paths(paths: Iterable[str]) -> dict[str, str]:
    """Each path relative to the folder above the files' common folder (drop/sub/f.csv)."""
    paths = [str(p) for p in paths]
    if not paths:
        return {}
    try:
        base = os.path.dirname(os.path.commonpath([os.path.dirname(p) for p in paths]))
    except ValueError:
        return {p: p for p in paths}
    return {p: os.path.relpath(p, base) if base else p for p in paths}


def _where(entry: dict[str, Any], names: dict[str, str]) -> str:
    f = entry.get("file")
    ln = entry.get("line")
    return f"{names.get(str(f), f)}:{ln}" if ln not in (None, -1) else str(names.get(str(f), f))


def write_data_docs(docs_root: Path, title: str, files: list[dict[str, Any]],
                    suites: list[tuple[str, dict[str, Any]]]) -> Path:
    """Write index.html and one page (plus GE's JSON) per suite under ``docs_root``.

    ``files``: one dict per file of the batch: path, verdict ('accepted'|'refused'),
    reasons (list of {line, rule, detail}), stage ('parse' or 'suites').
    ``suites``: (suite name, GE validation result as a JSON dict)."""
    docs_root = Path(docs_root)
    names = short_paths(f["path"] for f in files)
    suite_rows = []
    for name, res in suites:
        stats = res.get("statistics") or {}
        slug = _slug(name)
        _write(docs_root / "validations" / f"{slug}.json", json.dumps(res, indent=1, default=str))
        _write(docs_root / "validations" / f"{slug}.html", _suite_page(title, name, res, names))
        ok = bool(res.get("success"))
        suite_rows.append(
            f"<tr><td><a href='validations/{_e(slug)}.html'>{_e(name)}</a></td>"
            f"<td class='{'ok' if ok else 'bad'}'>{'passed' if ok else 'failed'}</td>"
            f"<td>{_e(stats.get('successful_expectations'))} of "
            f"{_e(stats.get('evaluated_expectations'))}</td></tr>")
    refused = [f for f in files if f["verdict"] != "accepted"]
    rows = []
    for f in sorted(files, key=lambda f: (f["verdict"] == "accepted", names.get(f["path"], ""))):
        reasons = "<br>".join(
            f"line {_e(r.get('line') if r.get('line') is not None else '—')}: "
            f"<b>{_e(r.get('rule'))}</b> {_e(r.get('detail'))}" for r in f.get("reasons") or [])
        cls = "ok" if f["verdict"] == "accepted" else "bad"
        rows.append(f"<tr><td class='mono'>{_e(names.get(f['path'], f['path']))}</td>"
                    f"<td class='{cls}'>{_e(f['verdict'])}</td><td>{_e(f.get('stage') or '')}</td>"
                    f"<td>{reasons}</td></tr>")
    body = (f"<h1>Data Docs — {_e(title)}</h1>"
            f"<p>{len(files)} files: {len(files) - len(refused)} accepted, "
            f"<span class='{'bad' if refused else 'ok'}'>{len(refused)} refused</span>. "
            f"A file is refused by the parser (structure, drop-format.md) or by the "
            f"great-expectations suites (the numbers); either way its reasons name the "
            f"line and the rule.</p>"
            "<h2>Files</h2><table><thead><tr><th>file</th><th>verdict</th><th>refused at</th>"
            f"<th>reasons</th></tr></thead><tbody>{''.join(rows)}</tbody></table>"
            "<h2>Expectation suites</h2>"
            + ("<table><thead><tr><th>suite</th><th>result</th><th>expectations met</th></tr>"
               f"</thead><tbody>{''.join(suite_rows)}</tbody></table>" if suite_rows else
               "<p class='note'>No file of this batch reached the suites.</p>"))
    index = docs_root / "index.html"
    _write(index, _page(f"Data Docs {title}", body))
    return index


def _suite_page(title: str, name: str, res: dict[str, Any], names: dict[str, str]) -> str:
    rows = []
    for er in res.get("results") or []:
        cfg = er.get("expectation_config") or {}
        meta = cfg.get("meta") or {}
        kw = {k: v for k, v in (cfg.get("kwargs") or {}).items() if k not in ("batch_id",)}
        r = er.get("result") or {}
        ok = bool(er.get("success"))
        where = ""
        idx = r.get("unexpected_index_list") or []
        if idx and isinstance(idx[0], dict):
            shown = []
            for entry in idx[:SHOWN_PER_EXPECTATION]:
                vals = ", ".join(f"{k} = {v}" for k, v in entry.items()
                                 if k not in ("file", "line", "_row"))
                shown.append(f"{_e(_where(entry, names))} ({_e(vals)})")
            more = len(idx) - len(shown)
            where = "<br>".join(shown) + (f"<br>… and {more} more (JSON)" if more > 0 else "")
        elif not ok:
            exc = (er.get("exception_info") or {}).get("exception_message")
            where = _e(f"whole table: observed {r.get('observed_value')}" if exc is None else exc)
        rows.append(f"<tr><td>{_e(meta.get('rule'))}</td><td>{_e(meta.get('what') or cfg.get('type'))}"
                    f"<div class='note mono'>{_e(cfg.get('type'))} {_e(json.dumps(kw, default=str))}"
                    f"</div></td><td class='{'ok' if ok else 'bad'}'>{'passed' if ok else 'FAILED'}"
                    f"</td><td>{_e(r.get('unexpected_count', ''))}</td><td class='mono'>{where}</td></tr>")
    body = (f"<p><a href='../index.html'>← {_e(title)}</a></p><h1>Suite {_e(name)}</h1>"
            f"<p>{'passed' if res.get('success') else 'failed'}; batch of {_e(title)}. Each "
            f"failure is named by file and line.</p><table><thead><tr><th>rule</th>"
            f"<th>expectation</th><th>result</th><th>unexpected</th><th>where (file:line)</th>"
            f"</tr></thead><tbody>{''.join(rows)}</tbody></table>")
    return _page(f"{name} — {title}", body)


def write_drop_index(drop_docs: Path, title: str) -> Path:
    """For a drop streamed in batches: ``parts.html``, a list of its part-NNNN pages."""
    parts = sorted(p.parent.name for p in Path(drop_docs).glob("part-*/index.html"))
    items = "".join(f"<li><a href='{_e(p)}/index.html'>{_e(p)}</a></li>" for p in parts)
    index = Path(drop_docs) / "parts.html"
    _write(index, _page(f"Data Docs {title}",
                        f"<h1>Data Docs — {_e(title)}</h1><p>The drop was validated in "
                        f"{len(parts)} batches:</p><ul>{items}</ul>"))
    return index
