"""``solarnav`` command line: one subcommand per module in :mod:`app.commands`.

A command module exposes ``add_parser(subparsers)`` (which registers its sub-parser) and ``run(args) -> int``;
it is enabled by adding its name to :data:`COMMANDS`. Bad input (:class:`~ingest.errors.InputError`) ends the
program with a one-line message and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from ingest.errors import InputError

COMMANDS = ("info", "dashboard")

#: Exit code for bad input (argparse uses 2 for bad arguments too).
EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every command of :data:`COMMANDS` registered."""
    parser = argparse.ArgumentParser(prog="solarnav", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"app.commands.{name}")
        module.add_parser(subparsers)
        subparsers.choices[name].set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns its exit code (2 with a one-line message on bad input)."""
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except InputError as exc:
        print(f"solarnav {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
