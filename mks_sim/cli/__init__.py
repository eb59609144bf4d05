"""The ``mks-sim`` command line.

Each subcommand lives in its own module ``mks_sim.cli.<name>`` defining ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``.

Exit codes, the same for every command: 0 found / success, 1 not found / failed (a clean
result, JSON with ``--json``), 2 bad input (a one-line ``mks-sim CMD: error: ...`` message,
never a traceback; argparse's own usage errors are 2 too). Errors of the library
(``MksError``) become exit 2. Before a command runs, every option is checked: a ``seed`` must
be >= 0 and no float option may be NaN or infinite, whichever command declares it. Python
warnings are shown as one line each (no source lines).

Helpers for commands: :func:`finite_float` and :func:`seed_int` (argparse ``type=``),
:func:`output_dir` and :func:`output_file` (validate an output path before any work starts).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import math
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from mks_sim.errors import MksError, SpecError

# Order is the order of `mks-sim --help`.
COMMANDS = (
    "demo",
    "paper",
    "sensors",
    "localize",
    "localize_cloud",
    "snapshot",
    "grasp",
    "objects",
    "scene",
)


def finite_float(text: str) -> float:
    """argparse ``type=``: a finite float (``nan``, ``inf`` are rejected)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def seed_int(text: str) -> int:
    """argparse ``type=``: a seed, an integer in [0, 2**63)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if not 0 <= value < 2**63:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def output_dir(path: str | os.PathLike[str], option: str = "--out") -> Path:
    """Check and create the output folder ``path`` before any work starts.

    Only the named folder is created: its parent must already exist.

    Raises:
        SpecError: ``path`` is an existing file, its parent folder does not exist, or the
            folder cannot be created or written.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise SpecError(f"{option}: expected an output folder, got an existing file '{out}'")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise SpecError(
            f"{option}: expected a folder whose parent exists, got '{out}' "
            f"(no folder '{parent}'; create it first)"
        )
    try:
        out.mkdir(exist_ok=True)
    except OSError as exc:
        raise SpecError(f"{option}: cannot create the folder '{out}': {exc.strerror}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise SpecError(f"{option}: expected a writable folder, got '{out}' (not writable)")
    return out


def output_file(path: str | os.PathLike[str], option: str, suffixes: Sequence[str] = ()) -> Path:
    """Check an output file path before any work starts (nothing is created).

    Raises:
        SpecError: a suffix not in ``suffixes``, an existing folder, a missing or unwritable
            parent folder.
    """
    out = Path(path)
    if suffixes and out.suffix.lower() not in suffixes:
        raise SpecError(f"{option}: expected a file ending in one of {list(suffixes)}, got '{out}'")
    if out.is_dir():
        raise SpecError(f"{option}: expected a file, got the folder '{out}'")
    parent = out.absolute().parent
    if not parent.is_dir():
        raise SpecError(
            f"{option}: expected a file in an existing folder, got '{out}' (no folder "
            f"'{parent}'; create it first)"
        )
    if not os.access(parent, os.W_OK | os.X_OK) or (out.exists() and not os.access(out, os.W_OK)):
        raise SpecError(f"{option}: expected a writable path, got '{out}' (not writable)")
    return out


def _option(dest: str) -> str:
    return "--" + dest.replace("_", "-")


def _floats(value: Any) -> Iterator[float]:
    if isinstance(value, float):
        yield value
    elif isinstance(value, list | tuple):
        for item in value:
            yield from _floats(item)


def check_options(args: argparse.Namespace) -> None:
    """Checks every command gets: ``seed`` >= 0, no NaN or infinite float option.

    Raises:
        SpecError: ``--seed: expected a non-negative integer, got -1``.
    """
    for dest, value in vars(args).items():
        if dest.startswith("_"):
            continue
        if dest.endswith("seed") and isinstance(value, int) and not isinstance(value, bool):
            if value < 0:
                raise SpecError(f"{_option(dest)}: expected a non-negative integer, got {value}")
        for f in _floats(value):
            if not math.isfinite(f):
                raise SpecError(f"{_option(dest)}: expected finite numbers, got {value!r}")


def _show_warning(
    message: Warning | str,
    category: type[Warning],
    filename: str,
    lineno: int,
    file: Any = None,
    line: str | None = None,
) -> None:
    """One line per warning on stderr (the default shows the source file and line)."""
    del filename, lineno, file, line
    text = " ".join(str(message).split())
    print(f"mks-sim: warning: {text} ({category.__name__})", file=sys.stderr)


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
    """Run ``mks-sim`` with ``argv`` (default ``sys.argv[1:]``); the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            check_options(args)
            return int(args._run(args) or 0)
        except MksError as exc:
            message = " ".join(str(exc).split())
            print(f"mks-sim {args.command}: error: {message}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
        except BrokenPipeError:  # `mks-sim ... | head`: the reader left; no traceback
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
