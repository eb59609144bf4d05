"""Feature models and the three matchers of paper section 2.1.

"A model is completely specified by naming a logical sensor and then giving a value for every
feature returned by the sensor", with "don't care" (:data:`~mks_sim.fields.DONT_CARE`) for the
features the model ignores. The non-don't-care fields form the *k-vector*; the model's values
on them are its *reference vector*. A description (one n-tuple of the sensor) matches the model
when ``distance(m, v) = SUM f_i(m_i, v_i)`` (or any :class:`~mks_sim.lowlevel.Metric` on the
k-vector) is ``<= threshold`` (inclusive, like the k-d tree's ``query_ball_point``).

The three matchers return the same list of :class:`Match` (every model-description pair within
the model's threshold, sorted by model name then description index):

(a) :func:`match_model_tree` — the reference vectors in a k-d tree (the *model tree*), queried
    with each description;
(b) :func:`match_description_tree` — the descriptions in a k-d tree, queried with each model;
(c) :func:`match_spg` — the reference vectors included in the data and a spatial proximity graph
    built with ``m="all"`` and the threshold; model-to-description edges are the matches.

Models on different field subsets (or sensors, or metrics) cannot share a tree: they are
grouped by (sensor, k-vector fields, metric) and each group is matched on its own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mks_sim.errors import DataError, SpecError
from mks_sim.fields import DONT_CARE, DontCare
from mks_sim.lowlevel import KDTree, Metric, SpatialProximityGraph

__all__ = [
    "FeatureModel",
    "Match",
    "match_brute_force",
    "match_description_tree",
    "match_model_tree",
    "match_spg",
]


@dataclass(frozen=True)
class FeatureModel:
    """A feature model: a logical sensor, a reference value or don't care per field.

    Args:
        name: the model's name (e.g. ``"C2"``).
        sensor: the logical sensor whose n-tuples the model describes.
        reference: one value per field of the sensor's output vector, ``DONT_CARE`` (or
            ``"*"``) for ignored fields.
        threshold: a description matches when its distance is <= threshold.
        metric: distance on the k-vector (default Euclidean); a Minkowski metric's weights /
            ranges and a ``sum_of`` metric's ``f_i`` are per k-vector field.
        fields: the sensor's field names, in order (optional; for messages and reports).
        description: free text.
        unit: what the numbers are in (e.g. ``"paper"`` or ``"m"``).
    """

    name: str
    sensor: str
    reference: tuple[float | DontCare, ...]
    threshold: float
    metric: Metric = field(default_factory=Metric.euclidean)
    fields: tuple[str, ...] | None = None
    description: str = ""
    unit: str = ""

    def __post_init__(self) -> None:
        where = f"feature model {self.name!r}"
        refs: list[float | DontCare] = []
        for i, v in enumerate(self.reference):
            if v is DONT_CARE or (isinstance(v, str) and v == "*"):
                refs.append(DONT_CARE)
            elif isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool):
                if not math.isfinite(float(v)):
                    raise SpecError(
                        f"{where}: reference[{i}]: expected a finite number or '*', got {v!r}"
                    )
                refs.append(float(v))
            else:
                raise SpecError(f"{where}: reference[{i}]: expected a number or '*', got {v!r}")
        object.__setattr__(self, "reference", tuple(refs))
        if not any(r is not DONT_CARE for r in refs):
            raise SpecError(
                f"{where}: reference: every field is don't care; at least one value needed"
            )
        if not (isinstance(self.threshold, int | float) and self.threshold >= 0):
            raise SpecError(f"{where}: threshold: expected a number >= 0, got {self.threshold!r}")
        object.__setattr__(self, "threshold", float(self.threshold))
        if self.fields is not None:
            object.__setattr__(self, "fields", tuple(self.fields))
            if len(self.fields) != len(refs):
                raise SpecError(
                    f"{where}: expected one reference value per field {list(self.fields)}, got {len(refs)}"
                )
        try:
            self.metric.check_dim(self.k, where)
        except DataError as exc:
            raise SpecError(str(exc)) from exc

    @property
    def n(self) -> int:
        """Length of the sensor's output vector."""
        return len(self.reference)

    @property
    def key_indices(self) -> tuple[int, ...]:
        """Positions of the k-vector fields (the non-don't-care ones) in the n-tuple."""
        return tuple(i for i, r in enumerate(self.reference) if r is not DONT_CARE)

    @property
    def k(self) -> int:
        return len(self.key_indices)

    @property
    def key_fields(self) -> tuple[str, ...]:
        """Names of the k-vector fields (``f<i>`` when the model has no field names)."""
        names = self.fields or tuple(f"f{i}" for i in range(self.n))
        return tuple(names[i] for i in self.key_indices)

    @property
    def reference_vector(self) -> NDArray[np.float64]:
        """(k,) the reference vector (the reference without its don't-care values)."""
        return np.array([self.reference[i] for i in self.key_indices], dtype=float)

    def k_vectors(self, descriptions: ArrayLike) -> NDArray[np.float64]:
        """(N, k) the k-vector columns of (N, n) descriptions (DataError if not finite)."""
        arr = np.asarray(descriptions, dtype=float)
        if arr.ndim == 1 and arr.size == self.n:
            arr = arr[None, :]
        if arr.ndim != 2 or arr.shape[1] != self.n:
            raise DataError(
                f"feature model {self.name!r} on {self.sensor!r}: expected (N, {self.n}) descriptions, "
                f"got shape {arr.shape}"
            )
        kv = arr[:, list(self.key_indices)]
        bad = ~np.isfinite(kv)
        if bad.any():
            row, col = (int(x) for x in np.argwhere(bad)[0])
            raise DataError(
                f"feature model {self.name!r}: description {row} field {self.key_fields[col]!r} "
                f"is {float(kv[row, col])}; the k-vector fields must be finite"
            )
        return kv

    def distance(self, descriptions: ArrayLike) -> NDArray[np.float64]:
        """(N,) ``distance(m, v)`` from the reference vector to each description."""
        return self.metric.distance(self.reference_vector, self.k_vectors(descriptions))

    def matches(self, descriptions: ArrayLike) -> NDArray[np.bool_]:
        """(N,) True where the description matches (distance <= threshold)."""
        return self.distance(descriptions) <= self.threshold

    @property
    def group_key(self) -> tuple[Any, ...]:
        """Models sharing this key can share one k-d tree."""
        return (self.sensor, self.n, self.key_indices, self.metric)


