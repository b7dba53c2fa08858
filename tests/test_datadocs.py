"""Data Docs work offline and name every refusal by file, line and rule (issue 11): the
parser's refusals are there too (all 11 of drop-bad), and a failed expectation names the
file and line of the row, not its index in the concatenated batch."""
from __future__ import annotations

import os
import re
import shutil
import subprocess

import pytest

from accelcal.schemas.dropformat import read_run
from accelcal.schemas.dropscan import discover
from accelcal.schemas.dropspec import DropFormatError
from accelcal.schemas.suites import validate_report


@pytest.fixture(scope="module")
def bad_docs(tmp_path_factory, examples):
    runs, parse = [], []
    for p in discover(examples / "drop-bad"):
        try:
            runs.append(read_run(p))
        except DropFormatError as e:
            parse.append(e.as_refusal())
    out = tmp_path_factory.mktemp("docs")
    rep = validate_report(runs, out, "drop-bad", parse_refusals=parse)
    return out / "drop-bad", rep, parse


def test_every_refusal_is_on_the_index_with_file_line_and_rule(bad_docs):
    root, rep, parse = bad_docs
    html = (root / "index.html").read_text()
    refused = {os.path.basename(p) for p, v in rep.refusals.items() if v} | {
        os.path.basename(r.path) for r in parse}
    assert len(refused) == 11
    for name in refused:
        assert f"drop-bad/{name}" in html, name
    assert "11 refused" in html
    for r in parse:
        assert f"<b>{r.rule}</b>" in html
    assert "line 26: <b>output-not-finite</b>" in html and "line 26: <b>time-not-increasing</b>" in html


def test_failed_expectations_name_file_and_line(bad_docs):
    root, _, _ = bad_docs
    # one suite per batch (issue 13): the kinds' suites merged, one page
    page = (root / "validations" / "batch.html").read_text()
    assert "drop-bad/nan-output.csv:26" in page and "drop-bad/time-backwards.csv:26" in page
    assert "FAILED" in page


def test_no_network_references(bad_docs):
    root, _, _ = bad_docs
    for f in root.rglob("*.html"):
        text = f.read_text()
        assert "<script" not in text and not re.search(r"(src|href)\s*=\s*['\"]?(https?:)?//", text), f


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium not installed")
def test_renders_offline_in_chromium(bad_docs, tmp_path):
    root, _, _ = bad_docs
    shot = tmp_path / "docs.png"
    # an unreachable proxy for everything but loopback: the page gets no network at all
    cmd = ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", "--proxy-server=127.0.0.1:9", "--hide-scrollbars",
           f"--user-data-dir={tmp_path / 'chrome'}", "--window-size=1200,1100",
           f"--screenshot={shot}", (root / "index.html").as_uri()]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=90,
                       env={**os.environ, "HOME": str(tmp_path)})
    assert p.returncode == 0, p.stderr[-2000:]
    from PIL import Image
    im = Image.open(shot).convert("RGB")
    colours = im.getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 100       # text, tables, red/green verdicts
    # the red of "refused" is there (the verdicts render without any icon font)
    assert any(r > 140 and g < 60 and b < 60 for _, (r, g, b) in colours)
