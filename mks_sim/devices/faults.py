"""Fault injection for simulated devices, and the read loop every simulated device shares.

A device's faults are a frozen :class:`DeviceFaults` value, replaced (not mutated) at runtime::

    device.faults = DeviceFaults(failed=True)          # read() raises DeviceFailure
    device.faults = DeviceFaults(stuck=True)           # read() repeats its last reading
    device.faults = DeviceFaults(dropout=0.3)          # 30 % of rays / pixels / taxels lost
    device.faults = DeviceFaults(noise_scale=4.0)      # noise sigma times 4
    device.faults = NO_FAULTS                          # healthy again

The CLI's ``--fail DEVICE`` and the gymnasium environment go through
:func:`mks_sim.devices.factory.set_fault` on the dict returned by ``make_devices``.
"""

from __future__ import annotations

import logging
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

import numpy as np

from mks_sim.errors import DeviceFailure, SpecError

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class DeviceFaults:
    """The fault state of one device.

    Attributes:
        failed: ``read()`` raises :class:`~mks_sim.errors.DeviceFailure`.
        stuck: ``read()`` returns the previous reading again (the first read of a stuck
            device still measures, so that there is something to repeat).
        dropout: fraction in [0, 1] of the device's elements (rays, depth pixels, taxels)
            that return nothing, on top of the device's own dropout rate.
        noise_scale: factor (>= 0) on every noise sigma of the device; 0 gives noise-free
            readings, 1 the device's nominal noise.
    """

    failed: bool = False
    stuck: bool = False
    dropout: float = 0.0
    noise_scale: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.dropout, int | float) and 0.0 <= self.dropout <= 1.0):
            raise SpecError(
                f"DeviceFaults.dropout: expected a number in [0, 1], got {self.dropout!r}"
            )
        if not (
            isinstance(self.noise_scale, int | float)
            and math.isfinite(self.noise_scale)
            and self.noise_scale >= 0.0
        ):
            raise SpecError(
                f"DeviceFaults.noise_scale: expected a finite number >= 0, got {self.noise_scale!r}"
            )

    @property
    def healthy(self) -> bool:
        """True when no fault is active."""
        return self == NO_FAULTS


NO_FAULTS = DeviceFaults()


def combined_dropout(rate: float, faults: DeviceFaults) -> float:
    """Probability that an element is lost: the device's own rate and the injected one."""
    return 1.0 - (1.0 - rate) * (1.0 - faults.dropout)


class SimDevice(ABC):
    """Base of the simulated devices: name, seeded noise, faults, stuck/failed behaviour.

    Subclasses implement :meth:`_measure`, which takes a fresh reading using ``self.rng`` for
    all randomness and ``self.faults`` for dropout and noise scale. ``read()`` wraps it with
    the failed / stuck logic. Satisfies the :class:`mks_sim.devices.base.Device` protocol.
    """

    def __init__(
        self, name: str, rng: np.random.Generator, faults: DeviceFaults | None = None
    ) -> None:
        if not isinstance(rng, np.random.Generator):
            raise SpecError(
                f"device {name!r}: expected rng to be a numpy.random.Generator, got {type(rng).__name__}"
            )
        self.name = name
        self.rng = rng
        self._faults = NO_FAULTS if faults is None else faults
        self._last: Any = None

    @property
    def faults(self) -> DeviceFaults:
        """The active fault state (assign a new :class:`DeviceFaults` to change it)."""
        return self._faults

    @faults.setter
    def faults(self, value: DeviceFaults) -> None:
        if not isinstance(value, DeviceFaults):
            raise SpecError(
                f"device {self.name!r}: expected DeviceFaults, got {type(value).__name__}"
            )
        if value != self._faults:
            logger.info("device %s: faults set to %s", self.name, value)
        self._faults = value

    def read(self) -> Any:
        """Return a reading (see the subclass) or raise ``DeviceFailure`` when failed."""
        if self._faults.failed:
            raise DeviceFailure(self.name, "failed (fault injected)")
        if self._faults.stuck and self._last is not None:
            return self._last
        reading = self._measure()
        self._last = reading
        return reading

    @abstractmethod
    def _measure(self) -> Any:
        """Take a fresh reading."""

    def close(self) -> None:  # noqa: B027 - optional hook, most devices hold nothing
        """Release resources (renderers); a closed device must not be read again."""

    def __enter__(self) -> SimDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, faults={self._faults})"
