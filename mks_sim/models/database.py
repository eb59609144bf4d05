"""The model database (paper section 3: "high-level object models are described and stored in
a model database" at configuration time).

Models are TOML files under ``data_dir("tasks") / "models"``; each file holds one or more
``[[model]]`` entries with a ``name`` and a ``kind``. A kind is turned into a model object by its
loader, named in the one table :data:`MODEL_KINDS` (kind -> ``"module:loader"``, imported the
first time the kind is met): ``"feature"`` (:class:`~mks_sim.models.feature.FeatureModel`, here),
``"rotinv"``, ``"hough3d"``, ``"freeform"``, ``"sphere"``. Code-built kinds (plugins, tests) are
added with :func:`register_model_kind`.

The same files hold ``[[object]]`` entries (what a physical object is: mesh, symmetry,
physics, kinds); :mod:`mks_sim.models.objects` reads those, this database skips them.

Feature model entry::

    [[model]]
    name = "C2"
    kind = "feature"
    sensor = "Circle_Detector"
    fields = ["x", "y", "radius"]          # optional: the sensor's output vector names
    reference = ["*", "*", 2]              # "*" = don't care
    threshold = 0.1
    metric = "euclidean"                   # or "manhattan" | "chebyshev" or a table:
    # metric = { kind = "euclidean", weights = [1.0], ranges = [512.0] }
    # metric = { kind = "sum_of", terms = [{ f = "abs", scale = 1.0 }] }  # f: abs | square
    unit = "paper"
"""

from __future__ import annotations

import logging
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.errors import MksError, NotFound, SpecError
from mks_sim.lowlevel.metric import Metric, abs_diff
from mks_sim.registry import Registry

__all__ = [
    "MODEL_KINDS",
    "MODEL_KIND_MODULES",
    "ModelDatabase",
    "ModelLoader",
    "load_feature_model",
    "metric_from_spec",
    "register_model_kind",
]

log = logging.getLogger(__name__)

# loader(entry: the [[model]] table, where: "file: model 'name'") -> the model object
ModelLoader = Callable[[Mapping[str, Any], str], Any]

#: Every model kind: kind -> "module:loader", one table resolved on first use (a
#: :class:`~mks_sim.registry.Registry`): importing a loader's module registers nothing, so there
#: is no import circle between the database and the kinds' modules.
MODEL_KINDS: Registry[ModelLoader] = Registry(
    "model kind",
    {
        "feature": "mks_sim.models.database:load_feature_model",
        "rotinv": "mks_sim.models.hough_kinds:load_rotinv_model",
        "hough3d": "mks_sim.models.hough_kinds:load_hough3d_model",
        "freeform": "mks_sim.models.freeform:load_freeform_entry",
        "sphere": "mks_sim.models.sphere:load_sphere_model",
    },
)

#: kind -> module of its loader (read-only view of :data:`MODEL_KINDS`, kept for callers).
MODEL_KIND_MODULES: dict[str, str] = {
    kind: MODEL_KINDS.entry_point(kind).split(":")[0] for kind in MODEL_KINDS
}


def register_model_kind(kind: str, loader: ModelLoader) -> None:
    """Add (or replace) the loader of model entries of ``kind`` built in code (plugins,
    tests); the built-in kinds are the :data:`MODEL_KINDS` table."""
    MODEL_KINDS.add(kind, loader, replace=True)


def registered_kinds() -> tuple[str, ...]:
    """Every model kind (nothing is imported)."""
    return tuple(MODEL_KINDS.names())


def _loader_for(kind: str, where: str) -> ModelLoader:
    if kind not in MODEL_KINDS:
        raise SpecError(
            f"{where}: field 'kind': unknown model kind {kind!r}; expected one of the model "
            f"kinds {MODEL_KINDS.names()}"
        )
    return MODEL_KINDS.get(kind)


# --------------------------------------------------------------------------- feature models

_F_TERMS: dict[str, Callable[[float], Any]] = {
    "abs": abs_diff,
    "square": lambda s: lambda m, v: ((np.asarray(m) - np.asarray(v)) / s) ** 2,
}


