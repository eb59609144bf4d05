"""Characteristic output vectors: named, ranged fields of a logical sensor's n-tuples.

Paper section 1.1: "the output of each logical sensor is defined as an n-tuple whose elements all
have a meaningful label ... and a range of possible values for that element", e.g. a camera is
(x-location, y-location, intensity) with ranges (0:1023, 0:1023, 0:255). Section 2.1 adds the
"don't care" reference value of feature models, and section 5 the *coercion* of two fields with
the same name but different ranges ("forcing a higher precision range to become a lower one").

This module holds:

- :data:`DONT_CARE` (written ``"*"`` in files) and :func:`parse_reference` /
  :func:`parse_reference_vector` that turn file values into reference values;
- :class:`Field` (name, range, unit, validation policy, precision) and :class:`OutputVector`;
- validation (:meth:`OutputVector.validate`) with the per-field policies ``reject``, ``clip``
  and ``flag``, whose every action is counted in a :class:`ValidationReport` (never silent);
- coercion (:func:`coarser`, :func:`coerce`) and :func:`merge_streams`, which merges streams of
  several sensors into one :class:`Stream` with per-row provenance.

Precision of a field: its ``resolution`` (the quantisation step, in the field's unit) when
given; a range written with integer bounds (``low = 0, high = 1023``) has resolution 1; a range
with float bounds and no resolution is continuous. Precision matters only for coercion:
validation never quantises.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError, NotFound, SpecError

__all__ = [
    "COERCIONS",
    "DONT_CARE",
    "POLICIES",
    "DontCare",
    "Field",
    "FieldCounts",
    "OutputVector",
    "Stream",
    "Validated",
    "ValidationReport",
    "coarser",
    "coerce",
    "coerce_stream",
    "merge_streams",
    "parse_reference",
    "parse_reference_vector",
    "reference_vector",
    "vector_from_dicts",
]

Policy = Literal["reject", "clip", "flag"]
Coercion = Literal["rescale", "requantize"]
POLICIES: Final[tuple[str, ...]] = ("reject", "clip", "flag")
COERCIONS: Final[tuple[str, ...]] = ("rescale", "requantize")


# --------------------------------------------------------------------------- don't care


class DontCare:
    """The "don't care" reference value of a feature model (paper section 2.1).

    A singleton: ``DontCare() is DONT_CARE``. Written ``"*"`` in files; ``repr`` is ``'*'``.
    """

    _instance: DontCare | None = None

    def __new__(cls) -> DontCare:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "'*'"

    def __str__(self) -> str:
        return "*"

    def __reduce__(self) -> tuple[type[DontCare], tuple[()]]:
        return (DontCare, ())

    def __copy__(self) -> DontCare:
        return self

    def __deepcopy__(self, memo: dict[int, Any]) -> DontCare:
        return self


DONT_CARE: Final[DontCare] = DontCare()


def _is_number(value: object) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def parse_reference(value: object, *, where: str = "") -> float | DontCare:
    """Turn a file value into a reference value: ``"*"`` -> :data:`DONT_CARE`, a number -> float.

    Args:
        value: what the file held (``"*"``, an int or a float; :data:`DONT_CARE` passes through).
        where: prefix for error messages (file, entry, field).

    Raises:
        SpecError: anything else, or a non-finite number.
    """
    prefix = f"{where}: " if where else ""
    if value is DONT_CARE or value == "*":
        return DONT_CARE
    if not _is_number(value):
        raise SpecError(f"{prefix}expected a number or '*' (don't care), got {value!r}")
    number = float(value)  # type: ignore[arg-type]
    if not math.isfinite(number):
        raise SpecError(f"{prefix}expected a finite number or '*' (don't care), got {value!r}")
    return number


def parse_reference_vector(
    values: Sequence[object], vector: OutputVector, *, where: str = ""
) -> tuple[float | DontCare, ...]:
    """Parse one reference value per field of ``vector`` (paper section 2.1).

    Each value must be ``"*"`` or a number inside its field's range.

    Returns:
        The reference values, in output-vector order.

    Raises:
        SpecError: wrong length, a value that is not ``"*"`` or a number, or out of range.
    """
    prefix = f"{where}: " if where else ""
    if isinstance(values, str | bytes) or not isinstance(values, Sequence):
        raise SpecError(f"{prefix}expected a list of {len(vector)} values, got {values!r}")
    if len(values) != len(vector):
        raise SpecError(
            f"{prefix}expected {len(vector)} values (one per field {vector.names}), "
            f"got {len(values)}"
        )
    refs: list[float | DontCare] = []
    for i, (value, fld) in enumerate(zip(values, vector.fields)):
        ref = parse_reference(value, where=f"{where}[{i}] ({fld.name})" if where else fld.name)
        if isinstance(ref, float) and not fld.low <= ref <= fld.high:
            raise SpecError(
                f"{prefix}[{i}] ({fld.name}): expected a value in {fld.low:g}:{fld.high:g} "
                f"or '*', got {ref:g}"
            )
        refs.append(ref)
    return tuple(refs)


def reference_vector(
    refs: Sequence[float | DontCare],
) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """Omit the "don't care" values (paper section 2.1: "the vector obtained by omitting the
    don't care values is called the reference vector for the model").

    Args:
        refs: one reference value per field (:func:`parse_reference_vector`).

    Returns:
        ``(indices (k,) int, values (k,) float)``: the positions of the cared-for fields (the
        model's k-vector, in output-vector order) and their reference values.
    """
    idx = [i for i, r in enumerate(refs) if r is not DONT_CARE]
    values = [float(refs[i]) for i in idx]  # type: ignore[arg-type]
    return np.asarray(idx, dtype=np.intp), np.asarray(values, dtype=np.float64)


# --------------------------------------------------------------------------- fields


@dataclass(frozen=True)
class Field:
    """One element of a characteristic output vector.

    Args:
        name: the label (``"x"``, ``"radius"``).
        low: smallest allowed value, in ``unit``.
        high: largest allowed value, in ``unit`` (``high > low``).
        unit: free text (``"m"``, ``"px"``, ``""``); fields merge only with the same unit.
        policy: what validation does with an out-of-range or NaN value: ``"reject"`` drops the
            row, ``"clip"`` clips to ``[low, high]`` (a NaN cannot be clipped: its row is
            dropped), ``"flag"`` keeps the value and sets its flag. All are counted.
        resolution: quantisation step in ``unit``; ``None`` means 1 when ``low`` and ``high``
            are both given as Python/TOML integers, otherwise continuous.
        coercion: how a finer field is coerced onto this one when they merge: ``"rescale"``
            (the paper's: the finer range is mapped linearly onto this range, e.g. pixel
            coordinates of two cameras of different resolution) or ``"requantize"`` (values
            are absolute quantities, e.g. metres: they are only quantised to this resolution).
    """

    name: str
    low: float
    high: float
    unit: str = ""
    policy: Policy = "reject"
    resolution: float | None = None
    coercion: Coercion = "rescale"

    def __post_init__(self) -> None:
        where = f"field {self.name!r}"
        if not isinstance(self.name, str) or not self.name.strip():
            raise SpecError(f"field name: expected a non-empty string, got {self.name!r}")
        for attr in ("low", "high"):
            value = getattr(self, attr)
            if not _is_number(value) or not math.isfinite(float(value)):
                raise SpecError(f"{where}: {attr}: expected a finite number, got {value!r}")
        integer_range = isinstance(self.low, int | np.integer) and isinstance(
            self.high, int | np.integer
        )
        object.__setattr__(self, "low", float(self.low))
        object.__setattr__(self, "high", float(self.high))
        if not self.high > self.low:
            raise SpecError(
                f"{where}: expected low < high, got low={self.low:g}, high={self.high:g}"
            )
        if not isinstance(self.unit, str):
            raise SpecError(f"{where}: unit: expected a string, got {self.unit!r}")
        if self.policy not in POLICIES:
            raise SpecError(f"{where}: policy: expected one of {POLICIES}, got {self.policy!r}")
        if self.coercion not in COERCIONS:
            raise SpecError(
                f"{where}: coercion: expected one of {COERCIONS}, got {self.coercion!r}"
            )
        if self.resolution is None:
            if integer_range:
                object.__setattr__(self, "resolution", 1.0)
        else:
            res = self.resolution
            if not _is_number(res) or not (math.isfinite(float(res)) and float(res) > 0):
                raise SpecError(
                    f"{where}: resolution: expected a positive number, got {self.resolution!r}"
                )
            object.__setattr__(self, "resolution", float(res))

    @property
    def span(self) -> float:
        """``high - low``."""
        return self.high - self.low

    @property
    def levels(self) -> float:
        """How many distinct values the field can hold (``inf`` when continuous)."""
        if self.resolution is None:
            return math.inf
        return math.floor(self.span / self.resolution + 1e-9) + 1

    def describe(self) -> str:
        """One line: ``x 0:1023 px (reject)``."""
        unit = f" {self.unit}" if self.unit else ""
        res = ""
        if self.resolution is not None and self.resolution != 1.0:
            res = f" step {self.resolution:g}"
        return f"{self.name} {self.low:g}:{self.high:g}{unit}{res} ({self.policy})"

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (for JSON)."""
        return {
            "name": self.name,
            "low": self.low,
            "high": self.high,
            "unit": self.unit,
            "policy": self.policy,
            "resolution": self.resolution,
            "coercion": self.coercion,
        }


@dataclass(frozen=True)
class FieldCounts:
    """What validation did to one field (counts of values, paper section 1.1 ranges).

    Attributes:
        name: the field.
        nan: NaN values found.
        out_of_range: finite or infinite values outside ``[low, high]`` (NaN not included).
        rejected: rows dropped because of this field (a row bad in two reject fields counts
            in both; :attr:`ValidationReport.dropped` counts it once).
        clipped: values clipped to the range.
        flagged: values kept and flagged.
    """

    name: str
    nan: int = 0
    out_of_range: int = 0
    rejected: int = 0
    clipped: int = 0
    flagged: int = 0

    @property
    def clean(self) -> bool:
        return self.nan == 0 and self.out_of_range == 0


@dataclass(frozen=True)
class ValidationReport:
    """Everything validation did to a stream: nothing is dropped or changed silently.

    Attributes:
        rows_in: rows given.
        rows_out: rows kept.
        fields: per-field counts, in output-vector order.
    """

    rows_in: int
    rows_out: int
    fields: tuple[FieldCounts, ...]

    @property
    def dropped(self) -> int:
        """Rows dropped (each counted once)."""
        return self.rows_in - self.rows_out

    @property
    def clean(self) -> bool:
        """True when no value was NaN or out of range."""
        return all(f.clean for f in self.fields)

    def field(self, name: str) -> FieldCounts:
        for counts in self.fields:
            if counts.name == name:
                return counts
        raise NotFound(f"no field {name!r} in report; fields: {[f.name for f in self.fields]}")

    def summary(self) -> str:
        """One line: ``"100 rows in, 97 kept, 3 dropped; x: 2 out of range (rejected 2)"``."""
        parts = [f"{self.rows_in} rows in, {self.rows_out} kept, {self.dropped} dropped"]
        for f in self.fields:
            if f.clean:
                continue
            what = []
            if f.out_of_range:
                what.append(f"{f.out_of_range} out of range")
            if f.nan:
                what.append(f"{f.nan} NaN")
            done = []
            if f.rejected:
                done.append(f"rejected {f.rejected}")
            if f.clipped:
                done.append(f"clipped {f.clipped}")
            if f.flagged:
                done.append(f"flagged {f.flagged}")
            parts.append(f"{f.name}: {', '.join(what)} ({', '.join(done)})")
        return "; ".join(parts)

    def __str__(self) -> str:
        return self.summary()


@dataclass(frozen=True, eq=False)
class Validated:
    """The result of :meth:`OutputVector.validate`.

    Attributes:
        data: (M, n) float64, the kept rows (clip fields clipped).
        flags: (M, n) bool, True where a ``flag`` field held a NaN or out-of-range value.
        report: the counts.
        kept: (N,) bool over the input rows, True for rows kept (to carry row metadata along).
    """

    data: NDArray[np.float64]
    flags: NDArray[np.bool_]
    report: ValidationReport
    kept: NDArray[np.bool_]


def _as_table(data: ArrayLike, n: int, where: str) -> NDArray[np.float64]:
    prefix = f"{where}: " if where else ""
    try:
        arr = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataError(f"{prefix}expected an (N, {n}) numeric array, got {exc}") from exc
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, n)
    if arr.ndim != 2 or arr.shape[1] != n:
        raise DataError(f"{prefix}expected an (N, {n}) array, got shape {arr.shape}")
    return arr


@dataclass(frozen=True)
class OutputVector:
    """A characteristic output vector: the ordered fields of a logical sensor's n-tuples."""

    fields: tuple[Field, ...]

    def __post_init__(self) -> None:
        fields = tuple(self.fields)
        if not fields:
            raise SpecError("output vector: expected at least one field, got none")
        for i, f in enumerate(fields):
            if not isinstance(f, Field):
                raise SpecError(f"output vector: [{i}]: expected a Field, got {f!r}")
        names = [f.name for f in fields]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise SpecError(f"output vector: duplicate field name(s) {dupes} in {names}")
        object.__setattr__(self, "fields", fields)

    @classmethod
    def of(cls, *fields: Field) -> OutputVector:
        """``OutputVector.of(Field(...), Field(...))``."""
        return cls(tuple(fields))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    @property
    def lows(self) -> NDArray[np.float64]:
        """(n,) lower bounds."""
        return np.array([f.low for f in self.fields], dtype=np.float64)

    @property
    def highs(self) -> NDArray[np.float64]:
        """(n,) upper bounds."""
        return np.array([f.high for f in self.fields], dtype=np.float64)

    def index(self, name: str) -> int:
        """Position of field ``name``; raises :class:`NotFound` listing the names."""
        for i, f in enumerate(self.fields):
            if f.name == name:
                return i
        raise NotFound(f"no field {name!r} in output vector; fields: {list(self.names)}")

    def field(self, name: str) -> Field:
        return self.fields[self.index(name)]

    def select(self, names: Iterable[str]) -> OutputVector:
        """The sub-vector of the named fields, in the order given."""
        return OutputVector(tuple(self.field(n) for n in names))

    def __len__(self) -> int:
        return len(self.fields)

    def __iter__(self) -> Iterator[Field]:
        return iter(self.fields)

    def __getitem__(self, i: int) -> Field:
        return self.fields[i]

    def describe(self) -> str:
        return "(" + ", ".join(f.describe() for f in self.fields) + ")"

    def coerce(self, data: ArrayLike, target: OutputVector) -> NDArray[np.float64]:
        """Coerce (N, n) ``data`` of this vector onto ``target`` field by field (:func:`coerce`).

        Raises:
            DataError: the field names (in order), units or coercion modes differ, or ``data``
                is not (N, n).
        """
        if self.names != target.names:
            raise DataError(
                f"cannot coerce fields {list(self.names)} onto {list(target.names)}; "
                "expected the same names in the same order"
            )
        arr = _as_table(data, len(self), "coerce")
        out = np.empty_like(arr)
        for j, (src, dst) in enumerate(zip(self.fields, target.fields)):
            out[:, j] = coerce(arr[:, j], src, dst)
        return out

    def validate(self, data: ArrayLike, *, strict: bool = False, where: str = "") -> Validated:
        """Apply each field's policy to NaN and out-of-range values of ``data``.

        Args:
            data: (N, n) numbers in output-vector order (an empty sequence means N = 0).
            strict: raise instead of dropping rows of ``reject`` fields (and NaN in ``clip``
                fields).
            where: prefix for error messages (file / sensor).

        Returns:
            :class:`Validated` (kept rows, flags, report, kept-row mask).

        Raises:
            DataError: ``data`` is not an (N, n) numeric array, or ``strict`` and a row would
                be dropped.
        """
        arr = _as_table(data, len(self), where)
        n_rows = arr.shape[0]
        nan = np.isnan(arr)  # (N, n)
        out = ~nan & ((arr < self.lows) | (arr > self.highs))  # (N, n)
        drop = np.zeros(n_rows, dtype=bool)
        flags = np.zeros(arr.shape, dtype=bool)
        result = arr.copy()
        counts: list[FieldCounts] = []
        for j, f in enumerate(self.fields):
            n_nan, n_out = int(nan[:, j].sum()), int(out[:, j].sum())
            rejected = clipped = flagged = 0
            if f.policy == "reject":
                bad = nan[:, j] | out[:, j]
                rejected = int(bad.sum())
                drop |= bad
            elif f.policy == "clip":
                result[:, j] = np.clip(result[:, j], f.low, f.high)
                clipped = n_out
                rejected = n_nan
                drop |= nan[:, j]
            else:
                flags[:, j] = nan[:, j] | out[:, j]
                flagged = n_nan + n_out
            counts.append(FieldCounts(f.name, n_nan, n_out, rejected, clipped, flagged))
        kept = ~drop
        report = ValidationReport(n_rows, int(kept.sum()), tuple(counts))
        if strict and report.dropped:
            prefix = f"{where}: " if where else ""
            raise DataError(f"{prefix}strict validation failed: {report.summary()}")
        return Validated(result[kept], flags[kept], report, kept)


# --------------------------------------------------------------------------- streams


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr.flags.writeable = False
    return arr


# eq=False: comparing streams field by field would compare arrays (ambiguous truth value).
@dataclass(frozen=True, eq=False)
class Stream:
    """The output of a logical sensor: an n-tuple stream and its output vector.

    Attributes:
        data: (N, n) float64 in output-vector order (read-only).
        vector: the characteristic output vector.
        sensor: the logical sensor that produced it.
        served_by: which alternate served: ``"primary"`` or the alternate's name.
        source: (N,) str, the sensor of each row (set by :func:`merge_streams`), or None.
        flags: (N, n) bool, the values flagged by validation (``flag`` policy), or None.
        report: what validation did, or None when the stream was not validated.
    """

    data: NDArray[np.float64]
    vector: OutputVector
    sensor: str
    served_by: str = "primary"
    source: NDArray[np.str_] | None = None
    flags: NDArray[np.bool_] | None = None
    report: ValidationReport | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        where = f"stream of {self.sensor!r}"
        data = _readonly(np.array(_as_table(self.data, len(self.vector), where), copy=True))
        object.__setattr__(self, "data", data)
        n_rows = data.shape[0]
        if self.source is not None:
            source = np.array(self.source, dtype=np.str_)
            if source.shape != (n_rows,):
                raise DataError(f"{where}: source: expected shape ({n_rows},), got {source.shape}")
            object.__setattr__(self, "source", _readonly(source))
        if self.flags is not None:
            flags = np.array(self.flags, dtype=bool)
            if flags.shape != data.shape:
                raise DataError(f"{where}: flags: expected shape {data.shape}, got {flags.shape}")
            object.__setattr__(self, "flags", _readonly(flags))

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def names(self) -> tuple[str, ...]:
        return self.vector.names

    def column(self, name: str) -> NDArray[np.float64]:
        """(N,) values of field ``name``."""
        return self.data[:, self.vector.index(name)]

    def select(self, names: Sequence[str]) -> Stream:
        """The stream restricted to the named fields (e.g. a model's k-vector)."""
        idx = [self.vector.index(n) for n in names]
        return Stream(
            self.data[:, idx],
            self.vector.select(names),
            self.sensor,
            self.served_by,
            self.source,
            None if self.flags is None else self.flags[:, idx],
            self.report,
        )


# --------------------------------------------------------------------------- coercion


def _precision_key(f: Field) -> float:
    if f.coercion == "rescale":
        return f.levels  # fewer levels = coarser
    return -(f.resolution or 0.0)  # larger step = coarser


def _check_mergeable(a: Field, b: Field, where: str = "") -> None:
    prefix = f"{where}: " if where else ""
    if a.name != b.name:
        raise DataError(f"{prefix}cannot coerce field {a.name!r} into field {b.name!r}")
    if a.unit != b.unit:
        raise DataError(
            f"{prefix}field {a.name!r}: incompatible units {a.unit!r} and {b.unit!r} "
            "(coercion changes precision, never units)"
        )
    if a.coercion != b.coercion:
        raise DataError(
            f"{prefix}field {a.name!r}: incompatible coercion modes {a.coercion!r} and "
            f"{b.coercion!r}"
        )


def coarser(*fields: Field) -> Field:
    """The coarsest of same-named fields (paper section 5: the lower precision wins).

    ``rescale`` fields: the one with fewest representable levels (0:511 is coarser than
    0:1023); ``requantize`` fields: the one with the largest resolution. Ties go to the first.

    Raises:
        DataError: names, units or coercion modes differ.
    """
    if not fields:
        raise DataError("coarser(): expected at least one field")
    for f in fields[1:]:
        _check_mergeable(fields[0], f)
    best = fields[0]
    for f in fields[1:]:
        if _precision_key(f) < _precision_key(best):
            best = f
    return best


def _quantise(values: NDArray[np.float64], target: Field) -> NDArray[np.float64]:
    if target.resolution is None:
        return values
    step = target.resolution
    # Half-up rounding (not numpy's half-to-even) keeps the map monotone and predictable.
    return target.low + np.floor((values - target.low) / step + 0.5) * step


def coerce(values: ArrayLike, source: Field, target: Field) -> NDArray[np.float64]:
    """Coerce values of ``source`` onto the (coarser) field ``target`` (paper section 5).

    ``rescale``: ``v' = target.low + (v - source.low) * target.span / source.span``, quantised
    to ``target.resolution`` (half up) and clipped to the target range, e.g. 0:1023 -> 0:511
    maps 1023 to 511 and 512 to 256 (255.75 rounded). ``requantize``: values keep their
    magnitude and are only quantised to ``target.resolution`` (range checks are left to
    validation with the target's policy). Values are always quantised to the target's grid,
    also when ``source == target`` (so every row of a merged stream has the same precision).
    NaN stays NaN.

    Args:
        values: (...,) values in ``source`` units.

    Returns:
        float64 array of the same shape.

    Raises:
        DataError: names, units or coercion modes differ.
    """
    _check_mergeable(source, target)
    v = np.asarray(values, dtype=np.float64)
    if target.coercion == "rescale":
        mapped = target.low + (v - source.low) * (target.span / source.span)
        return np.clip(_quantise(mapped, target), target.low, target.high)
    return _quantise(v, target)


def coerce_stream(stream: Stream, vector: OutputVector) -> Stream:
    """Coerce every field of ``stream`` onto the same-named field of ``vector``.

    Raises:
        DataError: the field names (in order), units or coercion modes differ.
    """
    if stream.vector.names != vector.names:
        raise DataError(
            f"stream of {stream.sensor!r}: fields {list(stream.vector.names)} do not match "
            f"{list(vector.names)}"
        )
    columns = [
        coerce(stream.data[:, j], src, dst)
        for j, (src, dst) in enumerate(zip(stream.vector, vector))
    ]
    data = np.stack(columns, axis=1) if columns else stream.data
    return Stream(
        data, vector, stream.sensor, stream.served_by, stream.source, stream.flags, stream.report
    )


def merge_streams(
    streams: Sequence[Stream], *, sensor: str = "merged", served_by: str = "merged"
) -> Stream:
    """Merge streams of different sensors with the same field names into one stream.

    Each field of the result is the coarsest of the streams' same-named fields
    (:func:`coarser`); every stream is coerced onto it (:func:`coerce`). The merged rows are
    validated against the merged vector (the coarser field's policy; nothing is silent: the
    report is on the result). ``source`` names each row's sensor (a stream's own ``source``
    when it has one, else its ``sensor``).

    Args:
        streams: one or more streams whose vectors have the same names in the same order.
        sensor: the merged stream's sensor name.
        served_by: the merged stream's ``served_by``.

    Returns:
        The merged :class:`Stream`, rows in the order of ``streams``.

    Raises:
        DataError: no streams, or the field names / units / coercion modes differ.
    """
    streams = list(streams)
    if not streams:
        raise DataError("merge_streams: expected at least one stream, got none")
    names = streams[0].vector.names
    for s in streams[1:]:
        if s.vector.names != names:
            raise DataError(
                f"merge_streams: stream of {s.sensor!r} has fields {list(s.vector.names)}, "
                f"stream of {streams[0].sensor!r} has {list(names)}; expected the same "
                "field names in the same order"
            )
    merged_fields = []
    for j in range(len(names)):
        fields_j = [s.vector[j] for s in streams]
        for s, f in zip(streams[1:], fields_j[1:]):
            try:
                _check_mergeable(fields_j[0], f)
            except DataError as exc:
                raise DataError(
                    f"merge_streams: {exc} (streams {streams[0].sensor!r} and {s.sensor!r})"
                ) from None
        merged_fields.append(coarser(*fields_j))
    vector = OutputVector(tuple(merged_fields))
    coerced = [coerce_stream(s, vector) for s in streams]
    data = np.concatenate([s.data for s in coerced], axis=0)
    source = np.concatenate(
        [s.source if s.source is not None else np.full(len(s), s.sensor) for s in streams]
    ).astype(np.str_)
    old_flags = np.concatenate(
        [s.flags if s.flags is not None else np.zeros(s.data.shape, dtype=bool) for s in streams],
        axis=0,
    )
    checked = vector.validate(data, where=f"merge_streams -> {sensor!r}")
    flags = checked.flags | old_flags[checked.kept]
    return Stream(
        checked.data,
        vector,
        sensor,
        served_by,
        source[checked.kept],
        flags if flags.any() else None,
        checked.report,
    )


def vector_from_dicts(items: Sequence[Mapping[str, Any]]) -> OutputVector:
    """Build an :class:`OutputVector` from plain dicts (``{"name": "x", "low": 0, ...}``)."""
    return OutputVector(tuple(Field(**dict(item)) for item in items))
