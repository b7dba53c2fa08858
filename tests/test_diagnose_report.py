"""``accelcal diagnose --report``: the page holds the terminal's text whole and in its
order (the advice after the report included), and ``diagnosis.json`` the advice
(``next_runs``) that ``--json`` gives."""
from __future__ import annotations

import html
import json
import re

import pytest

from accelcal.cli import main
from conftest import SHARED

CASE = SHARED / "diagnosis-dev" / "cases" / "cent-koq-d0"
ARGS = [str(CASE), "--baseline", "none"]


@pytest.mark.skipif(not CASE.is_dir(), reason=f"needs the lab's diagnosis-dev cases at {CASE.parent}")
def test_report_text_equals_the_terminals(tmp_path, capsys):
    capsys.readouterr()
    assert main(["diagnose", *ARGS, "--report", str(tmp_path / "rep")]) == 0
    terminal = capsys.readouterr().out
    assert main(["diagnose", *ARGS, "--json"]) == 0
    advice = json.loads(capsys.readouterr().out)["next_runs"]
    page = (tmp_path / "rep" / "diagnosis.html").read_text(encoding="utf-8")
    shown = html.unescape(re.search(r"<pre[^>]*>(.*?)</pre>", page, re.S).group(1))
    assert shown == terminal.rstrip("\n")
    assert advice and all(f"to {a['to']}:" in terminal for a in advice)
    data = json.loads((tmp_path / "rep" / "diagnosis.json").read_text(encoding="utf-8"))
    assert data["next_runs"] == advice
