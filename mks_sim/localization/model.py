"""Model kinds and loading a localizable model from a mesh by kind.

Kinds (``KINDS``):

- ``polyhedral`` — :class:`mks_sim.localize.PolyhedralModel`: vertexes and faces of a mostly
  planar surface (cube, industrial part);
- ``freeform`` — :class:`mks_sim.models.freeform.FreeformModel`: point-pair features of a
  curved surface (torus, blob);
- ``sphere`` — :class:`mks_sim.models.sphere.SphereModel`: a radius;
- ``auto`` — :func:`mesh_kind` chooses from the mesh: ``sphere`` when every vertex is at one
  distance from the centroid, ``polyhedral`` when most of the area lies in large planar
  facets, else ``freeform``.

The pipeline is chosen by the model's kind, never by an object's name.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from mks_sim.errors import DataError

__all__ = [
    "KINDS",
    "PLANAR_AREA_FRACTION",
    "mesh_kind",
    "model_from_mesh",
    "model_kind",
    "planar_area_fraction",
]

log = logging.getLogger(__name__)

#: The model kinds ``localize-cloud --kind`` accepts.
KINDS = ("auto", "polyhedral", "freeform", "sphere")
#: A mesh with at least this fraction of its area in large planar facets is polyhedral.
PLANAR_AREA_FRACTION = 0.6
#: A planar facet counts as large when it holds this fraction of the mesh area (the facets of
#: a tessellated curved surface are each far smaller; the polyhedral model's own threshold).
LARGE_FACET_FRACTION = 0.004


def planar_area_fraction(mesh: Any, min_face_fraction: float = LARGE_FACET_FRACTION) -> float:
    """Fraction of the mesh area lying in planar facets (coplanar triangles merged) of at
    least ``min_face_fraction`` of the area each."""
    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    good = area2 > 1e-18
    if not good.any():
        raise DataError("mesh has no triangle of non-zero area")
    n = cross[good] / area2[good, None]
    size = float(np.linalg.norm(np.ptp(v, axis=0)))
    offset = np.einsum("ij,ij->i", n, tri[good, 0]) / size
    key = np.column_stack([np.round(n * 1e3), np.round(offset * 1e3)])
    _, plane_of = np.unique(key, axis=0, return_inverse=True)
    plane_area = np.bincount(plane_of.reshape(-1), weights=area2[good])
    total = float(area2[good].sum())
    return float(plane_area[plane_area >= min_face_fraction * total].sum() / total)


def _sphere_radius(mesh: Any) -> float | None:
    """The radius when every vertex lies at one distance (within 2 %) from the centroid."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    r = np.linalg.norm(v - v.mean(axis=0), axis=1)
    mean = float(r.mean())
    if mean > 0 and float(np.max(np.abs(r - mean))) <= 0.02 * mean and len(v) >= 20:
        return mean
    return None


def mesh_kind(mesh: Any) -> str:
    """``sphere``, ``polyhedral`` or ``freeform`` for a model mesh (see the module doc)."""
    if _sphere_radius(mesh) is not None:
        return "sphere"
    return "polyhedral" if planar_area_fraction(mesh) >= PLANAR_AREA_FRACTION else "freeform"


def model_from_mesh(mesh: Any, name: str, kind: str = "auto") -> tuple[Any, str]:
    """A localizable model of ``mesh`` of the given kind; returns (model, the kind built).

    Raises:
        DataError: unknown kind, or a mesh the kind cannot use (a polyhedral model of a mesh
            without corners; a sphere of a mesh that is not one).
    """
    if kind not in KINDS:
        raise DataError(f"model kind: expected one of {list(KINDS)}, got {kind!r}")
    try:
        chosen = mesh_kind(mesh) if kind == "auto" else kind
    except DataError as exc:
        raise DataError(f"model {name!r}: {exc}") from None
    if chosen == "sphere":
        from mks_sim.models.sphere import SphereModel

        r = _sphere_radius(mesh)
        if r is None:
            raise DataError(f"model {name!r}: the mesh is not a sphere (vertex radii differ)")
        # the mesh's facets sit inside the true sphere by up to its sagitta
        return SphereModel(name, r, max(0.05 * r, 1e-6)), chosen
    if chosen == "freeform":
        from mks_sim.models.freeform import FreeformModel

        return FreeformModel.from_mesh(mesh, name), chosen
    from mks_sim.localize import PolyhedralModel

    return PolyhedralModel.from_mesh(mesh, name), chosen


def model_kind(model: Any) -> str:
    """The kind of a localizable model: ``sphere`` (a radius), ``polyhedral`` (corners and
    faces), ``freeform`` (point-pair tables), else its ``kind`` attribute or type name."""
    kind = getattr(model, "kind", None)
    if isinstance(kind, str) and kind in KINDS:
        return kind
    if isinstance(getattr(model, "radius_m", None), float):
        return "sphere"
    if hasattr(model, "corners") and hasattr(model, "faces"):
        return "polyhedral"
    if type(model).__name__ == "FreeformModel":
        return "freeform"
    return type(model).__name__
