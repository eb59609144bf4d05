"""The Kinova Jaco arm and 3-finger hand (dm_control entities) with fingertip touch pads.

The arm and hand are dm_control's ``JacoArm`` / ``JacoHand``; the hand is attached at the
arm's wrist site and the arm at the root-level ``robot_base`` site. We add, per fingertip, a
``TOUCH_ROWS x TOUCH_COLS`` pad of soft spherical "domes" (one geom per taxel) with a box
site around each dome and a MuJoCo ``<touch>`` sensor on the site.

Why domes: a rigid flat pad against a flat face gives MuJoCo a handful of contact points
(box-box gives the corners of the overlap polygon), so a taxel grid under one pad geom
lights one or two taxels. One geom per taxel gives one contact per taxel in touch; a soft
contact (``PAD_SOLREF``/``PAD_SOLIMP``) plus a small margin lets the object sink ~1 mm
into the pad so neighbouring domes share the load even when the face is slightly tilted.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
from dm_control import mjcf
from dm_control.entities.manipulators import kinova
from dm_control.utils import inverse_kinematics
from numpy.typing import ArrayLike

from mks_sim.sim import names

# Pad geometry in the distal phalanx body frame (b_finger_tip_<f>). The inner (closing)
# side of dm_control's finger_distal mesh is its +y face. MuJoCo collides the mesh by its
# convex hull, whose inner face runs from (x, y) = (7.8, 4.9) mm to (32.1, -0.2) mm
# (slope -0.21) and then to the tip (42.9, -3.3) mm, |z| < 11 mm (measured from the mesh
# vertices). The dome centres sit 0.5 mm outside that hull face, so each dome stands
# DOME_RADIUS + 0.5 mm proud of the hull and the pad, not the hull, meets the object.
PAD_ROW_X = (0.020, 0.027, 0.034)  # along the finger, knuckle side first
PAD_ROW_Y = (0.0029, 0.0014, -0.0002)  # hull face + 0.5 mm at each row
PAD_COL_Z = (-0.0065, 0.0, 0.0065)  # across the finger
DOME_RADIUS = 0.003  # m
# Soft rubber-like pad: 15 ms time constant (default 20 ms), impedance ramps over 2 mm.
PAD_SOLREF = (0.015, 1.0)
PAD_SOLIMP = (0.6, 0.95, 0.002, 0.5, 2.0)
PAD_MARGIN = 0.001
PAD_FRICTION = (1.2, 0.01, 0.0002)
FINGER_FRICTION = (1.0, 0.01, 0.0002)
# Wrist camera (RGB-D, device ``wrist_camera``; bin room, issue 13): on the hand body, 7 cm
# beside the palm axis and 10 cm behind the pinch point, looking along the fingers (MuJoCo
# cameras look along their -z, the hand body's -z is the fingers' direction), so the open
# fingers stay out of its 60 degree view.
WRIST_CAMERA = "wrist_camera"
WRIST_CAMERA_POS = (0.07, 0.0, -0.09)
WRIST_CAMERA_FOVY = 60.0


@dataclass(frozen=True)
class Robot:
    """The attached robot's dm_control entities (MJCF elements, not compiled state).

    Attributes:
        arm: dm_control ``JacoArm`` entity.
        hand: dm_control ``JacoHand`` entity (pinch site as tool centre point).
    """

    arm: kinova.JacoArm
    hand: kinova.JacoHand


def add_robot(root: mjcf.RootElement) -> Robot:
    """Build the Jaco arm + hand with touch pads and attach it at ``names.ROBOT_BASE_SITE``.

    Args:
        root: the world's MJCF root; gets the base site, the attached arm and the touch
            sensors (root-level names ``touch_finger_<f>_<i>``).

    Returns:
        The arm and hand entities (use ``physics.bind(robot.hand.pinch_site)`` etc.).
    """
    arm = kinova.JacoArm()
    hand = kinova.JacoHand(use_pinch_site_as_tcp=True)
    _add_touch_pads(root, hand)
    for geom in hand.mjcf_model.find_all("geom"):
        if geom.name and geom.name.startswith("finger"):
            geom.friction = FINGER_FRICTION
    # Gravity compensation: the velocity-servoed arm holds its pose instead of sagging,
    # which keeps "settle" phases and IK-driven controllers simple.
    for model in (arm.mjcf_model, hand.mjcf_model):
        for body in model.find_all("body"):
            body.gravcomp = 1.0
    hand.mjcf_model.find("body", "hand").add(
        "camera", name=WRIST_CAMERA, pos=WRIST_CAMERA_POS, fovy=WRIST_CAMERA_FOVY
    )
    arm.attach(hand)
    base = root.worldbody.add("site", name=names.ROBOT_BASE_SITE, pos=names.ROBOT_BASE_POS)
    base.attach(arm.mjcf_model)
    return Robot(arm=arm, hand=hand)


def _add_touch_pads(root: mjcf.RootElement, hand: kinova.JacoHand) -> None:
    cell_half = 0.0035  # taxel cells tile the pad: 7 mm pitch
    # The tip bodies carry childclass="finger_distal" (a mesh default); give the pads a
    # class of their own so they do not inherit the mesh.
    pad_class = hand.mjcf_model.default.add("default", dclass="touch_pad")
    pad_class.geom.type = "sphere"
    pad_class.site.type = "box"
    for finger in names.FINGERS:
        tip = hand.mjcf_model.find("body", f"b_finger_tip_{finger}")
        for row, (x, y) in enumerate(zip(PAD_ROW_X, PAD_ROW_Y, strict=True)):
            for col, z in enumerate(PAD_COL_Z):
                taxel = row * names.TOUCH_COLS + col
                tip.add(
                    "geom",
                    name=f"pad_finger_{finger}_{taxel}",
                    dclass=pad_class,
                    size=[DOME_RADIUS],
                    pos=[x, y, z],
                    mass=1e-4,
                    rgba=[0.15, 0.15, 0.15, 1.0],
                    group=names.GROUP_ROBOT,
                    contype=1,
                    conaffinity=1,
                    condim=4,
                    friction=PAD_FRICTION,
                    solref=PAD_SOLREF,
                    solimp=PAD_SOLIMP,
                    margin=PAD_MARGIN,
                )
                site = tip.add(
                    "site",
                    name=f"touch_finger_{finger}_{taxel}",
                    dclass=pad_class,
                    size=[cell_half, DOME_RADIUS + 0.002, cell_half],
                    pos=[x, y, z],
                    rgba=[0.9, 0.2, 0.2, 0.3],
                    group=4,
                )
                root.sensor.add("touch", site=site, name=names.touch_sensor(finger, taxel))


def hand_down_quat(yaw: float) -> np.ndarray:
    """(w, x, y, z) of the pinch site with the fingers pointing straight down.

    ``yaw`` (rad) turns the hand about world z; at ``yaw = 0`` the site's frame is the world
    frame turned 180 degrees about x (site +z = world -z).
    """
    half = 0.5 * yaw
    q_yaw = np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
    out = np.zeros(4)
    mujoco.mju_mulQuat(out, q_yaw, np.array([0.0, 1.0, 0.0, 0.0]))
    return out


def arm_qpos_for_pinch(
    physics: mjcf.Physics, pos_world: ArrayLike, yaw: float = 0.0
) -> tuple[np.ndarray, bool]:
    """Arm joint angles putting the pinch site at ``pos_world`` with the hand pointing down.

    Uses dm_control's ``qpos_from_site_pose`` on a copy of ``physics`` (the world is not
    changed). dm_control IK ignores joint limits; the result is checked against the limited
    joints (``joint_2``, ``joint_3``) and ``ok`` is False when IK failed or a limit is broken.

    Args:
        physics: the world's dm_control Physics.
        pos_world: (3,) target of the pinch site, metres, world frame.
        yaw: hand rotation about world z, radians.

    Returns:
        (qpos (6,) radians in ``names.ARM_JOINTS`` order, ok).
    """
    scratch = physics.copy(share_model=True)
    result = inverse_kinematics.qpos_from_site_pose(
        scratch,
        names.PINCH_SITE,
        target_pos=np.asarray(pos_world, dtype=float),
        target_quat=hand_down_quat(yaw),
        joint_names=list(names.ARM_JOINTS),
        tol=1e-10,
        max_steps=300,
        inplace=True,
    )
    model, data = scratch.model.ptr, scratch.data.ptr
    qpos = np.array([data.joint(j).qpos[0] for j in names.ARM_JOINTS])
    ok = bool(result.success)
    for i, joint in enumerate(names.ARM_JOINTS):
        jnt = model.joint(joint)
        if not jnt.limited[0]:
            continue
        low, high = jnt.range
        # Hinge angles are periodic: bring the solution into the limited range if a turn
        # of 2 pi does it.
        qpos[i] = low + np.mod(qpos[i] - low, 2 * np.pi)
        if qpos[i] > high:
            ok = False
    return qpos, ok
