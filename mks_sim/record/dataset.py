"""Record scripted grasp episodes as a Minari dataset.

Each episode runs where the others run (:mod:`mks_sim.tasks.backends`: this process, a local
process pool or Ray tasks): :func:`record_episode` steps ``mks_sim/Grasp-v*`` with the
scripted policy and returns the episode as a :class:`minari.data_collector.EpisodeBuffer`
(observations, actions, rewards, terminations, truncations, infos of
:class:`~mks_sim.record.infos.StepInfo`); the driver creates the dataset with
:func:`minari.create_dataset_from_buffers` and appends the buffers in seed order as they come
in. (``minari.DataCollector`` builds the same buffers in one process, but through
``jax.tree_util`` -- the ``minari[create]`` extra, jax and jaxlib -- and cannot gather
episodes from other processes.)

The dataset lives in the folder ``DIR`` given to ``--record``; its Minari id is the folder's
name (``NAME-vN``), so ``MINARI_DATASETS_PATH=<DIR's parent>`` lets
``minari.load_dataset(DIR.name)`` find it, and ``minari.MinariDataset(DIR / "data")`` reads it
from anywhere. Storage is Arrow without JPEG (image observations stay bit-exact).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import re
import time
import warnings
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.errors import MksError

__all__ = [
    "RECORD_INSTALL_HINT",
    "RecordJob",
    "check_record_dir",
    "load_recorded",
    "record_episode",
    "record_episodes",
]

RECORD_INSTALL_HINT = "pip install 'mks-sim[record]'"
POLICY = "mks_sim.envs.scripted:ScriptedGraspPolicy"
# Minari's dataset ids without a namespace: NAME-vVERSION.
_ID_RE = re.compile(r"^[-_\w]+?-v\d+$")


@dataclasses.dataclass(frozen=True)
class RecordJob:
    """One scripted episode to record.

    Attributes:
        env_id: a registered ``mks_sim/Grasp-v*`` id.
        object: ``cube`` | ``sphere`` | ``part``.
        seed: the ``reset`` seed.
        faults: devices failed for the episode.
        max_episode_steps: truncation horizon.
    """

    env_id: str
    object: str
    seed: int
    faults: tuple[str, ...] = ()
    max_episode_steps: int = 150


def _import_minari() -> Any:
    try:
        import minari
    except ImportError as exc:
        raise MksError(f"--record: Minari is not installed; run {RECORD_INSTALL_HINT}") from exc
    try:
        import pyarrow  # noqa: F401  (Minari's Arrow storage)
    except ImportError as exc:
        raise MksError(f"--record: pyarrow is not installed; run {RECORD_INSTALL_HINT}") from exc
    return minari


def check_record_dir(directory: str | os.PathLike[str]) -> Path:
    """Validate ``--record DIR`` before any episode runs; return it as an absolute path.

    Raises:
        MksError: Minari missing; ``DIR`` is a file, a non-empty folder, not named like a
            Minari dataset id (``NAME-vN``), or its parent is missing or not writable.
    """
    _import_minari()
    path = Path(directory).expanduser().resolve()
    if path.exists() and not path.is_dir():
        raise MksError(f"--record {directory}: expected a new folder, got an existing file")
    if path.is_dir() and any(path.iterdir()):
        raise MksError(
            f"--record {directory}: expected a new or empty folder, got one with files in it "
            "(a dataset is never overwritten)"
        )
    if not _ID_RE.match(path.name):
        raise MksError(
            f"--record {directory}: expected a folder named like a Minari dataset id, "
            f"NAME-vVERSION (e.g. grasp-cube-v0), got {path.name!r}"
        )
    if not path.parent.is_dir():
        raise MksError(
            f"--record {directory}: expected a folder whose parent exists (no folder "
            f"'{path.parent}'; create it first)"
        )
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise MksError(f"--record {directory}: expected a writable parent folder '{path.parent}'")
    return path


def default_env_id() -> str:
    """The newest registered grasp env (``mks_sim.envs.ENV_IDS``)."""
    from mks_sim.envs import ENV_IDS

    return ENV_IDS[-1]


def make_env(job: RecordJob) -> Any:
    """``gym.make`` of the job's env, wrapped in :class:`~mks_sim.record.infos.StepInfo`."""
    import gymnasium as gym

    import mks_sim  # noqa: F401  (registers the envs)
    from mks_sim.record.infos import StepInfo

    env = gym.make(job.env_id, object=job.object, faults=job.faults,
                   max_episode_steps=job.max_episode_steps)  # fmt: skip
    return StepInfo(env)


