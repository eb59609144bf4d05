"""Localize a model in a 3-D point cloud: the simulator-free pipeline (paper sections 2.2, 4).

(Interface first; the pipeline lands in the next commits.)

A model that can be localized implements :class:`LocalizableModel`: it proposes pose
hypotheses for a scene (any way it likes: rotation-invariant Hough over vertexes, control
points, feature matching...) and offers its surface for ICP refinement and scoring.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from mks_sim.models.pose import PoseHypothesis


@runtime_checkable
class LocalizableModel(Protocol):
    """What :func:`localize_cloud` needs from a model.

    Attributes:
        name: The model's name (for logs and reports).
    """

    name: str

    def hypotheses(
        self, scene_points: np.ndarray, scene_normals: np.ndarray | None
    ) -> list[PoseHypothesis]:
        """Candidate poses of the model in one scene segment.

        Args:
            scene_points: (N, 3) float, metres (or the model's unit), scene frame; one object
                segment (the table plane already removed).
            scene_normals: (N, 3) float unit normals oriented towards the sensor, or None.

        Returns:
            Hypotheses (``matrix`` is model -> scene, 4x4 column convention) in any order;
            ``votes`` filled, ``score`` may be nan (the pipeline verifies them).
        """
        ...

    def surface_points(self) -> np.ndarray:
        """(M, 3) float points sampled on the model surface, model frame (for ICP/scoring)."""
        ...

    def surface_normals(self) -> np.ndarray:
        """(M, 3) float outward unit normals matching :meth:`surface_points`."""
        ...

    def symmetries(self) -> np.ndarray | None:
        """(S, 3, 3) rotations about the model origin that map the model onto itself, or None.

        Hypotheses that differ by one of these are reported once (equivalents listed).
        """
        ...
