"""``accelcal simulate SCENARIO.toml --out DROP [--seed N] [--keep-ids]``."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..provenance import SIM_PREFIX
from .engine import simulate_campaign
from .io import write_drop
from .scenario import load_scenario


def sim_ids(runs, prefix: str = SIM_PREFIX):
    """Mark run_id and campaign as simulated (``SIM-...``), so a simulated campaign never
    shares a real campaign's label or run ids.  The unit serial stays: it names the unit
    whose truth was simulated (a simulated result is never current for a unit with a real
    calibration, accelcal.warehouse)."""
    for r in runs:
        for key in ("run_id", "campaign"):
            v = str(r.meta[key])
            if not v.startswith(prefix):
                r.meta[key] = prefix + v
    return runs


def simulate_to_drop(scenario_path, out_dir, seed: int | None = None,
                     keep_ids: bool = False) -> list[Path]:
    """Load a scenario, simulate it and write the drop; returns the written files.  Every
    file carries ``# simulated: true``; run ids and the campaign get the ``SIM-`` prefix
    unless ``keep_ids`` (the scenario's own ids, e.g. to compare with a sample drop)."""
    runs = simulate_campaign(load_scenario(scenario_path), seed=seed)
    return write_drop(runs if keep_ids else sim_ids(runs), out_dir)


def _run(args: argparse.Namespace) -> int:
    paths = simulate_to_drop(args.scenario, args.out, seed=args.seed, keep_ids=args.keep_ids)
    for p in paths:
        print(p)
    return 0


def register_cli(subparsers) -> argparse.ArgumentParser:
    """Add ``simulate`` to an argparse subparsers object; the command calls ``args.func(args)``."""
    p = subparsers.add_parser("simulate", help="simulate a scenario (TOML) into a drop folder",
                              description="Simulate the runs of a scenario TOML (see "
                              "accelcal.simulate.scenario) and write them as drop-format files. "
                              "A bare name such as 'demo' means a shipped scenario. Every file "
                              "is marked '# simulated: true'; `accelcal run` refuses such files "
                              "unless --allow-simulated.")
    p.add_argument("scenario", help="scenario TOML file (or the name of a shipped scenario)")
    p.add_argument("--out", required=True, help="drop folder to write into")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.add_argument("--keep-ids", action="store_true",
                   help="keep the scenario's run ids and campaign label (default: prefixed "
                        "with SIM-); the files are marked simulated either way")
    p.set_defaults(func=_run)
    return p
