"""The demo's built-in drop comes from the simulator (issue 3): the shipped files are
byte for byte what the shipped scenario writes."""
from pathlib import Path

import accelcal
from accelcal.simulate import simulate_to_drop

DEMO = Path(accelcal.__file__).parent / "demo_data" / "drop-demo"
SCENARIO = Path(accelcal.__file__).parent / "simulate" / "scenarios" / "demo.toml"


def test_demo_drop_is_simulator_output(tmp_path):
    written = simulate_to_drop(SCENARIO, tmp_path / "drop")
    shipped = sorted(p.relative_to(DEMO) for p in DEMO.rglob("*.csv"))
    fresh = sorted(Path(p).relative_to(tmp_path / "drop") for p in written)
    assert shipped == fresh and len(shipped) == 11
    for rel in shipped:
        assert (DEMO / rel).read_bytes() == (tmp_path / "drop" / rel).read_bytes(), rel
