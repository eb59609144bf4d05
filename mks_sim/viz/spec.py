"""The ``--rerun`` option: parse and validate where a recording goes, then open the recorder.

Forms (one string, validated before any work starts):

- ``save:PATH.rrd`` — write a recording file (the folder must exist or be creatable);
- ``spawn`` — start a Rerun viewer and stream to it;
- ``connect:ADDR`` — stream to a running viewer (``rerun+http://HOST:PORT/proxy``, or
  ``HOST:PORT`` which is completed to that form).

A trailing ``,normals`` (e.g. ``save:run.rrd,normals``) also logs the segmentation's surface
normals, which are many arrows and off by default.

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
OPTIONS = ("normals",)
_HOST_PORT = re.compile(r"^[A-Za-z0-9_.\-]+:\d{1,5}$")


@dataclass(frozen=True)
class RerunSpec:
    """Where a recording goes.

    Attributes:
        mode: ``save`` | ``spawn`` | ``connect``.
        target: the ``.rrd`` path (save), the gRPC URL (connect), or None (spawn).
        normals: also log surface normals (arrows).
    """

    mode: str
    target: str | None = None
    normals: bool = False


def parse_rerun_spec(text: str) -> RerunSpec:
    """Parse and validate a ``--rerun`` value (a ``save:`` path is checked for writing).

    Raises:
        SpecError: bad form, a save path not ending in ``.rrd``, or a folder that cannot be
            written.
    """
    body, normals = text.strip(), False
    head, sep, tail = body.rpartition(",")
    if sep and tail in OPTIONS:
        body, normals = head, True
    mode, colon, target = body.partition(":")
    expected = "expected save:PATH.rrd, spawn or connect:HOST:PORT (optionally ',normals')"
    if mode not in MODES:
        raise SpecError(f"--rerun: {expected}, got {text!r}")
    if mode == "spawn":
        if colon:
            raise SpecError(f"--rerun: spawn takes no argument; {expected}, got {text!r}")
        return RerunSpec("spawn", None, normals)
    if not target:
        raise SpecError(f"--rerun: {mode} needs an argument; {expected}, got {text!r}")
    if mode == "save":
        return RerunSpec("save", str(_check_save_path(Path(target), text)), normals)
    if _HOST_PORT.match(target):
        target = f"rerun+http://{target}/proxy"
    elif not target.startswith(("rerun://", "rerun+http://", "rerun+https://")):
        raise SpecError(
            f"--rerun: connect expected HOST:PORT or a rerun+http:// URL, got {target!r}"
        )
    return RerunSpec("connect", target, normals)


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
        "(append ',normals' for surface normals); needs the viz extra",
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
