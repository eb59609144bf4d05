"""Stable names of everything devices, controllers and evaluation read from a world.

Access MuJoCo by these names (``model.camera(OVERHEAD_CAMERA)``, ``data.site(...)``,
``data.sensor(...)``), never by index. Root-level names are clean; elements inside the
attached Jaco arm and hand carry dm_control's attachment prefix (``ROBOT_PREFIX`` /
``HAND_PREFIX``), spelled out in full below. See ``docs/worlds.md`` for frames and units.
"""

from __future__ import annotations

# --- cameras (MuJoCo convention: the camera looks along its -z axis, +x right, +y up) -------
OVERHEAD_CAMERA = "overhead_camera"  # straight down at the table, image up = world +y
STEREO_LEFT = "stereo_left"  # rectified pair: same orientation, parallel optical axes
STEREO_RIGHT = "stereo_right"  # STEREO_BASELINE_M along the left camera's +x axis
DEPTH_CAMERA = "depth_camera"  # oblique view for depth images
CAMERAS: tuple[str, ...] = (OVERHEAD_CAMERA, STEREO_LEFT, STEREO_RIGHT, DEPTH_CAMERA)
STEREO_BASELINE_M = 0.08

# --- range finder mounts (sites; +z axis = scanner boresight, pointing at the object region;
# +x horizontal (perpendicular to the boresight and world z), +y = z cross x) ----------------
RANGE_FINDER_MOUNTS: tuple[str, ...] = ("range_finder_mount_0", "range_finder_mount_1")

# --- table and work region --------------------------------------------------------------------
TABLE = "table"  # body; its top surface is at world z = TABLE_TOP_Z
TABLE_TOP_GEOM = "table_top"
TABLE_TOP_Z = 0.75  # metres above the floor (world z = 0)
OBJECT_REGION = "object_region"  # site at the centre of the object region, on the table top
OBJECT_REGION_CENTER_XY = (0.0, 0.0)
OBJECT_REGION_HALF_XY = (0.12, 0.10)  # metres; randomised objects stay inside
TRAY = "tray"  # scene1 only: light plate carrying the flat parts

# --- objects (bodies with a free joint named "<body>_joint") ---------------------------------
CUBE = "cube"
SPHERE = "sphere"
PART = "part"
CUBE_SIZE_M = 0.05  # edge length
SPHERE_RADIUS_M = 0.03
CLUTTER: tuple[str, ...] = ("clutter_0", "clutter_1", "clutter_2")  # scene2


def free_joint(body: str) -> str:
    """Name of the free joint of an object body (``"cube"`` -> ``"cube_joint"``)."""
    return f"{body}_joint"


# --- geom groups (mjvOption.geomgroup / mj_ray geomgroup) ----------------------------------
GROUP_VISUAL = 0  # rendered and ray cast: everything a sensor can see
GROUP_ROBOT = 1  # touch pads (also rendered; collision on)
GROUP_COLLISION_ONLY = 3  # invisible contact stand-ins (the part's convex decomposition)

# --- robot (dm_control Kinova Jaco arm + 3-finger hand) ---------------------------------------
ROBOT_BASE_SITE = "robot_base"  # root-level site the arm is attached at
ROBOT_BASE_POS = (0.0, 0.42, TABLE_TOP_Z)
ROBOT_PREFIX = "jaco_arm/"
HAND_PREFIX = "jaco_arm/jaco_hand/"
ARM_JOINTS: tuple[str, ...] = tuple(f"{ROBOT_PREFIX}joint_{i}" for i in range(1, 7))
FINGER_JOINTS: tuple[str, ...] = tuple(f"{HAND_PREFIX}finger_{i}" for i in range(1, 4))
ARM_ACTUATORS = ARM_JOINTS  # velocity actuators, same names as their joints
FINGER_ACTUATORS = FINGER_JOINTS  # velocity actuators; ctrl > 0 closes
PINCH_SITE = f"{HAND_PREFIX}pinchsite"  # tool centre point; +z points out of the palm
GRIP_SITE = f"{HAND_PREFIX}gripsite"
WRIST_SITE = f"{ROBOT_PREFIX}wristsite"
HAND_BODY = f"{HAND_PREFIX}hand"
FINGER_TIP_BODIES: tuple[str, ...] = tuple(f"{HAND_PREFIX}b_finger_tip_{i}" for i in (1, 2, 3))

# --- touch pads: a TOUCH_ROWS x TOUCH_COLS grid per fingertip ---------------------------------
FINGERS: tuple[int, ...] = (1, 2, 3)
TOUCH_ROWS = 3  # along the finger (index 0 = nearest the knuckle)
TOUCH_COLS = 3  # across the finger
TAXELS_PER_PAD = TOUCH_ROWS * TOUCH_COLS


def touch_sensor(finger: int, taxel: int) -> str:
    """Root-level name of the MuJoCo touch sensor of one taxel (N, normal force sum).

    ``taxel = row * TOUCH_COLS + col``; ``finger`` in 1..3.
    """
    return f"touch_finger_{finger}_{taxel}"


def touch_site(finger: int, taxel: int) -> str:
    """Full (prefixed) name of the site bounding one taxel."""
    return f"{HAND_PREFIX}touch_finger_{finger}_{taxel}"


def touch_geom(finger: int, taxel: int) -> str:
    """Full (prefixed) name of the soft pad geom of one taxel."""
    return f"{HAND_PREFIX}pad_finger_{finger}_{taxel}"


def touch_sensors(finger: int) -> tuple[str, ...]:
    """All taxel sensor names of one finger, row-major."""
    return tuple(touch_sensor(finger, i) for i in range(TAXELS_PER_PAD))
