"""Fingertip touch pads light a contact patch; held objects do not creep out of the grasp."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.sim import names
from mks_sim.sim.robot import arm_qpos_for_pinch
from mks_sim.sim.world import World, build_world

TOUCH_THRESHOLD_N = 1e-3
# Hand yaw relative to the cube for which the one-against-two-fingers grasp is balanced on the
# cube's faces (measured: every pad in contact).
GRASP_YAW = -np.pi / 12


def _taxels(world: World) -> np.ndarray:  # (3 fingers, 9 taxels) N
    return np.array(
        [[world.data.sensor(s).data[0] for s in names.touch_sensors(f)] for f in names.FINGERS]
    )


def _hold_arm(world: World, q_target: np.ndarray) -> None:
    for joint, q in zip(names.ARM_JOINTS, q_target, strict=True):
        err = q - world.data.joint(joint).qpos[0]
        world.data.actuator(joint).ctrl[0] = np.clip(5.0 * err, -1.0, 1.0)


def _run(world: World, q_arm: np.ndarray, steps: int, finger_ctrl: float = 2.0) -> None:
    for _ in range(steps):
        _hold_arm(world, q_arm)
        for act in names.FINGER_ACTUATORS:
            world.data.actuator(act).ctrl[0] = finger_ctrl
        world.step(1)


def _lone_cube_world(contact: dict | None = None) -> World:
    world = build_world("scene2")
    for i, name in enumerate((names.SPHERE, *names.CLUTTER)):
        T = np.eye(4)
        T[:3, 3] = (0.3 + 0.1 * i, -0.3, names.TABLE_TOP_Z + 0.05)
        world.set_object_pose(name, T)
    if contact:
        for key, value in contact.items():
            setattr(world.model.opt, key, value)
    world.settle(100)
    return world


def _grasp_cube(world: World) -> np.ndarray:
    cube = world.data.body(names.CUBE).xpos.copy()
    q_arm, ok = arm_qpos_for_pinch(world.physics, cube + (0, 0, 0.005), GRASP_YAW)
    assert ok
    for joint, q in zip(names.ARM_JOINTS, q_arm, strict=True):
        world.data.joint(joint).qpos[0] = q
    world.forward()
    _run(world, q_arm, 600)  # 1.2 s: fingers close (~1.2 s per the Jaco datasheet)
    return q_arm


def test_empty_pads_read_zero() -> None:
    world = build_world("scene2")
    assert np.all(_taxels(world) == 0.0)


def test_grasp_lights_a_patch_on_every_pad() -> None:
    world = _lone_cube_world()
    _grasp_cube(world)
    active = (_taxels(world) > TOUCH_THRESHOLD_N).sum(axis=1)
    assert active.max() >= 4, active
    assert np.all(active >= 3), active


def _pinch_frame_offset(world: World) -> np.ndarray:
    site = world.data.site(names.PINCH_SITE)
    return site.xmat.reshape(3, 3).T @ (world.data.body(names.CUBE).xpos - site.xpos)


def _held_slip_mm(world: World) -> tuple[float, float]:
    """Lift the grasped cube 12 cm, hold 2 s, return (lift height, slip over the next 1 s)."""
    q_grasp = _grasp_cube(world)
    cube0 = world.data.body(names.CUBE).xpos.copy()
    q_up, ok = arm_qpos_for_pinch(world.physics, cube0 + (0, 0, 0.125), GRASP_YAW)
    assert ok and q_grasp.shape == q_up.shape
    _run(world, q_up, 1000)
    before = _pinch_frame_offset(world)
    _run(world, q_up, 500)  # 1 s at 2 ms
    slip = 1000 * float(np.linalg.norm(_pinch_frame_offset(world) - before))
    return float(world.data.body(names.CUBE).xpos[2] - cube0[2]), slip


@pytest.mark.slow
def test_held_cube_does_not_creep() -> None:
    lift, slip_mm = _held_slip_mm(_lone_cube_world())
    assert lift > 0.10
    assert slip_mm < 0.5  # measured ~0.15 mm/s (docs/worlds.md)


@pytest.mark.slow
def test_default_contact_model_creeps() -> None:
    # The reason for our contact options: MuJoCo's defaults let the cube slide out.
    default = dict(cone=0, impratio=1.0, noslip_iterations=0)  # cone 0 = pyramidal
    lift, slip_mm = _held_slip_mm(_lone_cube_world(default))
    assert slip_mm > 1.0 or lift < 0.10


def test_taxel_layout_rows_run_towards_the_tip() -> None:
    world = build_world("scene2")
    for f in names.FINGERS:
        knuckle = world.data.body(f"{names.HAND_PREFIX}b_finger_{f}").xpos
        dist = np.array(
            [
                np.linalg.norm(world.data.site(names.touch_site(f, i)).xpos - knuckle)
                for i in range(names.TAXELS_PER_PAD)
            ]
        ).reshape(names.TOUCH_ROWS, names.TOUCH_COLS)
        assert np.all(np.diff(dist.mean(axis=1)) > 0.005)  # 7 mm pitch along the finger
        site = world.model.site(names.touch_site(f, 4))
        geom = world.model.geom(names.touch_geom(f, 4))
        assert site.bodyid[0] == geom.bodyid[0]
        assert world.model.body(site.bodyid[0]).name == names.FINGER_TIP_BODIES[f - 1]


# --------------------------------------------------------------- finger joint-torque devices


def _torque_devices(world: World):
    from mks_sim.devices.factory import FINGER_TORQUE_DEVICES, make_devices

    return make_devices(world.model, world.data, np.random.default_rng(0),
                        names=FINGER_TORQUE_DEVICES)  # fmt: skip


def _agree_with_pads(world: World) -> np.ndarray:
    """Each finger's torque reading against its pad (simulator touch sensors, the reference):
    pressing exactly when the pad feels > 0.05 N, with an equivalent force within a factor 1.5
    of the pad's. Returns the (3,) pressing flags."""
    pad_force = _taxels(world).sum(axis=1)
    pressing = []
    for f, dev in zip(names.FINGERS, _torque_devices(world).values(), strict=True):
        r = dev.read()
        assert r.pressing == (pad_force[f - 1] > 0.05), (f, r, pad_force)
        if r.pressing:
            assert pad_force[f - 1] / 1.5 < r.force[0] < 1.5 * pad_force[f - 1], (f, r, pad_force)
            assert r.pressure[0] > 500.0  # above Touch_Contacts' threshold
        else:
            assert r.force[0] == 0.0 and r.pressure[0] == 0.0
        pressing.append(r.pressing)
    return np.array(pressing)


