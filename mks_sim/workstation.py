"""Localization at the workstation, end to end from simulated sensors (paper section 4).

:func:`localize_object` runs the paper's execution flow (section 4, steps 1-7) for one object:

1. **Invoke the model.** The object's model comes from the model database
   (``tasks/models/*.toml``: ``cube`` -> ``cube_5cm``, ``sphere`` -> ``sphere_3cm``,
   ``part`` -> ``part``); the model names its logical sensor.
2. **Activate the logical sensors it needs** through a :class:`~mks_sim.sensing.SensorGraph`
   snapshot on the devices: only the model's sensor and its inputs
   (``graph.required([sensor])``) run; a failed device is replaced by the sensor's alternate
   (``Range_Points`` served by ``Stereo_Points`` when the range finder fails), which the
   snapshot's provenance reports. Ground truth is never read.
3. **k-d tree and SPG** of the 3-D points (``Range_Points``); the supporting table plane is
   found by RANSAC and removed, the rest splits into objects by SPG connectivity.
4. **Grouping**: normals, planar regions, vertexes (the table is the face an object rests on);
   curved regions and their sphere fits for the sphere (``Sphere_Detector``).
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
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError, MksError, NotFound, SensorFailure
from mks_sim.models.pose import PoseHypothesis

if TYPE_CHECKING:
    from mks_sim.lowlevel.grouping import Plane
    from mks_sim.models.database import ModelDatabase
    from mks_sim.sensing import SensorGraph

__all__ = [
    "OBJECT_MODELS",
    "OBJECT_SCENES",
    "WorkstationLocalization",
    "localize",
    "localize_object",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: object name -> model-database name.
OBJECT_MODELS: dict[str, str] = {"cube": "cube_5cm", "sphere": "sphere_3cm", "part": "part"}
#: object name -> the scene it is localized in (CLI, benchmark).
OBJECT_SCENES: dict[str, str] = {"cube": "scene2", "sphere": "scene2", "part": "part"}
#: The logical sensor a built-in model names (used when the database has no entry yet).
_BUILTIN_SENSORS: dict[str, str] = {
    "cube": "Vertex_Detector",
    "sphere": "Sphere_Detector",
    "part": "Control_Point_Detector",
}
POINTS_SENSOR = "Range_Points"
# A candidate explaining at least this many sensed points (within the inlier distance) makes
# the support-face hypotheses unnecessary (saves ~1-3 s); below it they compete as well.
SUPPORT_SKIP_EXPLAINED = 1000
SPHERE_SENSOR = "Sphere_Detector"
# Spheres of this radius range found by Sphere_Detector are set aside before polyhedral
# matching (the workstation's spheres are 3 cm; larger fits are curved-region artefacts).
MIN_EXPLAINED_SPHERE_M = 0.01
MAX_EXPLAINED_SPHERE_M = 0.05
TABLE_Z_M = 0.75  # nominal table height: a sensor calibration parameter (sensors/points.toml)


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


@functools.lru_cache(maxsize=4)
def _builtin_model(obj: str) -> Any:
    """A built-in polyhedral model in the object's body frame (database entry missing)."""
    from mks_sim.geometry.meshes import box_mesh, industrial_part_mesh
    from mks_sim.localize import PolyhedralModel
    from mks_sim.sim import names

    if obj == "cube":
        return PolyhedralModel.from_mesh(box_mesh(names.CUBE_SIZE_M), "cube_5cm")
    if obj == "part":
        return PolyhedralModel.from_mesh(industrial_part_mesh(), "part")
    from mks_sim.models.sphere import SphereModel

    return SphereModel("sphere_3cm", names.SPHERE_RADIUS_M, 0.004)


@functools.lru_cache(maxsize=8)
def _adapted(obj: str, model_name: str, entry_id: int, entry: Any) -> Any:
    del entry_id
    from mks_sim.localize import adapt_model
    from mks_sim.models.sphere import SphereModel

    if isinstance(entry, SphereModel):
        return entry
    return adapt_model(entry, model_name)


