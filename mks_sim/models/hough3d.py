"""3-D Hough shape model under translation (paper section 2.2).

The model is a set of vertexes ``P`` and a reference point ``P0`` (default: their centroid),
stored as the displacement vectors ``P0 - p`` from each vertex to the reference point. Every
detected vertex ``e`` votes for ``e + d`` for every displacement ``d``; the maxima of the
accumulator are the candidate positions of the translated reference point. For a translated
model the maximum is unique and equals the number of detected vertexes; missing vertexes lower
it; several copies of the object give several maxima (section 2.2).

The accumulator is sparse: votes are quantised to cubic cells of side ``cell`` and counted with
``np.unique`` over the occupied cells only, so memory grows with the number of votes
(``m * n``), never with the volume of space ("a 3-D accumulator array ... could easily exhaust
the memory of a machine", section 4.2). To be robust to noise each vote goes to the 2x2x2
cells nearest to it (so a vote near a cell border is not split from its partners), a detected
vertex counts at most once per cell, and adjacent cells of the same peak are merged.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_array
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.points import as_points
from mks_sim.geometry.transforms import make_transform
from mks_sim.models.pose import PoseHypothesis

__all__ = ["SparseAccumulator", "TranslationHough3D", "accumulate_sparse"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int64)


@dataclass(frozen=True, eq=False)
class SparseAccumulator:
    """Occupied cells of a quantised 3-D accumulator.

    Attributes:
        cells: (C, 3) int64 cell indices (cell ``c`` spans ``[c, c + 1) * cell_size``... shifted
            by half a cell: its centre is ``c * cell_size``).
        counts: (C,) votes per cell (distinct voters).
        cell_size: the cell side, in the points' units.
    """

    cells: NDArray[np.int64]
    counts: NDArray[np.int64]
    cell_size: float

    def centres(self) -> FloatArray:
        """(C, 3) cell centres."""
        return self.cells.astype(np.float64) * self.cell_size

    def __len__(self) -> int:
        return len(self.counts)


def accumulate_sparse(
    votes: ArrayLike, voters: ArrayLike, cell_size: float, spread: bool = True
) -> SparseAccumulator:
    """Quantise vote positions and count distinct voters per occupied cell.

    Args:
        votes: (V, 3) vote positions.
        voters: (V,) int id of the voter (a voter counts once per cell).
        cell_size: cell side (> 0).
        spread: vote into the 2x2x2 nearest cells (noise robustness) instead of the one cell
            containing the vote.

    Returns:
        The sparse accumulator.
    """
    V = as_points(votes, "accumulate_sparse: votes")
    ids = np.asarray(voters, dtype=np.int64).reshape(-1)
    if ids.shape != (len(V),):
        raise DataError(f"accumulate_sparse: expected {len(V)} voter ids, got {ids.shape}")
    if not cell_size > 0:
        raise SpecError(f"accumulate_sparse: cell_size: expected > 0, got {cell_size!r}")
    q = V / cell_size
    if spread:
        base = np.floor(q).astype(np.int64)  # the 8 cells whose centres surround the vote
        cells = (base[:, None, :] + _CORNERS[None]).reshape(-1, 3)
        ids = np.repeat(ids, len(_CORNERS))
    else:
        cells = np.rint(q).astype(np.int64)
    rows = np.unique(np.column_stack([cells, ids]), axis=0)  # one vote per (cell, voter)
    uniq, counts = np.unique(rows[:, :3], axis=0, return_counts=True)
    return SparseAccumulator(uniq, counts.astype(np.int64), float(cell_size))


class TranslationHough3D:
    """The 3-D Hough shape model of section 2.2 (translation only).

    Args:
        points: (n, 3) model vertexes.
        reference: (3,) reference point; default the centroid (the paper's example).
        cell: accumulator cell side; default 2 % of the model's diameter. Set it to about 2-3x
            the noise of the detected vertexes.
        name: model name.
        min_votes: maxima with fewer votes are not reported (default 2, or 1 for one vertex).
        symmetries: optional (K, 3, 3) rotations of the model (kept for evaluation).
    """

    def __init__(
        self,
        points: ArrayLike,
        reference: ArrayLike | None = None,
        cell: float | None = None,
        name: str = "",
        min_votes: int | None = None,
        symmetries: ArrayLike | None = None,
    ) -> None:
        P = as_points(points, "TranslationHough3D: model points")
        self.points: FloatArray = P
        self.name = name
        self.description = ""
        self.unit = ""
        self.symmetries = None if symmetries is None else np.asarray(symmetries, dtype=float)
        if reference is None:
            ref = P.mean(axis=0)
        else:
            ref = np.asarray(reference, dtype=np.float64).reshape(-1)
            if ref.shape != (3,) or not np.all(np.isfinite(ref)):
                raise DataError(
                    f"TranslationHough3D: reference: expected 3 finite numbers, got {reference!r}"
                )
        self.reference: FloatArray = ref
        self.displacements: FloatArray = ref - P  # (n, 3) vertex -> reference
        diameter = float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))
        if cell is None:
            cell = 0.02 * diameter if diameter > 0 else 1.0
        if not np.isfinite(cell) or cell <= 0:
            raise SpecError(f"TranslationHough3D: cell: expected a number > 0, got {cell!r}")
        self.cell = float(cell)
        self.min_votes = min_votes

    def accumulate(self, points: ArrayLike) -> SparseAccumulator:
        """Vote: every detected vertex ``e`` for ``e + d`` for every displacement ``d``."""
        D = as_points(points, "TranslationHough3D: detected points", min_points=1)
        votes = (D[:, None, :] + self.displacements[None]).reshape(-1, 3)  # (m * n, 3)
        voters = np.repeat(np.arange(len(D)), len(self.displacements))
        return accumulate_sparse(votes, voters, self.cell)

    def detect(self, points: ArrayLike) -> list[PoseHypothesis]:
        """Every accumulator maximum as a translation hypothesis, most votes first.

        Args:
            points: (m, 3) detected vertexes.

        Returns:
            Hypotheses (rotation identity); ``votes`` = detected vertexes supporting the
            maximum, ``reference_point`` the refined P0', ``correspondences`` (detected,
            model) pairs, ``rmse`` of the pairs about the translation.
        """
        D = as_points(points, "TranslationHough3D: detected points", min_points=1)
        acc = self.accumulate(D)
        min_votes = self.min_votes if self.min_votes is not None else min(2, len(D))
        strong = acc.counts >= min_votes
        cells, counts = acc.cells[strong], acc.counts[strong]
        if len(cells) == 0:
            return []
        # Adjacent cells with the peak's count belong to one peak (the 2x2x2 spread).
        pairs = cKDTree(cells).query_pairs(r=np.sqrt(3) + 1e-9, output_type="ndarray")
        if len(pairs):
            same = counts[pairs[:, 0]] == counts[pairs[:, 1]]
            pairs = pairs[same]
        adj = coo_array(
            (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells))
        )
        n_lab, labels = connected_components(adj, directed=False)
        # A peak is a local maximum: no neighbouring cell (outside it) has more votes.
        tree = cKDTree(cells)
        hyps: list[PoseHypothesis] = []
        seen: set[bytes] = set()
        for lab in range(n_lab):
            members = np.flatnonzero(labels == lab)
            v = int(counts[members[0]])
            nb = tree.query_ball_point(cells[members], r=np.sqrt(3) + 1e-9)
            nb_idx = np.unique(np.concatenate([np.asarray(x, dtype=np.int64) for x in nb]))
            if counts[nb_idx].max() > v:
                continue
            h = self._hypothesis(acc.cell_size * cells[members].mean(axis=0), D)
            if h is None or h.votes < min_votes:
                continue
            key = h.correspondences.tobytes()
            if key in seen:
                continue
            seen.add(key)
            hyps.append(h)
        hyps.sort(key=lambda h: (-h.votes, h.rmse))
        return hyps

    def _hypothesis(self, centre: FloatArray, D: FloatArray) -> PoseHypothesis | None:
        """Pair each detected vertex with its vote nearest the peak; fit the translation."""
        votes = D[:, None, :] + self.displacements[None]  # (m, n, 3)
        dist = np.linalg.norm(votes - centre, axis=2)  # (m, n)
        j = dist.argmin(axis=1)
        ok = dist[np.arange(len(D)), j] <= 1.5 * np.sqrt(3) * self.cell
        det_idx = np.flatnonzero(ok)
        mod_idx = j[ok]
        # One model vertex per detected vertex and vice versa: keep the closer claim.
        order = np.argsort(dist[det_idx, mod_idx])
        _, first = np.unique(mod_idx[order], return_index=True)
        keep = np.sort(order[first])
        det_idx, mod_idx = det_idx[keep], mod_idx[keep]
        if len(det_idx) == 0:
            return None
        t = (D[det_idx] - self.points[mod_idx]).mean(axis=0)
        resid = D[det_idx] - (self.points[mod_idx] + t)
        rmse = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
        return PoseHypothesis(
            matrix=make_transform(np.eye(3), t),
            reference_point=self.reference + t,
            votes=len(det_idx),
            correspondences=np.column_stack([det_idx, mod_idx]),
            rmse=rmse,
        )
