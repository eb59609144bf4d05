"""The localization engine (paper section 4): one low-level representation per snapshot,
hypotheses by model kind, batch verification.

Modules, one stage each:

- :mod:`~mks_sim.localization.representation` — :class:`Representation` (k-d tree, table,
  SPG, normals, segmentation of one point set, each computed at most once) and
  :func:`representation_of` (the one representation of a stream's points).
- :mod:`~mks_sim.localization.verify` — the one table finder, batch scoring of candidate
  poses, the one scene-consistency check, ranking.
- :mod:`~mks_sim.localization.model` — the model protocol, :class:`PolyhedralModel`,
  model kinds (``polyhedral``, ``freeform``, ``sphere``; ``auto`` from a mesh), loading.
- :mod:`~mks_sim.localization.hypotheses` — vertex, plane-pair, rotation-invariant,
  support-face and sphere-centre hypotheses.
- :mod:`~mks_sim.localization.pipeline` — object segments, polyhedral candidates, the
  workstation's paths by model kind, and :func:`localize_cloud` (one recorded cloud).
- :mod:`~mks_sim.localization.workstation` — the entry from simulated sensors:
  :func:`localize_object` (snapshot -> representation -> the path of the model's kind).

``mks_sim.localize`` and ``mks_sim.workstation`` re-export these (old imports keep working).
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