@dataclass(frozen=True, order=True)
class Match:
    """One model-description match: the model's name, the description's row, the distance."""

    model: str
    description: int
    distance: float


Descriptions = ArrayLike | Mapping[str, ArrayLike]


def _groups(
    models: Sequence[FeatureModel], descriptions: Descriptions
) -> list[tuple[list[FeatureModel], NDArray[np.float64]]]:
    """Group models by k-vector; pair each group with its sensor's (N, k) k-vectors."""
    if not models:
        return []
    names = [m.name for m in models]
    if len(set(names)) != len(names):
        raise SpecError(f"feature matchers: model names repeat: {sorted(names)}")
    groups: dict[tuple[Any, ...], list[FeatureModel]] = {}
    for m in models:
        groups.setdefault(m.group_key, []).append(m)
    out = []
    for members in groups.values():
        sensor = members[0].sensor
        if isinstance(descriptions, Mapping):
            if sensor not in descriptions:
                raise DataError(
                    f"feature matchers: no descriptions of sensor {sensor!r} (model "
                    f"{members[0].name!r}); got sensors {sorted(descriptions)}"
                )
            data = descriptions[sensor]
        else:
            sensors = sorted({m.sensor for m in models})
            if len(sensors) > 1:
                raise DataError(
                    f"feature matchers: models name several sensors {sensors}; pass a mapping "
                    "sensor -> descriptions"
                )
            data = descriptions
        arr = np.asarray(data, dtype=float)
        if arr.size == 0:
            arr = arr.reshape(0, members[0].n)
        out.append((members, members[0].k_vectors(arr)))
    return out


def _finish(
    models: list[FeatureModel], kv: NDArray[np.float64], pairs: set[tuple[int, int]]
) -> list[Match]:
    """Exact distance and threshold for candidate (model, description) pairs."""
    out = []
    for mi, di in pairs:
        model = models[mi]
        d = float(model.metric.distance(model.reference_vector, kv[di]))
        if d <= model.threshold:
            out.append(Match(model.name, int(di), d))
    return out


def match_model_tree(models: Sequence[FeatureModel], descriptions: Descriptions) -> list[Match]:
    """Matcher (a): reference vectors in a k-d tree, queried with each description."""
    matches: list[Match] = []
    for members, kv in _groups(models, descriptions):
        refs = np.stack([m.reference_vector for m in members])
        # The tree holds the models, the query is the description: f_i(m_i, v_i) needs the
        # metric with its arguments swapped.
        tree = KDTree(refs, metric=members[0].metric.transposed())
        r = max(m.threshold for m in members)
        pairs: set[tuple[int, int]] = set()
        if len(kv):
            for di, hits in enumerate(tree.query_ball_point(kv, r * (1 + 1e-12) + 1e-30)):
                pairs.update((mi, di) for mi in hits)
        matches += _finish(members, kv, pairs)
    return sorted(matches)


def match_description_tree(
    models: Sequence[FeatureModel], descriptions: Descriptions
) -> list[Match]:
    """Matcher (b): descriptions in a k-d tree, queried with each model's reference vector."""
    matches: list[Match] = []
    for members, kv in _groups(models, descriptions):
        tree = KDTree(kv, metric=members[0].metric)
        pairs: set[tuple[int, int]] = set()
        for mi, m in enumerate(members):
            hits = tree.query_ball_point(m.reference_vector, m.threshold * (1 + 1e-12) + 1e-30)
            pairs.update((mi, di) for di in hits)
        matches += _finish(members, kv, pairs)
    return sorted(matches)


def match_spg(models: Sequence[FeatureModel], descriptions: Descriptions) -> list[Match]:
    """Matcher (c): reference vectors included in the data, SPG with m="all" and the threshold.

    Rows 0..M-1 of the SPG are the group's reference vectors and rows M.. the descriptions
    (paper section 4.1: "we include the model reference vector at the beginning of the file").
    """
    matches: list[Match] = []
    for members, kv in _groups(models, descriptions):
        refs = np.stack([m.reference_vector for m in members])
        r = max(m.threshold for m in members)
        spg = SpatialProximityGraph(
            np.concatenate([refs, kv]),
            m="all",
            threshold=r * (1 + 1e-12) + 1e-30,
            metric=members[0].metric,
        )
        nm = len(members)
        pairs: set[tuple[int, int]] = set()
        for mi in range(nm):
            nb = spg.neighbors(mi)
            pairs.update((mi, int(j) - nm) for j in nb[nb >= nm])
        matches += _finish(members, kv, pairs)
    return sorted(matches)


def match_brute_force(models: Sequence[FeatureModel], descriptions: Descriptions) -> list[Match]:
    """Every model against every description (the reference for tests; O(M N))."""
    matches: list[Match] = []
    for members, kv in _groups(models, descriptions):
        for m in members:
            pairs = {(0, di) for di in range(len(kv))}
            matches += _finish([m], kv, pairs)
    return sorted(matches)
