"""`PoseHypothesis`: one candidate placement of a model in the scene, as a matcher reports it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError
from mks_sim.geometry.transforms import to_row_convention

__all__ = ["PoseHypothesis"]


def _frozen(arr: NDArray[np.generic]) -> NDArray[np.generic]:
    arr = np.array(arr, copy=True)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class PoseHypothesis:
    """A candidate transformation of a model into the detected (scene) frame.

    Attributes:
        matrix: (4, 4) float, column convention, model -> detected (``p_det = matrix @ p_model``).
        reference_point: (3,) float, the model's reference point in the detected frame (the
            Hough accumulator maximum, section 2.2).
        votes: accumulator votes for this hypothesis (number of supporting features).
        correspondences: (n, 2) int, rows ``(detected index, model index)``.
        rmse: root-mean-square residual of the fit, in the points' units.
        score: verification score (e.g. inlier fraction after refinement); ``nan`` until
            verified.

    Arrays are copied and made read-only on construction.
    """

    matrix: NDArray[np.float64]
    reference_point: NDArray[np.float64]
    votes: int = 0
    correspondences: NDArray[np.int64] = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )
    rmse: float = math.nan
    score: float = math.nan

    def __post_init__(self) -> None:
        T = np.asarray(self.matrix, dtype=np.float64)
        if T.shape != (4, 4):
            raise DataError(f"PoseHypothesis.matrix: expected shape (4, 4), got {T.shape}")
        ref = np.asarray(self.reference_point, dtype=np.float64).reshape(-1)
        if ref.shape != (3,):
            raise DataError(f"PoseHypothesis.reference_point: expected shape (3,), got {ref.shape}")
        corr = np.asarray(self.correspondences, dtype=np.int64)
        if corr.size == 0:
            corr = corr.reshape(0, 2)
        if corr.ndim != 2 or corr.shape[1] != 2:
            raise DataError(
                f"PoseHypothesis.correspondences: expected shape (n, 2), got {corr.shape}"
            )
        object.__setattr__(self, "matrix", _frozen(T))
        object.__setattr__(self, "reference_point", _frozen(ref))
        object.__setattr__(self, "correspondences", _frozen(corr))
        object.__setattr__(self, "votes", int(self.votes))
        object.__setattr__(self, "rmse", float(self.rmse))
        object.__setattr__(self, "score", float(self.score))

    @property
    def matrix_row_convention(self) -> NDArray[np.float64]:
        """(4, 4) the paper's row-convention form (``p_det = p_model @ M``)."""
        return to_row_convention(self.matrix)

    @property
    def rotation(self) -> NDArray[np.float64]:
        """(3, 3) rotation block of :attr:`matrix`."""
        return self.matrix[:3, :3].copy()

    @property
    def translation(self) -> NDArray[np.float64]:
        """(3,) translation of :attr:`matrix`."""
        return self.matrix[:3, 3].copy()

    def with_score(self, score: float) -> PoseHypothesis:
        """A copy with ``score`` set (verification result)."""
        return replace(self, score=float(score))

    def with_matrix(self, matrix: ArrayLike, rmse: float | None = None) -> PoseHypothesis:
        """A copy with a refined ``matrix`` (and optionally ``rmse``)."""
        return replace(
            self,
            matrix=np.asarray(matrix, dtype=np.float64),
            rmse=self.rmse if rmse is None else float(rmse),
        )

    def __repr__(self) -> str:
        ref = np.array2string(self.reference_point, precision=4)
        return (
            f"PoseHypothesis(reference_point={ref}, votes={self.votes}, "
            f"pairs={len(self.correspondences)}, rmse={self.rmse:.4g}, score={self.score:.4g})"
        )
