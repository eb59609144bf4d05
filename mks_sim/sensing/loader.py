"""Parse sensor definition files (TOML, ``sensors/*.toml``) into frozen specs.

The format is documented in ``docs/sensors.md``. Every error names the file, the sensor (or
device) and the field, and says what was expected and what was got, e.g.
``sensors/x.toml: sensor 'Range_Points': field 'output[2].low': expected a number, got
'abc'`` (the one format of :mod:`mks_sim.specs`).
Unknown keys are errors too (a typo must not silently drop a setting).
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mks_sim.errors import NotFound, SpecError
from mks_sim.fields import COERCIONS, POLICIES, Field, OutputVector
from mks_sim.sensing.spec import PRIMARY, AcceptanceSpec, AlternateSpec, DeviceSpec, SensorSpec
from mks_sim.specs import (
    MISSING,
    Where,
    located,
    require_keys,
    require_number,
    require_str,
    require_table,
)

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


@dataclass(frozen=True)
class SensorFile:
    """The contents of one sensor definition file."""

    path: Path
    sensors: tuple[SensorSpec, ...]
    devices: tuple[DeviceSpec, ...]


def _names(table: Mapping[str, Any], key: str, w: Where) -> tuple[str, ...]:
    value = table.get(key, MISSING)
    if not isinstance(value, list):
        raise w.error(key, "a list of device or sensor names", value)
    for i, item in enumerate(value):
        if not isinstance(item, str) or not item.strip():
            raise w.error(f"{key}[{i}]", "a device or sensor name (string)", item)
    dupes = sorted({v for v in value if value.count(v) > 1})
    if dupes:
        raise w.at(key).fail(f"expected distinct inputs, got duplicate(s) {dupes}")
    return tuple(value)


def _parse_acceptance(w: Where, value: Any) -> AcceptanceSpec | None:
    if value is MISSING:
        return None
    if not isinstance(value, Mapping):
        raise w.error("acceptance", 'a table { test = "name", params = { ... } }', value)
    aw = w.at("acceptance")
    require_keys(value, _ACCEPTANCE_KEYS, w, "acceptance")
    return AcceptanceSpec(
        require_str(value, "test", aw), require_table(value, "params", aw, default={})
    )


def _parse_field(w: Where, item: Any) -> Field:
    if not isinstance(item, Mapping):
        raise w.error(None, '{ name = "x", low = ..., high = ... }', item)
    require_keys(item, _FIELD_KEYS, w)
    name = require_str(item, "name", w)
    low = require_number(item, "low", w)
    high = require_number(item, "high", w)
    if not high > low:
        raise w.fail(f"expected low < high ({name}), got low={low}, high={high}")
    unit = require_str(item, "unit", w, default="", allow_empty=True)
    policy = require_str(item, "policy", w, default="reject", choices=POLICIES)
    coercion = require_str(item, "coercion", w, default="rescale", choices=COERCIONS)
    resolution = require_number(item, "resolution", w, 0.0, default=None, low_open=True)
    with located(w):
        return Field(name, low, high, unit, policy, resolution, coercion)


def _parse_output(w: Where, value: Any) -> OutputVector:
    if not isinstance(value, list) or not value:
        raise w.error("output", "a non-empty list of fields { name, low, high, ... }", value)
    fields = tuple(_parse_field(w.at(f"output[{i}]"), item) for i, item in enumerate(value))
    names = [f.name for f in fields]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise w.at("output").fail(f"expected distinct field names, got duplicate(s) {dupes}")
    return OutputVector(fields)


def _parse_alternate(w: Where, item: Any, index: int) -> AlternateSpec:
    here = f"alternate[{index}]"
    if not isinstance(item, Mapping):
        raise w.error(here, "a table [[sensor.alternate]]", item)
    require_keys(item, _ALTERNATE_KEYS, w, here)
    name = require_str(item, "name", w.at(here))
    if name == PRIMARY:
        raise w.error(f"{here}.name", f"a name other than {PRIMARY!r} (reserved)", name)
    aw = w.entry_of("alternate", name)
    return AlternateSpec(
        name,
        _names(item, "inputs", aw),
        require_str(item, "program", aw),
        require_table(item, "params", aw, default={}),
        _parse_acceptance(aw, item.get("acceptance", MISSING)),
    )


def _entry(path: Path, kind: str, index: int, item: Any) -> Where:
    """The :class:`Where` of the ``index``-th ``[[kind]]`` table (its ``name`` checked)."""
    at = Where(path, f"{kind}[{index}]")
    if not isinstance(item, Mapping):
        raise at.error(None, f"a table [[{kind}]]", item)
    return Where(path, kind, require_str(item, "name", at))


def _parse_sensor(path: Path, index: int, item: Any) -> SensorSpec:
    w = _entry(path, "sensor", index, item)
    require_keys(item, _SENSOR_KEYS, w)
    alternates_raw = item.get("alternate", [])
    if not isinstance(alternates_raw, list):
        raise w.error("alternate", "an array of tables [[sensor.alternate]]", alternates_raw)
    alternates = tuple(_parse_alternate(w, alt, i) for i, alt in enumerate(alternates_raw))
    alt_names = [a.name for a in alternates]
    dupes = sorted({n for n in alt_names if alt_names.count(n) > 1})
    if dupes:
        raise w.at("alternate").fail(f"expected distinct names, got duplicate(s) {dupes}")
    assert w.name is not None
    return SensorSpec(
        name=w.name,
        inputs=_names(item, "inputs", w),
        program=require_str(item, "program", w),
        output=_parse_output(w, item.get("output", MISSING)),
        params=require_table(item, "params", w, default={}),
        description=require_str(item, "description", w, default="", allow_empty=True),
        acceptance=_parse_acceptance(w, item.get("acceptance", MISSING)),
        alternates=alternates,
        file=path,
    )


def _parse_device(path: Path, index: int, item: Any) -> DeviceSpec:
    w = _entry(path, "device", index, item)
    require_keys(item, _DEVICE_KEYS, w)
    assert w.name is not None
    return DeviceSpec(
        w.name,
        require_str(item, "kind", w, default="", allow_empty=True),
        require_str(item, "description", w, default="", allow_empty=True),
        file=path,
    )


def parse_document(path: Path, doc: Mapping[str, Any]) -> SensorFile:
    """Turn a parsed TOML document into specs (``path`` is only used in messages)."""
    top = Where(path)
    require_keys(doc, _TOP_KEYS, top)
    tables: dict[str, list[Any]] = {}
    for key in _TOP_KEYS:
        value = doc.get(key, [])
        if not isinstance(value, list):
            raise top.error(
                key, f"an array of tables [[{key}]] (write [[{key}]], not [{key}])", value
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
            raise top.fail(f"expected distinct {kind} names, got duplicate(s) {dupes}")
    return SensorFile(path, sensors, devices)


def load_file(path: str | Path) -> SensorFile:
    """Read one sensor definition file.

    Raises:
        NotFound: the file does not exist.
        SpecError: malformed TOML (with the line and column) or a malformed entry.
    """
    path = Path(path)
    if path.exists() and not path.is_file():  # a folder, or a device such as /dev/zero
        kind = "a folder" if path.is_dir() else "a special file (device or pipe)"
        raise SpecError(f"{path}: expected a sensor file (TOML), got {kind}")
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
