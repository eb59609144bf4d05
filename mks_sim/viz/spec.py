"""The ``--rerun`` option: parse and validate where a recording goes, then open the recorder.

Forms (one string, validated before any work starts):

- ``save:PATH.rrd`` — write a recording file (the folder must exist or be creatable);
- ``spawn`` — start a Rerun viewer and stream to it;
- ``connect:ADDR`` — stream to a running viewer (``rerun+http://HOST:PORT/proxy``, or
  ``HOST:PORT`` which is completed to that form).

Trailing options, comma-separated: ``,normals`` (e.g. ``save:run.rrd,normals``) also logs the
segmentation's surface normals (many arrows, off by default); ``,all`` logs the point clouds
of every snapshot (by default range scans, large point streams and the SPG / segmentation are
drawn at most once per simulated second within an episode attempt: a grasp re-senses every
0.2 s).

Rerun itself (``rerun-sdk``, the ``viz`` extra) is imported only by :func:`open_recorder` for a
spec that asks for it: with no ``--rerun`` nothing of it is loaded.
"""

from __future__ import annotations

import argparse
import os
import re
from dataclasses import dataclass
from pathlib import Path

from mks_sim.errors import MksError, SpecError
from mks_sim.viz.recorder import NullRecorder, Recorder

__all__ = ["RerunSpec", "add_rerun_argument", "open_recorder", "parse_rerun_spec"]

MODES = ("save", "spawn", "connect")
OPTIONS = ("normals", "all")
_HOST_PORT = re.compile(r"^[A-Za-z0-9_.\-]+:\d{1,5}$")


@dataclass(frozen=True)
class RerunSpec:
    """Where a recording goes.

    Attributes:
        mode: ``save`` | ``spawn`` | ``connect``.
        target: the ``.rrd`` path (save), the gRPC URL (connect), or None (spawn).
        normals: also log surface normals (arrows).
        every: log the point clouds of every snapshot (no rate limit).
    """

    mode: str
    target: str | None = None
    normals: bool = False
    every: bool = False


def parse_rerun_spec(text: str) -> RerunSpec:
    """Parse and validate a ``--rerun`` value (a ``save:`` path is checked for writing).

    Raises:
        SpecError: bad form, a save path not ending in ``.rrd``, or a folder that cannot be
            written.
    """
    body, options = text.strip(), set[str]()
    head, sep, tail = body.rpartition(",")
    while sep and tail in OPTIONS:
        body, options = head, options | {tail}
        head, sep, tail = body.rpartition(",")
    normals, every = "normals" in options, "all" in options
    mode, colon, target = body.partition(":")
    expected = (
        "expected save:PATH.rrd, spawn or connect:HOST:PORT (optionally ',normals', ',all')"
    )
    if mode not in MODES:
        raise SpecError(f"--rerun: {expected}, got {text!r}")
    if mode == "spawn":
        if colon:
            raise SpecError(f"--rerun: spawn takes no argument; {expected}, got {text!r}")
        return RerunSpec("spawn", None, normals, every)
    if not target:
        raise SpecError(f"--rerun: {mode} needs an argument; {expected}, got {text!r}")
    if mode == "save":
        return RerunSpec("save", str(_check_save_path(Path(target), text)), normals, every)
    if _HOST_PORT.match(target):
        target = f"rerun+http://{target}/proxy"
    elif not target.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        raise SpecError(
            f"--rerun: connect expected HOST:PORT or a rerun+http:// URL, got {target!r}"
        )
    return RerunSpec("connect", target, normals, every)


def _check_save_path(path: Path, text: str) -> Path:
    if path.suffix != ".rrd":
        raise SpecError(f"--rerun: save expected a path ending in .rrd, got {text!r}")
    if path.is_dir():
        raise SpecError(f"--rerun: save expected a file path, got the folder {str(path)!r}")
    folder = path.parent
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir() or not os.access(existing, os.W_OK):
        raise SpecError(
            f"--rerun: save cannot write {str(path)!r}: {str(existing)!r} is not a writable folder"
        )
    if path.exists() and not os.access(path, os.W_OK):
        raise SpecError(f"--rerun: save cannot overwrite {str(path)!r} (not writable)")
    return path


def _spec_type(text: str) -> RerunSpec:
    # argparse turns an ArgumentTypeError into "error: argument --rerun: ..." and exit 2.
    try:
        return parse_rerun_spec(text)
    except SpecError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--rerun: ")) from None


def add_rerun_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--rerun SPEC`` (parsed into a :class:`RerunSpec`, default None)."""
    parser.add_argument(
        "--rerun", type=_spec_type, default=None, metavar="SPEC",
        help="record every stage with Rerun: save:PATH.rrd | spawn | connect:HOST:PORT "
        "(append ',normals' for surface normals, ',all' for every snapshot's clouds); "
        "needs the viz extra",
    )  # fmt: skip


def open_recorder(spec: RerunSpec | None, application_id: str = "mks_sim") -> Recorder:
    """The recorder for ``spec``: :class:`NullRecorder` when None, else a Rerun recorder.

    Raises:
        MksError: ``rerun-sdk`` is not installed (the message names the fix).
    """
    if spec is None:
        return NullRecorder()
    try:
        from mks_sim.viz.rerun_recorder import RerunRecorder
    except ImportError as exc:
        raise MksError(
            f"--rerun needs rerun-sdk ({exc}); run `pip install -e '.[viz]'`"
        ) from exc
    return RerunRecorder(spec, application_id)