def _copy(tree: Any) -> Any:
    if isinstance(tree, dict):
        return {k: _copy(v) for k, v in tree.items()}
    return np.array(tree, copy=True) if isinstance(tree, np.ndarray) else tree


def _append(columns: Any, tree: Any) -> Any:
    """Append one step's (nested dict) value to per-key lists."""
    if isinstance(tree, dict):
        columns = {} if columns is None else columns
        for k, v in tree.items():
            columns[k] = _append(columns.get(k), v)
        return columns
    columns = [] if columns is None else columns
    columns.append(_copy(tree))
    return columns


def record_episode(job: RecordJob) -> dict[str, Any]:
    """Run one scripted episode and return ``{"episode": summary, "buffer": EpisodeBuffer}``.

    Module-level so that process pools and Ray workers import it by name. The summary has
    the CLI's per-episode keys (``seed``, ``success``, ``retries``, ``error``, ``time_s``,
    ``failure``) plus ``steps``.
    """
    from minari.data_collector import EpisodeBuffer

    from mks_sim.envs.scripted import ScriptedGraspPolicy

    t0 = time.perf_counter()
    env = make_env(job)
    try:
        obs, info = env.reset(seed=job.seed)
        policy = ScriptedGraspPolicy(env.unwrapped)
        observations, infos = _append(None, obs), _append(None, info)
        actions: list[np.ndarray] = []
        rewards: list[float] = []
        terminations: list[bool] = []
        truncations: list[bool] = []
        terminated = truncated = False
        while not (terminated or truncated):
            action = np.asarray(policy(obs), dtype=env.action_space.dtype)
            obs, reward, terminated, truncated, info = env.step(action)
            actions.append(action.copy())
            rewards.append(float(reward))
            terminations.append(bool(terminated))
            truncations.append(bool(truncated))
            _append(observations, obs)
            _append(infos, info)
    finally:
        env.close()
    def num(x: float) -> float | None:
        return None if not np.isfinite(x) else round(float(x), 3)

    summary = {
        "seed": job.seed,
        "success": bool(info["success"]),
        "retries": 0,
        "error": {
            "position_mm": num(info["position_error_mm"]),
            "rotation_deg": num(info["rotation_error_deg"]),
        },
        "time_s": round(time.perf_counter() - t0, 3),
        "steps": len(actions),
        "failure": "" if info["success"] else f"ended in phase {policy.phase}",
    }
    buffer = EpisodeBuffer(seed=job.seed, observations=observations, actions=actions,
                           rewards=rewards, terminations=terminations, truncations=truncations,
                           infos=infos)  # fmt: skip
    return {"episode": summary, "buffer": buffer}


