"""What every device is, as far as the logical-sensor layer is concerned.

A device is anything with a stable ``name`` and a ``read()`` that returns its current reading
or raises :class:`~mks_sim.errors.DeviceFailure`. Simulated devices (``mks_sim.devices``) and
fake devices in tests both satisfy this protocol; the sensing layer knows nothing else of them.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Device(Protocol):
    """A physical (or simulated, or fake) sensor device."""

    name: str

    def read(self) -> Any:
        """Return the current reading; raise ``DeviceFailure`` when the device fails."""
        ...