def _resolve_model(obj: str, db: ModelDatabase | None) -> tuple[str, Any, str, str, Any]:
    """(model name, localizable model, its logical sensor, source, database entry or None).

    A database entry that carries only recoverable points (the part's four control points, a
    ``rotinv`` model) names the matcher; the surface for ICP and checks is the object's mesh.
    """
    model_name = OBJECT_MODELS[obj]
    try:
        entry = (db if db is not None else _default_db()).get(model_name)
    except NotFound:
        entry = None
    if entry is None:
        log.info("model %r not in the model database; using the built-in model", model_name)
        return model_name, _builtin_model(obj), _BUILTIN_SENSORS[obj], "builtin", None
    sensor = str(getattr(entry, "sensor", None) or _BUILTIN_SENSORS[obj])
    try:
        model = _adapted(obj, model_name, id(entry), entry)
    except (MksError, TypeError) as exc:
        log.info("model %r: %s; surface from the object's mesh", model_name, exc)
        return model_name, _builtin_model(obj), sensor, "database points + mesh surface", entry
    return model_name, model, sensor, "database", entry


# --------------------------------------------------------------------------- the flow


def localize_object(
    world: Any,
    object_name: str,
    devices: Mapping[str, Any],
    *,
    rng: np.random.Generator | None = None,
    graph: SensorGraph | None = None,
    db: ModelDatabase | None = None,
) -> WorkstationLocalization:
    """Localize one object from the devices' readings (paper section 4, steps 1-7).

    Args:
        world: the simulated world (unused by the flow itself: sensing goes through
            ``devices``; kept so the signature matches the grasp episode's ``localize_fn``).
        object_name: ``cube`` | ``sphere`` | ``part``.
        devices: device name -> device (``mks_sim.devices.make_devices``); failed or missing
            devices are replaced by the logical sensors' alternates.
        rng: generator for RANSAC and subsampling (default seeded 0).
        graph: the logical sensors (default ``SensorGraph.from_dir()``).
        db: the model database (default ``ModelDatabase.from_dir()``).

    Returns:
        :class:`WorkstationLocalization` (``found`` False when no candidate passes).

    Raises:
        NotFound: unknown object name.
        SensorFailure: the points sensor and all its alternates failed.
    """
    del world  # sensing goes through the devices only; never ground truth
    t0 = time.perf_counter()
    if object_name not in OBJECT_MODELS:
        raise NotFound(
            f"localize_object: unknown object {object_name!r}; expected one of "
            f"{sorted(OBJECT_MODELS)}"
        )
    rng = np.random.default_rng(0) if rng is None else rng
    graph = graph if graph is not None else _default_graph()
    timing: dict[str, float] = {}

    # 1. the model from the database; it names its logical sensor
    t = time.perf_counter()
    model_name, model, sensor, source, entry = _resolve_model(object_name, db)
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
    points = np.asarray(stream.data, dtype=np.float64)[:, :3]
    points = points[np.all(np.isfinite(points), axis=1)]
    timing["sensing"] = time.perf_counter() - t
    diag["points"] = len(points)
    if len(points) < 50:
        raise SensorFailure(POINTS_SENSOR, f"expected >= 50 points, got {len(points)}")

    if object_name == "sphere":
        hyps, extra = _localize_sphere(model, snap, sensor, points, rng, timing)
    else:
        hyps, extra = _localize_polyhedral(model, entry, snap, sensor, points, rng, timing)
    diag.update(extra)
    diag["timing"] = timing
    provenance = dict(snap.provenance)
    found = bool(hyps)
    T = np.asarray(hyps[0].matrix, dtype=np.float64) if found else None
    total = time.perf_counter() - t0
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


def _noise_scale(points: FloatArray, table: Plane | None, spacing: float) -> float:
    """Inlier distance for consistency checks: 3 sigma of the table's RANSAC inliers, >= 3 mm."""
    del points
    if table is not None and table.rmse > 0:
        return float(max(0.003, 3.0 * table.rmse))
    return float(max(0.003, 1.5 * spacing))


