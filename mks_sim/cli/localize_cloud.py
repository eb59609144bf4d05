"""`mks-sim localize-cloud` (under construction: its owner replaces this module)."""

from __future__ import annotations

import argparse

from mks_sim.errors import MksError

HELP = "(not built yet)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser


def run(args: argparse.Namespace) -> int:
    raise MksError("`mks-sim localize-cloud` is not built yet")
