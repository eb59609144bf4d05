"""Simulated devices of the workstation: cameras, stereo pair, scanning range finder, touch pads,
finger joint torques.

Every device has a stable ``name``, a ``read()`` (raising :class:`~mks_sim.errors.DeviceFailure`
when failed), a seeded noise model and runtime fault injection (:class:`DeviceFaults`).
See ``docs/devices.md``.
"""

from __future__ import annotations

from mks_sim.devices.base import Device
from mks_sim.devices.camera import Camera, CameraFrame, CameraNoise, intrinsics_from_fovy
from mks_sim.devices.factory import DEVICE_NAMES, DeviceSet, make_devices
from mks_sim.devices.faults import NO_FAULTS, DeviceFaults, SimDevice
from mks_sim.devices.finger_torque import FingerTorque, FingerTorqueReading
from mks_sim.devices.range_finder import RangeFinder, RangeScan, ScanPattern, merge_scans
from mks_sim.devices.stereo import StereoFrame, StereoPair, stereo_frame
from mks_sim.devices.touch import TouchPad, TouchReading

__all__ = [
    "DEVICE_NAMES",
    "NO_FAULTS",
    "Camera",
    "CameraFrame",
    "CameraNoise",
    "Device",
    "DeviceFaults",
    "DeviceSet",
    "FingerTorque",
    "FingerTorqueReading",
    "RangeFinder",
    "RangeScan",
    "ScanPattern",
    "SimDevice",
    "StereoFrame",
    "StereoPair",
    "TouchPad",
    "TouchReading",
    "intrinsics_from_fovy",
    "make_devices",
    "merge_scans",
    "stereo_frame",
]
