"""One spec-validation helper for sensor, task, model and scene files, one message format.

Every error reads::

    {file}: {entry kind} '{name}': field '{field}': expected {expected}, got {got!r}

for example ``sensors/points.toml: sensor 'Range_Points': field 'params.crop_min': expected a
list of 3 numbers, got 'abc'``. A loader makes one :class:`Where` per entry and passes it down;
the validators (:func:`require_str`, :func:`require_number`, :func:`require_keys`, ...) check a
value and return it, or raise a :class:`~mks_sim.errors.SpecError` already carrying the full
prefix. :func:`located` adds the prefix to errors raised by code that does not know where it is
(and leaves already-located errors alone, so a prefix is never doubled).

:func:`parse_dataclass` validates a parameter table against a frozen dataclass (field types,
unknown keys naming the allowed ones, constraints in ``field(metadata=...)``: ``low``,
``high``, ``low_open``, ``choices``, ``length``).
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from mks_sim.errors import SpecError

__all__ = [
    "MISSING",
    "Where",
    "describe",
    "located",
    "param",
    "params_schema",
    "parse_dataclass",
    "require_bool",
    "require_keys",
    "require_list",
    "require_number",
    "require_str",
    "require_table",
    "require_vector",
    "spec_error",
]


class _Missing:
    def __repr__(self) -> str:
        return "MISSING"


#: Marks a key that is absent from its table (as ``got``, it reads "nothing (missing)").
MISSING: Any = _Missing()

_MAX_REPR = 80


def describe(got: Any) -> str:
    """How a bad value is shown after ``got``: ``repr`` (shortened), "a table", "nothing"."""
    if got is MISSING:
        return "nothing (missing)"
    if isinstance(got, Mapping):
        return "a table"
    text = repr(got)
    if len(text) > _MAX_REPR:
        text = text[: _MAX_REPR - 3] + "..."
    return text


def _prefix(file: str | Path | None, entry: str | None) -> str:
    parts = [str(file)] if file not in (None, "") else []
    if entry:
        parts.append(entry)
    return ": ".join(parts)


def spec_error(
    file: str | Path | None, entry: str | None, field: str | None, expected: str, got: Any
) -> SpecError:
    """A located :class:`SpecError` in the one message format.

    Args:
        file: the spec file (None when the spec was built in code).
        entry: ``"sensor 'Range_Points'"`` (kind and quoted name), or None for the file level.
        field: the field path (``params.crop_min``, ``output[2].low``), or None.
        expected: what would have been accepted.
        got: the value found (:data:`MISSING` when absent).
    """
    head = _prefix(file, entry)
    body = f"expected {expected}, got {describe(got)}"
    if field:
        body = f"field '{field}': {body}"
    exc = SpecError(f"{head}: {body}" if head else body)
    exc.located = True  # type: ignore[attr-defined]
    return exc


@dataclass(frozen=True)
class Where:
    """Where a value sits: the file, the entry (kind and name) and a field path prefix.

    Attributes:
        file: the spec file, or None.
        kind: the entry kind (``sensor``, ``device``, ``model``, ``task``, ``object``...).
        name: the entry name, or None at file level.
        field: a field path prefix added before the fields of :meth:`error`.
    """

    file: str | Path | None = None
    kind: str | None = None
    name: str | None = None
    field: str = ""

    @property
    def entry(self) -> str | None:
        """``"sensor 'Range_Points'"``, or None at file level."""
        if self.kind is None:
            return None
        return self.kind if self.name is None else f"{self.kind} {self.name!r}"

    @property
    def prefix(self) -> str:
        """``"file: sensor 'X'"`` (what every message of this entry starts with)."""
        return _prefix(self.file, self.entry)

    def path(self, field: str | None) -> str:
        """The full field path under this place."""
        if not field:
            return self.field
        if not self.field:
            return field
        return f"{self.field}{field}" if field.startswith("[") else f"{self.field}.{field}"

    def at(self, field: str) -> Where:
        """The same entry, one field deeper (``where.at("params")``)."""
        return dataclasses.replace(self, field=self.path(field))

    def entry_of(self, kind: str, name: str | None) -> Where:
        """A nested entry of the same file (an alternate of a sensor, a term of a metric)."""
        nested = kind if name is None else f"{kind} {name!r}"
        outer = self.entry
        return Where(self.file, f"{outer}: {nested}" if outer else nested, None)

    def error(self, field: str | None, expected: str, got: Any) -> SpecError:
        """A :func:`spec_error` at ``field`` under this place."""
        return spec_error(self.file, self.entry, self.path(field), expected, got)

    def fail(self, message: str) -> SpecError:
        """A located SpecError with a free-form message (for checks across fields)."""
        where = self.prefix
        if self.field:
            message = f"field '{self.field}': {message}"
        exc = SpecError(f"{where}: {message}" if where else message)
        exc.located = True  # type: ignore[attr-defined]
        return exc


@contextmanager
def located(where: Where) -> Iterator[None]:
    """Prefix SpecErrors raised inside with ``where`` unless they are already located."""
    try:
        yield
    except SpecError as exc:
        if getattr(exc, "located", False):
            raise
        raise where.fail(str(exc)) from None


def _get(table: Mapping[str, Any], key: str) -> Any:
    return table.get(key, MISSING) if isinstance(table, Mapping) else MISSING


def require_keys(
    table: Any, allowed: Sequence[str], where: Where, field: str | None = None
) -> Mapping[str, Any]:
    """``table`` as a mapping whose keys are all in ``allowed``.

    Raises:
        SpecError: not a table, or an unknown key (the message lists the allowed ones).
    """
    if not isinstance(table, Mapping):
        raise where.error(field, "a table", table)
    for key in table:
        if key not in allowed:
            raise where.error(field, f"only the keys {sorted(allowed)}", key)
    return table


def require_table(
    table: Mapping[str, Any], key: str, where: Where, *, default: Any = MISSING
) -> Any:
    """``table[key]`` as a mapping (``default`` when absent, else an error)."""
    value = _get(table, key)
    if value is MISSING and default is not MISSING:
        return default
    if not isinstance(value, Mapping):
        raise where.error(key, "a table (e.g. { key = value })", value)
    return value


def require_str(
    table: Mapping[str, Any],
    key: str,
    where: Where,
    *,
    default: Any = MISSING,
    choices: Sequence[str] | None = None,
    allow_empty: bool = False,
) -> Any:
    """``table[key]`` as a string (non-empty unless ``allow_empty``; one of ``choices``)."""
    value = _get(table, key)
    if value is MISSING and default is not MISSING:
        return default
    if choices is not None:
        if value not in choices:
            raise where.error(key, f"one of {list(choices)}", value)
        return value
    if not isinstance(value, str) or (not allow_empty and not value.strip()):
        raise where.error(key, "a string" if allow_empty else "a non-empty string", value)
    return value


def _check_number(
    value: Any,
    field: str,
    where: Where,
    low: float | None,
    high: float | None,
    integer: bool,
    low_open: bool,
) -> int | float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise where.error(field, "an integer" if integer else "a number", value)
    if integer and not isinstance(value, int):
        if not (math.isfinite(value) and float(value).is_integer()):
            raise where.error(field, "an integer", value)
        value = int(value)
    if not math.isfinite(value):
        raise where.error(field, "a finite number", value)
    if low is not None and (value <= low if low_open else value < low):
        raise where.error(field, f"a number {'>' if low_open else '>='} {low:g}", value)
    if high is not None and value > high:
        raise where.error(field, f"a number <= {high:g}", value)
    return value


def require_number(
    table: Mapping[str, Any],
    key: str,
    where: Where,
    low: float | None = None,
    high: float | None = None,
    *,
    default: Any = MISSING,
    integer: bool = False,
    low_open: bool = False,
) -> Any:
    """``table[key]`` as a finite number in ``[low, high]`` (``(low, high]`` if ``low_open``)."""
    value = _get(table, key)
    if value is MISSING and default is not MISSING:
        return default
    return _check_number(value, key, where, low, high, integer, low_open)


def require_bool(
    table: Mapping[str, Any], key: str, where: Where, *, default: Any = MISSING
) -> Any:
    """``table[key]`` as ``true``/``false``."""
    value = _get(table, key)
    if value is MISSING and default is not MISSING:
        return default
    if not isinstance(value, bool):
        raise where.error(key, "true or false", value)
    return value


def require_list(
    table: Mapping[str, Any],
    key: str,
    where: Where,
    *,
    default: Any = MISSING,
    item: str = "str",
    non_empty: bool = False,
    length: int | None = None,
) -> Any:
    """``table[key]`` as a list of ``item`` (``"str"`` or ``"number"``), returned as a tuple."""
    value = _get(table, key)
    if value is MISSING and default is not MISSING:
        return default
    what = "strings" if item == "str" else "numbers"
    expected = f"a list of {length} {what}" if length is not None else f"a list of {what}"
    if not isinstance(value, list | tuple):
        raise where.error(key, expected, value)
    if length is not None and len(value) != length:
        raise where.error(key, expected, value)
    if non_empty and not value:
        raise where.error(key, f"a non-empty list of {what}", value)
    out: list[Any] = []
    for i, v in enumerate(value):
        if item == "str":
            if not isinstance(v, str) or not v.strip():
                raise where.error(f"{key}[{i}]", "a non-empty string", v)
            out.append(v)
        else:
            out.append(_check_number(v, f"{key}[{i}]", where, None, None, False, False))
    return tuple(out)


def require_vector(
    table: Mapping[str, Any], key: str, where: Where, n: int, *, default: Any = MISSING
) -> Any:
    """``table[key]`` as ``n`` finite numbers (a tuple of floats)."""
    value = require_list(
        table, key, where, default=MISSING if default is MISSING else None, item="number", length=n
    )
    if value is None:
        return default
    return tuple(float(v) for v in value)


# --------------------------------------------------------------------------- dataclasses

D = TypeVar("D")


def param(default: Any = MISSING, **constraints: Any) -> Any:
    """A dataclass field with validation constraints: ``m: int = param(8, low=1)``.

    Constraints: ``low``, ``high``, ``low_open`` (numbers), ``choices`` (strings),
    ``length`` (tuples), ``doc`` (one line for ``sensors --list``).
    """
    if default is MISSING:
        return dataclasses.field(metadata=constraints)
    return dataclasses.field(default=default, metadata=constraints)


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, field: str, where: Where, meta: Mapping[str, Any]) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if type(None) in args and value is None:
            return None
        rest = [a for a in args if a is not type(None)]
        errors: list[SpecError] = []
        for option in rest:
            try:
                return _convert(value, option, field, where, meta)
            except SpecError as exc:
                errors.append(exc)
        if len(errors) == 1:
            raise errors[0]
        raise where.error(field, " or ".join(_type_name(a) for a in rest), value)
    if origin is typing.Literal:
        if value not in args:
            raise where.error(field, f"one of {list(args)}", value)
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise where.error(field, "true or false", value)
        return value
    if tp in (int, float):
        out = _check_number(
            value,
            field,
            where,
            meta.get("low"),
            meta.get("high"),
            tp is int,
            bool(meta.get("low_open", False)),
        )
        return int(out) if tp is int else float(out)
    if tp is str:
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise where.error(field, f"one of {list(choices)}", value)
        if not isinstance(value, str):
            raise where.error(field, "a string", value)
        return value
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise where.error(field, _tuple_expected(args, meta), value)
        if args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise where.error(field, _tuple_expected(args, meta), value)
            items = list(args)
        else:
            item_tp = args[0] if args else Any
            length = meta.get("length")
            if length is not None and len(value) != length:
                raise where.error(field, _tuple_expected(args, meta), value)
            items = [item_tp] * len(value)
        return tuple(
            _convert(v, t, f"{field}[{i}]", where, {}) for i, (v, t) in enumerate(zip(value, items))
        )
    if tp is Any:
        return value
    raise TypeError(f"parse_dataclass: unsupported field type {tp!r} of {field}")


def _tuple_expected(args: tuple[Any, ...], meta: Mapping[str, Any]) -> str:
    if args and args[-1] is not Ellipsis:
        n = len(args)
        names = {_type_name(a) for a in args}
        item = "numbers" if names <= {"float", "int"} else "values"
        return f"a list of {n} {item}"
    item_tp = args[0] if args else Any
    item = {"float": "numbers", "int": "integers", "str": "strings"}.get(
        _type_name(item_tp), "values"
    )
    length = meta.get("length")
    return f"a list of {length} {item}" if length is not None else f"a list of {item}"


def parse_dataclass(cls: type[D], table: Any, where: Where, field: str = "params") -> D:
    """Build the frozen dataclass ``cls`` from a spec table, checking every key.

    Unknown keys are errors naming the allowed ones; each value is checked against the field's
    type (``int``, ``float``, ``bool``, ``str``, ``Literal``, ``tuple[...]``, ``X | None``) and
    the constraints of :func:`param`; a missing key takes the field's default.

    A ``__post_init__`` may check across fields by raising ``ValueError(field, expected,
    got)`` (three arguments: the message is built in the one format) or ``ValueError(text)``.

    Raises:
        SpecError: in the one message format, e.g. ``field 'params.m': expected a number >= 1,
            got 0``.
    """
    if table is MISSING or table is None:
        table = {}
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"parse_dataclass: expected a dataclass, got {cls!r}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    require_keys(table, sorted(fields), where, field)
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        path = f"{field}.{name}" if field else name
        if name not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise where.error(path, f"a value ({_type_name(hints[name])})", MISSING)
            continue
        kwargs[name] = _convert(table[name], hints[name], path, where, f.metadata)
    try:
        return cls(**kwargs)
    except ValueError as exc:  # a cross-field check in __post_init__
        if len(exc.args) == 3:  # ValueError(field, expected, got): the one format
            sub, expected, got = exc.args
            raise where.error(f"{field}.{sub}" if field else sub, expected, got) from None
        raise where.at(field).fail(str(exc)) from None


def _type_text(tp: Any) -> str:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return " | ".join("None" if a is type(None) else _type_text(a) for a in args)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in args)
    if origin is tuple:
        if args and args[-1] is Ellipsis:
            return f"list of {_type_text(args[0])}"
        return f"list of {len(args)} {_type_text(args[0]) if len(set(args)) == 1 else 'values'}"
    return _type_name(tp)


def params_schema(cls: type) -> dict[str, dict[str, Any]]:
    """What :func:`parse_dataclass` accepts for ``cls``: field -> ``{"type", "default" or
    "required", constraints}`` (for ``mks-sim sensors --programs``)."""
    hints = typing.get_type_hints(cls)
    out: dict[str, dict[str, Any]] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if not f.init:
            continue
        item: dict[str, Any] = {"type": _type_text(hints[f.name])}
        if f.default is not dataclasses.MISSING:
            item["default"] = list(f.default) if isinstance(f.default, tuple) else f.default
        elif f.default_factory is not dataclasses.MISSING:
            item["default"] = f.default_factory()
        else:
            item["required"] = True
        item.update({k: v for k, v in f.metadata.items() if v is not None})
        out[f.name] = item
    return out
