"""Localization at the workstation, end to end from simulated sensors (paper section 4).

:func:`localize_object` runs the paper's execution flow (section 4, steps 1-7) for one object:

1. **Invoke the model.** The object comes from the model database
   (``mks_sim.models.objects.load_object``: mesh, localization kinds, logical sensor); its
   default KIND picks the pipeline (``sphere``; ``freeform``, or a mostly curved mesh, for the
   free-form model it names or one built from its mesh; else the polyhedral surface of its
   mesh, plus the ``rotinv`` model it names: the cube's vertexes, the part's control points).
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
   polyhedral models (cube, industrial part; :mod:`mks_sim.localization.pipeline`); the
   sphere model picks the ``Sphere_Detector`` rows of its radius; a free-form model votes
   with point-pair keypoints on the object points (:func:`localize_freeform`).
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
    >>> from mks_sim.localization.workstation import localize_object
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
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mks_sim.errors import NotFound, SensorFailure, SpecError
from mks_sim.localization.model import PolyhedralModel, db_for, default_db, model_kind
from mks_sim.localization.pipeline import localize_polyhedral, localize_sphere
from mks_sim.localization.representation import RepresentationConfig
from mks_sim.models.pose import PoseHypothesis
from mks_sim.threads import with_one_blas_thread

if TYPE_CHECKING:
    from mks_sim.lowlevel.grouping import Plane
    from mks_sim.models.database import ModelDatabase
    from mks_sim.sensing import SensorGraph

__all__ = [
    "POINTS_SENSOR",
    "REPRESENTATION_SENSOR",
    "WorkstationLocalization",
    "find_table",
    "freeform_model",
    "localize",
    "localize_freeform",
    "localize_object",
    "table_z_m",
    "workstation_representation",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

POINTS_SENSOR = "Range_Points"
#: Fewer points off the table than this: nothing to localize (the polyhedral path's floor).
_MIN_OBJECT_POINTS = 30

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

    graph = graph if graph is not None else _default_graph()
    spec = graph.sensor(REPRESENTATION_SENSOR)
    params = spec.params
    if not isinstance(params.get("table_z_m"), int | float):
        raise SpecError(
            f"sensor {REPRESENTATION_SENSOR}: field 'params.table_z_m': expected the nominal "
            f"table height (metres), got {params.get('table_z_m')!r}"
        )
    from mks_sim.sensing.programs.points import representation_config

    # the description sensors' config (their programs read the same parameters), with the
    # workstation's table margin as default
    return replace(
        representation_config(params),
        table_margin_m=float(params.get("table_margin_m", 0.002)),
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


_SURFACES: dict[int, tuple[Any, Any]] = {}


def _surface_model(name: str, mesh: Any) -> Any:
    """The polyhedral model (surface samples, corners, faces) of an object's mesh, built once
    per mesh, with its surface's nearest-sample grid (built once here: every ICP and score
    of the workstation's localizations looks correspondences up in it)."""
    hit = _SURFACES.get(id(mesh))
    if hit is None or hit[0] is not mesh:
        model = PolyhedralModel.from_mesh(mesh, name)
        _with_lookup(model)
        hit = (mesh, model)
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
        db = default_db() if not models else db_for(tuple(str(m) for m in models))
    sensor = spec.sensor
    if spec.kind == "sphere":
        try:
            entry = spec.model("sphere", db=db)
        except NotFound:
            from mks_sim.models.sphere import SphereModel

            r = float(np.max(np.linalg.norm(spec.mesh.vertices, axis=1)))
            entry = SphereModel(f"{spec.name}_sphere", r, 0.004)
        return str(getattr(entry, "name", spec.name)), entry, sensor, "database", entry
    if _is_freeform(spec):
        name, model = freeform_model(spec, db)
        _with_lookup(model)  # the workstation's localizations only (not the bin's alternates)
        return name, model, spec.sensor, "database", None
    entry = None
    if "rotinv" in spec.models:
        try:
            entry = spec.model("rotinv", db=db)
        except NotFound as exc:
            log.info("object %r: %s", obj, exc)
    name = spec.models.get("rotinv", spec.name)
    return name, _surface_model(name, spec.mesh), sensor, "database + object mesh", entry


_FREEFORM: dict[int, tuple[Any, Any]] = {}


def _with_lookup(model: Any) -> None:
    """Give a long-lived model's surface its nearest-sample grid (once; the database and
    the caches here keep the model for the process)."""
    surface = getattr(model, "surface", None)
    if surface is not None and hasattr(surface, "with_lookup"):
        surface.with_lookup()


def _is_freeform(spec: Any) -> bool:
    """The object is localized by its free-form model: its default kind says so, or it names
    no kind but the polyhedral one while its mesh is mostly curved (``mesh_kind``: the
    decision of ``localize-cloud --kind auto``; a curved mesh has no corners to vote with)."""
    if spec.kind == "freeform":
        return True
    if spec.kind != "polyhedral" or "rotinv" in spec.models:
        return False
    from mks_sim.localization.model import mesh_kind

    return bool(mesh_kind(spec.mesh) == "freeform")


def freeform_model(spec: Any, db: ModelDatabase) -> tuple[str, Any]:
    """(name, the free-form model): the database entry the object names (its tables, built
    by ``objects add``), else one built from its mesh once per mesh."""
    if "freeform" in spec.models:
        try:
            entry = spec.model("freeform", db=db)
            return str(getattr(entry, "name", spec.name)), entry
        except NotFound as exc:
            log.info("object %r: %s; building the free-form model from its mesh", spec.name, exc)
    hit = _FREEFORM.get(id(spec.mesh))
    if hit is None or hit[0] is not spec.mesh:
        from mks_sim.localization.model import model_from_mesh

        hit = (spec.mesh, model_from_mesh(spec.mesh, f"{spec.name}_freeform", "freeform")[0])
        _FREEFORM[id(spec.mesh)] = hit
    return f"{spec.name}_freeform", hit[1]


