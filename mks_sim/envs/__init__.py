"""Gymnasium environments of mks_sim.

``import mks_sim`` registers them, so ``gymnasium.make("mks_sim/Grasp-v1", object="cube")``
works after it and ``gymnasium.make("mks_sim:mks_sim/Grasp-v1")`` works without it.

- ``mks_sim/Grasp-v0``: binary grip (``action[4] < 0`` opens, ``>= 0`` closes).
- ``mks_sim/Grasp-v1``: continuous grip (``action[4]`` is the finger velocity, a fraction of
  the actuator range); the scripted policy closes gently until touch, as the full loop does.
- ``mks_sim/Grasp-v2``: v1 with a full hand rotation per step (a world-frame rotation vector),
  so the scripted policy flies tilted grasp plans as planned.
- ``mks_sim/BinPick-v0``: the agent chooses which localized instance of a bin to pick
  (``mks_sim.envs.bin_env``).
"""

from __future__ import annotations

ENV_IDS = ("mks_sim/Grasp-v0", "mks_sim/Grasp-v1", "mks_sim/Grasp-v2")
#: Bin picking (issue 13): an agent picks localized instances into the output box.
BIN_ENV_ID = "mks_sim/BinPick-v0"
_ENTRY_POINTS = {
    "mks_sim/Grasp-v0": "mks_sim.envs.grasp_env:GraspEnv",
    "mks_sim/Grasp-v1": "mks_sim.envs.grasp_env:GraspEnvV1",
    "mks_sim/Grasp-v2": "mks_sim.envs.grasp_env:GraspEnvV2",
}


def register_envs() -> None:
    """Register ``mks_sim/Grasp-v0``, ``-v1`` and ``-v2`` with gymnasium (idempotent)."""
    import gymnasium

    for env_id, entry_point in _ENTRY_POINTS.items():
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=entry_point,
            max_episode_steps=200,
            kwargs={"object": "cube"},
        )
    if BIN_ENV_ID not in gymnasium.registry:  # bin picking (issue 13)
        gymnasium.register(
            id=BIN_ENV_ID, entry_point="mks_sim.envs.bin_env:BinPickEnv", max_episode_steps=26
        )
