"""Simulator: scenario TOML -> drop-format runs, using :mod:`accelcal.physics` as the
forward model.  The scenario format is documented in :mod:`accelcal.simulate.scenario`.

    load_scenario(path_or_dict) -> Scenario
    simulate_campaign(scenario, seed=None) -> list[SimRun]      # in memory
    write_run_file(meta, data, path) -> Path                    # one drop-format file
    write_drop(runs, out_dir) -> list[Path]
    simulate_to_drop(scenario_path, out_dir, seed=None) -> list[Path]
"""
from .engine import COLUMNS, SimRun, level_rates, simulate_campaign  # noqa: F401
from .io import format_run, simulate_to_drop, write_drop, write_run_file  # noqa: F401
from .scenario import SCENARIO_DIR, Scenario, ScenarioError, load_scenario  # noqa: F401

__all__ = ["load_scenario", "simulate_campaign", "SimRun", "write_run_file", "write_drop",
           "simulate_to_drop", "Scenario", "ScenarioError", "SCENARIO_DIR"]
