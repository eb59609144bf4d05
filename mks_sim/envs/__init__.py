"""Gymnasium environments of mks_sim.

``import mks_sim`` registers them; gymnasium's plugin loader (the ``gymnasium.envs`` entry
point ``mks_sim = "mks_sim.envs:register_envs"``) does too, so both
``gymnasium.make("mks_sim/Grasp-v0", object="cube")`` (after ``import mks_sim``) and
``gymnasium.make("mks_sim:mks_sim/Grasp-v0")`` work.
"""

from __future__ import annotations

ENV_IDS = ("mks_sim/Grasp-v0",)


def register_envs() -> None:
    """Register ``mks_sim/Grasp-v0`` with gymnasium (idempotent)."""
    import gymnasium

    if "mks_sim/Grasp-v0" in gymnasium.registry:
        return
    gymnasium.register(
        id="mks_sim/Grasp-v0",
        entry_point="mks_sim.envs.grasp_env:GraspEnv",
        max_episode_steps=200,
        kwargs={"object": "cube"},
    )
