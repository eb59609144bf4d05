"""Recordings of every stage with Rerun (``--rerun``); nothing here imports ``rerun``.

- :class:`Recorder` — what recordable code calls; :class:`NullRecorder` when logging is off;
- :func:`parse_rerun_spec` / :func:`add_rerun_argument` — the ``--rerun`` option;
- :func:`open_recorder` — the Rerun recorder for a spec (imports ``rerun`` only then).

Entity paths: ``docs/visualization.md``.
"""

from __future__ import annotations

from mks_sim.viz.recorder import NullRecorder, Recorder
from mks_sim.viz.spec import RerunSpec, add_rerun_argument, open_recorder, parse_rerun_spec

__all__ = [
    "NullRecorder",
    "Recorder",
    "RerunSpec",
    "add_rerun_argument",
    "open_recorder",
    "parse_rerun_spec",
]