def find_table(points: FloatArray, rng: np.random.Generator) -> tuple[Plane | None, float]:
    """The supporting plane (normal up, towards the sensors) and its inlier threshold.

    RANSAC near the nominal table height (a sensor calibration parameter); None if no
    horizontal plane holds at least 20 % of the points.
    """
    from mks_sim.lowlevel.grouping import Plane, fit_plane_ransac

    low = points[np.abs(points[:, 2] - TABLE_Z_M) < 0.02]
    if len(low) < max(50, 0.2 * len(points)):
        return None, 0.0
    plane, inl = fit_plane_ransac(low, 0.003, rng, iterations=100)
    if plane.normal[2] < 0:
        plane = plane.flipped()
    if plane.normal[2] < 0.95:
        return None, 0.0
    resid = plane.distance(low[inl])
    thr = float(max(0.003, 3.0 * np.sqrt(np.mean(resid**2))))
    return Plane(plane.normal, plane.offset, float(np.sqrt(np.mean(resid**2)))), thr


def _localize_polyhedral(
    model: Any,
    entry: Any,
    snap: Any,
    sensor: str,
    points: FloatArray,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    from mks_sim.localize import localize_cloud

    extra: dict[str, Any] = {}
    # 3. table plane, then the k-d tree / SPG / grouping / matching / ICP of localize_cloud
    t = time.perf_counter()
    table, table_thr = find_table(points, rng)
    if table is not None:
        objects = points[table.distance(points) > table_thr]
    else:
        objects = points
    timing["table"] = time.perf_counter() - t
    extra["table_z_m"] = None if table is None else float(table.offset / table.normal[2])
    # Curved objects explained by the sphere detector (the Surface_Curvature grouping of
    # Table 4-6) are set aside: a sphere resting on the cube would otherwise share its SPG
    # component and crowd the vertex matcher with facets of the sphere.
    try:
        spheres = np.asarray(snap.get(SPHERE_SENSOR).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("%s unavailable: %s", SPHERE_SENSOR, exc)
        spheres = np.zeros((0, 4))
    keep = np.ones(len(objects), dtype=bool)
    for s in spheres:
        if MIN_EXPLAINED_SPHERE_M <= s[3] <= MAX_EXPLAINED_SPHERE_M:
            shell = np.abs(np.linalg.norm(objects - s[:3], axis=1) - s[3])
            keep &= shell > max(table_thr, 0.003) + 0.001
    extra["spheres_set_aside"] = int(
        np.sum(
            (spheres[:, 3] >= MIN_EXPLAINED_SPHERE_M) & (spheres[:, 3] <= MAX_EXPLAINED_SPHERE_M)
        )
    )
    objects = objects[keep]
    # Spheres of the database's sphere models the detector missed (noisy stereo curvature):
    # fixed-radius centre Hough + fit + cap check, their shells set aside as well.
    t = time.perf_counter()
    d0 = _noise_scale(points, table, 0.0)
    for radius in _known_sphere_radii():
        seeds = _sphere_hough(objects, radius)
        found = [h for _, h, chk in _score_spheres(objects, seeds, radius, d0) if chk["ok"]]
        for h in found:
            shell = np.abs(np.linalg.norm(objects - h.matrix[:3, 3], axis=1) - radius)
            objects = objects[shell > d0 + 0.001]
        extra["spheres_set_aside"] += len(found)
    timing["known_spheres"] = time.perf_counter() - t
    extra["object_points"] = len(objects)
    if len(objects) < 30:
        return [], extra
    kwargs: dict[str, Any] = {
        "table": table if table is not None else "none",
        "max_hypotheses": 30,
        "rng": rng,
    }
    try:
        # min_score 0.5: a segment whose vertex hypotheses explain less than half of it also
        # gets plane-pair hypotheses (few vertexes seen, e.g. noisy stereo points).
        loc = localize_cloud(model, objects, min_score=0.5, **kwargs)
    except DataError as exc:  # degenerate plane pair in the fallback: vertexes only
        log.warning("localize_cloud with plane-pair fallback failed (%s); vertexes only", exc)
        extra["fallback_error"] = str(exc)
        loc = localize_cloud(model, objects, min_score=0.0, **kwargs)
    for k, v in loc.timing.items():
        if k != "total":
            timing[k] = v
    extra["segments"] = [len(s.indices) for s in loc.segments]
    extra["candidates"] = len(loc.hypotheses)

    # the model's own logical sensor (vertexes / control points): support of the estimate
    t = time.perf_counter()
    detected: FloatArray | None = None
    try:
        detected = np.asarray(snap.get(sensor).data, dtype=np.float64)[:, :3]
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
    timing["model_sensor"] = time.perf_counter() - t
    extra["detected_features"] = 0 if detected is None else len(detected)

    d = _noise_scale(points, table, loc.spacing)
    surface_pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface_nrm = np.asarray(model.surface_normals(), dtype=np.float64)
    candidates = list(loc.hypotheses)
    # 5'. the model's own matcher on its logical sensor: the rotation-invariant Hough of the
    # detected vertexes / control points (section 2.2.1), refined by ICP on the points
    t = time.perf_counter()
    if detected is not None and len(detected) >= 3 and callable(getattr(entry, "detect", None)):
        try:
            coarse = list(entry.detect(detected))[:10]
        except MksError as exc:
            log.info("%s: rotation-invariant Hough gave nothing: %s", sensor, exc)
            coarse = []
        extra["rotinv_maxima"] = len(coarse)
        refined = _refine_near(coarse, model, objects, d, rng)
        extra["rotinv_refined"] = len(refined)
        candidates += refined
    timing["rotinv"] = time.perf_counter() - t

    # 6. scene consistency of every candidate over the whole cloud
    t = time.perf_counter()
    checks = [
        _consistency(h.matrix, surface_pts, surface_nrm, points, table, d) for h in candidates
    ]
    timing["consistency"] = time.perf_counter() - t
    order, good = _rank(candidates, checks)
    extra["inlier_distance_m"] = d
    extra["checks"] = [checks[i] for i in order[:5]]
    if table is not None and _wants_support(good, checks, order):
        # The object rests on the table: hypotheses from every support face of the model put
        # on the sensed table plane (yaw from the footprint's principal axes and 8 fixed
        # yaws), refined by ICP and checked like the others; all candidates compete.
        t = time.perf_counter()
        support = _support_hypotheses(model, objects, table, d, rng)
        checks2 = [
            _consistency(h.matrix, surface_pts, surface_nrm, points, table, d) for h in support
        ]
        candidates += support
        checks += checks2
        order, good = _rank(candidates, checks)
        extra["checks"] = [checks[i] for i in order[:5]]
        extra["support_fallback"] = {
            "candidates": len(support),
            "ok": int(sum(c["ok"] for c in checks2)),
        }
        timing["support_fallback"] = time.perf_counter() - t
    # Polish: the best-scored candidates (ICP inlier fraction), passed or not, get a full
    # ICP on the points near them and are checked again (coarse starts stop short).
    t = time.perf_counter()
    top = sorted(range(len(candidates)), key=lambda i: -np.nan_to_num(candidates[i].score))[:6]
    polished = _refine_near([candidates[i] for i in top], model, objects, d, rng)
    if polished:
        checks3 = [
            _consistency(h.matrix, surface_pts, surface_nrm, points, table, d) for h in polished
        ]
        candidates += polished
        checks += checks3
        order, good = _rank(candidates, checks)
        extra["checks"] = [checks[i] for i in order[:5]]
    timing["polish"] = time.perf_counter() - t
    if good and detected is not None and len(detected):
        T = np.asarray(good[0].matrix)
        model_feats = getattr(model, "vertexes", None)
        if model_feats is not None:
            mv = np.asarray(model_feats) @ T[:3, :3].T + T[:3, 3]
            dist = cKDTree(detected).query(mv)[0]
            extra["feature_support"] = int((dist < 4 * d).sum())
    return good, extra


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


def _wants_support(
    good: list[PoseHypothesis], checks: list[dict[str, Any]], order: list[int]
) -> bool:
    """Run the support-face hypotheses unless a candidate passed with a well-explained scene
    (>= 1000 points within the inlier distance: most of a 5 cm object's visible surface)."""
    del good
    if not order or not checks[order[0]]["ok"]:
        return True
    return bool(checks[order[0]]["explained"] < SUPPORT_SKIP_EXPLAINED)


def _refine_near(
    hyps: list[PoseHypothesis], model: Any, objects: FloatArray, d: float, rng: np.random.Generator
) -> list[PoseHypothesis]:
    """ICP-refine coarse poses on the object points near each (model -> world)."""
    from mks_sim.models.refine import ModelSurface, verify_hypotheses

    if not hyps or len(objects) < 10:
        return []
    pts = np.asarray(model.surface_points(), dtype=np.float64)
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
            rng=rng,
        )
        out.extend(v.hypothesis for v in verified)
    return out


def _object_segments(objects: FloatArray, size: float, min_points: int = 60) -> list[FloatArray]:
    """SPG components (edges <= 12 mm) of the points above the table no larger than the model."""
    from mks_sim.lowlevel.spg import SpatialProximityGraph

    if len(objects) < min_points:
        return []
    spg = SpatialProximityGraph(objects, m=8, threshold=0.012)
    n, labels = spg.components()
    counts = np.bincount(labels, minlength=n)
    out = []
    for c in np.argsort(-counts):
        if counts[c] < min_points:
            break
        seg = objects[labels == c]
        xy = seg[:, :2] - seg[:, :2].mean(axis=0)
        if 2.0 * float(np.max(np.linalg.norm(xy, axis=1))) <= 1.3 * size:
            out.append(seg)
    return out


def _principal_angle(xy: FloatArray) -> float:
    c = xy - xy.mean(axis=0)
    w, v = np.linalg.eigh(c.T @ c)
    major = v[:, int(np.argmax(w))]
    return float(np.arctan2(major[1], major[0]))


def _support_hypotheses(
    model: Any, objects: FloatArray, table: Plane, d: float, rng: np.random.Generator
) -> list[PoseHypothesis]:
    """Poses with a support face of the model on the table plane, refined by ICP."""
    from mks_sim.geometry.transforms import make_transform
    from mks_sim.models.refine import ModelSurface, verify_hypotheses

    faces = getattr(model, "faces", ())
    pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface = ModelSurface.from_arrays(pts, model.surface_normals())
    up = table.normal / np.linalg.norm(table.normal)
    out: list[PoseHypothesis] = []
    for seg in _object_segments(objects, surface.size):
        starts: list[PoseHypothesis] = []
        seg_angle = _principal_angle(seg[:, :2])
        for face in faces:
            n = np.asarray(face.normal, dtype=np.float64)
            if np.max(pts @ n) > face.offset + 0.02 * surface.size:
                continue  # not a support face (model points beyond it)
            R0 = _rotation_between(n, -up)
            rotated = pts @ R0.T
            model_angle = _principal_angle(rotated[:, :2])
            yaws = [seg_angle - model_angle + k * np.pi / 2 for k in range(4)]
            yaws += [k * np.pi / 4 for k in range(8)]  # the footprint axis may mislead
            for yaw in yaws:
                Rz = _rotation_about(up, yaw)
                R = Rz @ R0
                moved = pts @ R.T
                t = np.zeros(3)
                t[:2] = seg[:, :2].mean(axis=0) - moved[:, :2].mean(axis=0)
                # the support face on the table plane
                t += up * (table.offset - float(np.min(moved @ up)))
                T = make_transform(R, t)
                starts.append(PoseHypothesis(T, T[:3, 3].copy(), votes=0))
        if not starts:
            continue
        verified = verify_hypotheses(
            starts,
            surface,
            seg,
            inlier_distance=d,
            icp_distance=max(4 * d, 0.15 * surface.size),
            symmetries=model.symmetries(),
            max_icp=len(starts),
            full_refine=6,
            rng=rng,
        )
        out.extend(v.hypothesis for v in verified)
    out.sort(key=lambda h: -h.score)
    return out


def _rotation_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rotation taking unit vector ``a`` to unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-9:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return _rotation_about(axis / np.linalg.norm(axis), np.pi)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _rotation_about(axis: FloatArray, angle: float) -> FloatArray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(axis, dtype=float) * angle).as_matrix()


