"""The ``mks-sim`` command line.

Each subcommand lives in its own module ``mks_sim.cli.<name>`` defining ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. Errors of the library (``MksError``) become
one-line messages and exit code 2; nothing reaches the user as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from mks_sim.errors import MksError

# Order is the order of `mks-sim --help`.
COMMANDS = (
    "demo",
    "paper",
    "sensors",
    "localize",
    "localize_cloud",
    "snapshot",
    "grasp",
)


def _command_name(module: str) -> str:
    return module.replace("_", "-")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mks-sim",
        description="Multi-sensor Kernel System: logical sensors, k-d tree, SPG, "
        "feature and Hough models, in a simulated MuJoCo workstation.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in COMMANDS:
        module = importlib.import_module(f"mks_sim.cli.{module_name}")
        cmd = sub.add_parser(_command_name(module_name), help=module.HELP, description=module.HELP)
        module.add_arguments(cmd)
        cmd.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args._run(args) or 0)
    except MksError as exc:
        print(f"mks-sim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
