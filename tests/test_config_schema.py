"""One schema for accelcal.toml, read by ``run``, ``report``, ``due``, ``design`` and the DCC:
an unknown key is one line naming the nearest known key, a value of the wrong type one line
with the file, the key and the type expected; every key documented today is known."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from accelcal import config as C

README = Path(__file__).resolve().parents[1] / "README.md"

READERS = {"report": lambda p: C.lab_config(p), "run": lambda p: C.run_parameters(p),
           "due": lambda p: C.forecast_config(p), "design": lambda p: C.rig_limits(p)}


def _one_line(fn, path: Path) -> str:
    with pytest.raises(C.ConfigError) as e:
        fn(path)
    msg = str(e.value)
    assert len(msg.splitlines()) == 1, msg
    return msg


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("text, key, near", [
    ('[lab]\nname = "x"\nadress = "y"\n', "[lab] adress", "address"),
    ('[rigs."TT-1"]\ng_local_u = 1e-5\n', '[rigs."TT-1"] g_local_u', "g_local_u_m_s2"),
    ('[certificat]\napprover = "x"\n', "certificat", "certificate"),
])
def test_an_unknown_key_names_the_nearest_known_key_for_every_command(tmp_path, reader, text, key, near):
    p = tmp_path / "accelcal.toml"
    p.write_text(text)
    msg = _one_line(READERS[reader], p)
    assert msg.startswith(str(p)) and f"unknown key {key}" in msg and repr(near) in msg, msg


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_wrong_type_is_one_line_with_file_line_key_and_type(tmp_path, reader):
    p = tmp_path / "accelcal.toml"
    p.write_text('[lab]\nname = "x"\n[rigs."TT-1"]\ng_local_u_m_s2 = "1e-5"\n')
    msg = _one_line(READERS[reader], p)
    assert msg.startswith(f'{p}: [rigs."TT-1"] g_local_u_m_s2 must be a positive number') and msg.endswith("(line 4)"), msg
    p.write_text('[certificate]\nstate_due_date = "yes"\n')
    assert "[certificate] state_due_date must be true or false" in _one_line(READERS[reader], p)


def test_every_key_the_readme_shows_and_the_next_keys_are_known(tmp_path):
    """The README's accelcal.toml blocks, and [prior."MODEL"] / [rigs."ID"] setup_min."""
    blocks = re.findall(r"```toml\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert blocks
    p = tmp_path / "accelcal.toml"
    extra = ('\n[prior."QA-2000"]\nK1 = { value = 1.2, u = 0.01 }\n'
             '[rigs."LXJ-9"]\nsetup_min = 15.0\nmax_g = 40\n')
    seen = set()
    for b in blocks:
        if "[candidates" in b:
            continue
        p.write_text(b + (extra if not seen else ""))
        import tomllib
        raw = tomllib.loads(p.read_text())
        C.check_config(raw, p)
        seen |= set(raw)
    assert {"lab", "certificate", "traceability", "rigs", "dcc", "tolerance", "forecast"} <= seen | {"prior"}
