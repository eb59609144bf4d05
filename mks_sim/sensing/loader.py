"""Parse sensor definition files (TOML, ``sensors/*.toml``) into frozen specs.

The format is documented in ``docs/sensors.md``. Every error names the file, the sensor (or
device) and the field, and says what was expected and what was got, e.g.
``sensors/x.toml: sensor 'Range_Points': output[2].low: expected a number, got 'abc'``.
Unknown keys are errors too (a typo must not silently drop a setting).
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mks_sim.errors import NotFound, SpecError
from mks_sim.fields import COERCIONS, POLICIES, Field, OutputVector
from mks_sim.sensing.spec import PRIMARY, AcceptanceSpec, AlternateSpec, DeviceSpec, SensorSpec

__all__ = ["SensorFile", "load_file", "parse_document"]

_TOP_KEYS = ("sensor", "device")
_SENSOR_KEYS = (
    "name",
    "description",
    "inputs",
    "program",
    "params",
    "output",
    "acceptance",
    "alternate",
)
_ALTERNATE_KEYS = ("name", "description", "inputs", "program", "params", "acceptance")
_FIELD_KEYS = ("name", "low", "high", "unit", "policy", "resolution", "coercion")
_ACCEPTANCE_KEYS = ("test", "params")
_DEVICE_KEYS = ("name", "kind", "description")

_MISSING = object()


@dataclass(frozen=True)
class SensorFile:
    """The contents of one sensor definition file."""

    path: Path
    sensors: tuple[SensorSpec, ...]
    devices: tuple[DeviceSpec, ...]


def _got(value: Any) -> str:
    if value is _MISSING:
        return "nothing (missing)"
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, list):
        return f"a list {value!r}"
    return repr(value)


class _Where:
    """Builds ``file: sensor 'X': key: expected ..., got ...`` messages."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix

    def error(self, key: str, expected: str, got: Any) -> SpecError:
        return SpecError(f"{self.prefix}: {key}: expected {expected}, got {_got(got)}")

    def check_keys(self, table: Mapping[str, Any], allowed: tuple[str, ...], key: str) -> None:
        for k in table:
            if k not in allowed:
                at = f"{key}." if key else ""
                raise SpecError(
                    f"{self.prefix}: {at}{k}: unknown key; expected one of {list(allowed)}"
                )

    def string(self, table: Mapping[str, Any], key: str, path: str, *, required: bool) -> str:
        value = table.get(key, _MISSING)
        if value is _MISSING and not required:
            return ""
        if not isinstance(value, str) or (required and not value.strip()):
            raise self.error(path, "a non-empty string" if required else "a string", value)
        return value

    def names(self, table: Mapping[str, Any], key: str, path: str) -> tuple[str, ...]:
        value = table.get(key, _MISSING)
        if not isinstance(value, list):
            raise self.error(path, "a list of device or sensor names", value)
        for i, item in enumerate(value):
            if not isinstance(item, str) or not item.strip():
                raise self.error(f"{path}[{i}]", "a device or sensor name (string)", item)
        dupes = sorted({v for v in value if value.count(v) > 1})
        if dupes:
            raise SpecError(f"{self.prefix}: {path}: duplicate input(s) {dupes}")
        return tuple(value)

    def table(self, table: Mapping[str, Any], key: str, path: str) -> Mapping[str, Any]:
        value = table.get(key, _MISSING)
        if value is _MISSING:
            return {}
        if not isinstance(value, Mapping):
            raise self.error(path, "a table (e.g. { key = value })", value)
        return value

    def number(self, table: Mapping[str, Any], key: str, path: str) -> int | float:
        value = table.get(key, _MISSING)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(path, "a number", value)
        if not math.isfinite(value):
            raise self.error(path, "a finite number", value)
        return value


def _parse_acceptance(w: _Where, value: Any, path: str) -> AcceptanceSpec | None:
    if value is _MISSING:
        return None
    if not isinstance(value, Mapping):
        raise w.error(path, 'a table { test = "name", params = { ... } }', value)
    w.check_keys(value, _ACCEPTANCE_KEYS, path)
    return AcceptanceSpec(
        w.string(value, "test", f"{path}.test", required=True),
        w.table(value, "params", f"{path}.params"),
    )


def _parse_field(w: _Where, item: Any, path: str) -> Field:
    if not isinstance(item, Mapping):
        raise w.error(path, '{ name = "x", low = ..., high = ... }', item)
    w.check_keys(item, _FIELD_KEYS, path)
    name = w.string(item, "name", f"{path}.name", required=True)
    low = w.number(item, "low", f"{path}.low")
    high = w.number(item, "high", f"{path}.high")
    if not high > low:
        raise SpecError(
            f"{w.prefix}: {path} ({name}): expected low < high, got low={low}, high={high}"
        )
    unit = w.string(item, "unit", f"{path}.unit", required=False)
    policy = item.get("policy", "reject")
    if policy not in POLICIES:
        raise w.error(f"{path}.policy", f"one of {list(POLICIES)}", policy)
    coercion = item.get("coercion", "rescale")
    if coercion not in COERCIONS:
        raise w.error(f"{path}.coercion", f"one of {list(COERCIONS)}", coercion)
    resolution = None
    if "resolution" in item:
        resolution = w.number(item, "resolution", f"{path}.resolution")
        if resolution <= 0:
            raise w.error(f"{path}.resolution", "a positive number", resolution)
    try:
        return Field(name, low, high, unit, policy, resolution, coercion)
    except SpecError as exc:  # pragma: no cover - the checks above mirror Field's
        raise SpecError(f"{w.prefix}: {path}: {exc}") from None


