"""``solarnav simulate --scenario NAME [--duration-s N] [--seed N] -o DIR``: write a simulated flight (PX4 ULog with
ground truth, sun-device CSV and device JSON, JSON record of the injected sensor errors)."""

from __future__ import annotations

import argparse

import numpy as np

from ingest.errors import InputError
from sim.px4_export import write_outputs
from sim.scenarios import SCENARIOS
from sim.simulate import simulate


def add_parser(subparsers) -> None:
    """Register the ``simulate`` sub-parser."""
    parser = subparsers.add_parser("simulate", help="write a simulated flight log with ground truth",
                                   description=__doc__)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), default="paper",
                        help="named scenario (default: paper)")
    parser.add_argument("--duration-s", type=float, default=None, metavar="N",
                        help="simulated time [s] (default: the mission's length)")
    parser.add_argument("--seed", type=int, default=None, metavar="N",
                        help="random seed (default: the scenario's, which reproduces the bundled sample logs)")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory (created if needed)")


def run(args: argparse.Namespace) -> int:
    """Simulate and write the files; prints one line per file. 0 on success."""
    if args.duration_s is not None and not args.duration_s > 0:
        raise InputError(f"must be a positive number of seconds, got {args.duration_s}", field="--duration-s")
    if args.seed is not None and args.seed < 0:
        raise InputError(f"must be a non-negative integer, got {args.seed}", field="--seed")
    scenario = SCENARIOS[args.scenario]
    seed = scenario.seed if args.seed is None else args.seed
    result = simulate(scenario, np.random.default_rng(seed), duration_s=args.duration_s, seed=seed)
    try:
        paths = write_outputs(result, args.output)
    except OSError as exc:
        raise InputError(f"cannot write the output ({exc.strerror})", source=args.output) from exc
    meta = result.log.meta
    print(f"scenario {scenario.name}, seed {seed}: {meta.duration_s:.1f} s simulated")
    for path in paths.values():
        print(f"  {path}  ({path.stat().st_size / 1e6:.2f} MB)")
    return 0
