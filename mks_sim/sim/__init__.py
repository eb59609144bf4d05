"""mks_sim.sim: the simulated workstation (MuJoCo + dm_control).

``build_world`` and ``World`` are imported lazily so that ``from mks_sim.sim import names``
stays cheap (no dm_control import). Ground truth lives in ``mks_sim.sim.truth`` (evaluation
code only).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mks_sim.sim.world import World, build_world

__all__ = ["World", "build_world"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from mks_sim.sim import world

        return getattr(world, name)
    raise AttributeError(f"module 'mks_sim.sim' has no attribute {name!r}")
