"""2-D Hough shape models: the paper's generalized Hough (section 2.2) and Ballard's R-table.

:class:`GeneralizedHough2D` is the algorithm exactly as section 2.2 states it: the model is a
reference point and the displacement vectors from the boundary points to it; "for all e, a
detected edge location, and for all d, a displacement vector, increment the accumulator at
(e + d)". Figures 2-2 / 2-3 are its worked example (see :mod:`mks_sim.paper.hough_cases`).

:class:`RTableHough` goes beyond the paper: Ballard's generalized Hough transform ("Generalizing
the Hough transform to detect arbitrary shapes", 1981), whose R-table indexes the displacement
vectors by the edge's gradient direction so that each edge votes only with the displacements of
boundary points of the same orientation, with an optional search over rotation and scale. Edges
and gradients come from OpenCV (Canny + Sobel).

Coordinates: points are ``(x, y)`` with ``x`` the column and ``y`` the row of an image (``y``
grows downwards); angles are measured from +x towards +y (``atan2(gy, gx)``), in radians.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError, SpecError

__all__ = [
    "GeneralizedHough2D",
    "Hough2DMatch",
    "RTableHough",
    "edges_and_gradients",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def _points2(points: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise DataError(f"{name}: expected an (N, 2) array of (x, y) points, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{name}: expected finite coordinates, got NaN or inf")
    return arr


class GeneralizedHough2D:
    """The paper's generalized 2-D Hough shape model (section 2.2, Figures 2-2 and 2-3).

    Args:
        boundary_points: (n, 2) model boundary points ``(x, y)``.
        reference: (2,) model reference point (default the origin, as in Figure 2-2).
    """

    def __init__(self, boundary_points: ArrayLike, reference: ArrayLike = (0.0, 0.0)) -> None:
        B = _points2(boundary_points, "GeneralizedHough2D: boundary_points")
        ref = np.asarray(reference, dtype=np.float64).reshape(-1)
        if ref.shape != (2,) or not np.all(np.isfinite(ref)):
            raise DataError(f"GeneralizedHough2D: reference: expected (x, y), got {reference!r}")
        self.boundary_points = B
        self.reference = ref
        # "compute the displacement vector from the boundary point to the reference point"
        self.displacements: FloatArray = ref - B

    @classmethod
    def from_displacements(cls, displacements: ArrayLike) -> GeneralizedHough2D:
        """A model given directly by its displacement vectors (reference at the origin)."""
        d = _points2(displacements, "GeneralizedHough2D: displacements")
        return cls(-d, (0.0, 0.0))

    def accumulate(
        self, edges: ArrayLike, shape: tuple[int, int], origin: int = 0
    ) -> tuple[NDArray[np.int64], int]:
        """Vote: for every edge ``e`` and displacement ``d``, increment the cell at ``e + d``.

        Args:
            edges: (m, 2) integer edge locations ``(x, y)`` = (column, row).
            shape: ``(rows, cols)`` of the accumulator array.
            origin: index of the first row/column (1 for the paper's 1-based figures).

        Returns:
            ``(accumulator (rows, cols) int, off)``: ``accumulator[row - origin, col - origin]``
            holds the votes; ``off`` counts votes that fell outside the array.
        """
        E = _points2(edges, "GeneralizedHough2D.accumulate: edges")
        votes = (E[:, None, :] + self.displacements[None]).reshape(-1, 2)
        cells = np.rint(votes).astype(np.int64) - origin  # (V, 2) (x, y) -> (col, row)
        rows, cols = shape
        inside = (
            (cells[:, 0] >= 0) & (cells[:, 0] < cols) & (cells[:, 1] >= 0) & (cells[:, 1] < rows)
        )
        acc = np.zeros((rows, cols), dtype=np.int64)
        np.add.at(acc, (cells[inside, 1], cells[inside, 0]), 1)
        return acc, int((~inside).sum())

    @staticmethod
    def maxima(acc: ArrayLike, origin: int = 0) -> tuple[int, NDArray[np.int64]]:
        """Global maximum of an accumulator and its cells ``(x, y)`` (possibly several)."""
        A = np.asarray(acc)
        top = int(A.max()) if A.size else 0
        rows, cols = np.nonzero(A == top)
        return top, np.column_stack([cols, rows]) + origin


# --------------------------------------------------------------------------- R-table (Ballard)


def edges_and_gradients(
    image: ArrayLike, low: float = 50.0, high: float = 150.0, blur: int = 3
) -> tuple[FloatArray, FloatArray]:
    """Edge locations (Canny) and gradient directions (Sobel) of a grey image.

    Args:
        image: (H, W) uint8 or float grey image (or (H, W, 3) BGR).
        low, high: Canny hysteresis thresholds.
        blur: Gaussian blur kernel size before Sobel (odd; 0 for none).

    Returns:
        ``(points (m, 2) float (x, y), angles (m,) radians atan2(gy, gx))``.
    """
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.size == 0:
        raise DataError(f"edges_and_gradients: expected an (H, W) image, got shape {img.shape}")
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        if not np.all(np.isfinite(f)):
            raise DataError("edges_and_gradients: image contains NaN or inf")
        span = f.max() - f.min()
        img = (255 * (f - f.min()) / (span if span > 0 else 1.0)).astype(np.uint8)
    edges = cv2.Canny(img, low, high)
    smooth = cv2.GaussianBlur(img, (blur, blur), 0) if blur else img
    gx = cv2.Sobel(smooth, cv2.CV_64F, 1, 0, ksize=3)
    gy = cv2.Sobel(smooth, cv2.CV_64F, 0, 1, ksize=3)
    ys, xs = np.nonzero(edges)
    return np.column_stack([xs, ys]).astype(np.float64), np.arctan2(gy[ys, xs], gx[ys, xs])


@dataclass(frozen=True)
class Hough2DMatch:
    """One R-table Hough maximum.

    Attributes:
        position: (2,) the template's reference point in the image ``(x, y)`` pixels.
        angle_deg: rotation of the template (from +x towards +y).
        scale: scale factor of the template.
        votes: accumulator votes.
    """

    position: tuple[float, float]
    angle_deg: float
    scale: float
    votes: int


class RTableHough:
    """Ballard's generalized Hough transform with an R-table indexed by gradient direction.

    Args:
        points: (n, 2) template edge points ``(x, y)``.
        angles: (n,) gradient directions at those points (radians).
        reference: (2,) template reference point; default the centroid of ``points``.
        n_bins: gradient-direction bins of the R-table over 360 degrees.
    """

    def __init__(
        self,
        points: ArrayLike,
        angles: ArrayLike,
        reference: ArrayLike | None = None,
        n_bins: int = 36,
    ) -> None:
        P = _points2(points, "RTableHough: points")
        a = np.asarray(angles, dtype=np.float64).reshape(-1)
        if a.shape != (len(P),) or not np.all(np.isfinite(a)):
            raise DataError(f"RTableHough: expected {len(P)} finite angles, got shape {a.shape}")
        if len(P) == 0:
            raise DataError("RTableHough: the template has no edge points")
        if n_bins < 1:
            raise SpecError(f"RTableHough: n_bins: expected >= 1, got {n_bins}")
        ref = P.mean(axis=0) if reference is None else np.asarray(reference, dtype=np.float64)
        self.reference = ref.reshape(2)
        self.n_bins = int(n_bins)
        r = self.reference - P  # (n, 2) boundary point -> reference
        b = self._bin(a)
        order = np.argsort(b, kind="stable")
        self._r = r[order]
        self._offsets = np.searchsorted(b[order], np.arange(self.n_bins + 1))

    @classmethod
    def from_image(
        cls,
        image: ArrayLike,
        reference: ArrayLike | None = None,
        n_bins: int = 36,
        low: float = 50.0,
        high: float = 150.0,
        blur: int = 3,
    ) -> RTableHough:
        """Build the R-table from a template image (edges and gradients via OpenCV)."""
        pts, ang = edges_and_gradients(image, low=low, high=high, blur=blur)
        return cls(pts, ang, reference=reference, n_bins=n_bins)

    @property
    def table(self) -> list[FloatArray]:
        """The R-table: per gradient bin, the (k, 2) displacement vectors."""
        o = self._offsets
        return [self._r[o[i] : o[i + 1]] for i in range(self.n_bins)]

    def _bin(self, angles: FloatArray) -> NDArray[np.int64]:
        frac = np.mod(angles, 2 * np.pi) / (2 * np.pi)
        return np.minimum((frac * self.n_bins).astype(np.int64), self.n_bins - 1)

    def detect_image(self, image: ArrayLike, **kwargs: object) -> list[Hough2DMatch]:
        """:meth:`detect` on an image's Canny edges and Sobel gradients."""
        canny = {k: kwargs.pop(k) for k in ("low", "high", "blur") if k in kwargs}
        pts, ang = edges_and_gradients(image, **canny)  # type: ignore[arg-type]
        shape = np.asarray(image).shape[:2]
        return self.detect(pts, ang, shape=(int(shape[0]), int(shape[1])), **kwargs)  # type: ignore[arg-type]

    def detect(
        self,
        points: ArrayLike,
        angles: ArrayLike,
        shape: tuple[int, int],
        rotations_deg: ArrayLike = (0.0,),
        scales: ArrayLike = (1.0,),
        cell: float = 2.0,
        n_best: int = 1,
        min_separation: float = 10.0,
    ) -> list[Hough2DMatch]:
        """Vote with the R-table over positions, rotations and scales.

        Each edge with gradient direction ``phi`` votes, for each rotation ``theta`` and scale
        ``s``, with the displacements stored under ``phi - theta`` (and the two neighbouring
        bins, for gradient noise), rotated by ``theta`` and scaled by ``s``.

        Args:
            points: (m, 2) edge points ``(x, y)`` of the image.
            angles: (m,) their gradient directions (radians).
            shape: ``(rows, cols)`` of the image (the position accumulator's extent).
            rotations_deg: rotations to search.
            scales: scales to search.
            cell: accumulator cell side in pixels.
            n_best: how many maxima to report.
            min_separation: maxima closer than this (pixels) to a better one are suppressed.

        Returns:
            Matches, most votes first.
        """
        E = _points2(points, "RTableHough.detect: points")
        phi = np.asarray(angles, dtype=np.float64).reshape(-1)
        if phi.shape != (len(E),):
            raise DataError(f"RTableHough.detect: expected {len(E)} angles, got {phi.shape}")
        thetas = np.radians(np.asarray(rotations_deg, dtype=np.float64).reshape(-1))
        ss = np.asarray(scales, dtype=np.float64).reshape(-1)
        rows, cols = int(np.ceil(shape[0] / cell)), int(np.ceil(shape[1] / cell))
        acc = np.zeros((len(thetas), len(ss), rows, cols), dtype=np.int64)
        counts = np.diff(self._offsets)
        for ti, th in enumerate(thetas):
            b0 = self._bin(phi - th)
            for shift in (-1, 0, 1):
                b = np.mod(b0 + shift, self.n_bins)
                n_per = counts[b]
                edge_idx = np.repeat(np.arange(len(E)), n_per)
                starts = np.repeat(self._offsets[b], n_per)
                within = np.arange(len(edge_idx)) - np.repeat(np.cumsum(n_per) - n_per, n_per)
                r = self._r[starts + within]  # (V, 2)
                c, s_ = np.cos(th), np.sin(th)
                r_rot = np.column_stack([c * r[:, 0] - s_ * r[:, 1], s_ * r[:, 0] + c * r[:, 1]])
                for si, sc in enumerate(ss):
                    v = E[edge_idx] + sc * r_rot
                    q = np.floor(v / cell).astype(np.int64)
                    ok = (q[:, 0] >= 0) & (q[:, 0] < cols) & (q[:, 1] >= 0) & (q[:, 1] < rows)
                    np.add.at(acc[ti, si], (q[ok, 1], q[ok, 0]), 1)
        return self._peaks(acc, thetas, ss, cell, n_best, min_separation)

    @staticmethod
    def _peaks(
        acc: NDArray[np.int64],
        thetas: FloatArray,
        scales: FloatArray,
        cell: float,
        n_best: int,
        min_separation: float,
    ) -> list[Hough2DMatch]:
        flat = acc.ravel()
        order = np.argsort(-flat, kind="stable")
        out: list[Hough2DMatch] = []
        for k in order[: max(50 * n_best, 200)]:
            if flat[k] <= 0 or len(out) >= n_best:
                break
            ti, si, yi, xi = np.unravel_index(k, acc.shape)
            # Refine within the 3x3 cell neighbourhood (vote-weighted centre).
            a = acc[ti, si]
            y0, y1, x0, x1 = (
                max(yi - 1, 0),
                min(yi + 2, a.shape[0]),
                max(xi - 1, 0),
                min(xi + 2, a.shape[1]),
            )
            w = a[y0:y1, x0:x1].astype(np.float64)
            yy, xx = np.mgrid[y0:y1, x0:x1]
            pos = ((np.sum(w * xx) / w.sum() + 0.5) * cell, (np.sum(w * yy) / w.sum() + 0.5) * cell)
            if any(
                np.hypot(pos[0] - m.position[0], pos[1] - m.position[1]) < min_separation
                for m in out
            ):
                continue
            out.append(
                Hough2DMatch(
                    position=(float(pos[0]), float(pos[1])),
                    angle_deg=float(np.degrees(thetas[ti])),
                    scale=float(scales[si]),
                    votes=int(flat[k]),
                )
            )
        return out
