"""Minari datasets of scripted episodes (``mks_sim.record``, ``mks-sim grasp --record``).

Datasets are written under ``tmp_path`` only (never the user's ``~/.minari``). The replay
test is the point of a dataset: a fresh env reset with an episode's seed and driven by its
recorded actions reproduces its recorded observations bit for bit.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.errors import MksError

minari = pytest.importorskip("minari")

from mks_sim.record import check_record_dir, load_recorded, record_episodes  # noqa: E402


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short cube episodes with the range finder failed (localization on stereo)."""
    folder = tmp_path_factory.mktemp("datasets") / "grasp-cube-v0"
    summaries = record_episodes(folder, "cube", [5, 6], ["range_finder"], max_episode_steps=12,
                                progress=False)  # fmt: skip
    assert [s["seed"] for s in summaries] == [5, 6]
    assert all(s["steps"] == 12 for s in summaries)
    return folder


@pytest.mark.slow
def test_load_dataset_reads_it_back(recorded: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(recorded.parent))
    ds = minari.load_dataset("grasp-cube-v0")
    assert ds.total_episodes == 2 and ds.total_steps == 24
    assert [m["seed"] for m in ds.storage.get_episode_metadata([0, 1])] == [5, 6]
    meta = ds.storage.metadata
    assert meta["mks_sim_faults"] == ["range_finder"] and meta["mks_sim_object"] == "cube"
    assert "Range_Points" in meta["mks_sim_logical_sensors"]
    assert ds.env_spec.kwargs["faults"] == ["range_finder"]
    assert ds.env_spec.max_episode_steps == 12
    ep = ds[0]
    assert meta["mks_sim_env_id"] == "mks_sim/Grasp-v2"  # the newest env by default
    assert ep.actions.shape == (12, 7)  # v2: dx, dy, dz, drx, dry, drz, grip
    assert ep.observations["pinch_rotation"].shape == (13, 3, 3)
    assert ep.rewards.shape == ep.terminations.shape == ep.truncations.shape == (12,)
    assert ep.truncations[-1] and not ep.terminations.any()
    assert ep.observations["pose_estimate"].shape == (13, 4, 4)


@pytest.mark.slow
def test_infos_have_one_structure_and_say_what_served(recorded: Path) -> None:
    ds = load_recorded(recorded)
    meta = ds.storage.metadata
    for ep in ds.iterate_episodes():
        infos = ep.infos
        n = len(ep.rewards) + 1  # the reset's info too
        assert all(len(v) == n for v in infos.values())
        assert infos["estimate"].shape == (n, 4, 4) and infos["success"].dtype == bool
        # The estimate in the info is the one the policy observed.
        assert np.array_equal(infos["estimate"], ep.observations["pose_estimate"])
        # Stereo localization of the cube: within a few mm of ground truth.
        assert np.all(infos["position_error_mm"] < 5.0)
        for device in meta["mks_sim_devices"]:
            assert np.all(infos[f"failed.{device}"] == (device == "range_finder"))
        for sensor in meta["mks_sim_logical_sensors"]:
            assert f"provenance.{sensor}" in infos
        # The range finder failed: its alternate served the points (a recorded fallback).
        assert set(infos["provenance.Range_Points"]) == {"Stereo_Points"}


@pytest.mark.slow
def test_replaying_actions_from_the_seed_reproduces_observations(recorded: Path) -> None:
    import mks_sim  # noqa: F401  (registers the envs)

    ds = load_recorded(recorded)
    seed = next(iter(ds.storage.get_episode_metadata([1])))["seed"]
    ep = ds[1]
    env = ds.recover_environment()
    try:
        obs, _ = env.reset(seed=seed)
        replayed = [obs]
        for action in ep.actions:
            replayed.append(env.step(action)[0])
    finally:
        env.close()
    for key, recorded_obs in ep.observations.items():
        np.testing.assert_array_equal(np.stack([o[key] for o in replayed]), recorded_obs,
                                      err_msg=key)  # fmt: skip


