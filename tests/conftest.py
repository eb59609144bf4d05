"""Suite-wide settings: deterministic property tests, headless GL."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

if os.environ.get("PYTEST_XDIST_WORKER"):
    # One thread a worker, as the episode pool's workers (mks_sim.tasks.backends): two workers
    # on two cores, each with two BLAS and two numba threads, oversubscribe them (one pair of
    # runs: 630 s, 616 s with one -- within the runs' spread). A test of threads sets its own.
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")
    import numba  # noqa: E402

    numba.set_num_threads(1)

import atexit  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

from hypothesis import HealthCheck, settings  # noqa: E402

from mks_sim.sim.piles import CACHE_ENV  # noqa: E402

# Property tests must be deterministic in CI: the same examples every run.
settings.register_profile(
    "mks",
    derandomize=True,
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("mks")


_PILES = Path(__file__).parent / "assets" / "piles"


def pytest_configure(config) -> None:
    """The pile cache (``mks_sim.sim.piles``) of the run, unless the environment names one:
    the piles kept in ``tests/assets/piles`` (the tuning bins the suite localizes in, each
    keyed by the compiled model, seed, MuJoCo version and settling code: a change settles
    anew) and a folder of this run for the rest, shared by the workers (they inherit the
    controller's environment); never the user's cache."""
    if hasattr(config, "workerinput") or CACHE_ENV in os.environ:
        return
    run_dir = tempfile.mkdtemp(prefix="mks_sim_piles_")
    atexit.register(shutil.rmtree, run_dir, True)
    os.environ[CACHE_ENV] = os.pathsep.join([run_dir, str(_PILES)])


def pytest_sessionfinish(session) -> None:
    """``MKS_KERNEL_SIGNATURES=<file>``: add the kernel signatures this process used to the
    file (``mks_sim.kernels.record``; the list ``make test`` compiles ahead)."""
    path = os.environ.get("MKS_KERNEL_SIGNATURES")
    if path:
        from mks_sim import kernels

        kernels.record(path)
