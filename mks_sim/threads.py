"""One BLAS thread while the pipeline runs (:func:`one_blas_thread`).

numpy, scipy and OpenCV each bring an OpenBLAS with a thread per core. The pipeline's
matrix products are small ((N, 3) @ (3, 3)) and run between OpenCV's and the k-d trees'
own worker threads: a threaded BLAS call then waits for threads that are busy or asleep.
With the range finder failed, the two (235k, 3) @ (3, 3) products of ``stereo_to_points``
took 90-100 ms each inside a localization and 1.4 ms alone; on the healthy path the
slowest 5 % of localizations were the ones that waited (part p95 133 -> 92 ms with one
BLAS thread, the medians unchanged). One thread gives the same products (the split is over
rows, not over the sums).

Uses ``threadpoolctl`` (the library scikit-learn uses for the same thing); the limit is
undone when the block ends, so a caller's own BLAS settings are kept. The limit is
process-wide: localizations run in several threads of one process at once would restore
each other's settings out of order (the package runs them in processes: ``--workers``,
Ray).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["one_blas_thread", "with_one_blas_thread"]

_CONTROLLER: Any = None
F = TypeVar("F", bound=Callable[..., Any])


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every loaded BLAS library limited to one thread."""
    global _CONTROLLER
    from threadpoolctl import ThreadpoolController

    if _CONTROLLER is None:  # ~2 ms: it lists the loaded libraries; the limit costs ~15 us
        import cv2  # noqa: F401  (its OpenBLAS too: the stereo pair's products)
        import numpy  # noqa: F401
        import scipy.linalg  # noqa: F401

        _CONTROLLER = ThreadpoolController()
    with _CONTROLLER.limit(limits=1, user_api="blas"):
        yield


def with_one_blas_thread(fn: F) -> F:
    """Decorator: ``fn`` runs inside :func:`one_blas_thread`."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with one_blas_thread():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
