"""The one error hierarchy of mks_sim.

Every error says what was expected, what was got, the valid options where there are some, and
where (file, entry, field). Library code raises these; the CLI turns them into one-line messages
and a non-zero exit code, never a traceback.
"""

from __future__ import annotations


class MksError(Exception):
    """Base class of every error mks_sim raises on purpose."""


class SpecError(MksError):
    """A configuration file (sensor, model, task, world) or a spec object is malformed.

    Messages name the file, the entry (sensor/model/task name) and the field.
    """


class DataError(MksError):
    """Input data is unusable: NaN where none is allowed, wrong shape, empty, truncated file."""


class DeviceFailure(MksError):
    """A (simulated or real) device failed to deliver a reading."""

    def __init__(self, device: str, reason: str = "failed") -> None:
        super().__init__(f"device {device!r} failed: {reason}")
        self.device = device
        self.reason = reason


class SensorFailure(MksError):
    """A logical sensor's program could not produce its output (and no alternate could)."""

    def __init__(self, sensor: str, reason: str) -> None:
        super().__init__(f"logical sensor {sensor!r} failed: {reason}")
        self.sensor = sensor
        self.reason = reason


class NotFound(MksError):
    """A model, sensor, file or object was asked for by name and does not exist,
    or a search (e.g. localization) found nothing."""