@pytest.mark.slow
def test_finger_torque_reads_contact_like_the_pads() -> None:
    """Open in the air: no finger presses; closed on the cube: every finger presses (from the
    motor torque and encoder only), as the pads say; closed on nothing, the fingers at the
    joint's stop do not, the two meeting each other do (their pads touch too)."""
    world = _lone_cube_world()
    assert not _agree_with_pads(world).any()
    _grasp_cube(world)
    assert _agree_with_pads(world).all()
    air = _lone_cube_world()
    far = np.eye(4)
    far[:3, 3] = (0.6, -0.3, names.TABLE_TOP_Z + 0.05)
    air.set_object_pose(names.CUBE, far)
    _run(air, np.array([air.data.joint(j).qpos[0] for j in names.ARM_JOINTS]), 600)
    assert _agree_with_pads(air).sum() in (0, 2)  # nothing, or two fingertips meeting


@pytest.mark.slow
def test_finger_torque_faults() -> None:
    from mks_sim.devices import DeviceFaults
    from mks_sim.errors import DeviceFailure

    world = _lone_cube_world()
    _grasp_cube(world)
    dev = _torque_devices(world)["finger_torque_1"]
    first = dev.read()
    dev.faults = DeviceFaults(dropout=1.0)
    assert not dev.read().pressing  # every reading dropped
    dev.faults = DeviceFaults(failed=True)
    with pytest.raises(DeviceFailure, match="finger_torque_1"):
        dev.read()
    dev.faults = DeviceFaults(noise_scale=0.0)
    assert dev.read().pressing and abs(dev.read().torque_nm - first.torque_nm) < 0.05
