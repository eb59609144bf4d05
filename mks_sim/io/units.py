"""Unit sanity check between a model and a scene (metres vs millimetres mix-ups).

A model built in millimetres matched against a scan in metres finds nothing and says nothing;
:func:`check_scale` notices the mismatch from the sizes alone and suggests the ``--scale``.
"""

from __future__ import annotations

import functools
import logging

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError

__all__ = ["check_scale", "extent", "require_spread"]

log = logging.getLogger(__name__)

_FACTORS = (1e-3, 1e-2, 2.54e-2, 1.0, 25.4, 1e2, 1e3)  # mm, cm, inch <-> m
#: the same, commonest mix-up first (mm <-> m, cm <-> m, inch <-> mm, inch <-> m)
_LIKELY = (1e-3, 1e3, 1e-2, 1e2, 25.4, 2.54e-2)


def extent(points: ArrayLike) -> float:
    """Robust size of a point set: the diagonal of its 2nd-98th percentile box (NaN-safe;
    over 4,000 points drawn with a fixed seed from a larger cloud: a 640 x 480 scan's box
    took 7 ms over all its points, and it only has to tell millimetres from metres; a
    stride would alias with the rows of an organised scan)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) > 4000:
        p = p[_sample(len(p))]
    # (per column and compress: an axis-1 all and a mask's row gather are several times slower)
    p = np.compress(np.isfinite(p[:, 0]) & np.isfinite(p[:, 1]) & np.isfinite(p[:, 2]), p, axis=0)
    if len(p) < 2:
        return 0.0
    lo, hi = _percentiles(p, 0.02), _percentiles(p, 0.98)
    return float(np.linalg.norm(hi - lo))


@functools.lru_cache(maxsize=8)
def _sample(n: int) -> NDArray[np.intp]:
    """The 4,000 rows of an n-point cloud :func:`extent` reads (drawn once per size, with
    the fixed seed: a generator's set-up cost more than the percentiles)."""
    rows: NDArray[np.intp] = np.random.default_rng(0).integers(0, n, 4000)
    rows.setflags(write=False)
    return rows


def _percentiles(p: NDArray[np.float64], q: float) -> NDArray[np.float64]:
    """``np.percentile(p, 100 q, axis=0)`` of finite (N >= 2, 3) points, to the bit (a
    zero's sign aside: which of -0.0 and 0.0 a partition puts first): the two order
    statistics around the virtual index ``(N - 1) q`` of each column by one partition, and
    numpy's linear interpolation between them (from the upper one when the weight is at
    least a half), 2x faster than numpy's general path."""
    n = len(p)
    virtual = (n - 1) * q
    below = int(np.floor(virtual))
    above = min(below + 1, n - 1)
    gamma = virtual - below
    out = np.empty(p.shape[1])
    for d in range(p.shape[1]):
        col = np.partition(p[:, d], [below, above])
        a, b = col[below], col[above]
        diff = b - a
        out[d] = b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma
    return out


def require_spread(points: ArrayLike, where: str, *, min_points: int = 3) -> None:
    """Reject a cloud that cannot hold a surface: too few finite points, all points at one
    location, or all on one line. Fast (one SVD of a centred sample), so a degenerate scene is
    refused before any grouping work.

    Raises:
        DataError: ``scan.ply: expected points spread over a surface, got all 500 points at
            (0.1, 0.2, 0.3)``.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < min_points:
        raise DataError(f"{where}: expected at least {min_points} finite points, got {len(p)}")
    span = float(np.max(np.ptp(p, axis=0)))
    if span == 0.0:
        x, y, z = (float(v) for v in p[0])
        raise DataError(
            f"{where}: expected points spread over a surface, got all {len(p)} points at "
            f"({x:.6g}, {y:.6g}, {z:.6g})"
        )
    sample = p[:: max(1, len(p) // 20000)]
    sv = np.linalg.svd(sample - sample.mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-9 * sv[0]:
        raise DataError(
            f"{where}: expected points spread over a surface, got all {len(p)} points on "
            f"one line (length {span:.4g})"
        )


def check_scale(
    model_points: ArrayLike | None,
    scene_points: ArrayLike,
    scale: float = 1.0,
    *,
    ratio: float = 10.0,
    model_extent: float | None = None,
) -> str | None:
    """A warning message when the scaled model and the scene differ in size by > ``ratio``.

    The scene may hold clutter and a table, so only a model much larger than the whole scene,
    or much smaller than a ``1 / ratio**2`` fraction of it, is flagged.

    Args:
        model_points: (M, 3) model surface points or vertices, model units.
        scene_points: (N, 3) scene points, scene units (NaN allowed).
        scale: the factor the caller will apply to the model (model units -> scene units).
        ratio: tolerated size ratio.
        model_extent: ``extent(model_points)`` when the caller has it (a long-lived model
            computes it once); ``model_points`` is then not read.

    Returns:
        None when plausible, else a message naming both sizes and the suggested scale (also
        logged as a warning).
    """
    if model_extent is None:
        if model_points is None:
            raise DataError("check_scale: expected the model's points or its extent")
        model_extent = extent(model_points)
    m = model_extent * scale
    s = extent(scene_points)
    if m <= 0 or s <= 0:
        return None
    if m <= s * ratio and m * ratio**2 >= s:
        return None
    # The commonest mix-up that brings the model into the accepted band [s / ratio**2,
    # s * ratio]: the nearest factor to a fixed target size was a coin toss between 0.001
    # and 0.01 for a 50 mm cube in mm on a 0.55 m scan in m.
    lo, hi = s / ratio**2, s * ratio
    fits = [f for f in _LIKELY if lo <= m * f <= hi]
    best = (
        fits[0] if fits else min(_FACTORS, key=lambda f: abs(np.log(m * f / (s / np.sqrt(ratio)))))
    )
    msg = (
        f"model size {m:.4g} (after scale {scale:g}) vs scene size {s:.4g}: they differ by "
        f"{max(m / s, s / m):.0f}x - are the units the same? try --scale {scale * best:g}"
    )
    log.warning(msg)
    return msg
