"""Where episodes run: in this process, a local process pool, or Ray tasks.

An episode is a pure function of its job (seed -> result, :func:`mks_sim.tasks.episode.
run_episode`), so any engine that maps a function over jobs can run a sweep. Two backends:

- ``"local"`` (default): this process for ``workers == 1``, else a spawn-started
  :class:`~concurrent.futures.ProcessPoolExecutor`. A worker that dies takes the pool with it
  (``BrokenProcessPool``); the unfinished jobs are resubmitted to a fresh pool.
- ``"ray"``: one Ray task per job (``ray.remote(max_retries=...)``). Ray re-executes a task
  whose worker process died; application errors are not retried. ``address=None`` starts a
  local Ray with ``workers`` CPUs (and shuts it down afterwards); ``"auto"`` or
  ``"HOST:PORT"`` joins a running cluster (see ``docs/scale.md``). When Ray is already
  initialised in this process (a test fixture, a notebook) that session is used and left
  running.

Either way the results come back in job order, one per job: a retried job is counted once.

Example:
    >>> from mks_sim.tasks.backends import EpisodeJob, run_episodes
    >>> jobs = [EpisodeJob("sphere", seed) for seed in (0, 1)]
    >>> results = run_episodes(jobs, backend="local", workers=2)  # doctest: +SKIP
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import socket
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from mks_sim.errors import MksError

__all__ = [
    "BACKENDS",
    "EpisodeJob",
    "check_backend",
    "grasp_episode",
    "ray_available",
    "ray_session",
    "run_episodes",
]

logger = logging.getLogger(__name__)

BACKENDS = ("local", "ray")
#: Re-runs of a job whose worker process died (Ray's own default is 3 as well).
MAX_RETRIES = 3
RAY_INSTALL_HINT = "pip install 'mks-sim[ray]'"

EpisodeFn = Callable[[Any], dict]


@dataclass(frozen=True)
class EpisodeJob:
    """One grasp episode to run.

    Attributes:
        object: ``cube`` | ``sphere`` | ``part`` (task ``grasp_<object>``).
        seed: the episode seed.
        faults: device names failed for the whole episode.
    """

    object: str
    seed: int
    faults: tuple[str, ...] = ()


def grasp_episode(job: EpisodeJob) -> dict:
    """The closed-loop grasp of ``job`` as the CLI's per-episode JSON record.

    Module-level so that spawn-started processes and Ray workers import it by name.
    """
    from mks_sim.tasks.episode import run_episode

    return run_episode(job.object, job.seed, job.faults).to_json()


def ray_available() -> bool:
    """Whether ``import ray`` works (the ``ray`` extra is installed)."""
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def check_backend(backend: str, address: str | None = None) -> None:
    """Validate a backend choice before any episode runs.

    Raises:
        MksError: unknown backend, ``address`` without Ray, or Ray not installed.
    """
    if backend not in BACKENDS:
        raise MksError(f"--backend: expected one of {BACKENDS}, got {backend!r}")
    if address is not None and backend != "ray":
        raise MksError(f"--address: only with --backend ray, got --backend {backend}")
    if backend == "ray" and not ray_available():
        raise MksError(f"--backend ray: Ray is not installed; run {RAY_INSTALL_HINT}")


def run_episodes(
    jobs: Sequence[Any],
    *,
    fn: EpisodeFn = grasp_episode,
    backend: str = "local",
    address: str | None = None,
    workers: int = 1,
    max_retries: int = MAX_RETRIES,
    progress: bool = True,
    desc: str = "episodes",
    on_result: Callable[[int, dict], Any] | None = None,
) -> list[Any]:
    """Run ``fn(job)`` for every job on ``backend``; results in job order.

    Args:
        jobs: the jobs (picklable; :class:`EpisodeJob` for the default ``fn``).
        fn: a module-level function ``job -> dict`` (imported by name in the workers).
        backend: ``"local"`` or ``"ray"``.
        address: Ray only: None (start a local Ray with ``workers`` CPUs), ``"auto"`` or
            ``"HOST:PORT"`` of a running cluster.
        workers: local processes (1 = this process), or the CPUs of a local Ray.
        max_retries: re-runs of a job whose worker process died.
        progress: show a tqdm bar on stderr.
        desc: the bar's label.
        on_result: called in this process as each job finishes, with the job's index and
            result, in completion order; its return value is kept instead of the result
            (e.g. a summary once the bulky part is written out).

    Returns:
        ``[fn(job) for job in jobs]`` (or what ``on_result`` kept), each job counted
        exactly once.

    Raises:
        MksError: bad arguments, Ray missing, or a job whose worker died more than
            ``max_retries`` times. Errors raised by ``fn`` itself propagate.
    """
    check_backend(backend, address)
    if workers < 1:
        raise MksError(f"workers: expected >= 1, got {workers}")
    if max_retries < 0:
        raise MksError(f"max_retries: expected >= 0, got {max_retries}")
    from tqdm import tqdm

    started = _ray_connect(address, workers) if backend == "ray" else False
    bar = tqdm(total=len(jobs), desc=desc, unit="ep", file=sys.stderr, disable=not progress)

    def finish(i: int, result: dict) -> Any:
        kept = on_result(i, result) if on_result is not None else result
        bar.update()
        return kept

    try:
        if backend == "ray":
            return _run_ray(jobs, fn, max_retries, finish)
        if workers == 1:
            return [finish(i, fn(job)) for i, job in enumerate(jobs)]
        return _run_pool(jobs, fn, workers, max_retries, finish)
    finally:
        bar.close()
        if started:
            import ray

            ray.shutdown()


def _run_pool(
    jobs: Sequence[Any],
    fn: EpisodeFn,
    workers: int,
    max_retries: int,
    finish: Callable[[int, dict], Any],
) -> list[Any]:
    """Spawn-started process pool; a broken pool is replaced and its unfinished jobs rerun."""
    with _one_thread_per_worker():
        return _pool_loop(jobs, fn, workers, max_retries, finish)


#: Thread-pool sizes of OpenMP / OpenBLAS / MKL, read when a worker loads numpy.
_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _one_thread_per_worker() -> Iterator[None]:
    """Spawned workers get one BLAS/OpenMP thread each, as Ray gives its tasks (one worker
    per core; more threads only oversubscribe). A value the user exported is kept."""
    saved = {var: os.environ.get(var) for var in _THREAD_VARS}
    for var in _THREAD_VARS:
        os.environ.setdefault(var, "1")
    try:
        yield
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


def _pool_loop(
    jobs: Sequence[Any],
    fn: EpisodeFn,
    workers: int,
    max_retries: int,
    finish: Callable[[int, dict], Any],
) -> list[Any]:
    ctx = multiprocessing.get_context("spawn")
    results: dict[int, Any] = {}
    breaks = 0
    while len(results) < len(jobs):
        todo = [i for i in range(len(jobs)) if i not in results]
        try:
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures: dict[Future, int] = {pool.submit(fn, jobs[i]): i for i in todo}
                pending = set(futures)
                try:
                    while pending:
                        done, pending = wait(pending, return_when=FIRST_COMPLETED)
                        broken: BrokenProcessPool | None = None
                        for fut in done:
                            exc = fut.exception()
                            if isinstance(exc, BrokenProcessPool):  # a worker died
                                broken = exc
                                continue
                            i = futures[fut]
                            results[i] = finish(i, fut.result())  # fn's errors propagate
                        if broken is not None:
                            raise broken
                except BaseException as exc:
                    if not isinstance(exc, BrokenProcessPool):  # an error: stop, run no more
                        pool.shutdown(wait=True, cancel_futures=True)
                    raise
        except BrokenProcessPool as exc:
            breaks += 1
            left = len(jobs) - len(results)
            if breaks > max_retries:
                raise MksError(
                    f"local pool: a worker process died {breaks} times "
                    f"(expected <= max_retries={max_retries}); {left} job(s) unfinished"
                ) from exc
            logger.warning(
                "local pool: a worker process died (%s); rerunning %d unfinished job(s)",
                exc,
                left,
            )
    return [results[i] for i in range(len(jobs))]


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast on a HOST:PORT nobody listens at (Ray itself waits minutes for its GCS)."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        raise MksError(f"--address: expected auto or HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host.removeprefix("ray://"), int(port)), timeout_s).close()
    except OSError as exc:
        raise MksError(f"--address: no Ray cluster reachable at {address!r} ({exc})") from exc


@contextlib.contextmanager
def ray_session(address: str | None = None, workers: int = 1) -> Iterator[None]:
    """Keep one Ray session open over several :func:`run_episodes` calls (a sweep).

    Starts a local Ray with ``workers`` CPUs (``address=None``) or joins ``address``, unless
    Ray is already initialised; shuts down only what it started.
    """
    check_backend("ray", address)
    started = _ray_connect(address, workers)
    try:
        yield
    finally:
        if started:
            import ray

            ray.shutdown()


def _ray_connect(address: str | None, workers: int) -> bool:
    """Initialise Ray unless it already is; True when this call started the session."""
    import ray

    if address not in (None, "auto"):
        _check_reachable(address)  # even with a session open: a bad address is an error
    if ray.is_initialized():
        return False
    if address is None:
        ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING)
        return True
    try:
        ray.init(address=address, logging_level=logging.WARNING)
    except ConnectionError as exc:
        raise MksError(f"--address: no Ray cluster reachable at {address!r} ({exc})") from exc
    return True


def _run_ray(
    jobs: Sequence[Any],
    fn: EpisodeFn,
    max_retries: int,
    finish: Callable[[int, dict], Any],
) -> list[Any]:
    import ray
    from ray.exceptions import RayTaskError, WorkerCrashedError

    task = ray.remote(num_cpus=1, max_retries=max_retries)(fn)
    refs = {task.remote(job): i for i, job in enumerate(jobs)}
    results: dict[int, Any] = {}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                try:
                    result = ray.get(ref)
                except WorkerCrashedError as exc:
                    raise MksError(
                        f"ray: job {refs[ref]} ({jobs[refs[ref]]!r}): its worker died "
                        f"{max_retries + 1} times (expected <= max_retries={max_retries})"
                    ) from exc
                except RayTaskError as exc:
                    # The episode's own error, as the local backend raises it (an MksError
                    # keeps its exit code).
                    cause = exc.cause
                    raise (cause if isinstance(cause, BaseException) else exc) from None
                results[refs[ref]] = finish(refs[ref], result)
    except BaseException:
        for ref in pending:  # a joined cluster would go on running them for nobody
            ray.cancel(ref)
        raise
    return [results[i] for i in range(len(jobs))]
