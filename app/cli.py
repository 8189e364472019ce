"""``solarnav`` command line: one subcommand per module in :mod:`app.commands`.

A command module exposes ``add_parser(subparsers)`` (which registers its sub-parser) and ``run(args) -> int``;
it is enabled by adding its name to :data:`COMMANDS`. Bad input (:class:`~ingest.errors.InputError`, or an
unreadable path) ends the program with a one-line message on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from ingest.errors import InputError

COMMANDS = ("info", "dashboard", "simulate", "calibrate", "replay", "sun", "params", "report", "batch")

#: Exit code for bad input (argparse uses 2 for bad arguments too).
EXIT_BAD_INPUT = 2


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The top-level parser with every command of :data:`COMMANDS` registered, or only ``command``: a command
    module imports its whole stack (the simulator, Dask, the calibration), so ``solarnav replay`` imports the
    replay's alone (seconds less before the first line of work)."""
    parser = argparse.ArgumentParser(prog="solarnav", description=__doc__.splitlines()[0])
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in (command,) if command in COMMANDS else COMMANDS:
        module = importlib.import_module(f"app.commands.{name}")
        module.add_parser(subparsers)
        subparsers.choices[name].set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command and return its exit status (console scripts call ``sys.exit(main())``).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        The command's status; 2 for bad arguments (argparse's usage message) or bad input (one line
        ``solarnav: error: ...`` on stderr).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser(argv[0] if argv else None).parse_args(argv)
    except SystemExit as exc:  # --help or an argument error, already printed by argparse
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    try:
        return args.run(args)
    except (InputError, OSError) as exc:
        message = " ".join(str(exc).split())  # one line, whatever the message holds
        print(f"solarnav: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
