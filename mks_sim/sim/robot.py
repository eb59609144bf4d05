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

from dm_control import mjcf
from dm_control.entities.manipulators import kinova

from mks_sim.sim import names

# Pad geometry in the distal phalanx body frame (b_finger_tip_<f>): the inner (closing)
# side of dm_control's finger_distal mesh is the +y face, flat at y ~ 0 for x in
# [0.02, 0.036] m and |z| < 0.0105 m (measured from the mesh vertices).
PAD_ROW_X = (0.0215, 0.0280, 0.0345)  # along the finger, knuckle side first
PAD_COL_Z = (-0.0065, 0.0, 0.0065)  # across the finger
PAD_SURFACE_Y = 0.0002
DOME_RADIUS = 0.003  # m
DOME_CENTER_Y = PAD_SURFACE_Y  # dome protrudes DOME_RADIUS beyond the finger surface
# Soft rubber-like pad: 15 ms time constant (default 20 ms), impedance ramps over 2 mm.
PAD_SOLREF = (0.015, 1.0)
PAD_SOLIMP = (0.6, 0.95, 0.002, 0.5, 2.0)
PAD_MARGIN = 0.0008
PAD_FRICTION = (1.2, 0.01, 0.0002)
FINGER_FRICTION = (1.0, 0.01, 0.0002)


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
    arm.attach(hand)
    base = root.worldbody.add("site", name=names.ROBOT_BASE_SITE, pos=names.ROBOT_BASE_POS)
    base.attach(arm.mjcf_model)
    return Robot(arm=arm, hand=hand)


def _add_touch_pads(root: mjcf.RootElement, hand: kinova.JacoHand) -> None:
    cell_half = 0.00325
    # The tip bodies carry childclass="finger_distal" (a mesh default); give the pads a
    # class of their own so they do not inherit the mesh.
    pad_class = hand.mjcf_model.default.add("default", dclass="touch_pad")
    pad_class.geom.type = "sphere"
    pad_class.site.type = "box"
    for finger in names.FINGERS:
        tip = hand.mjcf_model.find("body", f"b_finger_tip_{finger}")
        for row, x in enumerate(PAD_ROW_X):
            for col, z in enumerate(PAD_COL_Z):
                taxel = row * names.TOUCH_COLS + col
                tip.add(
                    "geom",
                    name=f"pad_finger_{finger}_{taxel}",
                    dclass=pad_class,
                    size=[DOME_RADIUS],
                    pos=[x, DOME_CENTER_Y, z],
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
                    pos=[x, DOME_CENTER_Y, z],
                    rgba=[0.9, 0.2, 0.2, 0.3],
                    group=4,
                )
                root.sensor.add("touch", site=site, name=names.touch_sensor(finger, taxel))