def _rank(
    candidates: list[PoseHypothesis], checks: list[dict[str, Any]]
) -> tuple[list[int], list[PoseHypothesis]]:
    """Candidate order (consistent first, then most points explained, then score) and the
    consistent candidates in that order."""
    order = sorted(
        range(len(checks)),
        key=lambda i: (not checks[i]["ok"], -checks[i]["explained"], -candidates[i].score),
    )
    return order, [candidates[i] for i in order if checks[i]["ok"]]


def _consistency(
    T: FloatArray,
    surface_pts: FloatArray,
    surface_nrm: FloatArray,
    cloud: FloatArray,
    table: Plane | None,
    d: float,
) -> dict[str, Any]:
    """Does the posed model agree with what the sensors saw?

    Counts, over the sensed points near the posed model: ``explained`` (within ``d`` of its
    surface), ``inside`` (inside the model solid by more than ``d``: the sensor saw through
    the object) and ``below`` (under the model in their vertical column: the overhead and
    oblique sensors could not have seen them). ``penetration``: fraction of the model
    surface below the table plane by more than ``d``.
    """
    R, t = T[:3, :3], T[:3, 3]
    P = surface_pts @ R.T + t
    N = surface_nrm @ R.T
    # Only surface the sensors (all above the table) can see explains a point: a downward
    # face resting on the table would otherwise "explain" the table under a wrong pose.
    seen = N[:, 2] > -0.3
    centre = P.mean(axis=0)
    radius = float(np.max(np.linalg.norm(P - centre, axis=1)))
    near = cloud[np.linalg.norm(cloud - centre, axis=1) <= radius + 2 * d]
    out: dict[str, Any] = {"explained": 0, "inside": 0, "below": 0, "penetration": 0.0}
    if table is not None:
        out["penetration"] = float(np.mean(table.distance(P) < -d))
    if len(near):
        dist, idx = cKDTree(P).query(near)
        dist_seen = cKDTree(P[seen]).query(near)[0] if seen.any() else np.full(len(near), np.inf)
        explained = dist_seen <= d
        sd = np.einsum("ij,ij->i", near - P[idx], N[idx])
        sd[dist <= d] = 0.0  # on the surface (a visible or a resting face): not inside
        inside = (~explained) & (sd < -d)
        # vertical columns: a model surface point within d (xy) above an unexplained point
        rest = np.flatnonzero(~explained & ~inside)
        below = np.zeros(len(near), dtype=bool)
        if len(rest):
            tree2 = cKDTree(P[:, :2])
            # radius d/2 and two model points: sensor noise along the silhouette edges
            # (stereo) does not count, a point well inside the footprint does
            cols = tree2.query_ball_point(near[rest, :2], r=0.5 * d)
            zq = near[rest, 2]
            for j, c in enumerate(cols):
                if len(c) >= 2 and np.sort(P[c, 2])[-2] > zq[j] + 2 * d:
                    below[rest[j]] = True
        out["explained"] = int(explained.sum())
        out["inside"] = int(inside.sum())
        out["below"] = int(below.sum())
    bad = out["inside"] + out["below"]
    out["ok"] = bool(
        out["explained"] >= 30
        and bad <= 0.05 * max(out["explained"], 1)
        and out["penetration"] <= 0.02
    )
    return out


