"""``mks_sim/BinPick-v0`` (issue 13): multi-object observation with a validity mask."""

from __future__ import annotations

import numpy as np
import pytest


def test_registered_and_bad_count():
    import gymnasium as gym

    import mks_sim  # noqa: F401 - registers the envs
    from mks_sim.envs import BIN_ENV_ID
    from mks_sim.envs.bin_env import BinPickEnv

    assert BIN_ENV_ID in gym.registry
    with pytest.raises(ValueError, match=r"count: expected an integer in 1..12, got 13"):
        BinPickEnv(count=13)


@pytest.mark.slow
def test_bin_pick_env_passes_check_env_and_picks():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import mks_sim  # noqa: F401

    env = gym.make("mks_sim/BinPick-v0", count=2)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    assert obs["valid"].dtype == np.int8 and obs["valid"].sum() >= 1
    assert info["present"] == 2 and info["picked"] == 0
    assert info["views"] >= 1 and info["faults"] == {}
    # valid rows come first, invalid rows are zeros
    k = int(obs["valid"].sum())
    assert np.all(obs["valid"][:k] == 1) and not np.any(obs["poses"][k:])
    assert np.allclose(np.linalg.norm(obs["poses"][:k, 3:], axis=1), 1.0)
    obs, reward, terminated, truncated, info = env.step(0)
    assert reward == float(info["picked"] == 1)
    env.close()
