"""One snapshot of the sensors: each device read at most once, each sensor run at most once.

Paper section 3: the data from the sensors is analysed "as a sequence of snapshots". Within a
snapshot a logical sensor runs its primary program; if an input device fails (or is not
connected), an input sensor fails, the program raises :class:`SensorFailure`, the output is
unusable or the acceptance test rejects it, the next alternate runs (paper section 1.1: "failure
of a physical device does not preclude the definition of an alternative method for obtaining
the same information"). Every fallback is logged at WARNING with its reason and recorded in
:attr:`Snapshot.provenance` / :attr:`Snapshot.attempts`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from mks_sim.errors import DataError, DeviceFailure, NotFound, SensorFailure
from mks_sim.fields import Stream
from mks_sim.sensing.registry import get_acceptance, get_program
from mks_sim.sensing.spec import AlternateSpec, SensorSpec

if TYPE_CHECKING:
    from mks_sim.devices.base import Device
    from mks_sim.sensing.graph import SensorGraph

__all__ = ["Attempt", "Snapshot"]

log = logging.getLogger("mks_sim.sensing")


@dataclass(frozen=True)
class Attempt:
    """One try of one way (primary or alternate) of a sensor.

    Attributes:
        sensor: the logical sensor.
        way: ``"primary"`` or the alternate's name.
        ok: True when this way served the sensor.
        reason: why it failed ("" when ok).
    """

    sensor: str
    way: str
    ok: bool
    reason: str = ""


class Snapshot:
    """Lazy, cached evaluation of a :class:`SensorGraph` over a set of devices.

    Args:
        graph: the checked sensor graph.
        devices: device name -> object with ``read()`` (the ``Device`` protocol); a declared
            device missing from the mapping counts as failed ("not connected").
        strict: rows that validation would drop (``reject`` policy, NaN in ``clip`` fields)
            make the way fail instead (and the next alternate runs).
    """

    def __init__(
        self, graph: SensorGraph, devices: Mapping[str, Device], *, strict: bool = False
    ) -> None:
        self.graph = graph
        self.strict = strict
        self._devices = dict(devices)
        self._readings: dict[str, Any] = {}
        self._device_errors: dict[str, DeviceFailure] = {}
        self._streams: dict[str, Stream] = {}
        self._failures: dict[str, SensorFailure] = {}
        self._attempts: dict[str, list[Attempt]] = {}
        self._provenance: dict[str, str] = {}
        self._representations: dict[tuple[str, Any], Any] = {}

    # ------------------------------------------------------------------ public

    @property
    def provenance(self) -> dict[str, str]:
        """Sensor -> the way that served it (``"primary"`` or an alternate's name), for every
        sensor evaluated successfully so far (a copy)."""
        return dict(self._provenance)

    @property
    def failures(self) -> dict[str, str]:
        """Sensor -> reason, for every sensor that failed in this snapshot."""
        return {name: exc.reason for name, exc in self._failures.items()}

    @property
    def attempts(self) -> dict[str, tuple[Attempt, ...]]:
        """Sensor -> every way tried, in order."""
        return {name: tuple(a) for name, a in self._attempts.items()}

    @property
    def devices_read(self) -> frozenset[str]:
        """The devices read (successfully or not) in this snapshot."""
        return frozenset(self._readings) | frozenset(self._device_errors)

    def read(self, device: str) -> Any:
        """The reading of ``device``, read at most once per snapshot (failures are cached too).

        Raises:
            NotFound: ``device`` is not declared in the graph.
            DeviceFailure: the device failed or is not in the devices mapping.
        """
        if device in self._readings:
            return self._readings[device]
        if device in self._device_errors:
            raise self._device_errors[device]
        if device not in self.graph.device_names:
            raise NotFound(
                f"unknown device {device!r}; declared devices: {sorted(self.graph.device_names)}"
            )
        dev = self._devices.get(device)
        try:
            if dev is None:
                raise DeviceFailure(device, "not connected (not in the devices of this snapshot)")
            reading = dev.read()
        except DeviceFailure as exc:
            self._device_errors[device] = exc
            raise
        self._readings[device] = reading
        return reading

    def get(self, sensor: str) -> Stream:
        """The output of ``sensor``, evaluated at most once per snapshot.

        Raises:
            NotFound: no such sensor.
            SensorFailure: every way (primary and alternates) failed; the message lists each
                attempt's reason.
        """
        if sensor in self._streams:
            return self._streams[sensor]
        if sensor in self._failures:
            raise self._failures[sensor]
        if sensor in self.graph.device_names:
            raise NotFound(f"{sensor!r} is a device, not a logical sensor; use read({sensor!r})")
        spec = self.graph.sensor(sensor)
        try:
            stream = self._evaluate(spec)
        except SensorFailure as exc:
            self._failures[sensor] = exc
            raise
        self._streams[sensor] = stream
        return stream

    def representation(self, sensor: str, config: Any = None) -> Any:
        """The low-level representation of a point sensor's output (k-d tree, table, SPG,
        normals, segmentation; :class:`mks_sim.localization.representation.Representation`),
        built at most once per snapshot and shared with the description programs that read
        the same stream.

        Args:
            sensor: a logical sensor whose first three fields are x, y, z.
            config: a ``RepresentationConfig`` (default ``RepresentationConfig()``).

        Raises:
            SensorFailure: the sensor failed, or its points cannot be represented.
        """
        key = (sensor, config)
        if key not in self._representations:
            from mks_sim.localization.representation import representation_of

            stream = self.get(sensor)
            try:
                self._representations[key] = representation_of(stream.data, config)
            except DataError as exc:
                raise SensorFailure(sensor, str(exc)) from exc
        return self._representations[key]

    def origins(self, sensor: str) -> np.ndarray:
        """(K, 3) world positions the points of ``sensor`` were seen from: the optical
        centres of the device readings the way that served it used (each range-finder
        view's mount, each camera's centre; through input sensors too). Sensor
        calibration, like the poses the programs reproject with; empty when ``sensor`` has
        not been served or its readings carry no pose.

        Raises:
            NotFound: no such sensor.
        """
        spec = self.graph.sensor(sensor)
        way = next((w for w in spec.ways if w.name == self._provenance.get(sensor)), None)
        found: list[np.ndarray] = []
        for name in () if way is None else way.inputs:
            if name in self.graph:
                found.extend(self.origins(name))
            elif name in self._readings:
                found.extend(_reading_origins(self._readings[name]))
        return np.asarray(found, dtype=np.float64).reshape(-1, 3)

    def evaluate(self, names: Iterable[str]) -> dict[str, Stream]:
        """``get`` each sensor of ``names`` (inputs are evaluated on demand, so a failed input
        only matters to the ways that use it); raises on the first sensor that fails."""
        wanted = [names] if isinstance(names, str) else list(names)
        return {name: self.get(name) for name in wanted}

    # ------------------------------------------------------------------ internals

    def _evaluate(self, spec: SensorSpec) -> Stream:
        ways = spec.ways
        attempts = self._attempts.setdefault(spec.name, [])
        for k, way in enumerate(ways):
            try:
                stream = self._run(spec, way)
            except (DeviceFailure, SensorFailure, DataError) as exc:
                reason = exc.reason if isinstance(exc, SensorFailure) else str(exc)
                if isinstance(exc, SensorFailure) and exc.sensor != spec.name:
                    reason = str(exc)  # an input sensor failed: say which
                attempts.append(Attempt(spec.name, way.name, False, reason))
                if k + 1 < len(ways):
                    log.warning(
                        "sensor %r: %s failed (%s); falling back to alternate %r",
                        spec.name,
                        way.name,
                        reason,
                        ways[k + 1].name,
                    )
                continue
            attempts.append(Attempt(spec.name, way.name, True))
            self._provenance[spec.name] = way.name
            if way.name != "primary":
                log.info("sensor %r served by alternate %r", spec.name, way.name)
            return stream
        tried = "; ".join(f"{a.way}: {a.reason}" for a in attempts if not a.ok)
        raise SensorFailure(spec.name, f"all {len(ways)} way(s) failed: {tried}")

    def _run(self, spec: SensorSpec, way: AlternateSpec) -> Stream:
        inputs: dict[str, Any] = {}
        for name in way.inputs:
            inputs[name] = self.get(name) if name in self.graph else self.read(name)
        program = get_program(way.program)
        result = program(MappingProxyType(inputs), way.params)
        where = f"{spec.where} ({way.name}, program {way.program!r})"
        source = flags_in = None
        if isinstance(result, Stream):
            if result.vector.names != spec.output.names:
                raise DataError(
                    f"{where}: program returned fields {list(result.vector.names)}, expected "
                    f"{list(spec.output.names)}"
                )
            data, source, flags_in = result.data, result.source, result.flags
        else:
            data = result
        checked = spec.output.validate(data, strict=self.strict, where=where)
        if not checked.report.clean:
            level = logging.WARNING if checked.report.dropped else logging.INFO
            log.log(level, "%s: validation: %s", where, checked.report.summary())
        flags = checked.flags
        if flags_in is not None:
            flags = flags | flags_in[checked.kept]
        stream = Stream(
            checked.data,
            spec.output,
            spec.name,
            way.name,
            None if source is None else source[checked.kept],
            flags if flags.any() else None,
            checked.report,
        )
        if way.acceptance is not None:
            test = get_acceptance(way.acceptance.test)
            why = test(stream, way.acceptance.params)
            if why:
                raise SensorFailure(
                    spec.name, f"acceptance test {way.acceptance.test!r} rejected it: {why}"
                )
        return stream


def _reading_origins(reading: Any) -> list[np.ndarray]:
    """The optical centres of one device reading (duck-typed: the sensing layer does not
    import the devices): a range scan's ``sensor_to_world``, a camera frame's
    ``camera_to_world``, a stereo frame's ``left_to_world`` and its right camera; a list of
    readings (a range finder's views) gives each one's."""
    if isinstance(reading, list | tuple):
        return [o for r in reading for o in _reading_origins(r)]
    for attr in ("sensor_to_world", "camera_to_world", "left_to_world"):
        pose = getattr(reading, attr, None)
        if pose is not None and np.shape(pose) == (4, 4):
            pose = np.asarray(pose, dtype=np.float64)
            out = [pose[:3, 3]]
            right = getattr(reading, "right_to_left", None)
            if attr == "left_to_world" and right is not None and np.shape(right) == (4, 4):
                out.append((pose @ np.asarray(right, dtype=np.float64))[:3, 3])
            return out
    return []
