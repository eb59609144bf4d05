"""Model-database loaders for the Hough shape models: kinds ``"rotinv"`` and ``"hough3d"``.

Entry format (TOML, ``tasks/models/*.toml``)::

    [[model]]
    name = "paper_cube"
    kind = "rotinv"                 # RotationInvariantHough (section 2.2.1)
                                    # or "hough3d": TranslationHough3D (section 2.2)
    points = [[-1, -1, -1], ...]    # (n, 3) model points (vertexes / control points)
    reference = [1.5, 1.3, 1.25]    # optional; rotinv: chosen automatically, hough3d: centroid
    tolerance = 0.01                # optional; rotinv: sphere tolerance, hough3d: cell size
    symmetry = "cube"               # optional: "cube" (the 24 rotations) | "none"
    description = "..."             # optional
    unit = "paper"                  # optional, informative

The database's :data:`~mks_sim.models.database.MODEL_KINDS` table names these loaders
(``"mks_sim.models.hough_kinds:load_rotinv_model"``, ...); importing a module registers
nothing, and neither :mod:`~mks_sim.models.rotinv` nor :mod:`~mks_sim.models.hough3d` imports
this one (no import circle).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from mks_sim.errors import MksError, SpecError
from mks_sim.geometry.transforms import cube_rotations

__all__ = ["SYMMETRIES", "load_hough3d_model", "load_rotinv_model"]

SYMMETRIES = ("cube", "none")
_ALLOWED = {"name", "kind", "points", "reference", "tolerance", "symmetry", "description", "unit"}


def _parse_common(entry: Mapping[str, Any], where: str) -> dict[str, Any]:
    unknown = set(entry) - _ALLOWED
    if unknown:
        raise SpecError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(_ALLOWED)}")
    pts = entry.get("points")
    if pts is None:
        raise SpecError(f"{where}: field 'points' is missing (expected [[x, y, z], ...])")
    try:
        arr = np.asarray(pts, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise SpecError(
            f"{where}: field 'points': expected a list of [x, y, z] numbers, got {pts!r}"
        ) from exc
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) < 3 or not np.all(np.isfinite(arr)):
        raise SpecError(
            f"{where}: field 'points': expected at least 3 finite [x, y, z] rows, "
            f"got shape {arr.shape}"
        )
    ref = entry.get("reference")
    if ref is not None:
        try:
            ref_arr = np.asarray(ref, dtype=np.float64)
        except (TypeError, ValueError):
            ref_arr = np.zeros(0)
        if ref_arr.shape != (3,) or not np.all(np.isfinite(ref_arr)):
            raise SpecError(f"{where}: field 'reference': expected [x, y, z], got {ref!r}")
        ref = ref_arr
    tol = entry.get("tolerance")
    if tol is not None and (
        isinstance(tol, bool)
        or not isinstance(tol, int | float)
        or not math.isfinite(tol)
        or tol <= 0
    ):
        raise SpecError(f"{where}: field 'tolerance': expected a number > 0, got {tol!r}")
    sym = entry.get("symmetry", "none")
    if sym not in SYMMETRIES:
        raise SpecError(
            f"{where}: field 'symmetry': expected one of {list(SYMMETRIES)}, got {sym!r}"
        )
    return {
        "points": arr,
        "reference": ref,
        "tolerance": None if tol is None else float(tol),
        "symmetries": cube_rotations() if sym == "cube" else None,
        "name": str(entry.get("name", "")),
    }


def _build(make: Any, entry: Mapping[str, Any], where: str) -> Any:
    """Build a Hough model with ``make(args)``; its errors become SpecErrors naming the entry."""
    args = _parse_common(entry, where)  # its errors already name the entry
    try:
        model = make(args)
    except MksError as exc:
        raise SpecError(f"{where}: {exc}") from exc
    model.description = str(entry.get("description", ""))
    model.unit = str(entry.get("unit", ""))
    return model


def load_rotinv_model(entry: Mapping[str, Any], where: str) -> Any:
    """Loader of ``kind = "rotinv"`` -> :class:`~mks_sim.models.rotinv.RotationInvariantHough`."""
    from mks_sim.models.rotinv import RotationInvariantHough

    return _build(
        lambda a: RotationInvariantHough(
            a["points"],
            reference=a["reference"],
            tolerance=a["tolerance"],
            symmetries=a["symmetries"],
            name=a["name"],
        ),
        entry,
        where,
    )


def load_hough3d_model(entry: Mapping[str, Any], where: str) -> Any:
    """Loader of ``kind = "hough3d"`` -> :class:`~mks_sim.models.hough3d.TranslationHough3D`."""
    from mks_sim.models.hough3d import TranslationHough3D

    return _build(
        lambda a: TranslationHough3D(
            a["points"],
            reference=a["reference"],
            cell=a["tolerance"],
            name=a["name"],
            symmetries=a["symmetries"],
        ),
        entry,
        where,
    )