def _localize_sphere(
    model: Any,
    snap: Any,
    sensor: str,
    points: FloatArray,
    rng: np.random.Generator,
    timing: dict[str, float],
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    """Sphere: Sphere_Detector rows of the model's radius plus a fixed-radius centre Hough
    (votes ``p - r n``), each refined by a fixed-radius robust fit and scored by how much of
    the sphere's upper cap the sensed points cover."""
    extra: dict[str, Any] = {}
    t = time.perf_counter()
    try:
        rows = np.asarray(snap.get(sensor).data, dtype=np.float64).reshape(-1, 4)
    except MksError as exc:
        log.info("logical sensor %s unavailable: %s", sensor, exc)
        rows = np.zeros((0, 4))
    timing["model_sensor"] = time.perf_counter() - t
    extra["detected_features"] = len(rows)
    radius = float(model.radius_m)
    match = model.match(rows) if hasattr(model, "match") else np.arange(len(rows))
    extra["matched"] = len(match)

    t = time.perf_counter()
    table, table_thr = find_table(points, rng)
    objects = points if table is None else points[table.distance(points) > table_thr]
    d = _noise_scale(points, table, 0.0)
    seeds = [rows[i, :3] for i in match]
    seeds += _sphere_hough(objects, radius)
    timing["matching"] = time.perf_counter() - t
    extra["candidates"] = len(seeds)

    t = time.perf_counter()
    scored = _score_spheres(objects, seeds, radius, d)
    timing["refinement"] = time.perf_counter() - t
    scored.sort(key=lambda x: (not x[2]["ok"], -x[0], x[1].rmse))
    extra["inlier_distance_m"] = d
    extra["checks"] = [chk for _, _, chk in scored[:5]]
    good: list[PoseHypothesis] = []
    for _, h, chk in scored:
        if chk["ok"] and all(np.linalg.norm(h.matrix[:3, 3] - g.matrix[:3, 3]) > d for g in good):
            good.append(h)
    return good, extra


def _score_spheres(
    objects: FloatArray, seeds: list[FloatArray], radius: float, d: float
) -> list[tuple[float, PoseHypothesis, dict[str, Any]]]:
    """Refine sphere centre seeds (fixed radius) and check each: cap coverage, residual."""
    out: list[tuple[float, PoseHypothesis, dict[str, Any]]] = []
    if len(objects) < 20:
        return out
    tree = cKDTree(objects)
    cap = _fibonacci(400)
    cap = cap[cap[:, 2] > 0.3]
    for c0 in seeds:
        fit = _fit_fixed_sphere(objects, tree, np.asarray(c0, dtype=float), radius, d)
        if fit is None:
            continue
        c, rmse, n_in = fit
        near_d = tree.query(c + radius * cap)[0]
        coverage = float(np.mean(near_d <= d))
        inside = len(tree.query_ball_point(c, r=max(radius - 2 * d, 0.0)))
        check = {
            "coverage": coverage,
            "explained": n_in,
            "inside": inside,
            "rmse_m": rmse,
            # a third of the cap may be hidden (resting on the cube, stereo gaps); fits to
            # other curved surfaces leave larger residuals
            "ok": bool(
                coverage >= 0.4
                and rmse <= 0.05 * radius
                and inside <= 0.05 * max(n_in, 1)
                and n_in >= 30
            ),
        }
        T = np.eye(4)
        T[:3, 3] = c
        h = PoseHypothesis(T, c.copy(), votes=n_in, rmse=rmse, score=coverage)
        out.append((coverage, h, check))
    return out


def _fibonacci(n: int) -> FloatArray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5**0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.c_[r * np.cos(phi), r * np.sin(phi), z]


def _sphere_hough(objects: FloatArray, radius: float, peaks: int = 4) -> list[FloatArray]:
    """Centres voted by ``p - r n`` (normals towards the sensors above), the fullest cells."""
    from mks_sim.lowlevel.grouping import estimate_normals

    if len(objects) < 50:
        return []
    sn = estimate_normals(objects, m=24, viewpoint=(0.0, 0.0, 2.0), curvature_rings=1)
    votes = objects - radius * sn.normals
    cell = radius / 5.0
    keys = np.floor(votes / cell).astype(np.int64)
    uniq, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    out: list[FloatArray] = []
    for k in np.argsort(-counts)[: peaks * 3]:
        if counts[k] < 10 or len(out) >= peaks:
            break
        c = votes[inv == k].mean(axis=0)
        if all(np.linalg.norm(c - o) > radius / 2 for o in out):
            out.append(c)
    return out


def _fit_fixed_sphere(
    objects: FloatArray, tree: cKDTree, c0: FloatArray, radius: float, d: float
) -> tuple[FloatArray, float, int] | None:
    """Centre of a sphere of known radius fitted robustly to the points near ``c0``'s shell."""
    from scipy.optimize import least_squares

    c = c0.copy()
    band = max(3.0 * d, 0.15 * radius)
    for _ in range(4):
        idx = tree.query_ball_point(c, r=radius + band)
        pts = objects[idx]
        if len(pts) < 20:
            return None
        shell = np.abs(np.linalg.norm(pts - c, axis=1) - radius) < band
        pts = pts[shell]
        if len(pts) < 20:
            return None

        def resid(x: FloatArray, p: FloatArray = pts) -> FloatArray:
            return np.linalg.norm(p - x, axis=1) - radius

        res = least_squares(resid, c, loss="soft_l1", f_scale=max(d / 3.0, 1e-4))
        step = float(np.linalg.norm(res.x - c))
        c = res.x
        band = max(1.5 * d, 0.5 * band)
        if step < 1e-5:
            break
    r = np.linalg.norm(objects[tree.query_ball_point(c, r=radius + d)] - c, axis=1) - radius
    inl = np.abs(r) <= d
    if inl.sum() < 20:
        return None
    return c, float(np.sqrt(np.mean(r[inl] ** 2))), int(inl.sum())