@contextlib.contextmanager
def _datasets_root(root: Path) -> Iterator[None]:
    """Point Minari's dataset root at ``root`` for the block (it reads the variable)."""
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        yield
    finally:
        if old is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def record_episodes(
    directory: str | os.PathLike[str],
    object: str,
    seeds: Sequence[int],
    faults: Sequence[str] = (),
    *,
    env_id: str | None = None,
    max_episode_steps: int = 150,
    backend: str = "local",
    address: str | None = None,
    workers: int = 1,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Record one scripted episode per seed into the Minari dataset folder ``directory``.

    Args:
        directory: the new dataset folder (its name ``NAME-vN`` is the dataset id).
        object: ``cube`` | ``sphere`` | ``part``.
        seeds: one episode per seed, dataset episode ``i`` = ``seeds[i]``.
        faults: devices failed for every episode.
        env_id: the env (default: the newest ``mks_sim/Grasp-v*``).
        max_episode_steps: truncation horizon.
        backend, address, workers, progress: as :func:`mks_sim.tasks.backends.run_episodes`.

    Returns:
        The per-episode summaries, in seed order.

    Raises:
        MksError: as :func:`check_record_dir`, or a bad backend.
    """
    from mks_sim.record.infos import default_names
    from mks_sim.tasks.backends import run_episodes

    path = check_record_dir(directory)
    minari = _import_minari()
    env_id = env_id or default_env_id()
    jobs = [RecordJob(env_id, object, int(s), tuple(faults), max_episode_steps) for s in seeds]
    sensors, devices = default_names()
    env = make_env(jobs[0])  # spaces and the env spec (as gym.make made it for the episodes)
    try:
        spec = env.env.spec  # gym.make's (with max_episode_steps), inside StepInfo
        if path.is_dir():
            path.rmdir()  # empty (checked): Minari creates the folder itself
        with _datasets_root(path.parent), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*author_email.*")
            dataset = minari.create_dataset_from_buffers(
                dataset_id=path.name,
                buffer=[],  # episodes are written as they come in (_InOrderWriter)
                env=env.env,  # an Env, not a spec: Minari would gym.make another one
                eval_env=spec,
                algorithm_name=POLICY,
                author="mks_sim",
                code_permalink="mks_sim/record/dataset.py",
                observation_space=env.observation_space,
                action_space=env.action_space,
                description=(
                    f"Scripted grasps of the {object} in {env_id} (seeds {seeds[0]}.."
                    f"{seeds[-1]}, faults {list(faults) or 'none'}); infos: success, the "
                    "localization estimate and its error, logical-sensor provenance, faults."
                ),
                data_format="arrow",
                requirements=["mks-sim[record]"],
                jpeg_encoding=False,
            )
    finally:
        env.close()
    dataset.storage.update_metadata(
        {
            "mks_sim_env_id": env_id,
            "mks_sim_object": object,
            "mks_sim_faults": list(faults),
            "mks_sim_logical_sensors": list(sensors),
            "mks_sim_devices": list(devices),
            "mks_sim_policy": POLICY,
        }
    )
    writer = _InOrderWriter(dataset.storage, {"object": object, "faults": list(faults)})
    try:
        return run_episodes(jobs, fn=record_episode, backend=backend, address=address,
                            workers=workers, progress=progress, desc=f"record {object}",
                            on_result=writer)  # fmt: skip
    finally:
        writer.flush()  # also when an episode failed or the run was interrupted


class _InOrderWriter:
    """Write episode buffers to the dataset in job order as they arrive (out of order).

    An episode waits in memory only until those before it are written; writes go in batches
    (each write re-sizes the dataset folder). A run that stops half-way leaves a valid
    dataset of its first finished episodes, with no gaps.
    """

    BATCH = 16

    def __init__(self, storage: Any, episode_metadata: dict[str, Any]) -> None:
        self.storage = storage
        self.episode_metadata = episode_metadata
        self.next = 0  # the next episode id to write
        self.waiting: dict[int, dict[str, Any]] = {}
        self.ready: list[tuple[int, dict[str, Any]]] = []

    def __call__(self, index: int, result: dict[str, Any]) -> dict[str, Any]:
        self.waiting[index] = result
        while self.next in self.waiting:
            self.ready.append((self.next, self.waiting.pop(self.next)))
            self.next += 1
        if len(self.ready) >= self.BATCH:
            self.flush()
        return result["episode"]

    def flush(self) -> None:
        if not self.ready:
            return
        ids = [i for i, _ in self.ready]
        self.storage.update_episodes(
            [dataclasses.replace(r["buffer"], id=i) for i, r in self.ready]
        )
        self.storage.update_episode_metadata(
            [{**self.episode_metadata, "success": r["episode"]["success"]} for _, r in self.ready],
            ids,
        )
        self.ready = []


def load_recorded(directory: str | os.PathLike[str]) -> Any:
    """The :class:`minari.MinariDataset` in the folder ``directory`` (path API).

    Raises:
        MksError: Minari missing, or no dataset in ``directory``.
    """
    minari = _import_minari()
    data = Path(directory).expanduser() / "data"
    if not data.is_dir():
        raise MksError(f"{directory}: expected a Minari dataset folder (with data/), got none")
    return minari.MinariDataset(data)
