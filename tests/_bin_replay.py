"""Replaying a saved state of a tuning bin (the arm at home, the pile settled) for a pick test."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np


@contextmanager
def replayed_bin(seed: int, qpos: Sequence[float]) -> Iterator[Any]:
    """The bin of ``seed`` with its joints set to ``qpos`` (velocities zero) and the arm
    holding still: yields its :class:`~mks_sim.tasks.bin.BinPicker` (devices open)."""
    import mujoco

    from mks_sim.devices import make_devices
    from mks_sim.tasks.bin import BinPicker, bin_world

    world = bin_world(seed)
    with make_devices(world.model, world.data, np.random.default_rng(seed), {}) as devices:
        robot = BinPicker(world, devices, active=False)
        world.data.qpos[:] = qpos
        world.data.qvel[:] = 0.0
        mujoco.mj_forward(world.model, world.data)
        robot.ctl.q_target = robot.ctl.arm_qpos()
        yield robot
