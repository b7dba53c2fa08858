"""``accelcal simulate SCENARIO.toml --out DROP [--seed N]``."""
from __future__ import annotations

import argparse
from pathlib import Path

from .engine import simulate_campaign
from .io import write_drop
from .scenario import load_scenario


def simulate_to_drop(scenario_path, out_dir, seed: int | None = None) -> list[Path]:
    """Load a scenario, simulate it and write the drop; returns the written files."""
    return write_drop(simulate_campaign(load_scenario(scenario_path), seed=seed), out_dir)


def _run(args: argparse.Namespace) -> int:
    paths = simulate_to_drop(args.scenario, args.out, seed=args.seed)
    for p in paths:
        print(p)
    return 0


def register_cli(subparsers) -> argparse.ArgumentParser:
    """Add ``simulate`` to an argparse subparsers object; the command calls ``args.func(args)``."""
    p = subparsers.add_parser("simulate", help="simulate a scenario (TOML) into a drop folder",
                              description="Simulate the runs of a scenario TOML (see "
                              "accelcal.simulate.scenario) and write them as drop-format files. "
                              "A bare name such as 'demo' means a shipped scenario.")
    p.add_argument("scenario", help="scenario TOML file (or the name of a shipped scenario)")
    p.add_argument("--out", required=True, help="drop folder to write into")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: the scenario's)")
    p.set_defaults(func=_run)
    return p