def metric_from_spec(spec: Any, k: int, where: str) -> Metric:
    """Build a Metric from a file value (a name or a table); see the module docstring."""
    if spec is None:
        return Metric.euclidean()
    if isinstance(spec, str):
        spec = {"kind": spec}
    if not isinstance(spec, Mapping):
        raise SpecError(f"{where}: field 'metric': expected a name or a table, got {spec!r}")
    kind = spec.get("kind", "euclidean")
    try:
        if kind in ("euclidean", "manhattan", "chebyshev"):
            unknown = set(spec) - {"kind", "weights", "ranges"}
            if unknown:
                raise SpecError(f"unknown keys {sorted(unknown)}; expected kind, weights, ranges")
            metric = getattr(Metric, kind)(spec.get("weights"), spec.get("ranges"))
        elif kind == "sum_of":
            terms = spec.get("terms")
            if not isinstance(terms, list) or len(terms) != k:
                raise SpecError(
                    f"expected 'terms': a list of {k} tables (one per k-vector field), got {terms!r}"
                )
            fs = []
            for j, t in enumerate(terms):
                name = t.get("f") if isinstance(t, Mapping) else None
                if name not in _F_TERMS:
                    raise SpecError(
                        f"terms[{j}].f: expected one of {sorted(_F_TERMS)}, got {name!r}"
                    )
                fs.append(_F_TERMS[name](float(t.get("scale", 1.0))))
            metric = Metric.sum_of(fs)
        else:
            raise SpecError(
                f"kind: expected one of ['chebyshev', 'euclidean', 'manhattan', 'sum_of'], got {kind!r}"
            )
        metric.check_dim(k, "metric")
    except MksError as exc:
        raise SpecError(f"{where}: field 'metric': {exc}") from exc
    return metric


def load_feature_model(entry: Mapping[str, Any], where: str) -> Any:
    """Loader of ``kind = "feature"`` entries -> :class:`FeatureModel`."""
    from mks_sim.fields import parse_reference
    from mks_sim.models.feature import FeatureModel

    allowed = {
        "name",
        "kind",
        "sensor",
        "fields",
        "reference",
        "threshold",
        "metric",
        "description",
        "unit",
    }
    unknown = set(entry) - allowed
    if unknown:
        raise SpecError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    for key in ("sensor", "reference", "threshold"):
        if key not in entry:
            raise SpecError(f"{where}: field {key!r} is missing")
    sensor = entry["sensor"]
    if not isinstance(sensor, str) or not sensor:
        raise SpecError(f"{where}: field 'sensor': expected a sensor name, got {sensor!r}")
    ref = entry["reference"]
    if not isinstance(ref, list) or not ref:
        raise SpecError(
            f"{where}: field 'reference': expected a non-empty list of numbers or '*', got {ref!r}"
        )
    refs = tuple(
        parse_reference(v, where=f"{where}: field 'reference'[{i}]") for i, v in enumerate(ref)
    )
    threshold = entry["threshold"]
    if isinstance(threshold, bool) or not isinstance(threshold, int | float) or not threshold >= 0:
        raise SpecError(f"{where}: field 'threshold': expected a number >= 0, got {threshold!r}")
    fields = entry.get("fields")
    if fields is not None and (
        not isinstance(fields, list)
        or not all(isinstance(f, str) for f in fields)
        or len(fields) != len(refs)
    ):
        raise SpecError(
            f"{where}: field 'fields': expected {len(refs)} field names (one per reference value), got {fields!r}"
        )
    k = sum(1 for v in refs if isinstance(v, float))  # the k-vector: non-don't-care fields
    metric = metric_from_spec(entry.get("metric"), k, where)
    try:
        return FeatureModel(
            name=entry["name"],
            sensor=sensor,
            reference=refs,
            threshold=float(threshold),
            metric=metric,
            fields=tuple(fields) if fields else None,
            description=str(entry.get("description", "")),
            unit=str(entry.get("unit", "")),
        )
    except SpecError as exc:
        raise SpecError(f"{where}: {exc}") from exc


# --------------------------------------------------------------------------- the database


