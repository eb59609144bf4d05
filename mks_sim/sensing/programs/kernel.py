"""Generic kernel programs and acceptance tests.

Programs (``program = "..."`` in a sensor file):

- ``passthrough``: one input, already an (N, n) table (a device reading or a stream); param
  ``key`` picks an entry of a dict-like device reading.
- ``select_fields``: one input stream; param ``fields`` (list of names) in output order.
- ``concat``: stack every input (streams or (N, n) tables of equal width), no coercion.
- ``merge``: :func:`~mks_sim.fields.merge_streams` of every input stream (same field names,
  coerced to the coarsest field, per-row ``source`` kept).
- ``constant``: param ``rows`` (list of lists), no inputs needed (fixtures, references).

Acceptance tests (``acceptance = { test = "...", params = {...} }``): ``min_rows`` (``min``),
``max_rows`` (``max``), ``max_nan_fraction`` (``max``: NaN values / all values),
``max_flagged_fraction`` (``max``: flagged values / all values), ``max_dropped_fraction``
(``max``: rows dropped by validation / rows produced).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mks_sim.errors import SensorFailure, SpecError
from mks_sim.fields import Stream, merge_streams
from mks_sim.sensing.registry import takes_params
from mks_sim.specs import param

__all__ = [
    "ConstantParams",
    "MaxParams",
    "MinParams",
    "NoParams",
    "PassthroughParams",
    "SelectFieldsParams",
]


@dataclass(frozen=True)
class NoParams:
    """Params of a program that takes none (any key is an error)."""


@dataclass(frozen=True)
class PassthroughParams:
    """``passthrough``: ``key`` picks an entry of a dict-like device reading."""

    key: str | None = None


@dataclass(frozen=True)
class SelectFieldsParams:
    """``select_fields``: the field names to keep, in output order."""

    fields: tuple[str, ...] = param()


@dataclass(frozen=True)
class ConstantParams:
    """``constant``: the rows of the table."""

    rows: tuple[tuple[float, ...], ...] = param()


@dataclass(frozen=True)
class MinParams:
    """Acceptance test ``min_rows``: ``min``, a number >= 0."""

    min: float = param(low=0.0)


@dataclass(frozen=True)
class MaxParams:
    """Acceptance tests ``max_rows`` and the fractions: ``max``, a number >= 0."""

    max: float = param(low=0.0)


def _param(
    params: Mapping[str, Any], name: str, program: str, kind: type | tuple[type, ...]
) -> Any:
    if name not in params:
        raise SpecError(f"program {program!r}: params.{name}: expected a value, got nothing")
    value = params[name]
    if isinstance(value, bool) or not isinstance(value, kind):
        raise SpecError(f"program {program!r}: params.{name}: expected {kind}, got {value!r}")
    return value


def _table(value: Any, what: str) -> NDArray[np.float64]:
    if isinstance(value, Stream):
        return np.asarray(value.data)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SensorFailure(
            what, f"expected an (N, n) numeric table, got {type(value).__name__}"
        ) from exc
    if arr.ndim != 2:
        raise SensorFailure(what, f"expected an (N, n) numeric table, got shape {arr.shape}")
    return arr


def _single(inputs: Mapping[str, Any], program: str) -> tuple[str, Any]:
    if len(inputs) != 1:
        raise SpecError(
            f"program {program!r}: expected exactly one input, got {len(inputs)}: {list(inputs)}"
        )
    return next(iter(inputs.items()))


@takes_params(PassthroughParams)
def passthrough(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> NDArray[np.float64]:
    """The single input as an (N, n) float table (``params.key`` selects a dict entry)."""
    name, value = _single(inputs, "passthrough")
    if "key" in params:
        key = _param(params, "key", "passthrough", str)
        if not isinstance(value, Mapping) or key not in value:
            raise SensorFailure(name, f"reading has no entry {key!r}")
        value = value[key]
    return _table(value, name)


@takes_params(SelectFieldsParams)
def select_fields(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> NDArray[np.float64]:
    """Columns ``params.fields`` of the single input stream, in that order."""
    name, value = _single(inputs, "select_fields")
    fields = _param(params, "fields", "select_fields", (list, tuple))
    if not isinstance(value, Stream):
        raise SpecError(f"program 'select_fields': input {name!r} must be a logical sensor")
    return value.select(list(fields)).data


@takes_params(NoParams)
def concat(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> NDArray[np.float64]:
    """Every input stacked row-wise (equal widths, no coercion)."""
    del params
    tables = [_table(v, k) for k, v in inputs.items()]
    if not tables:
        raise SpecError("program 'concat': expected at least one input, got none")
    widths = {t.shape[1] for t in tables}
    if len(widths) != 1:
        shapes = {k: t.shape for k, t in zip(inputs, tables)}
        raise SensorFailure("concat", f"inputs have different widths: {shapes}")
    return np.concatenate(tables, axis=0)


@takes_params(NoParams)
def merge(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> Stream:
    """``merge_streams`` of every input stream (coercion to the coarsest field, provenance)."""
    del params
    streams = []
    for k, v in inputs.items():
        if not isinstance(v, Stream):
            raise SpecError(f"program 'merge': input {k!r} must be a logical sensor")
        streams.append(v)
    return merge_streams(streams)


@takes_params(ConstantParams)
def constant(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> NDArray[np.float64]:
    """``params.rows`` as an (N, n) table."""
    del inputs
    rows = _param(params, "rows", "constant", (list, tuple))
    try:
        arr = np.asarray([list(r) for r in rows], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SpecError(
            f"program 'constant': params.rows: expected a list of number lists: {exc}"
        ) from None
    return arr


def _limit(params: Mapping[str, Any], name: str, test: str) -> float:
    value = params.get(name)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(
            f"acceptance test {test!r}: params.{name}: expected a number, got {value!r}"
        )
    return float(value)


@takes_params(MinParams)
def min_rows(stream: Stream, params: Mapping[str, Any]) -> str | None:
    """Reject fewer than ``params.min`` rows."""
    low = _limit(params, "min", "min_rows")
    return f"{len(stream)} rows, expected at least {low:g}" if len(stream) < low else None


@takes_params(MaxParams)
def max_rows(stream: Stream, params: Mapping[str, Any]) -> str | None:
    """Reject more than ``params.max`` rows."""
    high = _limit(params, "max", "max_rows")
    return f"{len(stream)} rows, expected at most {high:g}" if len(stream) > high else None


def _fraction(count: int, total: int) -> float:
    return count / total if total else 0.0


@takes_params(MaxParams)
def max_nan_fraction(stream: Stream, params: Mapping[str, Any]) -> str | None:
    """Reject when more than ``params.max`` of the values are NaN (only ``flag`` fields can
    keep NaN after validation)."""
    high = _limit(params, "max", "max_nan_fraction")
    frac = _fraction(int(np.isnan(stream.data).sum()), stream.data.size)
    return f"NaN fraction {frac:.3g} > {high:g}" if frac > high else None


@takes_params(MaxParams)
def max_flagged_fraction(stream: Stream, params: Mapping[str, Any]) -> str | None:
    """Reject when more than ``params.max`` of the values are flagged."""
    high = _limit(params, "max", "max_flagged_fraction")
    flagged = 0 if stream.flags is None else int(stream.flags.sum())
    frac = _fraction(flagged, stream.data.size)
    return f"flagged fraction {frac:.3g} > {high:g}" if frac > high else None


@takes_params(MaxParams)
def max_dropped_fraction(stream: Stream, params: Mapping[str, Any]) -> str | None:
    """Reject when validation dropped more than ``params.max`` of the rows produced."""
    high = _limit(params, "max", "max_dropped_fraction")
    if stream.report is None:
        return None
    frac = _fraction(stream.report.dropped, stream.report.rows_in)
    return f"dropped fraction {frac:.3g} > {high:g}" if frac > high else None
