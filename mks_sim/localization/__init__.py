"""The localization engine (paper section 4): one low-level representation per snapshot,
hypotheses by model kind, batch verification.

Modules, one stage each:

- :mod:`~mks_sim.localization.representation` — :class:`Representation` (k-d tree, table,
  SPG, normals, segmentation of one point set, each computed at most once) and
  :func:`representation_of` (the one representation of a stream's points).
- :mod:`~mks_sim.localization.verify` — the one table finder, batch scoring of candidate
  poses, the one scene-consistency check, ranking.
- :mod:`~mks_sim.localization.model` — model kinds (``polyhedral``, ``freeform``,
  ``sphere``; ``auto`` from a mesh), loading a model of a kind.
- :mod:`~mks_sim.localization.hypotheses` — support-face and sphere-centre hypotheses.
- :mod:`~mks_sim.localization.pipeline` — object segments and polyhedral candidates over a
  representation (the stages in order).

The simulator-free pipeline is :func:`mks_sim.localize.localize_cloud`; the workstation flow
is :func:`mks_sim.workstation.localize_object`.
"""

from mks_sim.localization.representation import (
    Representation,
    RepresentationConfig,
    representation_of,
)
from mks_sim.localization.verify import Consistency, batch_explained, consistency, find_table

__all__ = [
    "Consistency",
    "Representation",
    "RepresentationConfig",
    "batch_explained",
    "consistency",
    "find_table",
    "representation_of",
]