@dataclass(frozen=True)
class ModelRecord:
    """Where a model came from."""

    name: str
    kind: str
    path: Path


class ModelDatabase:
    """Models by name, loaded from TOML files.

    Use :meth:`from_dir` or :meth:`from_files`; :meth:`get` a model by name.
    """

    def __init__(self, models: Mapping[str, Any], records: Mapping[str, ModelRecord]) -> None:
        self._models = dict(models)
        self._records = dict(records)

    @classmethod
    def from_dir(cls, path: str | Path | None = None) -> ModelDatabase:
        """Load every ``*.toml`` in ``path`` (default ``data_dir("tasks") / "models"``)."""
        if path is None:
            from mks_sim.resources import data_dir

            path = data_dir("tasks") / "models"
        folder = Path(path)
        if not folder.is_dir():
            raise NotFound(f"model database: folder not found: {folder}")
        return cls.from_files(sorted(folder.glob("*.toml")))

    @classmethod
    def from_dirs(cls, paths: list[Path] | list[str]) -> ModelDatabase:
        """Load every ``*.toml`` of several folders (e.g. ``objects.models_dirs(...)``)."""
        files: list[Path] = []
        for folder in map(Path, paths):
            if not folder.is_dir():
                raise NotFound(f"model database: folder not found: {folder}")
            files += sorted(folder.glob("*.toml"))
        return cls.from_files(files)

    @classmethod
    def from_files(cls, paths: list[Path] | list[str]) -> ModelDatabase:
        """Load the given model files (duplicate names across files are an error)."""
        models: dict[str, Any] = {}
        records: dict[str, ModelRecord] = {}
        for p in map(Path, paths):
            try:
                doc = tomllib.loads(p.read_text(encoding="utf-8"))
            except FileNotFoundError as exc:
                raise NotFound(f"model file not found: {p}") from exc
            except tomllib.TOMLDecodeError as exc:
                raise SpecError(f"{p}: not valid TOML: {exc}") from exc
            entries = doc.get("model", [])
            unknown = set(doc) - {"model", "object"}
            if unknown:
                raise SpecError(
                    f"{p}: unknown top-level key(s) {sorted(unknown)}; expected [[model]] "
                    "and [[object]] entries"
                )
            if not isinstance(entries, list) or not (entries or doc.get("object")):
                raise SpecError(
                    f"{p}: expected one or more [[model]] entries (or [[object]] entries), got none"
                )
            for j, entry in enumerate(entries):
                name = entry.get("name") if isinstance(entry, Mapping) else None
                if not isinstance(name, str) or not name:
                    raise SpecError(
                        f"{p}: model entry {j}: field 'name': expected a non-empty string, got {name!r}"
                    )
                where = f"{p}: model {name!r}"
                kind = entry.get("kind")
                if not isinstance(kind, str):
                    raise SpecError(f"{where}: field 'kind': expected a string, got {kind!r}")
                if name in models:
                    raise SpecError(
                        f"{where}: duplicate model name (first defined in {records[name].path})"
                    )
                models[name] = _loader_for(kind, where)(entry, where)
                records[name] = ModelRecord(name, kind, p)
        return cls(models, records)

    def names(self) -> list[str]:
        """All model names, sorted."""
        return sorted(self._models)

    def kind(self, name: str) -> str:
        """The kind of model ``name``."""
        self.get(name)
        return self._records[name].kind

    def path(self, name: str) -> Path:
        """The file model ``name`` was loaded from."""
        self.get(name)
        return self._records[name].path

    def of_kind(self, kind: str) -> list[str]:
        """Names of the models of one kind, sorted."""
        return sorted(n for n, r in self._records.items() if r.kind == kind)

    def get(self, name: str) -> Any:
        """The model ``name`` (NotFound listing the known names)."""
        try:
            return self._models[name]
        except KeyError:
            raise NotFound(
                f"model {name!r} not in the model database; known models: {self.names()}"
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._models

    def __len__(self) -> int:
        return len(self._models)

    def __repr__(self) -> str:
        return f"ModelDatabase({self.names()})"
