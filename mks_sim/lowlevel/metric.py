"""Distance functions for the k-d tree and the SPG (paper sections 1.2, 2.1 and 3).

Two families:

* Minkowski metrics (Euclidean ``p=2``, Manhattan ``p=1``, Chebyshev ``p=inf``) with optional
  per-feature range normalisation and weights — the paper's "normalizing the ranges of the
  features and assigning weights" (section 3). They are implemented by *scaling coordinates*
  (``x'_i = x_i * w_i / range_i``), so ``scipy.spatial.cKDTree`` answers them exactly:

  ``d(a, b) = || (a - b) * w / range ||_p``

* The paper's general form ``distance(m, v) = SUM f_i(m_i, v_i)`` (section 2.1) with
  user-supplied ``f_i`` (:meth:`Metric.sum_of`). Each ``f_i`` must be vectorised over numpy
  arrays, return values ``>= 0`` and be non-decreasing in ``|m_i - v_i|`` on each side of
  ``m_i``. The k-d tree answers such queries exactly by a superset box query followed by an
  exact refinement (see :mod:`mks_sim.lowlevel.kdtree`).

Argument order: the first argument of ``f_i`` is the *query* point, the second a point stored
in the tree. :meth:`Metric.transposed` swaps them (for asymmetric ``f_i``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError, SpecError

FeatureDistance = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]

__all__ = ["FeatureDistance", "Metric", "abs_diff"]

# Bisection steps for inverting f_i. Every step keeps `hi` a valid bound (f(hi) > r), so fewer
# steps only loosen the superset (by span * 2**-32), never break exactness.
_BISECT_STEPS = 32


def abs_diff(scale: float = 1.0) -> FeatureDistance:
    """Return ``f(m, v) = |m - v| / scale`` — a ready-made ``f_i`` for :meth:`Metric.sum_of`."""
    if not (scale > 0 and math.isfinite(scale)):
        raise SpecError(f"abs_diff: expected a positive finite scale, got {scale!r}")

    def f(m: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.abs(np.asarray(m, float) - np.asarray(v, float)) / scale

    return f


def _positive_tuple(values: ArrayLike | None, what: str) -> tuple[float, ...] | None:
    if values is None:
        return None
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 2 and arr.shape[1] == 2:  # (k, 2) low/high pairs -> widths
        arr = arr[:, 1] - arr[:, 0]
    if arr.ndim != 1 or arr.size == 0:
        raise SpecError(
            f"Metric {what}: expected a (k,) sequence (or (k, 2) low/high), got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise SpecError(f"Metric {what}: expected positive finite values, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


@dataclass(frozen=True)
class Metric:
    """A distance function on k-vectors.

    Build with :meth:`euclidean`, :meth:`manhattan`, :meth:`chebyshev`, :meth:`minkowski` or
    :meth:`sum_of`; do not call the constructor directly.

    Attributes:
        kind: ``"minkowski"`` or ``"sum_of"``.
        p: Minkowski exponent (1, 2 or ``inf``; any ``p >= 1`` works).
        weights: per-feature weights (k,) or None (all 1).
        ranges: per-feature range widths (k,) or None (no normalisation).
        fs: the ``f_i`` of a ``sum_of`` metric.
        scales: ``sum_of`` only: coordinate scales used to build the bounding tree (k,) or None.
            They never change results, only how tight the superset query is.
    """

    kind: str = "minkowski"
    p: float = 2.0
    weights: tuple[float, ...] | None = None
    ranges: tuple[float, ...] | None = None
    fs: tuple[FeatureDistance, ...] = field(default=(), compare=True)
    scales: tuple[float, ...] | None = None
    swapped: bool = False

    # ------------------------------------------------------------------ constructors
    @classmethod
    def minkowski(
        cls, p: float, weights: ArrayLike | None = None, ranges: ArrayLike | None = None
    ) -> Metric:
        """Weighted, range-normalised Minkowski metric ``||(a - b) * w / range||_p``."""
        if not (p >= 1):
            raise SpecError(f"Metric.minkowski: expected p >= 1, got {p!r}")
        return cls(
            kind="minkowski",
            p=float(p),
            weights=_positive_tuple(weights, "weights"),
            ranges=_positive_tuple(ranges, "ranges"),
        )

    @classmethod
    def euclidean(cls, weights: ArrayLike | None = None, ranges: ArrayLike | None = None) -> Metric:
        """Euclidean distance (p=2), optionally weighted and range-normalised."""
        return cls.minkowski(2.0, weights, ranges)

    @classmethod
    def manhattan(cls, weights: ArrayLike | None = None, ranges: ArrayLike | None = None) -> Metric:
        """Manhattan distance (p=1), optionally weighted and range-normalised."""
        return cls.minkowski(1.0, weights, ranges)

    @classmethod
    def chebyshev(cls, weights: ArrayLike | None = None, ranges: ArrayLike | None = None) -> Metric:
        """Chebyshev distance (p=inf), optionally weighted and range-normalised."""
        return cls.minkowski(math.inf, weights, ranges)

    @classmethod
    def sum_of(cls, fs: Sequence[FeatureDistance], scales: ArrayLike | None = None) -> Metric:
        """The paper's ``distance(m, v) = SUM f_i(m_i, v_i)`` (section 2.1).

        Args:
            fs: one callable per feature, ``f_i(m (Q,), v (Q,)) -> (Q,) >= 0``, vectorised,
                non-decreasing in ``|m_i - v_i|`` on each side of ``m_i``.
            scales: optional (k,) typical scale of each feature; the bounding tree is built on
                ``x / scales`` (tighter supersets when features have very different units).
        """
        fs = tuple(fs)
        if not fs or not all(callable(f) for f in fs):
            raise SpecError(
                f"Metric.sum_of: expected a non-empty sequence of callables, got {fs!r}"
            )
        sc = _positive_tuple(scales, "scales")
        if sc is not None and len(sc) != len(fs):
            raise SpecError(f"Metric.sum_of: expected {len(fs)} scales, got {len(sc)}")
        return cls(kind="sum_of", p=1.0, fs=fs, scales=sc)

    # ------------------------------------------------------------------ properties
    @property
    def is_minkowski(self) -> bool:
        """True when cKDTree answers the metric exactly on scaled coordinates."""
        return self.kind == "minkowski"

    @property
    def dim(self) -> int | None:
        """The k the metric is tied to, or None if it works for any k."""
        if self.kind == "sum_of":
            return len(self.fs)
        for t in (self.weights, self.ranges):
            if t is not None:
                return len(t)
        return None

    def transposed(self) -> Metric:
        """The metric with the arguments of every ``f_i`` swapped (identity for Minkowski)."""
        if self.kind != "sum_of":
            return self
        return Metric(
            kind="sum_of", p=1.0, fs=self.fs, scales=self.scales, swapped=not self.swapped
        )

    def check_dim(self, k: int, where: str = "") -> None:
        """Raise :class:`DataError` if the metric is tied to a different k."""
        d = self.dim
        if d is not None and d != k:
            raise DataError(
                f"{where or 'Metric'}: metric is defined on k={d} features, data has k={k}"
            )

    def coordinate_scale(self, k: int) -> NDArray[np.float64]:
        """(k,) multipliers applied to coordinates before they enter cKDTree."""
        self.check_dim(k)
        s = np.ones(k)
        if self.kind == "sum_of":
            if self.scales is not None:
                s = 1.0 / np.asarray(self.scales)
            return s
        if self.weights is not None:
            s = s * np.asarray(self.weights)
        if self.ranges is not None:
            s = s / np.asarray(self.ranges)
        return s

    # ------------------------------------------------------------------ evaluation
    def terms(self, query: ArrayLike, data: ArrayLike) -> NDArray[np.float64]:
        """Per-feature ``f_i(query_i, data_i)`` of a ``sum_of`` metric, broadcast: (..., k)."""
        q, d = np.broadcast_arrays(np.asarray(query, float), np.asarray(data, float))
        if self.swapped:
            q, d = d, q
        out = np.empty(q.shape, dtype=float)
        for i, f in enumerate(self.fs):
            out[..., i] = f(q[..., i], d[..., i])
        return out

    def distance(self, query: ArrayLike, data: ArrayLike) -> NDArray[np.float64]:
        """Distance between broadcast rows: query (..., k), data (..., k) -> (...,)."""
        q = np.asarray(query, dtype=float)
        d = np.asarray(data, dtype=float)
        k = q.shape[-1]
        self.check_dim(k)
        if self.kind == "sum_of":
            return np.asarray(self.terms(q, d).sum(axis=-1))
        if self.weights is None and self.ranges is None:
            diff = np.abs(q - d)
        else:
            # Scale first, then subtract: the same arithmetic as cKDTree on scaled coordinates,
            # so tree distances and these agree to the last bit.
            s = self.coordinate_scale(k)
            diff = np.abs(q * s - d * s)
        if self.p == math.inf:
            return np.asarray(diff.max(axis=-1)) if k else np.zeros(diff.shape[:-1])
        if self.p == 1:
            return np.asarray(diff.sum(axis=-1))
        if self.p == 2:
            return np.asarray(np.sqrt((diff * diff).sum(axis=-1)))
        return np.asarray((diff**self.p).sum(axis=-1) ** (1.0 / self.p))

    def axis_bounds(
        self,
        query: NDArray[np.float64],
        r: NDArray[np.float64],
        span: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """Per-axis bounds of a ``sum_of`` threshold ball.

        Since every ``f_i >= 0``, ``SUM f_i <= r`` implies ``f_i(d_i) <= r`` for each i, and by
        monotonicity ``|d_i| < b_i`` with ``b_i`` the first offset at which ``f_i`` exceeds r.
        ``b_i`` is found by bisection on ``[0, span_i]`` (an offset beyond the data's extent
        reaches no point, so the axis is then unbounded for our purpose).

        Args:
            query: (Q, k) query points.
            r: (Q,) thresholds.
            span: (Q, k) largest offset from each query coordinate to the data's bounding box.

        Returns:
            (Q, k) bounds; every point within distance r lies within them (strictly or equal).
        """
        q = np.asarray(query, float)
        r = np.asarray(r, float)[:, None]
        span = np.maximum(np.asarray(span, float), 0.0)
        bound = np.empty_like(q)
        for sign in (1.0, -1.0):

            def f_at(off: NDArray[np.float64], sign: float = sign) -> NDArray[np.float64]:
                return self.terms(q, q + sign * off)

            inside_all = f_at(span) <= r  # the whole axis side lies in the ball
            lo = np.zeros_like(q)
            hi = span.copy()
            for _ in range(_BISECT_STEPS):
                mid = 0.5 * (lo + hi)
                ok = f_at(mid) <= r
                lo = np.where(ok, mid, lo)
                hi = np.where(ok, hi, mid)
            side = np.where(inside_all, span, hi)
            bound = side if sign > 0 else np.maximum(bound, side)
        # Guard against rounding in q + off: widen by a relative hair (still a superset).
        return bound * (1.0 + 1e-9) + 1e-12 * (1.0 + np.abs(q))


def validate_points(points: ArrayLike, where: str, k: int | None = None) -> NDArray[np.float64]:
    """Convert to a finite (N, k) float64 array or raise :class:`DataError`."""
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(
            f"{where}: expected an (N, k) array of numbers, got {type(points).__name__}"
        ) from exc
    if arr.ndim == 1 and k is not None and arr.size == k:
        arr = arr[None, :]
    if arr.ndim != 2:
        raise DataError(f"{where}: expected an (N, k) array, got shape {arr.shape}")
    if k is not None and arr.shape[1] != k:
        raise DataError(f"{where}: expected k={k} columns, got shape {arr.shape}")
    if arr.shape[1] == 0:
        raise DataError(f"{where}: expected k >= 1 columns, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        rows = np.unique(np.nonzero(bad)[0])[:5].tolist()
        raise DataError(f"{where}: expected finite values, got NaN/inf in rows {rows}")
    return arr
