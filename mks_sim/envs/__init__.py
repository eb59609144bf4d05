"""Gymnasium environments (registered on import of mks_sim.envs)."""


def register_envs() -> None:
    """Entry point for gymnasium's plugin loader (filled in by the environment module)."""
