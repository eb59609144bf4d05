"""Replaying a saved state of a tuning bin (the arm at home, the pile settled) for a pick test."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np


@contextmanager
def replayed_bin(seed: int, qpos: Sequence[float]) -> Iterator[Any]:
    """The bin of ``seed`` with its joints set to ``qpos`` (velocities zero) and the arm
    holding still: yields its :class:`~mks_sim.tasks.bin.BinPicker` (devices open).

    The pile is not dropped and settled first (``bin_world(seed)``, up to 30 s): every joint
    is set from ``qpos``, so the drop would be overwritten. ``seed`` seeds the devices' noise,
    as in the run that was saved."""
    import mujoco

    from mks_sim.devices import make_devices
    from mks_sim.sim.scenes import scene_file, scene_from_doc
    from mks_sim.sim.world import World
    from mks_sim.tasks.bin import BIN_SCENE, BinPicker, _bin_doc

    path = scene_file(BIN_SCENE)
    world = World(scene_from_doc(_bin_doc(path, None, None), path))
    world.mark_initial()
    with make_devices(world.model, world.data, np.random.default_rng(seed), {}) as devices:
        robot = BinPicker(world, devices, active=False)
        world.data.qpos[:] = qpos
        world.data.qvel[:] = 0.0
        mujoco.mj_forward(world.model, world.data)
        robot.ctl.q_target = robot.ctl.arm_qpos()
        yield robot
