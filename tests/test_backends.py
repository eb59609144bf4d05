"""Episode backends: the local process pool and Ray (``mks_sim.tasks.backends``).

Ray starts once for this module (``ray.init(num_cpus=2)``, a fixture) and is always shut
down. A worker that dies mid-job is simulated by a job that kills its own process
(``os._exit``) on its first attempt, remembered by a marker file in ``tmp_path``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

from mks_sim.errors import MksError
from mks_sim.tasks.backends import EpisodeJob, check_backend, run_episodes


def _crash_once(job: tuple[str, int]) -> dict:
    """Return the job's number; the first attempt at job 1 kills its worker process."""
    folder, n = job
    marker = Path(folder) / f"crashed-{n}"
    if n == 1 and not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(1)  # a worker dying mid-episode, as an OOM kill or a segfault would
    return {"n": n, "pid": os.getpid()}


def _always_crash(job: tuple[str, int]) -> dict:
    os._exit(1)


def _fails(job: int) -> dict:
    raise MksError(f"episode {job} failed on purpose")


def _fail_first_or_sleep(job: tuple[str, int]) -> dict:
    folder, n = job
    if n == 0:
        raise MksError("episode 0 failed on purpose")
    time.sleep(1.0)
    (Path(folder) / f"ran-{n}").write_text("")
    return {"n": n}


def _threads(job: int) -> dict:
    return {"n": job, "omp": os.environ.get("OMP_NUM_THREADS")}


@pytest.fixture(scope="module")
def ray_session():
    ray = pytest.importorskip("ray")
    import logging

    # The test module is not importable in Ray's workers (tests/ is not a package):
    # ship its functions by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.WARNING)
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_complete(results: list[dict], n: int) -> None:
    assert [r["n"] for r in results] == list(range(n))  # job order, none lost, none twice


def test_in_process_runs_jobs_in_order(tmp_path: Path) -> None:
    jobs = [(str(tmp_path), n) for n in (0, 2, 3)]
    results = run_episodes(jobs, fn=_crash_once, workers=1, progress=False)
    assert [r["n"] for r in results] == [0, 2, 3]
    assert {r["pid"] for r in results} == {os.getpid()}


def test_local_pool_reruns_jobs_of_a_dead_worker(tmp_path: Path) -> None:
    jobs = [(str(tmp_path), n) for n in range(4)]
    results = run_episodes(jobs, fn=_crash_once, workers=2, progress=False)
    _check_complete(results, 4)
    assert (tmp_path / "crashed-1").exists()  # the first attempt did die
    assert results[1]["pid"] != int((tmp_path / "crashed-1").read_text())


def test_local_pool_gives_up_after_max_retries(tmp_path: Path) -> None:
    with pytest.raises(MksError, match=r"worker process died 2 times .*max_retries=1"):
        run_episodes([(str(tmp_path), 0)], fn=_always_crash, workers=2, max_retries=1,
                     progress=False)  # fmt: skip


def test_local_pool_propagates_episode_errors() -> None:
    with pytest.raises(MksError, match="episode [12] failed on purpose"):  # whichever ends first
        run_episodes([1, 2], fn=_fails, workers=2, progress=False)


def test_local_pool_stops_on_an_episode_error(tmp_path: Path) -> None:
    jobs = [(str(tmp_path), n) for n in range(12)]
    with pytest.raises(MksError, match="episode 0 failed on purpose"):
        run_episodes(jobs, fn=_fail_first_or_sleep, workers=2, progress=False)
    # The jobs not yet handed to a worker were cancelled, not run to the end.
    assert len(list(tmp_path.glob("ran-*"))) < 11


def test_pool_workers_get_one_blas_thread_unless_exported(monkeypatch) -> None:
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    results = run_episodes([0, 1], fn=_threads, workers=2, progress=False)
    assert [r["omp"] for r in results] == ["1", "1"]  # as Ray gives its tasks
    assert "OMP_NUM_THREADS" not in os.environ  # the parent's environment is left as it was
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    results = run_episodes([0, 1], fn=_threads, workers=2, progress=False)
    assert [r["omp"] for r in results] == ["3", "3"]


