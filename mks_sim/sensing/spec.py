"""Frozen specs of devices and logical sensors, as declared in ``sensors/*.toml``.

Declaration apart from execution: these are plain values parsed from files
(:mod:`mks_sim.sensing.loader`); :class:`~mks_sim.sensing.graph.SensorGraph` checks them
together and :class:`~mks_sim.sensing.snapshot.Snapshot` runs them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from mks_sim.fields import OutputVector

__all__ = ["AcceptanceSpec", "AlternateSpec", "DeviceSpec", "SensorSpec", "freeze_params"]

PRIMARY = "primary"


def freeze_params(params: Mapping[str, Any] | None) -> Mapping[str, Any]:
    """A read-only copy of ``params`` (nested dicts and lists frozen too)."""

    def freeze(value: Any) -> Any:
        if isinstance(value, Mapping):
            return MappingProxyType({k: freeze(v) for k, v in value.items()})
        if isinstance(value, list | tuple):
            return tuple(freeze(v) for v in value)
        return value

    return freeze(dict(params or {}))  # type: ignore[no-any-return]


def _thaw(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _thaw(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return [_thaw(v) for v in value]
    return value


@dataclass(frozen=True)
class DeviceSpec:
    """A declared device (``[[device]]`` in ``sensors/devices.toml``).

    Attributes:
        name: stable device name (``range_finder``); the key of the devices mapping given
            to :meth:`SensorGraph.snapshot`.
        kind: what it is (``camera``, ``range_finder``, ``touch``...), free text.
        description: one line for people.
        file: where it was declared (None when built in code).
    """

    name: str
    kind: str = ""
    description: str = ""
    file: Path | None = field(default=None, compare=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "description": self.description,
            "file": None if self.file is None else str(self.file),
        }


@dataclass(frozen=True)
class AcceptanceSpec:
    """An acceptance test run on a sensor's validated output: ``test(stream, params)``."""

    test: str
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", freeze_params(self.params))

    def to_dict(self) -> dict[str, Any]:
        return {"test": self.test, "params": _thaw(self.params)}


@dataclass(frozen=True)
class AlternateSpec:
    """One way of computing a logical sensor: the primary or a ``[[sensor.alternate]]``.

    Attributes:
        name: ``"primary"`` for the sensor's own program, else the alternate's name (this is
            what provenance reports).
        inputs: device names or logical-sensor names, in the order the program expects.
        program: registered program name.
        params: passed to the program (read-only).
        acceptance: the acceptance test of this way (an alternate without its own inherits the
            sensor's), or None.
    """

    name: str
    inputs: tuple[str, ...]
    program: str
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    acceptance: AcceptanceSpec | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "params", freeze_params(self.params))

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "inputs": list(self.inputs),
            "program": self.program,
            "params": _thaw(self.params),
            "acceptance": None if self.acceptance is None else self.acceptance.to_dict(),
        }


@dataclass(frozen=True)
class SensorSpec:
    """A logical sensor (``[[sensor]]``): a program over devices or other logical sensors.

    Attributes:
        name: unique sensor name (``Range_Points``).
        description: one line for people.
        inputs, program, params, acceptance: the primary way (see :class:`AlternateSpec`).
        output: the characteristic output vector (shared by all alternates).
        alternates: tried in order when the primary fails.
        file: where it was declared (None when built in code).
    """

    name: str
    inputs: tuple[str, ...]
    program: str
    output: OutputVector
    params: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    description: str = ""
    acceptance: AcceptanceSpec | None = None
    alternates: tuple[AlternateSpec, ...] = ()
    file: Path | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "inputs", tuple(self.inputs))
        object.__setattr__(self, "params", freeze_params(self.params))
        object.__setattr__(self, "alternates", tuple(self.alternates))

    @property
    def primary(self) -> AlternateSpec:
        """The primary way as an :class:`AlternateSpec` named ``"primary"``."""
        return AlternateSpec(PRIMARY, self.inputs, self.program, self.params, self.acceptance)

    @property
    def ways(self) -> tuple[AlternateSpec, ...]:
        """The primary then the alternates, in the order they are tried (alternates without
        their own acceptance test inherit the sensor's)."""
        alts = tuple(
            a
            if a.acceptance is not None or self.acceptance is None
            else AlternateSpec(a.name, a.inputs, a.program, a.params, self.acceptance)
            for a in self.alternates
        )
        return (self.primary, *alts)

    @property
    def all_inputs(self) -> tuple[str, ...]:
        """Every input of the primary and the alternates, first occurrence order."""
        seen: dict[str, None] = {}
        for way in (self.primary, *self.alternates):
            for name in way.inputs:
                seen.setdefault(name)
        return tuple(seen)

    @property
    def where(self) -> str:
        """``"sensors/x.toml: sensor 'Name'"`` for error messages."""
        prefix = f"{self.file}: " if self.file is not None else ""
        return f"{prefix}sensor {self.name!r}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "file": None if self.file is None else str(self.file),
            "inputs": list(self.inputs),
            "program": self.program,
            "params": _thaw(self.params),
            "output": [f.to_dict() for f in self.output],
            "acceptance": None if self.acceptance is None else self.acceptance.to_dict(),
            "alternates": [a.to_dict() for a in self.alternates],
        }
