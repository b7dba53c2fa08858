"""``accelcal simulate SCENARIO.toml --out DROP [--seed N] [--keep-ids]``."""
from __future__ import annotations

import argparse


def _run(args: argparse.Namespace) -> int:
    from ..simulate import simulate_to_drop   # on use: the simulator's scipy costs every CLI start
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
