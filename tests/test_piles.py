"""The pile cache (mks_sim.sim.piles): a restored pile is the settled one, to the bit."""

from __future__ import annotations

import logging

import mujoco
import numpy as np
import pytest

from mks_sim.sim import piles
from mks_sim.sim.world import World
from mks_sim.tasks.bin import bin_world

SEED = 3  # a one-part bin: a short settle


def _count_settles(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []
    real = World.randomize

    def counted(self: World, rng: np.random.Generator, *a: object, **k: object) -> None:
        calls.append(1)
        real(self, rng, *a, **k)  # type: ignore[arg-type]

    monkeypatch.setattr(World, "randomize", counted)
    return calls


def _state(world: World) -> np.ndarray:
    out = np.empty(mujoco.mj_stateSize(world.model, mujoco.mjtState.mjSTATE_INTEGRATION))
    mujoco.mj_getState(world.model, world.data, out, mujoco.mjtState.mjSTATE_INTEGRATION)
    return out


def test_a_restored_pile_is_the_settled_one_and_steps_the_same(tmp_path, monkeypatch):
    """The second world of a seed is restored (no settle) with the state settling gives
    (time, positions, velocities, warm start: equal to the bit to a world settled without the
    cache), and stepping both on gives the same trajectory; rest_steps comes back too."""
    monkeypatch.setenv(piles.CACHE_ENV, str(tmp_path))
    settles = _count_settles(monkeypatch)
    first = bin_world(SEED, count=1)
    assert len(settles) == 1 and len(list(tmp_path.glob("*.npz"))) == 1
    again = bin_world(SEED, count=1)
    assert len(settles) == 1  # restored
    settled = bin_world(SEED, count=1, cache=False)  # the simulator's own answer
    assert len(settles) == 2
    np.testing.assert_array_equal(_state(again), _state(settled))
    np.testing.assert_array_equal(_state(first), _state(settled))
    assert again.rest_steps == settled.rest_steps > 0
    for w in (again, settled):
        w.data.ctrl[:] = 0.1
        w.step(200)
    np.testing.assert_array_equal(again.data.qpos, settled.data.qpos)
    assert not np.allclose(again.data.qpos, first.data.qpos)  # (the steps moved something)


def test_keys_differ_by_seed_model_and_mujoco(tmp_path, monkeypatch):
    monkeypatch.setenv(piles.CACHE_ENV, str(tmp_path))
    one = bin_world(None, count=1)
    two = bin_world(None, count=2)
    key = piles.pile_key(one, 1)
    assert key == piles.pile_key(bin_world(None, count=1), 1)
    assert key != piles.pile_key(one, 2)
    assert key != piles.pile_key(two, 1)
    monkeypatch.setattr(mujoco, "__version__", "0.0.0")
    assert key != piles.pile_key(one, 1)


def test_off_unreadable_and_unwritable(tmp_path, monkeypatch, caplog):
    """``off``: settled every time, nothing written; a damaged file is settled anew and
    replaced; a folder that cannot be written still gives the settled pile (a log line)."""
    settles = _count_settles(monkeypatch)
    monkeypatch.setenv(piles.CACHE_ENV, "off")
    assert piles.cache_dirs() == []
    bin_world(SEED, count=1)
    bin_world(SEED, count=1)
    assert len(settles) == 2
    monkeypatch.setenv(piles.CACHE_ENV, str(tmp_path))
    world = bin_world(SEED, count=1)
    (saved,) = tmp_path.glob("*.npz")
    saved.write_bytes(b"not a pile")
    caplog.set_level(logging.INFO, logger="mks_sim.sim.piles")
    again = bin_world(SEED, count=1)
    assert len(settles) == 4 and "unreadable" in caplog.text
    np.testing.assert_array_equal(_state(again), _state(world))
    bin_world(SEED, count=1)
    assert len(settles) == 4  # the damaged file was replaced
    blocked = tmp_path / "file"
    blocked.write_text("")
    monkeypatch.setenv(piles.CACHE_ENV, str(blocked / "sub"))
    caplog.clear()
    world = bin_world(SEED, count=1)
    assert "not written" in caplog.text
    np.testing.assert_array_equal(_state(world), _state(again))


def test_default_folder_is_the_user_cache(monkeypatch, tmp_path):
    monkeypatch.delenv(piles.CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert piles.cache_dirs() == [tmp_path / "mks_sim" / "piles"]
    monkeypatch.setenv(piles.CACHE_ENV, f"{tmp_path / 'a'}:{tmp_path / 'b'}")
    assert piles.cache_dirs() == [tmp_path / "a", tmp_path / "b"]


def test_the_suites_piles_are_current():
    """``tests/assets/piles`` holds the pile of tuning bin 22 (six parts) for this bin scene,
    MuJoCo and settling code; stale piles are never wrong (their keys no longer match) but
    leave the suite to settle every tuning bin again (60-90 s more): after a change to the
    bin scene or ``sim/world.py``, regenerate them (README: delete them, then
    ``MKS_SIM_PILE_CACHE=tests/assets/piles make test``). Skipped under another MuJoCo than
    the one they were written with (``MUJOCO_VERSION``)."""
    from pathlib import Path

    folder = Path(__file__).parent / "assets" / "piles"
    written = (folder / "MUJOCO_VERSION").read_text().strip()
    if mujoco.__version__ != written:
        pytest.skip(f"piles written with MuJoCo {written}, this is {mujoco.__version__}")
    key = piles.pile_key(bin_world(None), 22)
    assert (folder / f"{key}.npz").is_file(), (
        "tests/assets/piles is stale: delete its *.npz and run "
        "MKS_SIM_PILE_CACHE=tests/assets/piles make test"
    )
