"""Localization at the workstation, end to end from simulated sensors (paper section 4).

:func:`localize_object` runs the paper's execution flow (section 4, steps 1-7) for one object:

1. **Invoke the model.** The object comes from the model database
   (``mks_sim.models.objects.load_object``: mesh, localization kinds, logical sensor); its
   default KIND picks the pipeline (``sphere`` or the polyhedral surface of its mesh, plus
   the ``rotinv`` model it names: the cube's vertexes, the part's control points).
2. **Activate the logical sensors it needs** through a :class:`~mks_sim.sensing.SensorGraph`
   snapshot on the devices: only the model's sensor and its inputs
   (``graph.required([sensor])``) run; a failed device is replaced by the sensor's alternate
   (``Range_Points`` served by ``Stereo_Points`` when the range finder fails), which the
   snapshot's provenance reports. Ground truth is never read.
3. **The snapshot's representation** of the points (``snap.representation``,
   :mod:`mks_sim.localization.representation`): k-d tree, the table plane (RANSAC near its
   nominal height) and the objects above it, their SPG, normals, curvature and planar /
   curved segmentation, each computed once and shared with the description sensors.
4. **Grouping**: object segments (SPG components; spheres set aside), their planar regions
   and vertexes (the table is the face an object rests on).
5. **Matching**: vertex-frame Hough votes / the rotation-invariant Hough of section 2.2.1 for the
   polyhedral models (cube, industrial part, :func:`mks_sim.localize.localize_cloud`); the
   sphere model picks the ``Sphere_Detector`` rows of its radius.
6. **Refinement**: point-to-plane ICP (cube, part) or a geometric sphere fit to the points
   near the detected sphere, and a scene-consistency check of every candidate (no sensed point
   inside the posed model or seen through it, no penetration of the table) that picks the
   candidate explaining the most points.
7. **Report** the transformation ``object_to_world`` (4x4, column convention, metres) of the
   object's BODY frame — the frame :mod:`mks_sim.sim.truth` reports: the cube's and the
   sphere's centre, the industrial part's bottom-face centre (``industrial_part_mesh``).

Example:
    >>> import numpy as np
    >>> from mks_sim.sim.world import build_world
    >>> from mks_sim.devices import make_devices
    >>> from mks_sim.workstation import localize_object
    >>> world = build_world("scene2", seed=1)
    >>> with make_devices(world.model, world.data, np.random.default_rng(1)) as devices:
    ...     result = localize_object(world, "cube", devices)  # doctest: +SKIP
    >>> result.object_to_world  # doctest: +SKIP
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import MksError, NotFound, SensorFailure
from mks_sim.localization.hypotheses import (
    score_spheres,
    sphere_centre_hough,
    support_face_hypotheses,
)
from mks_sim.localization.model import model_kind
from mks_sim.localization.representation import Representation, RepresentationConfig
from mks_sim.localization.verify import Consistency, consistency, rank
from mks_sim.models.pose import PoseHypothesis

if TYPE_CHECKING:
    from mks_sim.lowlevel.grouping import Plane
    from mks_sim.models.database import ModelDatabase
    from mks_sim.sensing import SensorGraph

__all__ = [
    "WorkstationLocalization",
    "localize",
    "localize_object",
    "table_z_m",
    "workstation_representation",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

POINTS_SENSOR = "Range_Points"
# An object segment whose points a consistent candidate explains at least this fraction of
# needs no support-face hypotheses.
SUPPORT_EXPLAINED_FRACTION = 0.8
SPHERE_SENSOR = "Sphere_Detector"
# Spheres of this radius range found by Sphere_Detector are set aside before polyhedral
# matching (the workstation's spheres are 3 cm; larger fits are curved-region artefacts).
MIN_EXPLAINED_SPHERE_M = 0.01
MAX_EXPLAINED_SPHERE_M = 0.05
#: The description sensor whose ``params`` (``sensors/points.toml``: nominal table height and
#: margin, SPG gap and neighbours) the flow's representation of ``Range_Points`` shares.
REPRESENTATION_SENSOR = "Vertex_Detector"


def workstation_representation(graph: SensorGraph | None = None) -> RepresentationConfig:
    """The representation the flow asks the snapshot for: the parameters of
    :data:`REPRESENTATION_SENSOR` in the sensor files (default graph: ``sensors/``), so the
    description sensors and the matchers share one representation of ``Range_Points``.

    Raises:
        SpecError: the sensor has no ``table_z_m`` parameter (a sensor calibration value).
    """
    from mks_sim.errors import SpecError

    graph = graph if graph is not None else _default_graph()
    spec = graph.sensor(REPRESENTATION_SENSOR)
    params = spec.params
    if not isinstance(params.get("table_z_m"), int | float):
        raise SpecError(
            f"sensor {REPRESENTATION_SENSOR}: field 'params.table_z_m': expected the nominal "
            f"table height (metres), got {params.get('table_z_m')!r}"
        )
    return RepresentationConfig(
        table_z_m=float(params["table_z_m"]),
        table_margin_m=float(params.get("table_margin_m", 0.002)),
        gap_m=float(params.get("gap_m", 0.012)),
        m=int(params.get("m", 12)),
    )


def table_z_m(graph: SensorGraph | None = None) -> float:
    """The nominal table height (metres): a sensor calibration parameter, ``table_z_m`` of
    :data:`REPRESENTATION_SENSOR` (``sensors/points.toml``)."""
    z = workstation_representation(graph).table_z_m
    assert z is not None  # checked by workstation_representation
    return z


@dataclass(frozen=True, eq=False)
class WorkstationLocalization:
    """Result of :func:`localize_object`.

    Attributes:
        object: ``cube`` | ``sphere`` | ``part``.
        found: a candidate passed verification.
        object_to_world: (4, 4) column-convention pose of the object's body frame in the world
            frame (metres), or None when not found.
        hypotheses: verified candidates, best first (``matrix`` model -> world).
        provenance: logical sensor -> the way that served it (``"primary"`` or an alternate's
            name, e.g. ``{"Range_Points": "Stereo_Points"}``).
        time_s: wall-clock seconds of the whole flow (sensing included).
        diagnostics: model name and source, sensors run, point counts, per-stage seconds,
            candidate checks.
    """

    object: str
    found: bool
    object_to_world: FloatArray | None
    hypotheses: tuple[PoseHypothesis, ...]
    provenance: dict[str, str]
    time_s: float
    diagnostics: dict[str, Any] = field(default_factory=dict)

    @property
    def matrix(self) -> FloatArray | None:
        """Alias of :attr:`object_to_world`."""
        return self.object_to_world


# --------------------------------------------------------------------------- resources


@functools.lru_cache(maxsize=1)
def _default_graph() -> SensorGraph:
    from mks_sim.sensing import SensorGraph

    return SensorGraph.from_dir()


@functools.lru_cache(maxsize=1)
def _default_db() -> ModelDatabase:
    from mks_sim.models.database import ModelDatabase

    return ModelDatabase.from_dir()


_SURFACES: dict[int, tuple[Any, Any]] = {}


def _surface_model(name: str, mesh: Any) -> Any:
    """The polyhedral model (surface samples, corners, faces) of an object's mesh, built once
    per mesh."""
    from mks_sim.localize import PolyhedralModel

    hit = _SURFACES.get(id(mesh))
    if hit is None or hit[0] is not mesh:
        hit = (mesh, PolyhedralModel.from_mesh(mesh, name))
        _SURFACES[id(mesh)] = hit
    return hit[1]


def _resolve_model(
    obj: str, db: ModelDatabase | None, models: Sequence[str | Path] = ()
) -> tuple[str, Any, str, str, Any]:
    """(model name, localizable model, its logical sensor, source, database entry or None).

    The object comes from the model database (``mks_sim.models.objects.load_object``): its
    default localization KIND picks the pipeline (``sphere``: the sphere model of its radius;
    otherwise the polyhedral surface of its mesh), its ``sensor`` the logical sensor; a
    ``rotinv`` model it names (the cube's vertexes, the part's control points) adds the
    rotation-invariant Hough of that sensor's points.

    Raises:
        NotFound: unknown object.
    """
    from mks_sim.models.objects import load_object, object_names

    try:
        spec = load_object(obj, models=models)
    except NotFound:
        raise NotFound(
            f"localize_object: unknown object {obj!r}; expected one of {object_names(models)}"
        ) from None
    if db is None:
        db = _default_db() if not models else _db_for(tuple(str(m) for m in models))
    sensor = spec.sensor
    if spec.kind == "sphere":
        try:
            entry = spec.model("sphere", db=db)
        except NotFound:
            from mks_sim.models.sphere import SphereModel

            r = float(np.max(np.linalg.norm(spec.mesh.vertices, axis=1)))
            entry = SphereModel(f"{spec.name}_sphere", r, 0.004)
        return str(getattr(entry, "name", spec.name)), entry, sensor, "database", entry
    entry = None
    if "rotinv" in spec.models:
        try:
            entry = spec.model("rotinv", db=db)
        except NotFound as exc:
            log.info("object %r: %s", obj, exc)
    name = spec.models.get("rotinv", spec.name)
    return name, _surface_model(name, spec.mesh), sensor, "database + object mesh", entry


@functools.lru_cache(maxsize=4)
def _db_for(models: tuple[str, ...]) -> ModelDatabase:
    from mks_sim.models.database import ModelDatabase
    from mks_sim.models.objects import models_dirs

    return ModelDatabase.from_dirs(models_dirs(models))


# --------------------------------------------------------------------------- the flow


def localize_object(
    world: Any,
    object_name: str,
    devices: Mapping[str, Any],
    *,
    rng: np.random.Generator | None = None,
    graph: SensorGraph | None = None,
    db: ModelDatabase | None = None,
    models: Sequence[str | Path] = (),
) -> WorkstationLocalization:
    """Localize one object from the devices' readings (paper section 4, steps 1-7).

    Args:
        world: the simulated world (unused by the flow itself: sensing goes through
            ``devices``; kept so the signature matches the grasp episode's ``localize_fn``).
        object_name: an object of the model database (``cube``, ``sphere``, ``part``, ...).
        devices: device name -> device (``mks_sim.devices.make_devices``); failed or missing
            devices are replaced by the logical sensors' alternates.
        rng: generator for RANSAC and subsampling (default seeded 0).
        graph: the logical sensors (default ``SensorGraph.from_dir()``).
        db: the model database (default ``ModelDatabase.from_dir()``).
        models: extra model-database folders (``--models``; objects and models).

    Returns:
        :class:`WorkstationLocalization` (``found`` False when no candidate passes).

    Raises:
        NotFound: unknown object name.
        SensorFailure: the points sensor and all its alternates failed.
    """
    del world  # sensing goes through the devices only; never ground truth
    t0 = time.perf_counter()
    rng = np.random.default_rng(0) if rng is None else rng
    graph = graph if graph is not None else _default_graph()
    timing: dict[str, float] = {}

    # 1. the model from the database; it names its logical sensor
    t = time.perf_counter()
    model_name, model, sensor, source, entry = _resolve_model(object_name, db, models)
    timing["model"] = time.perf_counter() - t
    diag: dict[str, Any] = {"model": model_name, "model_source": source, "sensor": sensor}

    # 2. activate only the logical sensors the model needs
    t = time.perf_counter()
    snap = graph.snapshot(devices)
    try:
        diag["sensors_required"] = sorted(graph.required([sensor]))
    except MksError:
        diag["sensors_required"] = [sensor]
    stream = snap.get(POINTS_SENSOR)
    timing["sensing"] = time.perf_counter() - t
    diag["points"] = len(stream.data)
    if len(stream.data) < 50:
        raise SensorFailure(POINTS_SENSOR, f"expected >= 50 points, got {len(stream.data)}")
    t_proc = time.perf_counter()
    # 3. the snapshot's one low-level representation (shared with the description sensors)
    t = time.perf_counter()
    rep = snap.representation(POINTS_SENSOR, workstation_representation(graph))
    rep.segmentation  # noqa: B018 - normals, curvature and regions, once
    timing["representation"] = time.perf_counter() - t
    points = rep.points
    diag["representation_points"] = len(points)

    kind = model_kind(model)
    diag["kind"] = kind
    if kind == "sphere":
        hyps, extra = _localize_sphere(model, snap, sensor, rep, rng, timing)
    else:
        hyps, extra = _localize_polyhedral(model, entry, snap, sensor, rep, rng, timing)
    timing["processing"] = time.perf_counter() - t_proc
    diag.update(extra)
    diag["timing"] = timing
    provenance = dict(snap.provenance)
    found = bool(hyps)
    T = np.asarray(hyps[0].matrix, dtype=np.float64) if found else None
    total = time.perf_counter() - t0
    timing["total"] = total
    log.info(
        "localize_object(%s): found=%s via %s in %.2f s (%s)",
        object_name,
        found,
        provenance.get(POINTS_SENSOR, "?"),
        total,
        model_name,
    )
    return WorkstationLocalization(
        object=object_name,
        found=found,
        object_to_world=T,
        hypotheses=tuple(hyps),
        provenance=provenance,
        time_s=total,
        diagnostics=diag,
    )


#: Alias used by the grasp episode (``mks_sim.tasks.episode.sensor_localize_fn``).
localize = localize_object


def _noise_scale(table: Plane | None, spacing: float) -> float:
    """Inlier distance for consistency checks: 3 sigma of the table's RANSAC inliers, >= 3 mm."""
    if table is not None and table.rmse > 0:
        return float(max(0.003, 3.0 * table.rmse))
    return float(max(0.003, 1.5 * spacing))


def find_table(points: FloatArray, rng: np.random.Generator) -> tuple[Plane | None, float]:
    """The supporting plane near the nominal table height and its band half-width (the one
    table finder, :func:`mks_sim.localization.verify.find_table`)."""
    from mks_sim.localization.verify import find_table as _find

    plane, thr, _ = _find(points, rng, spacing=0.0, noise=0.0, near_z=table_z_m())
    return plane, thr


def _set_aside_spheres(
    rep: Representation, snap: Any, d0: float, extra: dict[str, Any]
) -> NDArray[np.bool_]:
    """(K,) mask over ``rep.objects``: False on the shells of spheres found by the
    Sphere_Detector (3 cm-ish radii) and of the database's spheres the detector missed
    (fixed-radius centre Hough + fit + cap check)."""
    objects = rep.objects
    keep = np.ones(len(objects), dtype=bool)
    try:
        spheres = np.asarray(snap.get(SPHERE_SENSOR).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("%s unavailable: %s", SPHERE_SENSOR, exc)
        spheres = np.zeros((0, 4))
    band = max(rep.table_threshold, 0.003) + 0.001
    n = 0
    for s in spheres:
        if MIN_EXPLAINED_SPHERE_M <= s[3] <= MAX_EXPLAINED_SPHERE_M:
            keep &= np.abs(np.linalg.norm(objects - s[:3], axis=1) - s[3]) > band
            n += 1
    normals = rep.normals.normals
    for radius in _known_sphere_radii():
        sub = np.flatnonzero(keep)
        seeds = sphere_centre_hough(objects[sub], radius, normals[sub])
        found = [h for _, h, chk in score_spheres(objects[sub], seeds, radius, d0) if chk["ok"]]
        for h in found:
            shell = np.abs(np.linalg.norm(objects - h.matrix[:3, 3], axis=1) - radius)
            keep &= shell > d0 + 0.001
        n += len(found)
    extra["spheres_set_aside"] = n
    return keep


def _localize_polyhedral(
    model: Any,
    entry: Any,
    snap: Any,
    sensor: str,
    rep: Representation,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    from mks_sim.localization.pipeline import object_segments, polyhedral_candidates

    extra: dict[str, Any] = {}
    points = rep.points
    table = rep.table
    extra["table_z_m"] = None if table is None else float(table.offset / table.normal[2])
    d = _noise_scale(table, rep.spacing)
    # Curved objects explained by the sphere detector (the Surface_Curvature grouping of
    # Table 4-6) are set aside: a sphere resting on the cube would otherwise share its SPG
    # component and crowd the vertex matcher with facets of the sphere.
    t = time.perf_counter()
    keep = _set_aside_spheres(rep, snap, d, extra)
    objects = rep.objects[keep]
    extra["object_points"] = len(objects)
    if len(objects) < 30:
        timing["hypotheses"] = time.perf_counter() - t
        return [], extra
    surface = model.surface
    segments = object_segments(rep, surface.size, keep=keep)
    timing["hypotheses"] = time.perf_counter() - t
    timing["verification"] = 0.0
    candidates, _ = polyhedral_candidates(model, rep, segments, rng=rng, timing=timing)
    extra["segments"] = [len(s.indices) for s in segments]
    extra["candidates"] = len(candidates)

    # the model's own logical sensor (vertexes / control points): support of the estimate
    t = time.perf_counter()
    detected: FloatArray | None = None
    try:
        detected = np.asarray(snap.get(sensor).data, dtype=np.float64)[:, :3]
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
    extra["detected_features"] = 0 if detected is None else len(detected)
    surface_pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface_nrm = np.asarray(model.surface_normals(), dtype=np.float64)
    # 5'. the model's own matcher on its logical sensor: the rotation-invariant Hough of the
    # detected vertexes / control points (section 2.2.1), refined by ICP on the points
    if detected is not None and len(detected) >= 3 and callable(getattr(entry, "detect", None)):
        try:
            coarse = list(entry.detect(detected))[:10]
        except MksError as exc:
            log.info("%s: rotation-invariant Hough gave nothing: %s", sensor, exc)
            coarse = []
        extra["rotinv_maxima"] = len(coarse)
        timing["hypotheses"] += time.perf_counter() - t
        t = time.perf_counter()
        refined = _refine_near(_best_coarse(coarse, model, objects, d, 2), model, objects, d, rng)
        extra["rotinv_refined"] = len(refined)
        candidates += refined
        timing["verification"] += time.perf_counter() - t
    else:
        timing["hypotheses"] += time.perf_counter() - t

    # 6. scene consistency of the best candidates over the whole cloud
    t = time.perf_counter()
    top = _top(candidates, 5)
    candidates = [candidates[i] for i in top]
    checks = [
        consistency(h.matrix, surface_pts, surface_nrm, points, table, d, rep.tree)
        for h in candidates
    ]
    order, good = rank(candidates, checks)
    timing["verification"] += time.perf_counter() - t
    extra["inlier_distance_m"] = d
    unexplained: list[Any] = []
    if table is not None and _best_covers_little(candidates, checks, order, model, objects, d):
        # support segments as the sensors separate objects: SPG components over 12 mm edges
        wide = object_segments(rep, surface.size, keep=keep, gap=rep.gap, merge=False)
        unexplained = _unexplained_segments(wide, candidates, checks, model, d)
    if table is not None and unexplained:
        # The object rests on the table: hypotheses from every support face of the model put
        # on the sensed table plane (yaw from the footprint's principal axes and 8 fixed
        # yaws), pre-scored in a batch, the best refined by ICP and checked like the others.
        t = time.perf_counter()
        support = support_face_hypotheses(
            model, unexplained, table, rep.table_threshold, d, rng, timing
        )
        t2 = time.perf_counter()
        checks2 = [
            consistency(h.matrix, surface_pts, surface_nrm, points, table, d, rep.tree)
            for h in support
        ]
        candidates += support
        checks += checks2
        order, good = rank(candidates, checks)
        timing["verification"] += time.perf_counter() - t2
        extra["support_fallback"] = {
            "candidates": len(support),
            "ok": int(sum(c.ok for c in checks2)),
            "seconds": time.perf_counter() - t,
        }
    # Polish: the best-ranked candidate (the two best when it failed the check) gets a full
    # ICP on the points near it and is checked again (coarse starts stop short).
    t = time.perf_counter()
    n_polish = 1 if order and checks[order[0]].ok else 2
    polished = _refine_near([candidates[i] for i in order[:n_polish]], model, objects, d, rng)
    if polished:
        checks3 = [
            consistency(h.matrix, surface_pts, surface_nrm, points, table, d, rep.tree)
            for h in polished
        ]
        candidates += polished
        checks += checks3
        order, good = rank(candidates, checks)
    timing["verification"] += time.perf_counter() - t
    extra["checks"] = [checks[i].as_dict() for i in order[:5]]
    if good and detected is not None and len(detected):
        T = np.asarray(good[0].matrix)
        model_feats = getattr(model, "vertexes", None)
        if model_feats is not None:
            mv = np.asarray(model_feats) @ T[:3, :3].T + T[:3, 3]
            dist = cKDTree(detected).query(mv)[0]
            extra["feature_support"] = int((dist < 4 * d).sum())
    return good, extra


def _top(candidates: list[PoseHypothesis], n: int) -> list[int]:
    """Indices of the ``n`` best-scored candidates (nan last), in that order."""
    return sorted(range(len(candidates)), key=lambda i: -np.nan_to_num(candidates[i].score))[:n]


def _best_coarse(
    hyps: list[PoseHypothesis], model: Any, objects: FloatArray, d: float, n: int
) -> list[PoseHypothesis]:
    """The ``n`` coarse poses explaining the most object points (one batch query)."""
    from mks_sim.localization.verify import batch_explained

    if len(hyps) <= n or len(objects) == 0:
        return hyps
    good = [h for h in hyps if np.asarray(h.matrix).shape == (4, 4)]
    if len(good) <= n:
        return good
    # fraction of the model samples near object points (the scene holds other objects too)
    tree = cKDTree(objects)
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    pts = pts[:: max(1, len(pts) // 300)]
    score = batch_explained(pts, np.stack([h.matrix for h in good]), tree, 2 * d)
    return [good[i] for i in np.argsort(-score, kind="stable")[:n]]


@functools.lru_cache(maxsize=1)
def _known_sphere_radii() -> tuple[float, ...]:
    """Radii of the database's sphere models (metres)."""
    try:
        db = _default_db()
    except MksError:
        return ()
    radii = []
    for name in db.names():
        r = getattr(db.get(name), "radius_m", None)
        if isinstance(r, float) and r > 0:
            radii.append(r)
    return tuple(sorted(set(radii)))


def _best_covers_little(
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    order: list[int],
    model: Any,
    objects: FloatArray,
    d: float,
) -> bool:
    """No consistent candidate, or the best shows less of the model's surface than one view
    does (:data:`mks_sim.localize.VISIBLE_FRACTION` of its samples with an object point
    nearby; a fraction of the model's fixed sampling, independent of the scan density): the
    object may be another, partly hidden segment."""
    from mks_sim.localization.verify import surface_coverage
    from mks_sim.localize import VISIBLE_FRACTION

    if not order or not checks[order[0]].ok or len(objects) == 0:
        return True
    T = np.asarray(candidates[order[0]].matrix, dtype=np.float64)
    cover = surface_coverage(model.surface_points(), T[None], cKDTree(objects), d)
    return bool(cover[0] < VISIBLE_FRACTION)


def _unexplained_segments(
    segments: list[Any],
    candidates: list[PoseHypothesis],
    checks: list[Consistency],
    model: Any,
    d: float,
) -> list[Any]:
    """The object segments that no consistent candidate explains (less than
    :data:`SUPPORT_EXPLAINED_FRACTION` of their points within ``d`` of one of the posed
    models): they get the support-face hypotheses (an object seen only partly, e.g. under
    the sphere, gives no vertexes). A fraction, not a point count: independent of density."""
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    posed = [
        pts @ np.asarray(h.matrix)[:3, :3].T + np.asarray(h.matrix)[:3, 3]
        for h, c in zip(candidates, checks)
        if c.ok
    ]
    trees = [cKDTree(P) for P in posed]
    out = []
    for seg in segments:
        covered = np.zeros(len(seg.points), dtype=bool)
        for tree in trees:
            covered |= np.isfinite(tree.query(seg.points, distance_upper_bound=d)[0])
        if covered.mean() < SUPPORT_EXPLAINED_FRACTION:
            out.append(seg)
    return out


def _refine_near(
    hyps: list[PoseHypothesis], model: Any, objects: FloatArray, d: float, rng: np.random.Generator
) -> list[PoseHypothesis]:
    """ICP-refine coarse poses on the object points near each (model -> world)."""
    from mks_sim.models.refine import ModelSurface, verify_hypotheses

    if not hyps or len(objects) < 10:
        return []
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface = getattr(model, "surface", None)
    if not isinstance(surface, ModelSurface) or surface.points is not pts:
        surface = ModelSurface.from_arrays(pts, model.surface_normals())
    centre = pts.mean(axis=0)
    radius = float(np.max(np.linalg.norm(pts - centre, axis=1)))
    out: list[PoseHypothesis] = []
    for h in hyps:
        T = np.asarray(h.matrix, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            continue
        c = T[:3, :3] @ centre + T[:3, 3]
        near = objects[np.linalg.norm(objects - c, axis=1) <= radius + 2 * d]
        if len(near) < 10:
            continue
        verified = verify_hypotheses(
            [h],
            surface,
            near,
            inlier_distance=d,
            icp_distance=max(4 * d, 0.1 * surface.size),
            symmetries=model.symmetries(),
            max_icp=1,
            max_scene_points=1000,
            rng=rng,
        )
        out.extend(v.hypothesis for v in verified)
    return out


def _localize_sphere(
    model: Any,
    snap: Any,
    sensor: str,
    rep: Representation,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    """Sphere: Sphere_Detector rows of the model's radius plus a fixed-radius centre Hough
    (votes ``p - r n``), each refined by a fixed-radius robust fit and scored by how much of
    the sphere's upper cap the sensed points cover."""
    del rng
    extra: dict[str, Any] = {}
    t = time.perf_counter()
    try:
        rows = np.asarray(snap.get(sensor).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
        rows = np.zeros((0, 4))
    extra["detected_features"] = len(rows)
    radius = float(model.radius_m)
    match = model.match(rows) if hasattr(model, "match") else np.arange(len(rows))
    extra["matched"] = len(match)
    objects = rep.objects
    d = _noise_scale(rep.table, rep.spacing)
    seeds = [rows[i, :3] for i in match]
    seeds += sphere_centre_hough(objects, radius, rep.normals.normals)
    timing["hypotheses"] = time.perf_counter() - t
    extra["candidates"] = len(seeds)

    t = time.perf_counter()
    scored = score_spheres(objects, seeds, radius, d)
    scored.sort(key=lambda x: (not x[2]["ok"], -x[0], x[1].rmse))
    extra["inlier_distance_m"] = d
    extra["checks"] = [chk for _, _, chk in scored[:5]]
    good: list[PoseHypothesis] = []
    for _, h, chk in scored:
        if chk["ok"] and all(np.linalg.norm(h.matrix[:3, 3] - g.matrix[:3, 3]) > d for g in good):
            good.append(h)
    timing["verification"] = time.perf_counter() - t
    return good, extra