def test_bad_backend_arguments() -> None:
    with pytest.raises(MksError, match=r"--backend: expected one of \('local', 'ray'\), got 'dask'"):
        check_backend("dask")
    with pytest.raises(MksError, match="--address: only with --backend ray"):
        check_backend("local", "auto")
    with pytest.raises(MksError, match="workers: expected >= 1, got 0"):
        run_episodes([], workers=0)


def test_unreachable_ray_address_fails_fast() -> None:
    pytest.importorskip("ray")
    with pytest.raises(MksError, match=r"--address: no Ray cluster reachable at '127.0.0.1:1'"):
        run_episodes([], backend="ray", address="127.0.0.1:1")
    with pytest.raises(MksError, match=r"--address: expected auto or HOST:PORT, got 'head'"):
        run_episodes([], backend="ray", address="head")


def test_ray_missing_names_the_extra(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(MksError, match=r"Ray is not installed; run pip install 'mks-sim\[ray\]'"):
        check_backend("ray")
    from mks_sim.cli import main

    assert main(["grasp", "--object", "cube", "--backend", "ray"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'mks-sim[ray]'" in err[0]


@pytest.mark.slow
def test_ray_retries_a_dead_worker(ray_session, tmp_path: Path) -> None:
    jobs = [(str(tmp_path), n) for n in range(4)]
    results = run_episodes(jobs, fn=_crash_once, backend="ray", progress=False)
    _check_complete(results, 4)
    assert (tmp_path / "crashed-1").exists()
    assert results[1]["pid"] != int((tmp_path / "crashed-1").read_text())
    assert ray_session.is_initialized()  # a session the caller started is left running


@pytest.mark.slow
def test_ray_gives_up_after_max_retries(ray_session, tmp_path: Path) -> None:
    with pytest.raises(MksError, match=r"its worker died 2 times .*max_retries=1"):
        run_episodes([(str(tmp_path), 0)], fn=_always_crash, backend="ray", max_retries=1,
                     progress=False)  # fmt: skip


@pytest.mark.slow
def test_ray_propagates_episode_errors(ray_session) -> None:
    with pytest.raises(MksError, match="episode 2 failed on purpose"):
        run_episodes([2], fn=_fails, backend="ray", progress=False)


@pytest.mark.slow
def test_same_seeds_same_episodes_on_both_backends(ray_session) -> None:
    """Real grasp episodes (sensor-based localization): identical records but the wall time."""
    jobs = [EpisodeJob("sphere", seed) for seed in (3, 4)]
    local = run_episodes(jobs, backend="local", workers=2, progress=False)
    remote = run_episodes(jobs, backend="ray", progress=False)
    assert [e["seed"] for e in local] == [3, 4]
    for a, b in zip(local, remote, strict=True):
        a, b = dict(a), dict(b)
        a.pop("time_s"), b.pop("time_s")
        assert a == b


@pytest.mark.slow
def test_cli_records_on_ray(ray_session, tmp_path: Path, capsys) -> None:
    """``grasp --record --backend ray``: episode buffers come back from Ray workers."""
    pytest.importorskip("minari")
    import json

    from mks_sim.cli import main
    from mks_sim.record import load_recorded

    folder = tmp_path / "ray-sphere-v0"
    code = main(["grasp", "--object", "sphere", "--seed", "3", "--episodes", "2", "--backend",
                 "ray", "--record", str(folder), "--max-steps", "3", "--json"])  # fmt: skip
    assert code == 1  # three steps never lift the sphere; the dataset is written anyway
    assert [e["seed"] for e in json.loads(capsys.readouterr().out)["episodes"]] == [3, 4]
    ds = load_recorded(folder)
    assert ds.total_episodes == 2 and ds.total_steps == 6
    assert [m["seed"] for m in ds.storage.get_episode_metadata([0, 1])] == [3, 4]
