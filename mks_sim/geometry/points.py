"""The one validator for point arrays at the boundary of the geometry and model rooms."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError

FloatArray = NDArray[np.float64]


def as_points(
    points: ArrayLike, where: str, min_points: int = 1, *, allow_single: bool = False
) -> FloatArray:
    """Validate and return an (N, 3) finite float64 array.

    Args:
        points: (N, 3) coordinates (or (3,) when ``allow_single``, returned as (1, 3)).
        where: what the array is, for the error message (e.g. ``"scene points"``).
        min_points: fewest rows accepted.
        allow_single: accept one point given as a (3,) vector.

    Raises:
        DataError: not numbers, wrong shape, too few rows, or NaN/inf in any row (the message
            counts the bad rows: callers that should drop them do so before calling this).
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{where}: expected (N, 3) numbers, got {type(points).__name__}") from exc
    if allow_single and arr.shape == (3,):
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise DataError(f"{where}: expected shape (N, 3), got {arr.shape}")
    if arr.shape[0] < min_points:
        raise DataError(f"{where}: expected at least {min_points} points, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(arr), axis=1)))
        raise DataError(f"{where}: {bad} rows contain NaN or inf; drop them first")
    return arr


def fibonacci_sphere(n: int) -> FloatArray:
    """(n, 3) unit vectors spread evenly over the sphere (Fibonacci lattice, ``z`` from
    ``1 - 1/n`` down to ``-1 + 1/n``): the one direction sampler of the package."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]
