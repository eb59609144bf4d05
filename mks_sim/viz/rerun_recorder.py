"""The Rerun recorder: every stage of a run as entities on a timeline of simulated time.

Imported only when ``--rerun`` is given (:func:`mks_sim.viz.spec.open_recorder`). Entity paths
and their meaning: ``docs/visualization.md``. Timelines: ``sim_time`` (simulated seconds),
``episode`` (the grasp episode's seed) and ``attempt`` (grasp attempt, 1-based).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
import rerun as rr

from mks_sim import workstation
from mks_sim.cli.snapshot import disparity
from mks_sim.devices.camera import Camera
from mks_sim.errors import MksError
from mks_sim.sensing import SensorGraph
from mks_sim.sim import names
from mks_sim.viz.recorder import DeviceTap, GraphTap, as_matrix
from mks_sim.viz.scene import (
    body_to_world,
    flat_name,
    geom_meshes,
    grasp_point,
    grasp_quality,
    object_mesh,
    rebuilt_grouping,
    transform_segments,
    undirected_edges,
    wireframe,
)
from mks_sim.viz.spec import RerunSpec
from mks_sim.viz.viewer import listening, viewer_on_path

__all__ = ["RerunRecorder"]

log = logging.getLogger(__name__)

# One colour per range-finder view / device, and for the marks drawn over the scene.
_PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [148, 103, 189], [140, 86, 75]], np.uint8
)
_SELF_HIT = (214, 39, 40)
_PLANAR = (31, 119, 180)
_CURVED = (214, 39, 40)
_CHOSEN = (0, 200, 0)
_TRUTH = (255, 215, 0)
_HYPOTHESIS = (150, 150, 150)
# Re-sensing every 0.2 s during an approach would store every scan, stream and SPG (~1.5 MB
# per snapshot): point clouds are drawn at most this often (simulated seconds), and for the
# first snapshot of every episode / attempt, unless the spec says ",all".
CLOUD_PERIOD_S = 1.0
# Self-hit rays have no range (the device reports none): drawn this long from the mount.
_SELF_HIT_RAY_M = 0.1
SPAWN_PORT = 9876  # Rerun's default viewer port
VIEWER_WAIT_S = 8.0  # a spawned viewer binds its port within ~1-3 s
CONNECT_WAIT_S = 1.0  # a viewer connected to is running already
VIEWER_FLUSH_S = 30.0
_LEVELS = {"INFO": rr.TextLogLevel.INFO, "WARN": rr.TextLogLevel.WARN,
           "ERROR": rr.TextLogLevel.ERROR}  # fmt: skip


def _no_viewer(spec: RerunSpec, url: str) -> str:
    """The one-line error for a viewer that is not there (spawned or connected to)."""
    why = "the viewer did not start (no display?)" if spec.mode == "spawn" else (
        "no Rerun viewer listens there")  # fmt: skip
    return (
        f"--rerun {spec.mode}: {why} at {url}; record to a file instead with "
        "--rerun save:PATH.rrd and open it with `rerun PATH.rrd`"
    )


class RerunRecorder:
    """A :class:`~mks_sim.viz.recorder.Recorder` writing to Rerun.

    Args:
        spec: where the recording goes (save / spawn / connect).
        application_id: the Rerun application id (the command's name).
    """

    enabled = True

    def __init__(self, spec: RerunSpec, application_id: str = "mks_sim") -> None:
        self.spec = spec
        if spec.mode == "connect" and not listening(str(spec.target), CONNECT_WAIT_S):
            # before the stream connects: a gRPC sink to nobody blocked 5 s connecting and
            # 5 s more on disconnect, and logged its errors on the way out
            raise MksError(_no_viewer(spec, str(spec.target)))
        self.rec = rr.RecordingStream(application_id)
        try:
            if spec.mode == "save":
                self.rec.save(str(spec.target))
            elif spec.mode == "spawn":
                viewer_on_path()
                self.rec.spawn(port=SPAWN_PORT)
            else:
                self.rec.connect_grpc(str(spec.target))
        except Exception as exc:  # rerun raises its own (RuntimeError, OSError, ...) types
            msg = " ".join(str(exc).split())  # one line
            raise MksError(f"--rerun {spec.mode}: cannot open the recording: {msg}") from exc
        # A viewer that is not there would make the run hang at the end, flushing to nobody:
        # fail now, before any work.
        if spec.mode == "spawn":
            url = f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"
            if not listening(url, VIEWER_WAIT_S):
                self.rec.disconnect()
                raise MksError(_no_viewer(spec, url))
        self._snapshots: list[Any] = []
        self._robot: list[Any] = []
        self._robot_joints: list[str] = []
        self._robot_bodies: list[tuple[str, int]] = []
        self._time = 0.0  # the world's simulated time (MjData.time)
        self._offset = 0.0  # where the current episode starts on the sim_time timeline
        self._end = 0.0  # the latest sim_time logged
        self._episode: int | None = None
        self._world: Any = None
        self._devices: dict[str, DeviceTap] = {}
        self._read: set[str] = set()
        self._stereo: dict[str, Any] = {}
        self._last_cloud: dict[str, float] = {}
        self.rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)

    # ------------------------------------------------------------------ timelines

    def set_time(self, sim_time_s: float) -> None:
        self._time = float(sim_time_s)
        t = self._offset + self._time
        self._end = max(self._end, t)
        self.rec.set_time("sim_time", duration=t)

    def set_episode(self, episode: int | None, attempt: int | None = None) -> None:
        self._last_cloud.clear()
        if episode is not None:
            if episode != self._episode:  # episodes follow one another on sim_time
                self._offset, self._episode = self._end, episode
            self.rec.set_time("episode", sequence=int(episode))
        if attempt is not None:
            self.rec.set_time("attempt", sequence=int(attempt))

    def _sync_time(self, world: Any) -> None:
        data = getattr(world, "data", None)
        if data is not None:
            self.set_time(float(data.time))

    # ------------------------------------------------------------------ taps

    def tap_devices(self, devices: Mapping[str, Any]) -> Mapping[str, Any]:
        # A device tapped already (the demo taps, then hands the devices to an episode that
        # taps again) is kept as it is: each reading is logged once.
        self._devices = {
            name: dev if isinstance(dev, DeviceTap) else DeviceTap(dev, name, self.log_reading)
            for name, dev in devices.items()
        }
        return self._devices

    def log_camera_views(self) -> None:
        """Read and log every tapped camera not read yet (context views after a
        localization; cameras only, so no later reading of another device changes)."""
        for name, dev in self._devices.items():
            if name not in self._read and isinstance(dev.device, Camera):
                try:
                    dev.read()
                except MksError as exc:
                    self.log_text(f"{name}: {exc}", "WARN")

    def tap_graph(self, graph: Any) -> Any:
        if graph is None:
            graph = SensorGraph.from_dir()
        return GraphTap(graph, self._snapshots)

    # ------------------------------------------------------------------ devices

    def log_reading(self, device: str, reading: Any) -> None:
        """One device reading: camera frame, range scans or a touch pad."""
        self._read.add(device)
        if self._world is not None:
            self._sync_time(self._world)
        if hasattr(reading, "rgb"):
            self._log_camera(device, reading)
        elif hasattr(reading, "pressure"):
            self._log_touch(device, reading)
        elif isinstance(reading, (list, tuple)) and reading and hasattr(reading[0], "self_hit"):
            self._log_scans(device, reading)

    def _log_camera(self, device: str, frame: Any) -> None:
        base = f"world/cameras/{device}"
        T = np.asarray(frame.camera_to_world, dtype=float)
        h, w = frame.shape
        self.rec.log(base, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log(
            base,
            rr.Pinhole(image_from_camera=np.asarray(frame.K), resolution=[w, h],
                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.1),
        )  # fmt: skip
        self.rec.log(f"{base}/rgb", rr.Image(np.ascontiguousarray(frame.rgb)))
        if frame.depth is not None:
            depth = np.nan_to_num(np.asarray(frame.depth, dtype=np.float32), nan=0.0)
            self.rec.log(f"{base}/depth", rr.DepthImage(depth, meter=1.0))
        if device in (names.STEREO_LEFT, names.STEREO_RIGHT):
            self._stereo[device] = frame
            if len(self._stereo) == 2:
                pair, self._stereo = self._stereo, {}
                try:
                    d = disparity(pair[names.STEREO_LEFT], pair[names.STEREO_RIGHT])
                except (MksError, ValueError, cv2.error) as exc:
                    log.debug("disparity: %s", exc)
                    return
                self.rec.log("stereo/disparity", rr.DepthImage(np.nan_to_num(d, nan=0.0),
                                                               meter=1.0))  # fmt: skip

    def _due(self, kind: str) -> bool:
        """True when a point cloud of ``kind`` should be drawn now (see CLOUD_PERIOD_S)."""
        if self.spec.every or self._time - self._last_cloud.get(kind, -np.inf) >= (
            CLOUD_PERIOD_S - 1e-9
        ):
            self._last_cloud[kind] = self._time
            return True
        return False

    def _log_scans(self, device: str, scans: Sequence[Any]) -> None:
        if not self._due(device):
            return
        for scan in scans:
            base = f"world/{device}/view_{int(scan.view)}"
            color = _PALETTE[int(scan.view) % len(_PALETTE)]
            self.rec.log(f"{base}/points", rr.Points3D(scan.hit_points, colors=color, radii=0.001))
            T = np.asarray(scan.sensor_to_world, dtype=float)
            dirs = np.asarray(scan.directions_sensor)[np.asarray(scan.self_hit)] @ T[:3, :3].T
            self.rec.log(
                f"{base}/self_hit",
                rr.Arrows3D(origins=np.repeat(T[None, :3, 3], len(dirs), axis=0),
                            vectors=_SELF_HIT_RAY_M * dirs, colors=_SELF_HIT),
            )  # fmt: skip

    def _log_touch(self, device: str, reading: Any) -> None:
        pressure = np.asarray(reading.pressure, dtype=float)
        pos = np.asarray(reading.positions_world, dtype=float)
        scale = max(float(pressure.max(initial=0.0)), 1.0)
        colors = np.c_[255 * np.clip(pressure / scale, 0, 1), np.zeros((len(pressure), 2))]
        self.rec.log(
            f"world/touch/{device}",
            rr.Points3D(pos, colors=colors.astype(np.uint8), radii=0.002,
                        labels=[f"{p:.0f} Pa" for p in pressure]),
        )  # fmt: skip
        self.rec.log(f"touch/{device}/pressure_pa", rr.BarChart(pressure))
        self.rec.log(f"touch/{device}/force_n", rr.Scalars(float(np.sum(reading.force))))

    # ------------------------------------------------------------------ robot

    def log_world(self, world: Any) -> None:
        self._world = world
        self._sync_time(world)
        self._robot = geom_meshes(world.model, names.ROBOT_PREFIX)
        # Meshes hang under their body's entity (geom-in-body transform, static); only the
        # bodies move. Names are flattened ("jaco_arm/b_1" -> "jaco_arm.b_1") so that no
        # body's entity is the parent of another's (their poses are world poses).
        for g in self._robot:
            path = f"world/robot/{flat_name(g.body)}/{flat_name(g.name)}"
            color = (255 * g.rgba[:3]).astype(np.uint8)
            T = g.geom_to_body
            self.rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]),
                         static=True)  # fmt: skip
            self.rec.log(
                path,
                rr.Mesh3D(vertex_positions=g.vertices, triangle_indices=g.faces,
                          albedo_factor=color),
                static=True,
            )  # fmt: skip
        self._robot_bodies = sorted({(g.body, g.body_id) for g in self._robot})
        m = world.model
        self._robot_joints = [
            m.joint(j).name for j in range(m.njnt)
            if m.joint(j).name.startswith(names.ROBOT_PREFIX)
        ]  # fmt: skip
        self.log_robot(world)

    def log_robot(self, world: Any) -> None:
        self._sync_time(world)
        for body, bid in self._robot_bodies:
            T = body_to_world(world.data, bid)
            self.rec.log(f"world/robot/{flat_name(body)}",
                         rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))  # fmt: skip
        for j in self._robot_joints:
            q = float(world.data.joint(j).qpos[0])
            self.rec.log(f"robot/joints/{j.removeprefix(names.ROBOT_PREFIX)}", rr.Scalars(q))

    # ------------------------------------------------------------------ sensing

    def log_snapshot(self, snap: Any, readings: Mapping[str, Any] | None = None) -> None:
        """Device ``readings`` taken outside the snapshot (name -> reading), the devices the
        snapshot read, then its logical sensor streams, fallbacks and grouping."""
        readings = dict(readings or {})
        for name in sorted(snap.devices_read - set(readings)):
            try:
                readings[name] = snap.read(name)  # cached by the snapshot: no new reading
            except MksError:
                continue
        for name, reading in readings.items():
            self.log_reading(name, reading)
        self._log_snapshot(snap)

    def _log_snapshot(self, snap: Any) -> None:
        """The logical sensor streams a snapshot has evaluated, its fallbacks, and the SPG /
        segmentation of its points."""
        for sensor, attempts in snap.attempts.items():
            for a in attempts:
                if not a.ok:
                    served = snap.provenance.get(sensor, "nothing")
                    self.log_text(
                        f"{sensor}: {a.way} failed ({a.reason}); served by {served}", "WARN"
                    )
        for sensor, served in sorted(snap.provenance.items()):
            try:
                stream = snap.get(sensor)
            except MksError:
                continue
            self._log_stream(sensor, stream, served)
        if "Range_Points" in snap.provenance and self._due("grouping"):
            self._log_grouping(snap)

    def _log_stream(self, sensor: str, stream: Any, served: str) -> None:
        names_ = list(stream.vector.names)
        data = np.asarray(stream.data, dtype=float)
        if not {"x", "y"} <= set(names_) or len(data) == 0:
            return
        xyz = np.c_[data[:, names_.index("x")], data[:, names_.index("y")],
                    data[:, names_.index("z")] if "z" in names_
                    else np.full(len(data), names.TABLE_TOP_Z)]  # fmt: skip
        path = f"world/sensors/{sensor}"
        if "radius" in names_:
            r = data[:, names_.index("radius")]
            self.rec.log(
                path,
                rr.Ellipsoids3D(centers=xyz, half_sizes=np.repeat(r[:, None], 3, axis=1),
                                labels=[f"r={1000 * v:.1f} mm ({served})" for v in r]),
            )  # fmt: skip
            return
        if "curvature" in names_:
            code = data[:, names_.index("curvature")]
            colors = np.where((code < 0)[:, None], _PLANAR, _CURVED).astype(np.uint8)
            self.rec.log(path, rr.Points3D(xyz, colors=colors, radii=0.001))
            return
        big = len(data) > 200
        if big and not self._due(f"sensor:{sensor}"):
            return
        self.rec.log(
            path,
            rr.Points3D(xyz, radii=0.001 if big else 0.003,
                        labels=None if big else [f"{sensor} ({served})"] * len(xyz)),
        )  # fmt: skip

    def _log_grouping(self, snap: Any) -> None:
        """SPG edges and the segmentation (planar/curved, per region) of the object points:
        the localization's own representation when the snapshot holds one (cached: nothing is
        rebuilt), else rebuilt for display from ``Range_Points``."""
        clouds = self._engine_grouping(snap)
        if clouds is None:
            pts = np.asarray(snap.get("Range_Points").data, dtype=float)[:, :3]
            clouds = rebuilt_grouping(pts[np.all(np.isfinite(pts), axis=1)])
        segs: list[np.ndarray] = []
        region_pts: list[np.ndarray] = []
        region_ids: list[np.ndarray] = []
        kind_colors: list[np.ndarray] = []
        normals: list[np.ndarray] = []
        next_id = 1
        for cloud, edges, seg in clouds:
            segs.append(np.stack([cloud[edges[:, 0]], cloud[edges[:, 1]]], axis=1))
            if seg is None:
                continue
            ids = np.zeros(len(cloud), dtype=np.int64)
            for region_idx in [r.indices for r in seg.planes] + [r.indices for r in seg.curved]:
                ids[region_idx] = next_id
                next_id += 1
            region_pts.append(cloud)
            region_ids.append(ids)
            kind_colors.append(np.where((np.asarray(seg.codes) < 0)[:, None], _PLANAR, _CURVED))
            if self.spec.normals:
                normals.append(np.c_[cloud, 0.01 * np.asarray(seg.normals)])
        if segs:
            lines = np.concatenate(segs)
            self.rec.log("world/spg/edges", rr.LineStrips3D(lines, radii=0.0002, colors=(128,) * 3))
        if region_pts:
            pts = np.concatenate(region_pts)
            self.rec.log(
                "world/segmentation/regions",
                rr.Points3D(pts, class_ids=np.concatenate(region_ids), radii=0.0012),
            )
            self.rec.log(
                "world/segmentation/curvature",
                rr.Points3D(pts, colors=np.concatenate(kind_colors).astype(np.uint8),
                            radii=0.0012),
            )  # fmt: skip
        if normals:
            n = np.concatenate(normals)
            self.rec.log("world/segmentation/normals", rr.Arrows3D(origins=n[:, :3],
                                                                   vectors=n[:, 3:]))  # fmt: skip

    def _engine_grouping(self, snap: Any) -> list[tuple[np.ndarray, np.ndarray, Any]] | None:
        """[(object points, SPG edges, segmentation)] from the snapshot's cached
        representation of ``Range_Points`` with the workstation's configuration (None when
        the snapshot or the engine offers none)."""
        config_of = getattr(workstation, "workstation_representation", None)
        if config_of is None or not hasattr(snap, "representation"):
            return None
        try:
            config = config_of()
            rep = snap.representation("Range_Points", config)
            cloud = np.asarray(rep.objects, dtype=float)
            if len(cloud) < 3:
                return []
            return [(cloud, undirected_edges(rep.graph.adjacency), rep.segmentation)]
        except (MksError, AttributeError, TypeError) as exc:
            log.debug("representation: %s", exc)
            return None

    # ------------------------------------------------------------------ localization

    def log_localization(self, result: Any, *, world: Any = None) -> None:
        if world is not None:
            self._sync_time(world)
        kept, self._snapshots[:] = list(self._snapshots), []
        for snap in kept:
            self._log_snapshot(snap)
        obj = str(getattr(result, "object", "object"))
        base = f"world/localization/{obj}"
        mesh = object_mesh(obj, world)
        frame = wireframe(*mesh) if mesh is not None else None
        hyps = tuple(getattr(result, "hypotheses", ()))
        self._log_hypotheses(base, hyps, frame)
        T = as_matrix(getattr(result, "object_to_world", None))
        if T is not None:
            self._log_pose(f"{base}/chosen", T)
            if frame is not None:
                self.rec.log(
                    f"{base}/chosen/wireframe",
                    rr.LineStrips3D(list(frame), colors=_CHOSEN, radii=0.0006),
                )
        else:
            self.rec.log(f"{base}/chosen", rr.Clear(recursive=True))
        diag = getattr(result, "diagnostics", None) or {}
        found = bool(getattr(result, "found", T is not None))
        timing = diag.get("timing", {}) if isinstance(diag, dict) else {}
        self.log_text(
            f"localize {obj}: {'found' if found else 'NOT FOUND'}, {len(hyps)} hypotheses; "
            + ", ".join(f"{k} {v:.2f} s" for k, v in timing.items() if isinstance(v, float)),
            "INFO" if found else "WARN",
        )

    def _log_hypotheses(self, base: str, hyps: Sequence[Any], frame: np.ndarray | None) -> None:
        """Every hypothesis as a posed wireframe (or posed model points) with its score, and
        the Hough maxima (translations, sized by votes); earlier ones are cleared."""
        self.rec.log(f"{base}/hypotheses", rr.Clear(recursive=True))
        maxima = []
        for k, h in enumerate(hyps):
            T = as_matrix(h.matrix)
            if T is None:
                continue
            score = float(getattr(h, "score", float("nan")))
            votes = int(getattr(h, "votes", 0))
            maxima.append((T[:3, 3], votes, score))
            if frame is not None:
                label = f"#{k} score {score:.3f} votes {votes}"
                if frame.ndim == 3:
                    self.rec.log(
                        f"{base}/hypotheses/{k}",
                        rr.LineStrips3D(list(transform_segments(frame, T)), colors=_HYPOTHESIS,
                                        radii=0.0003, labels=label),
                    )  # fmt: skip
                else:
                    pts = frame @ T[:3, :3].T + T[:3, 3]
                    self.rec.log(f"{base}/hypotheses/{k}",
                                 rr.Points3D(pts, colors=_HYPOTHESIS, radii=0.0008,
                                             labels=[label] + [""] * (len(pts) - 1)))  # fmt: skip
        self.rec.log(
            f"{base}/hough_maxima",
            rr.Points3D([m[0] for m in maxima], radii=[0.002 + 0.0002 * min(m[1], 40)
                        for m in maxima],
                        labels=[f"votes {m[1]} score {m[2]:.3f}" for m in maxima]),
        )  # fmt: skip

    # ------------------------------------------------------------------ point clouds

    def log_cloud(
        self,
        points: Any,
        result: Any,
        *,
        model_points: Any = None,
        model_mesh: tuple[np.ndarray, np.ndarray] | None = None,
        name: str = "model",
    ) -> None:
        """A simulator-free localization (``localize_cloud``): the scene points, its object
        segments (with their vertexes), and every hypothesis posed (model mesh wireframe, or
        model points when there is no mesh; model coordinates in scene units)."""
        pts = np.asarray(points, dtype=float)[:, :3]
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        self.rec.log("world/scene/points", rr.Points3D(pts, radii=0.0008, colors=(160,) * 3))
        base = f"world/localization/{name}"
        voxel = float(getattr(result, "voxel", 0.0) or 0.0)
        segments = tuple(getattr(result, "segments", ()))
        if segments and voxel == 0.0:  # indices refer to the NaN-free input scene
            seg_pts = [pts[np.asarray(s.indices)] for s in segments]
            ids = np.concatenate([np.full(len(p), k + 1) for k, p in enumerate(seg_pts)])
            self.rec.log("world/scene/segments",
                         rr.Points3D(np.concatenate(seg_pts), class_ids=ids, radii=0.001))
        verts = [np.asarray(getattr(s.vertexes, "points", np.empty((0, 3))), dtype=float)
                 for s in segments]  # fmt: skip
        verts = [v for v in verts if v.ndim == 2 and len(v)]
        if verts:
            self.rec.log("world/scene/vertexes", rr.Points3D(np.concatenate(verts), radii=0.002))
        frame: np.ndarray | None = None
        if model_mesh is not None:
            frame = wireframe(*model_mesh)
        elif model_points is not None:
            mp = np.asarray(model_points, dtype=float)
            frame = mp[:: max(1, len(mp) // 2000)]
        hyps = tuple(getattr(result, "hypotheses", ()))
        self._log_hypotheses(base, hyps, frame)
        if getattr(result, "found", False) and hyps:
            T = as_matrix(hyps[0].matrix)
            if T is not None:
                self._log_pose(f"{base}/chosen", T)
        for w in getattr(result, "warnings", ()):
            self.log_text(f"localize-cloud: {w}", "WARN")
        self.log_text(
            f"localize-cloud {name}: {'found' if getattr(result, 'found', False) else 'NOT FOUND'}"
            f", {len(hyps)} hypotheses", "INFO"
        )

    def log_truth(self, object_name: str, object_to_world: Any, *, world: Any = None) -> None:
        T = as_matrix(object_to_world)
        if T is None:
            return
        path = f"eval/truth/{object_name}"
        self._log_pose(path, T)
        mesh = object_mesh(object_name, world)
        if mesh is not None:
            self.rec.log(f"{path}/wireframe",
                         rr.LineStrips3D(list(wireframe(*mesh)), colors=_TRUTH, radii=0.0004,
                                         labels="ground truth (evaluation only)"))  # fmt: skip

    def _log_pose(self, path: str, T: np.ndarray) -> None:
        self.rec.log(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log(path, rr.TransformAxes3D(axis_length=0.05))

    # ------------------------------------------------------------------ grasp

    def log_grasps(self, candidates: Sequence[Any], chosen: Any = None) -> None:
        pts, labels, quality, contacts = [], [], [], []
        for k, c in enumerate(candidates):
            p = grasp_point(c)
            if p is None:
                continue
            q = grasp_quality(c, k)
            pts.append(p)
            quality.append(q)
            labels.append(f"#{k} quality {q:.3f}"
                          + (f" cost {c.cost:.4f}" if hasattr(c, "cost") else ""))  # fmt: skip
            if hasattr(c, "contacts_world"):
                contacts.append(np.asarray(c.contacts_world, dtype=float))
        if pts:
            qs = np.asarray(quality)
            s = (qs - qs.min()) / max(float(np.ptp(qs)), 1e-12)
            colors = np.c_[255 * (1 - s), 255 * s, np.zeros_like(s)].astype(np.uint8)
            self.rec.log("world/grasp/candidates",
                         rr.Points3D(pts, colors=colors, radii=0.003, labels=labels))  # fmt: skip
            self.rec.log("grasp/best_quality", rr.Scalars(float(qs.max())))
        if contacts:
            self.rec.log("world/grasp/contacts",
                         rr.LineStrips3D(contacts, radii=0.0005, colors=(0, 120, 255)))  # fmt: skip
        p = grasp_point(chosen) if chosen is not None else None
        if p is not None:
            self.rec.log("world/grasp/chosen", rr.Points3D([p], colors=_CHOSEN, radii=0.005,
                                                           labels="chosen grasp"))  # fmt: skip

    # ------------------------------------------------------------------ text, end

    def log_text(self, text: str, level: str = "INFO") -> None:
        self.rec.log("log", rr.TextLog(text, level=_LEVELS.get(level, rr.TextLogLevel.INFO)))

    def close(self) -> None:
        try:
            # A file is written whole; a viewer that went away is given up after a while.
            self.rec.flush(timeout_sec=1e9 if self.spec.mode == "save" else VIEWER_FLUSH_S)
        except Exception as exc:  # rerun's own error types
            log.warning("--rerun %s: recording not fully delivered: %s", self.spec.mode, exc)
        if self.spec.mode == "save":
            self.rec.disconnect()

    def __enter__(self) -> RerunRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
