"""The workstation's device set: ``make_devices(model, data, rng, faults) -> DeviceSet``.

Stable device names (``docs/architecture.md``): ``overhead_camera``, ``stereo_left``,
``stereo_right``, ``depth_camera``, ``range_finder``, ``touch_finger_1..3``, ``wrist_camera``
(RGB-D on the Jaco's hand, moved by the arm; issue 13), ``finger_torque_1..3`` (each
finger's motor torque and encoder: is it pressing on something; issue 12). Each device gets
its own generator spawned from ``rng`` in that fixed order, so one seed gives the same readings
however many devices are read. A device whose MuJoCo element is missing from the model (a
world without a hand has no touch pads) is left out, with a log message.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from typing import Any

import mujoco
import numpy as np

from mks_sim.devices.camera import Camera, CameraNoise
from mks_sim.devices.faults import NO_FAULTS, DeviceFaults, SimDevice
from mks_sim.devices.finger_torque import FingerTorque
from mks_sim.devices.range_finder import RangeFinder, ScanPattern
from mks_sim.devices.touch import TouchPad
from mks_sim.errors import NotFound, SpecError
from mks_sim.sim import names as sim_names

logger = logging.getLogger(__name__)

CAMERA_DEVICES = ("overhead_camera", "stereo_left", "stereo_right", "depth_camera")
TOUCH_DEVICES = ("touch_finger_1", "touch_finger_2", "touch_finger_3")
#: Cameras carried by the robot: device name -> MuJoCo camera (inside the attached hand).
ROBOT_CAMERAS = {"wrist_camera": f"{sim_names.HAND_PREFIX}wrist_camera"}
# New devices go last: each device's generator is the i-th child of the seed, so appending
# keeps every existing device's readings.
#: Each finger's joint-torque sensing (motor torque + encoder): "finger i presses on
#: something", the Touch_Contacts alternate for a failed pad (devices/finger_torque.py).
FINGER_TORQUE_DEVICES = ("finger_torque_1", "finger_torque_2", "finger_torque_3")
DEVICE_NAMES = (
    *CAMERA_DEVICES, "range_finder", *TOUCH_DEVICES, *ROBOT_CAMERAS, *FINGER_TORQUE_DEVICES
)  # fmt: skip

# Default options per device (overridable through make_devices(options=...)).
DEFAULT_OPTIONS: dict[str, dict[str, Any]] = {
    "overhead_camera": {"width": 640, "height": 480, "depth": False},
    "stereo_left": {"width": 640, "height": 480, "depth": False},
    "stereo_right": {"width": 640, "height": 480, "depth": False},
    "depth_camera": {"width": 320, "height": 240, "depth": True},
    "range_finder": {
        "mounts": ("range_finder_mount_0", "range_finder_mount_1"),
        # ~2.5 mm spacing on the object region from the mounts ~0.57 m away (0.25 deg steps).
        "pattern": ScanPattern(n_pan=128, n_tilt=112, pan_deg=16.0, tilt_deg=14.0),
        "max_range_m": 2.0,
        "sigma_m": 0.0005,
        # Visible geoms and touch pads; never group 3, the invisible collision stand-ins.
        "geomgroup": (1, 1, 1, 0, 0, 0),
    },
    "touch_finger_1": {},
    "touch_finger_2": {},
    "touch_finger_3": {},
    # An industrial 3-D camera on the wrist (structured light, sub-mm class): ~0.5 mm depth
    # noise at the 0.45 m of a view above the bin, like the range finder's 0.5 mm. With the
    # generic RGB-D camera's noise (1 mm + 0.2 %: ~2 mm there) the bin's parts were not found.
    "wrist_camera": {
        "width": 320,
        "height": 240,
        "depth": True,
        "noise": CameraNoise(depth_sigma_m=0.0003, depth_sigma_rel=0.0005),
    },
    "finger_torque_1": {},
    "finger_torque_2": {},
    "finger_torque_3": {},
}


class DeviceSet(dict[str, SimDevice]):
    """``{name: device}`` with fault control and one ``close()`` for all renderers."""

    def set_fault(self, name: str, faults: DeviceFaults | None = None, **kw: Any) -> None:
        """Set device ``name`` 's faults: a :class:`DeviceFaults`, or its fields as keywords
        (``set_fault("range_finder", failed=True)``); ``set_fault(name)`` clears them.

        Raises:
            NotFound: no such device.
        """
        if name not in self:
            raise NotFound(f"no device named {name!r}; devices: {sorted(self)}")
        self[name].faults = faults if faults is not None else DeviceFaults(**kw)

    def clear_faults(self) -> None:
        """Make every device healthy."""
        for dev in self.values():
            dev.faults = NO_FAULTS

    def close(self) -> None:
        """Close every device (releases camera renderers)."""
        for dev in self.values():
            dev.close()

    def __enter__(self) -> DeviceSet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _touch_sensors(model: mujoco.MjModel, device: str) -> list[str]:
    """Taxel sensors of pad ``device`` (``touch_finger_<f>``) per ``mks_sim.sim.names``,
    those present in the model."""
    finger = int(device.rsplit("_", 1)[1])
    candidates = sim_names.touch_sensors(finger)
    return [s for s in candidates if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, s) >= 0]


def _robot_bodies(model: mujoco.MjModel) -> tuple[str, ...]:
    """Bodies of the robot (arm and hand): the scanner self-filters their returns."""
    found = []
    for b in range(model.nbody):
        nm = model.body(b).name
        if nm.startswith(sim_names.ROBOT_PREFIX):
            found.append(nm)
    return tuple(found)


def make_devices(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    rng: np.random.Generator,
    faults: Mapping[str, DeviceFaults] | None = None,
    *,
    names: Iterable[str] = DEVICE_NAMES,
    options: Mapping[str, Mapping[str, Any]] | None = None,
    camera_noise: CameraNoise | None = None,
) -> DeviceSet:
    """Build the workstation devices over a compiled world.

    Args:
        model, data: the world's ``MjModel`` / ``MjData`` (``World.model``, ``World.data``).
        rng: parent generator; each device gets a child spawned in ``DEVICE_NAMES`` order.
        faults: initial faults by device name.
        names: which devices to build (default: all).
        options: per-device keyword overrides of ``DEFAULT_OPTIONS``.
        camera_noise: noise of every camera (default :class:`CameraNoise`).

    Returns:
        A :class:`DeviceSet`; close it (or use ``with``) to release the renderers.

    Raises:
        SpecError: an unknown device name or fault entry.
    """
    wanted = list(names)
    for n in (*wanted, *(faults or {})):
        if n not in DEVICE_NAMES:
            raise SpecError(f"unknown device {n!r}; expected one of {DEVICE_NAMES}")
    children = dict(zip(DEVICE_NAMES, rng.spawn(len(DEVICE_NAMES))))
    faults = faults or {}
    devices = DeviceSet()
    try:
        for name in DEVICE_NAMES:
            if name not in wanted:
                continue
            opts = {**DEFAULT_OPTIONS[name], **(options or {}).get(name, {})}
            dev = _make_one(model, data, name, children[name], opts, camera_noise)
            if dev is None:
                continue
            dev.faults = faults.get(name, NO_FAULTS)
            devices[name] = dev
    except Exception:
        devices.close()
        raise
    return devices


def _make_one(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    name: str,
    rng: np.random.Generator,
    opts: dict[str, Any],
    camera_noise: CameraNoise | None,
) -> SimDevice | None:
    if name in CAMERA_DEVICES:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name) < 0:
            logger.info("device %s: no camera of that name in the model; left out", name)
            return None
        opts.setdefault("noise", camera_noise)
        return Camera(model, data, name, rng, name=name, **opts)
    if name in ROBOT_CAMERAS:
        camera = ROBOT_CAMERAS[name]
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            logger.info("device %s: no camera %s in the model; left out", name, camera)
            return None
        opts.setdefault("noise", camera_noise)
        return Camera(model, data, camera, rng, name=name, **opts)
    if name == "range_finder":
        mounts = [
            m
            for m in opts.pop("mounts")
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, m) >= 0
        ]
        if not mounts:
            logger.info("device range_finder: no mount sites in the model; left out")
            return None
        opts.setdefault("self_bodies", _robot_bodies(model))
        return RangeFinder(model, data, mounts, rng, name=name, **opts)
    if name in FINGER_TORQUE_DEVICES:
        finger = int(name.rsplit("_", 1)[1])
        joint, act = sim_names.FINGER_JOINTS[finger - 1], sim_names.FINGER_ACTUATORS[finger - 1]
        sites = tuple(sim_names.touch_site(finger, i) for i in range(sim_names.TAXELS_PER_PAD))
        present = (
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint) >= 0
            and mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, act) >= 0
            and all(mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, s) >= 0 for s in sites)
        )
        if not present:
            logger.info("device %s: no finger joint / actuator / pad in the model; left out", name)
            return None
        return FingerTorque(model, data, joint, act, sites, rng, name=name, **opts)
    sensors = _touch_sensors(model, name)
    if not sensors:
        logger.info("device %s: no taxel sensors in the model; left out", name)
        return None
    return TouchPad(model, data, sensors, rng, name=name, **opts)