def localize_freeform(
    model: Any, rep: Any, rng: np.random.Generator, timing: dict[str, float]
) -> tuple[list[PoseHypothesis], dict[str, Any]]:
    """The free-form path over a snapshot's representation: the free-form matcher of
    ``localize-cloud`` (point-pair keypoint votes, ICP, coverage score;
    :func:`~mks_sim.localization.pipeline.localize_cloud`) on the object points, the sensed
    table given, then the scene-consistency check over the whole cloud that the other kinds
    pass (no sensed point inside the posed model or seen through it, no table penetration),
    which vetoes candidates but keeps the matcher's order.

    Args:
        model: a :class:`~mks_sim.models.freeform.FreeformModel` (metres).
        rep: the snapshot's :class:`~mks_sim.localization.representation.Representation`.
        rng: generator (subsampling, RANSAC).
        timing: per-stage seconds, filled in (``hypotheses``, ``verification``).

    Returns:
        (consistent hypotheses best first, diagnostics).
    """
    from mks_sim.localization.pipeline import _noise_scale, localize_cloud
    from mks_sim.localization.verify import consistency

    extra: dict[str, Any] = {}
    table = rep.table
    extra["table_z_m"] = None if table is None else float(table.offset / table.normal[2])
    objects = rep.objects
    extra["object_points"] = len(objects)
    timing.setdefault("hypotheses", 0.0)
    timing.setdefault("verification", 0.0)
    if len(objects) < 30:
        return [], extra
    # the object points only: the table is already found (its plane is passed for the
    # support face), so the cloud matcher neither searches nor segments it again
    loc = localize_cloud(model, objects, table="none" if table is None else table, rng=rng)
    timing["hypotheses"] += loc.timing.get("representation", 0.0) + loc.timing["hypotheses"]
    timing["verification"] += loc.timing["verification"]
    extra["candidates"] = len(loc.hypotheses)
    extra["segments"] = [len(s.indices) for s in loc.segments]
    t = time.perf_counter()
    d = _noise_scale(table, rep.spacing)  # the other kinds' inlier distance
    surface_pts = np.asarray(model.surface_points(), dtype=np.float64)
    surface_nrm = np.asarray(model.surface_normals(), dtype=np.float64)
    candidates = list(loc.hypotheses)
    checks = [
        consistency(h.matrix, surface_pts, surface_nrm, rep.points, table, d)
        for h in candidates
    ]
    # The check vetoes; the matcher's order stands (its score, inlier fraction x residual x
    # coverage, tells a rounded shape from its near-mirror pose where point counts tie: the
    # generated blob, tuning seed 11, 1233 vs 1231 points explained by a pose flipped 178 deg)
    good = [h for h, c in zip(candidates, checks, strict=True) if c.ok]
    timing["verification"] += time.perf_counter() - t
    extra["inlier_distance_m"] = d
    extra["checks"] = [c.as_dict() for c in checks[:5]]
    return good, extra


# --------------------------------------------------------------------------- the flow


@with_one_blas_thread
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
        SpecError: the object's model names a logical sensor the graph does not define
            (before any device is read).
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
    try:  # a model naming a sensor the graph does not know is a bad model, not a fault
        diag["sensors_required"] = sorted(graph.required([sensor]))
    except NotFound:
        raise SpecError(
            f"object {object_name!r}: its model names logical sensor {sensor!r}, "
            f"which the sensor graph does not define"
        ) from None

    # 2. activate only the logical sensors the model needs
    t = time.perf_counter()
    snap = graph.snapshot(devices)
    stream = snap.get(POINTS_SENSOR)
    timing["sensing"] = time.perf_counter() - t
    diag["points"] = len(stream.data)
    if len(stream.data) < 50:
        raise SensorFailure(POINTS_SENSOR, f"expected >= 50 points, got {len(stream.data)}")
    t_proc = time.perf_counter()
    # 3. the snapshot's one low-level representation (shared with the description sensors)
    t = time.perf_counter()
    rep = snap.representation(POINTS_SENSOR, workstation_representation(graph))
    # nothing on the table (an episode's check after the object was lifted out of view):
    # not found, rather than a segmentation of no points
    empty = len(rep.objects) < _MIN_OBJECT_POINTS
    if not empty:
        rep.segmentation  # noqa: B018 - normals, curvature and regions, once
    timing["representation"] = time.perf_counter() - t
    points = rep.points
    diag["representation_points"] = len(points)

    kind = model_kind(model)
    diag["kind"] = kind
    hyps: list[PoseHypothesis]
    extra: dict[str, Any]
    if empty:
        hyps, extra = [], {"object_points": len(rep.objects)}
    elif kind == "sphere":
        hyps, extra = localize_sphere(model, snap, sensor, rep, rng, timing)
    elif kind == "freeform":
        hyps, extra = localize_freeform(model, rep, rng, timing)
    else:
        views = snap.origins(POINTS_SENSOR)
        diag["viewpoints"] = len(views)
        hyps, extra = localize_polyhedral(model, entry, snap, sensor, rep, rng, timing, views)
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


def find_table(points: FloatArray, rng: np.random.Generator) -> tuple[Plane | None, float]:
    """The supporting plane near the nominal table height and its band half-width (the one
    table finder, :func:`mks_sim.localization.verify.find_table`)."""
    from mks_sim.localization.verify import find_table as _find

    plane, thr, _ = _find(points, rng, spacing=0.0, noise=0.0, near_z=table_z_m())
    return plane, thr
