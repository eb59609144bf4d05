"""The sensor graph: every logical sensor and device, checked together at load time.

Paper section 1.1: a logical sensor is a program whose inputs are system-defined devices or the
outputs of other logical sensors, with alternates when a device fails. :class:`SensorGraph`
holds the specs of a set of sensor files, rejects at load time what could only fail later
(unknown inputs or programs, cycles, duplicate names), answers which sensors and devices a
model needs (paper section 4, steps 1-2: only those are activated), and makes snapshots.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

from mks_sim.errors import NotFound, SpecError
from mks_sim.resources import data_dir
from mks_sim.sensing.loader import load_file
from mks_sim.sensing.registry import ACCEPTANCE, PROGRAMS, params_type
from mks_sim.sensing.spec import PRIMARY, DeviceSpec, SensorSpec
from mks_sim.specs import Where, parse_dataclass

if TYPE_CHECKING:
    from mks_sim.devices.base import Device
    from mks_sim.sensing.snapshot import Snapshot

__all__ = ["DEVICES_FILE", "SensorGraph", "default_devices"]

log = logging.getLogger(__name__)

#: The file, in a sensors folder, that declares the devices.
DEVICES_FILE = "devices.toml"


def default_devices() -> tuple[DeviceSpec, ...]:
    """The devices declared in the installed ``sensors/devices.toml`` (empty if absent)."""
    path = data_dir("sensors") / DEVICES_FILE
    if not path.is_file():
        log.debug("no %s; no default devices", path)
        return ()
    return load_file(path).devices


def _where(spec: SensorSpec, way: str) -> Where:
    where = Where(spec.file, "sensor", spec.name)
    return where if way == PRIMARY else where.entry_of("alternate", way)


class SensorGraph:
    """A checked set of logical sensors over a set of declared devices.

    Args:
        sensors: the sensor specs (names unique).
        devices: the declared devices (specs or bare names); None means the devices of the
            installed ``sensors/devices.toml``.
        check_programs: look every program and acceptance test up in the registry (True
            except for tools that only want to show files).

    Raises:
        SpecError: duplicate names, a sensor named like a device, an unknown input, program
            or acceptance test, or a cycle; the message names file, sensor and field.
    """

    def __init__(
        self,
        sensors: Iterable[SensorSpec],
        devices: Iterable[DeviceSpec | str] | None = None,
        *,
        check_programs: bool = True,
    ) -> None:
        device_specs = default_devices() if devices is None else tuple(devices)
        self._devices: dict[str, DeviceSpec] = {}
        for dev in device_specs:
            spec = DeviceSpec(dev) if isinstance(dev, str) else dev
            if spec.name in self._devices:
                first = self._devices[spec.name]
                raise SpecError(
                    f"device {spec.name!r} is declared twice ({first.file or 'code'} and "
                    f"{spec.file or 'code'})"
                )
            self._devices[spec.name] = spec
        self._sensors: dict[str, SensorSpec] = {}
        for sensor in sensors:
            if sensor.name in self._sensors:
                first_file = self._sensors[sensor.name].file
                raise SpecError(
                    f"{sensor.where}: name: sensor {sensor.name!r} is defined twice "
                    f"({first_file or 'code'} and {sensor.file or 'code'})"
                )
            if sensor.name in self._devices:
                raise SpecError(
                    f"{sensor.where}: name: {sensor.name!r} is already a device name "
                    f"(declared in {self._devices[sensor.name].file or 'code'})"
                )
            self._sensors[sensor.name] = sensor
        self._check_inputs()
        if check_programs:
            self._check_programs()
        self._check_cycles()

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_files(
        cls,
        files: Iterable[str | Path],
        *,
        devices: Iterable[DeviceSpec | str] | None = None,
        check_programs: bool = True,
    ) -> SensorGraph:
        """Load sensor files (each may hold ``[[sensor]]`` and ``[[device]]`` tables).

        Devices: ``devices`` when given; else those declared in the files; else (no file
        declares any) the installed ``sensors/devices.toml``.
        """
        sensors: list[SensorSpec] = []
        declared: list[DeviceSpec] = []
        for path in files:
            loaded = load_file(path)
            sensors.extend(loaded.sensors)
            declared.extend(loaded.devices)
        if devices is None and declared:
            devices = declared
        return cls(sensors, devices, check_programs=check_programs)

    @classmethod
    def from_dir(
        cls,
        path: str | Path | None = None,
        *,
        devices: Iterable[DeviceSpec | str] | None = None,
        check_programs: bool = True,
    ) -> SensorGraph:
        """Load every ``*.toml`` of a folder (default: the installed ``sensors/``), sorted.

        Raises:
            NotFound: the folder does not exist.
        """
        folder = data_dir("sensors") if path is None else Path(path)
        if not folder.is_dir():
            raise NotFound(f"{folder}: sensors folder not found")
        return cls.from_files(
            sorted(folder.glob("*.toml")), devices=devices, check_programs=check_programs
        )

    # ------------------------------------------------------------------ checks

    def _check_inputs(self) -> None:
        for spec in self._sensors.values():
            for way in (spec.primary, *spec.alternates):
                for i, name in enumerate(way.inputs):
                    if name not in self._sensors and name not in self._devices:
                        raise _where(spec, way.name).error(
                            f"inputs[{i}]",
                            "a logical sensor or a declared device (devices: "
                            f"{sorted(self._devices)}; sensors: {sorted(self._sensors)})",
                            name,
                        )

    def _check_programs(self) -> None:
        """Every program and acceptance test exists, and their params fit their dataclass."""
        for spec in self._sensors.values():
            for way in (spec.primary, *spec.alternates):
                where = _where(spec, way.name)
                if way.program not in PROGRAMS:
                    raise where.error(
                        "program", f"one of the programs {PROGRAMS.names()}", way.program
                    )
                cls = params_type(PROGRAMS.get(way.program))
                if cls is not None:
                    parse_dataclass(cls, way.params, where, "params")
                if way.acceptance is None:
                    continue
                if way.acceptance.test not in ACCEPTANCE:
                    raise where.error(
                        "acceptance.test",
                        f"one of the acceptance tests {ACCEPTANCE.names()}",
                        way.acceptance.test,
                    )
                cls = params_type(ACCEPTANCE.get(way.acceptance.test))
                if cls is not None:
                    parse_dataclass(cls, way.acceptance.params, where, "acceptance.params")

    def _check_cycles(self) -> None:
        state: dict[str, int] = {}  # 1 = on the current path, 2 = done
        path: list[str] = []

        def visit(name: str) -> None:
            state[name] = 1
            path.append(name)
            spec = self._sensors[name]
            for dep in spec.all_inputs:
                if dep not in self._sensors:
                    continue
                if state.get(dep) == 1:
                    cycle = [*path[path.index(dep) :], dep]
                    raise SpecError(
                        f"{spec.where}: inputs: cycle of logical sensors "
                        f"{' -> '.join(cycle)}; a sensor cannot depend on itself"
                    )
                if dep not in state:
                    visit(dep)
            path.pop()
            state[name] = 2

        for name in self._sensors:
            if name not in state:
                visit(name)

    def check_model_files(self, paths: Iterable[str | Path]) -> int:
        """Check that every ``sensor`` named by a ``[[model]]`` or ``[[object]]`` entry of the
        model files ``paths`` is a logical sensor of this graph (the database is loaded
        against the sensor graph: a typo must not silently drop a sensor from provenance).

        Returns:
            How many sensor references were checked.

        Raises:
            SpecError: ``tasks/models/x.toml: model 'x': field 'sensor': expected one of the
                logical sensors [...], got 'No_Such_Sensor'`` (or a malformed file).
        """
        import tomllib

        checked = 0
        for path in map(Path, paths):
            try:
                doc = tomllib.loads(path.read_text(encoding="utf-8"))
            except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
                raise SpecError(f"{path}: cannot read the model file: {exc}") from None
            for kind in ("model", "object"):
                entries = doc.get(kind, [])
                for i, entry in enumerate(entries if isinstance(entries, list) else []):
                    if not isinstance(entry, Mapping):
                        continue
                    name = entry.get("name")
                    where = Where(path, kind, name if isinstance(name, str) else f"[{i}]")
                    key = "sensor" if "sensor" in entry else "sensors"
                    refs = entry.get(key)
                    if refs is None:
                        continue
                    for sensor in refs if isinstance(refs, list) else [refs]:
                        checked += 1
                        if not isinstance(sensor, str) or sensor not in self._sensors:
                            raise where.error(
                                key, f"one of the logical sensors {sorted(self._sensors)}", sensor
                            )
        return checked

    # ------------------------------------------------------------------ queries

    @property
    def sensors(self) -> Mapping[str, SensorSpec]:
        """Sensor name -> spec, in declaration order (read-only)."""
        return MappingProxyType(self._sensors)

    @property
    def devices(self) -> Mapping[str, DeviceSpec]:
        """Device name -> spec (read-only)."""
        return MappingProxyType(self._devices)

    @property
    def sensor_names(self) -> tuple[str, ...]:
        return tuple(self._sensors)

    @property
    def device_names(self) -> frozenset[str]:
        return frozenset(self._devices)

    def sensor(self, name: str) -> SensorSpec:
        """The spec of sensor ``name``; raises :class:`NotFound` listing the sensors."""
        try:
            return self._sensors[name]
        except KeyError:
            raise NotFound(
                f"unknown logical sensor {name!r}; sensors: {sorted(self._sensors)}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._sensors

    def __iter__(self) -> Iterator[SensorSpec]:
        return iter(self._sensors.values())

    def __len__(self) -> int:
        return len(self._sensors)

    def _check_names(self, names: Iterable[str]) -> list[str]:
        if isinstance(names, str):
            names = [names]
        names = list(names)
        for name in names:
            if name not in self._sensors and name not in self._devices:
                raise NotFound(
                    f"unknown sensor or device {name!r}; sensors: {sorted(self._sensors)}; "
                    f"devices: {sorted(self._devices)}"
                )
        return names

    def required(self, names: Iterable[str], *, alternates: bool = True) -> frozenset[str]:
        """The sensors and devices that ``names`` need (paper section 4, steps 1-2).

        Args:
            names: sensor (or device) names a model invokes.
            alternates: include what the alternates need (everything that *may* be
                activated); False gives only the primaries' closure (what runs when nothing
                fails).

        Returns:
            The names themselves plus every sensor and device they depend on.

        Raises:
            NotFound: an unknown name.
        """
        needed: set[str] = set()
        stack = self._check_names(names)
        while stack:
            name = stack.pop()
            if name in needed:
                continue
            needed.add(name)
            spec = self._sensors.get(name)
            if spec is not None:
                stack.extend(spec.all_inputs if alternates else spec.inputs)
        return frozenset(needed)

    def order(self, names: Iterable[str] | None = None) -> list[str]:
        """The sensors needed by ``names`` (default: all), dependencies first."""
        wanted = self.required(self._sensors if names is None else names)
        result: list[str] = []
        seen: set[str] = set()

        def visit(name: str) -> None:
            seen.add(name)
            for dep in self._sensors[name].all_inputs:
                if dep in self._sensors and dep not in seen:
                    visit(dep)
            result.append(name)

        for name in self._sensors:
            if name in wanted and name not in seen:
                visit(name)
        return result

    def snapshot(self, devices: Mapping[str, Device], *, strict: bool = False) -> Snapshot:
        """A snapshot over ``devices`` (device name -> object with ``read()``).

        See :class:`~mks_sim.sensing.snapshot.Snapshot`.
        """
        from mks_sim.sensing.snapshot import Snapshot

        return Snapshot(self, devices, strict=strict)

    def files(self) -> list[Path]:
        """The files the sensors and devices came from."""
        seen: dict[Path, None] = {}
        specs: list[DeviceSpec | SensorSpec] = [*self._devices.values(), *self._sensors.values()]
        for spec in specs:
            if spec.file is not None:
                seen.setdefault(spec.file)
        return list(seen)

    def __repr__(self) -> str:
        return (
            f"SensorGraph({len(self._sensors)} sensors: {list(self._sensors)}, "
            f"{len(self._devices)} devices)"
        )
