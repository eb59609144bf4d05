"""Letting go over the output box (issue 13): a part that still hangs on a finger's pad after
the hand opened is set down (``mks_sim.tasks.bin._set_down_hung``) instead of being lifted
with the hand and dropped on the way home."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mks_sim.tasks import bin as binmod

# Tuning bin 21's third pick (the part "part_4"), saved the moment the hand, holding it over
# the box, was about to open: joints, velocities, controls, the solver's warm start, the
# controller's arm target. Nothing else of the run is needed.
_HUNG = Path(__file__).parent / "assets" / "bin21_hung_part.npz"


class _Hand:
    """A hand whose pads feel a hung part until the pinch point has been ``frees_at_m`` below
    where it opened (never when None); records the moves."""

    def __init__(self, frees_at_m: float | None, touch: float = 90.0) -> None:
        self.pos = np.array([0.0, 0.0, 0.9])
        self.start_z = self.pos[2]
        self.frees_at_m = frees_at_m
        self.reading = touch
        self.moves: list[np.ndarray] = []

    def touch(self) -> np.ndarray:
        return np.array([self.reading, 0.0, np.nan])

    def pinch_pos(self) -> np.ndarray:
        return self.pos.copy()

    def pinch_yaw(self) -> float:
        return 0.0

    def pinch_rotation(self) -> np.ndarray:
        return np.diag([1.0, -1.0, -1.0])  # straight down

    def move_to(self, pos, yaw, spacing_m=0.01, rotation=None) -> bool:
        assert rotation is None  # a top-down hand holds its yaw
        self.pos = np.asarray(pos, dtype=float).copy()
        self.moves.append(self.pos.copy())
        if self.frees_at_m is not None and self.start_z - self.pos[2] >= self.frees_at_m - 1e-9:
            self.reading = 0.0
        return True


def test_nothing_felt_after_opening_means_no_move():
    hand = _Hand(frees_at_m=None, touch=0.01)
    assert binmod._set_down_hung(hand, table_z=0.75) == 0
    assert hand.moves == []


def test_a_hung_part_is_set_down_and_the_hand_comes_back_up():
    hand = _Hand(frees_at_m=binmod.HUNG_LOWER_M)
    assert binmod._set_down_hung(hand, table_z=0.75) == 1
    np.testing.assert_allclose(
        hand.moves, [[0.0, 0.0, 0.9 - binmod.HUNG_LOWER_M], [0.0, 0.0, 0.9]], atol=1e-12
    )


def test_a_part_that_stays_hung_is_tried_at_most_hung_tries_times_and_not_below_the_floor():
    hand = _Hand(frees_at_m=None)
    hand.pos[2] = hand.start_z = 0.75 + 0.03  # the fingertips 12 mm over the box's floor
    assert binmod._set_down_hung(hand, table_z=0.75) == binmod.HUNG_TRIES
    lows = [p[2] for p in hand.moves[::2]]
    assert min(lows) == pytest.approx(0.75 + binmod.TIPS_BELOW_PINCH_M)
    assert len(hand.moves) == 2 * binmod.HUNG_TRIES


@pytest.mark.slow
def test_a_part_hanging_on_the_open_hand_is_set_down_in_the_box():
    """The replayed pick: opened, the part still weighs on finger 1's pad. Lifted at once
    (the old release) it rises with the hand (ground truth: the part's height); set down
    first, the pad comes free and it stays in the box as the hand rises."""
    import mujoco

    from mks_sim.devices import make_devices
    from mks_sim.sim import truth
    from mks_sim.sim.scenes import scene_file, scene_from_doc
    from mks_sim.sim.world import World

    saved = np.load(_HUNG)
    path = scene_file(binmod.BIN_SCENE)
    world = World(scene_from_doc(binmod._bin_doc(path, None, None), path))
    m, d = world.model, world.data
    with make_devices(m, d, np.random.default_rng(21), {}) as devices:
        robot = binmod.BinPicker(world, devices, active=False)
        ctl = robot.ctl

        def opened_and_raised(set_down: bool) -> SimpleNamespace:
            mujoco.mj_resetData(m, d)
            for field in ("qpos", "qvel", "act", "ctrl", "qacc_warmstart"):
                getattr(d, field)[:] = saved[field]
            mujoco.mj_forward(m, d)
            ctl.q_target = saved["q_target"].copy()
            ctl.finger_target, ctl.grip = None, 1.0  # holding
            ctl.open(50)
            felt = ctl.touch().copy()
            tries = binmod._set_down_hung(ctl, robot.table_z) if set_down else 0
            up = ctl.pinch_pos()
            up[2] = robot.table_z + binmod.CLEARANCE_ABOVE_M
            ctl.move_to(up, ctl.pinch_yaw(), spacing_m=0.02)
            world.step(100)
            z = truth.object_to_world(world, "part_4")[2, 3]
            return SimpleNamespace(felt=felt, tries=tries, z=z, touch=ctl.touch().copy())

        old = opened_and_raised(set_down=False)
        assert old.felt[0] > binmod.HUNG_TOUCH_N  # the premise: it hangs on finger 1
        assert old.z > robot.table_z + 0.15  # lifted with the hand, out of the box
        assert not binmod.in_output_box(world, "part_4")
        new = opened_and_raised(set_down=True)
        assert new.tries >= 1
        assert np.nanmax(new.touch) <= binmod.HUNG_TOUCH_N
        assert binmod.in_output_box(world, "part_4"), new.z
