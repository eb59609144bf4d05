"""Logical sensors: the sensor definition language, its programs and snapshots.

Paper section 1.1: a logical sensor is a program over devices or other logical sensors, with
alternates when an input fails, defined by its characteristic output vector. Sensor files
(``sensors/*.toml``) become frozen specs; :class:`SensorGraph` checks them together;
:meth:`SensorGraph.snapshot` runs them over a set of devices. See ``docs/sensors.md``.
"""

from __future__ import annotations

from mks_sim.sensing.graph import DEVICES_FILE, SensorGraph, default_devices
from mks_sim.sensing.loader import SensorFile, load_file
from mks_sim.sensing.registry import (
    ACCEPTANCE,
    PROGRAMS,
    acceptance_names,
    get_acceptance,
    get_program,
    program_names,
    register_acceptance,
    register_program,
    takes_params,
)
from mks_sim.sensing.snapshot import Attempt, Snapshot
from mks_sim.sensing.spec import AcceptanceSpec, AlternateSpec, DeviceSpec, SensorSpec

__all__ = [
    "ACCEPTANCE",
    "DEVICES_FILE",
    "PROGRAMS",
    "AcceptanceSpec",
    "AlternateSpec",
    "Attempt",
    "DeviceSpec",
    "SensorFile",
    "SensorGraph",
    "SensorSpec",
    "Snapshot",
    "acceptance_names",
    "default_devices",
    "get_acceptance",
    "get_program",
    "load_file",
    "program_names",
    "register_acceptance",
    "register_program",
    "takes_params",
]