def _parse_output(w: _Where, value: Any) -> OutputVector:
    if not isinstance(value, list) or not value:
        raise w.error("output", "a non-empty list of fields { name, low, high, ... }", value)
    fields = tuple(_parse_field(w, item, f"output[{i}]") for i, item in enumerate(value))
    names = [f.name for f in fields]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise SpecError(f"{w.prefix}: output: duplicate field name(s) {dupes} in {names}")
    return OutputVector(fields)


def _parse_alternate(w: _Where, item: Any, path: str) -> AlternateSpec:
    if not isinstance(item, Mapping):
        raise w.error(path, "a table [[sensor.alternate]]", item)
    w.check_keys(item, _ALTERNATE_KEYS, path)
    name = w.string(item, "name", f"{path}.name", required=True)
    if name == PRIMARY:
        raise w.error(f"{path}.name", f"a name other than {PRIMARY!r} (reserved)", name)
    aw = _Where(f"{w.prefix}: alternate {name!r}")
    return AlternateSpec(
        name,
        aw.names(item, "inputs", "inputs"),
        aw.string(item, "program", "program", required=True),
        aw.table(item, "params", "params"),
        _parse_acceptance(aw, item.get("acceptance", _MISSING), "acceptance"),
    )


def _entry_name(path: Path, kind: str, index: int, item: Any) -> str:
    """The ``name`` of the ``index``-th ``[[kind]]`` table, or a SpecError saying what is wrong."""
    if not isinstance(item, Mapping):
        raise SpecError(f"{path}: {kind}[{index}]: expected a table [[{kind}]], got {_got(item)}")
    name = item.get("name", _MISSING)
    if not isinstance(name, str) or not name.strip():
        raise SpecError(
            f"{path}: {kind}[{index}]: name: expected a non-empty string, got {_got(name)}"
        )
    return name


def _parse_sensor(path: Path, index: int, item: Any) -> SensorSpec:
    name = _entry_name(path, "sensor", index, item)
    w = _Where(f"{path}: sensor {name!r}")
    w.check_keys(item, _SENSOR_KEYS, "")
    alternates_raw = item.get("alternate", [])
    if not isinstance(alternates_raw, list):
        raise w.error("alternate", "an array of tables [[sensor.alternate]]", alternates_raw)
    alternates = tuple(
        _parse_alternate(w, alt, f"alternate[{i}]") for i, alt in enumerate(alternates_raw)
    )
    alt_names = [a.name for a in alternates]
    dupes = sorted({n for n in alt_names if alt_names.count(n) > 1})
    if dupes:
        raise SpecError(f"{w.prefix}: alternate: duplicate alternate name(s) {dupes}")
    return SensorSpec(
        name=name,
        inputs=w.names(item, "inputs", "inputs"),
        program=w.string(item, "program", "program", required=True),
        output=_parse_output(w, item.get("output", _MISSING)),
        params=w.table(item, "params", "params"),
        description=w.string(item, "description", "description", required=False),
        acceptance=_parse_acceptance(w, item.get("acceptance", _MISSING), "acceptance"),
        alternates=alternates,
        file=path,
    )


def _parse_device(path: Path, index: int, item: Any) -> DeviceSpec:
    name = _entry_name(path, "device", index, item)
    w = _Where(f"{path}: device {name!r}")
    w.check_keys(item, _DEVICE_KEYS, "")
    return DeviceSpec(
        name,
        w.string(item, "kind", "kind", required=False),
        w.string(item, "description", "description", required=False),
        file=path,
    )


def parse_document(path: Path, doc: Mapping[str, Any]) -> SensorFile:
    """Turn a parsed TOML document into specs (``path`` is only used in messages)."""
    for key in doc:
        if key not in _TOP_KEYS:
            raise SpecError(
                f"{path}: {key}: unknown top-level key; expected [[sensor]] or [[device]] tables"
            )
    tables: dict[str, list[Any]] = {}
    for key in _TOP_KEYS:
        value = doc.get(key, [])
        if not isinstance(value, list):
            raise SpecError(
                f"{path}: {key}: expected an array of tables [[{key}]], got a single "
                f"table [{key}] (write [[{key}]])"
            )
        tables[key] = value
    sensors = tuple(_parse_sensor(path, i, t) for i, t in enumerate(tables["sensor"]))
    devices = tuple(_parse_device(path, i, t) for i, t in enumerate(tables["device"]))
    for kind, names in (
        ("sensor", [s.name for s in sensors]),
        ("device", [d.name for d in devices]),
    ):
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise SpecError(f"{path}: duplicate {kind} name(s) {dupes}")
    return SensorFile(path, sensors, devices)


def load_file(path: str | Path) -> SensorFile:
    """Read one sensor definition file.

    Raises:
        NotFound: the file does not exist.
        SpecError: malformed TOML (with the line and column) or a malformed entry.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise NotFound(f"{path}: sensor file not found") from None
    except OSError as exc:
        raise SpecError(f"{path}: cannot read: {exc}") from exc
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: expected UTF-8 text: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        if m := re.search(r"\s*\(at line (\d+), column (\d+)\)", msg):
            msg = msg[: m.start()] + msg[m.end() :]
            raise SpecError(f"{path}: line {m[1]}, column {m[2]}: malformed TOML: {msg}") from None
        raise SpecError(f"{path}: malformed TOML: {msg}") from None
    return parse_document(path, doc)