class _FakeStorage:
    def __init__(self) -> None:
        self.writes: list[list[int]] = []
        self.metadata: dict[int, dict] = {}

    def update_episodes(self, buffers) -> None:
        self.writes.append([b.id for b in buffers])

    def update_episode_metadata(self, metadatas, ids) -> None:
        self.metadata.update(zip(ids, metadatas, strict=True))


def test_episodes_are_written_in_seed_order_as_they_arrive() -> None:
    from minari.data_collector import EpisodeBuffer

    from mks_sim.record.dataset import _InOrderWriter

    storage = _FakeStorage()
    writer = _InOrderWriter(storage, {"object": "cube"})
    writer.BATCH = 2
    arrival = [2, 0, 3, 1, 5, 4]  # completion order of six jobs
    kept = [writer(i, {"buffer": EpisodeBuffer(seed=100 + i),
                       "episode": {"seed": 100 + i, "success": i % 2 == 0}})
            for i in arrival]  # fmt: skip
    writer.flush()
    assert [k["seed"] for k in kept] == [100 + i for i in arrival]  # summaries handed back
    # 0 alone is below the batch; 1 releases 1, 2, 3 behind it; 4 releases 5.
    assert storage.writes == [[0, 1, 2, 3], [4, 5]]  # job order, no gaps, batched
    assert storage.metadata == {i: {"object": "cube", "success": i % 2 == 0} for i in range(6)}


def test_record_dir_is_checked_before_any_episode(tmp_path: Path, capsys) -> None:
    (tmp_path / "grasp-v0").write_text("not a folder")
    assert main(["grasp", "--object", "cube", "--record", str(tmp_path / "grasp-v0")]) == 2
    assert "expected a new folder, got an existing file" in capsys.readouterr().err
    full = tmp_path / "full-v0"
    full.mkdir()
    (full / "x").write_text("")
    with pytest.raises(MksError, match="expected a new or empty folder"):
        check_record_dir(full)
    with pytest.raises(MksError, match=r"NAME-vVERSION \(e.g. grasp-cube-v0\), got 'cube'"):
        check_record_dir(tmp_path / "cube")
    with pytest.raises(MksError, match="expected a folder whose parent exists"):
        check_record_dir(tmp_path / "missing" / "grasp-cube-v0")
    assert main(["grasp", "--object", "cube", "--record", str(tmp_path / "a-v0"),
                 "--video", str(tmp_path / "a.mp4")]) == 2  # fmt: skip
    assert not (tmp_path / "a-v0").exists()


def test_minari_missing_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "minari", None)
    with pytest.raises(
        MksError, match=r"Minari is not installed; run pip install 'mks-sim\[record\]'"
    ):
        check_record_dir(tmp_path / "grasp-cube-v0")


def test_unrecorded_runs_do_not_import_minari() -> None:
    import subprocess

    code = ("import sys, mks_sim.cli.grasp, mks_sim.tasks.backends, mks_sim.envs;"
            "print('minari' in sys.modules, 'ray' in sys.modules)")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


@pytest.mark.slow
def test_cli_record_writes_a_dataset(tmp_path: Path, capsys) -> None:
    import json

    folder = tmp_path / "grasp-sphere-v3"
    # Two spawn-started workers: the episode buffers come back from other processes. Five
    # steps never lift the sphere: exit 1 (an episode failed), the dataset is written anyway.
    assert main(["grasp", "--object", "sphere", "--seed", "4", "--episodes", "2",
                 "--workers", "2", "--record", str(folder), "--max-steps", "5", "--json"]) == 1  # fmt: skip
    doc = json.loads(capsys.readouterr().out)
    assert [e["seed"] for e in doc["episodes"]] == [4, 5]
    ds = load_recorded(folder)
    assert ds.total_episodes == 2 and ds.total_steps == 10
    assert ds.storage.metadata["dataset_id"] == "grasp-sphere-v3"
    assert [m["seed"] for m in ds.storage.get_episode_metadata([0, 1])] == [4, 5]
