"""Sphere models (model kind ``"sphere"``): a sphere of known radius, found by a sphere fit.

Model file entry (``tasks/models/*.toml``)::

    [[model]]
    name = "sphere_3cm"
    kind = "sphere"
    radius_m = 0.03
    tolerance_m = 0.004          # accept fits whose radius is within this of radius_m
    sensor = "Sphere_Detector"   # the logical sensor that reports (x, y, z, radius)
    max_rmse_ratio = 0.1         # optional: reject fits with rmse > ratio * radius

A :class:`SphereModel` is a :class:`~mks_sim.localize.LocalizableModel`: in a scene segment it
fits a sphere to the points (:func:`mks_sim.lowlevel.grouping.fit_sphere`) and proposes the
translation to its centre. A sphere's orientation is not observable: hypotheses carry the
identity rotation and ``symmetries()`` is None (compare positions only). ``match(rows)`` picks
the Sphere_Detector rows of the model's radius.

The database's one model-kind table (:data:`~mks_sim.models.database.MODEL_KINDS`, a
:class:`~mks_sim.registry.Registry`) names :func:`load_sphere_model` for kind ``"sphere"``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.points import fibonacci_sphere
from mks_sim.models.pose import PoseHypothesis

__all__ = ["SphereModel", "load_sphere_model"]


@dataclass(frozen=True)
class SphereModel:
    """A sphere of radius ``radius_m`` (metres); model frame origin at its centre."""

    name: str
    radius_m: float
    tolerance_m: float
    sensor: str = "Sphere_Detector"
    max_rmse_ratio: float = 0.1
    n_surface: int = 2000
    description: str = ""

    def match(self, rows: np.ndarray) -> np.ndarray:
        """Indices of Sphere_Detector rows (x, y, z, radius) within tolerance of the radius."""
        rows = np.asarray(rows, dtype=float).reshape(-1, 4)
        return np.flatnonzero(np.abs(rows[:, 3] - self.radius_m) <= self.tolerance_m)

    def hypotheses(
        self, scene_points: np.ndarray, scene_normals: np.ndarray | None = None
    ) -> list[PoseHypothesis]:
        """A translation to the fitted centre, if the fit has the model's radius."""
        from mks_sim.lowlevel.grouping import fit_sphere

        pts = np.asarray(scene_points, dtype=float).reshape(-1, 3)
        try:
            fit = fit_sphere(pts)
        except DataError:
            return []
        if abs(fit.radius - self.radius_m) > self.tolerance_m:
            return []
        if fit.rmse > self.max_rmse_ratio * self.radius_m:
            return []
        T = np.eye(4)
        T[:3, 3] = fit.center
        return [PoseHypothesis(T, fit.center, votes=len(pts), rmse=fit.rmse)]

    def surface_points(self) -> np.ndarray:
        """(M, 3) points on the sphere, model frame."""
        return self.radius_m * fibonacci_sphere(self.n_surface)

    def surface_normals(self) -> np.ndarray:
        """(M, 3) outward normals."""
        return fibonacci_sphere(self.n_surface)

    def symmetries(self) -> np.ndarray | None:
        """None: every rotation is a symmetry; compare positions only."""
        return None


def load_sphere_model(entry: Mapping[str, Any], where: str) -> SphereModel:
    """Loader of ``kind = "sphere"`` model entries."""
    allowed = {"name", "kind", "radius_m", "tolerance_m", "sensor", "max_rmse_ratio", "description"}
    unknown = set(entry) - allowed
    if unknown:
        raise SpecError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    values = {}
    for key, default in (("radius_m", None), ("tolerance_m", None), ("max_rmse_ratio", 0.1)):
        v = entry.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int | float) or not v > 0:
            raise SpecError(f"{where}: field {key!r}: expected a number > 0, got {v!r}")
        values[key] = float(v)
    sensor = entry.get("sensor", "Sphere_Detector")
    if not isinstance(sensor, str) or not sensor:
        raise SpecError(f"{where}: field 'sensor': expected a sensor name, got {sensor!r}")
    return SphereModel(
        name=str(entry["name"]),
        radius_m=values["radius_m"],
        tolerance_m=values["tolerance_m"],
        sensor=sensor,
        max_rmse_ratio=values["max_rmse_ratio"],
        description=str(entry.get("description", "")),
    )

