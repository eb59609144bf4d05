"""One closed-loop grasp episode: sense, localize, plan, approach, close by touch, lift,
verify, and on failure localize again and retry.

:func:`run_episode` is a pure function of its arguments (seed -> result), so a process pool
or a distributed engine can map it over seeds. Localization is injected
(``localize_fn(world, object_name) -> 4x4 | None``); the default is the sensor-based
workstation pipeline bound to the episode's devices. Ground truth is read only by
:mod:`mks_sim.tasks.evaluate` to score the episode.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from mks_sim.errors import DataError, DeviceFailure, MksError, NotFound, SensorFailure
from mks_sim.sim import names
from mks_sim.tasks.controller import ArmHandController, RobotNames
from mks_sim.tasks.evaluate import HOLD_S, HoldMonitor, localization_error
from mks_sim.tasks.grasp import GraspPlan, rank_grasps
from mks_sim.tasks.objects import geometry_for
from mks_sim.tasks.spec import TaskSpec, task_for_object

logger = logging.getLogger(__name__)

LocalizeFn = Callable[[Any, str], "np.ndarray | None"]
FrameSink = Callable[[np.ndarray], None]

OBJECTS = ("cube", "sphere", "part")
TOUCH_DEVICES = ("touch_finger_1", "touch_finger_2", "touch_finger_3")
TOUCH_THRESHOLD_N = 0.05  # summed pad force; the pads' noise floor is ~5 mN
# Where set-up puts objects a task removes: on the floor, far outside every sensor's view.
_PARKING = np.array([1.6, 1.6, 0.05])


@dataclass(frozen=True)
class EpisodeResult:
    """Outcome of one episode.

    Attributes:
        object: ``cube`` | ``sphere`` | ``part``.
        seed: the episode seed.
        success: ground-truth verdict (object >= 8 cm above the table for the whole 1 s hold).
        retries: attempts after the first.
        position_error_mm: localization error of the estimate the last attempt used (mm).
        rotation_error_deg: same, rotation modulo symmetries (degrees).
        time_s: wall-clock time of the episode, seconds.
        sim_time_s: simulated time, seconds.
        believed_success: what the robot itself concluded from touch and re-sensing.
        min_clearance_m: lowest clearance during the final hold (ground truth), metres.
        failure: why the last attempt failed ("" on success).
        faults: devices failed for the episode.
        estimate: the last estimate used, 16 floats row-major (or None).
    """

    object: str
    seed: int
    success: bool
    retries: int
    position_error_mm: float
    rotation_error_deg: float
    time_s: float
    sim_time_s: float
    believed_success: bool = False
    min_clearance_m: float = float("nan")
    failure: str = ""
    faults: tuple[str, ...] = ()
    estimate: tuple[float, ...] | None = None
    attempts_log: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> dict[str, Any]:
        """The CLI's per-episode JSON record."""

        def num(x: float) -> float | None:
            return None if not math.isfinite(x) else round(float(x), 3)

        return {
            "seed": self.seed,
            "success": self.success,
            "retries": self.retries,
            "error": {
                "position_mm": num(self.position_error_mm),
                "rotation_deg": num(self.rotation_error_deg),
            },
            "time_s": round(self.time_s, 3),
            "sim_time_s": round(self.sim_time_s, 3),
            "believed_success": self.believed_success,
            "failure": self.failure,
        }

    def as_dict(self) -> dict[str, Any]:
        """All fields (for reports)."""
        return asdict(self)


def _as_matrix(result: Any) -> np.ndarray | None:
    """Accept a 4x4 array or an object carrying one (``object_to_world``/``matrix``)."""
    if result is None:
        return None
    for attr in ("object_to_world", "matrix", "pose"):
        if hasattr(result, attr) and not isinstance(result, np.ndarray):
            result = getattr(result, attr)
            break
    if result is None:
        return None
    T = np.asarray(result, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(f"localize_fn: expected a finite 4x4 object_to_world, got shape {T.shape}")
    return T


def sensor_localize_fn(devices: Mapping[str, Any], **kwargs: Any) -> LocalizeFn:
    """The real localization: ``mks_sim.workstation.localize`` over the episode's devices.

    Raises:
        MksError: the workstation pipeline is not installed.
    """
    try:
        from mks_sim.workstation import localize  # type: ignore[import-not-found]
    except ImportError as exc:
        raise MksError(
            f"the sensor-based localization (mks_sim.workstation.localize) is not available: {exc}"
        ) from exc

    def fn(world: Any, object_name: str) -> np.ndarray | None:
        try:
            return _as_matrix(localize(world, object_name, devices, **kwargs))
        except (NotFound, SensorFailure, DeviceFailure) as exc:
            logger.info("localization of %s failed: %s", object_name, exc)
            return None

    return fn


def make_touch_reader(devices: Mapping[str, Any]) -> Callable[[], np.ndarray]:
    """(3,) summed pad forces (N) from the touch devices; nan for a failed pad."""

    def read() -> np.ndarray:
        out = np.full(3, np.nan)
        for i, name in enumerate(TOUCH_DEVICES):
            dev = devices.get(name)
            if dev is None:
                continue
            try:
                reading = dev.read()
            except DeviceFailure:
                continue
            force = getattr(reading, "force", reading)
            out[i] = float(np.sum(force))
        return out

    return read


def build_episode_world(task: TaskSpec, rng: np.random.Generator) -> Any:
    """The task's world with objects placed from ``rng`` and removed objects parked.

    A placement that finds no free spot is redrawn from the same generator (deterministic).
    """
    from mks_sim.sim.world import build_world

    world = build_world(task.scene)
    randomize_world(world, rng)
    if task.remove:
        remove_objects(world, task.remove)
    return world


def randomize_world(world: Any, rng: np.random.Generator, tries: int = 10) -> None:
    """``world.randomize(rng)``, redrawn when the placement finds no free spot."""
    for k in range(tries):
        try:
            world.randomize(rng)
            break
        except MksError as exc:
            if k == tries - 1:
                raise
            logger.info("placement redrawn: %s", exc)
    world.mark_initial()


def make_scene_points_fn(devices: Mapping[str, Any]) -> Callable[[], np.ndarray | None]:
    """Sensed 3-D points of the scene (world frame): the ``Range_Points`` logical sensor
    (with its alternates), else the range finder's raw hits; None when nothing delivers."""

    def read() -> np.ndarray | None:
        try:
            from mks_sim.sensing import SensorGraph  # type: ignore[attr-defined]

            stream = SensorGraph.from_dir().snapshot(devices).get("Range_Points")
            return np.asarray(stream.data, dtype=float)[:, :3]
        except (MksError, ImportError, AttributeError) as exc:
            logger.debug("Range_Points unavailable (%s); reading the range finder", exc)
        dev = devices.get("range_finder")
        if dev is None:
            return None
        try:
            scans = dev.read()
        except DeviceFailure:
            return None
        pts = [np.asarray(s.hit_points, dtype=float) for s in scans]
        return np.concatenate(pts) if pts else None

    return read


def obstacle_points(
    points: np.ndarray | None, object_to_world: np.ndarray, radius_m: float, table_z: float
) -> np.ndarray | None:
    """Scene points that are neither the table nor within ``radius_m`` of the object."""
    if points is None or len(points) == 0:
        return None
    pts = points[np.all(np.isfinite(points), axis=1)]
    pts = pts[pts[:, 2] > table_z + 0.004]
    far = np.linalg.norm(pts - object_to_world[:3, 3], axis=1) > radius_m
    return pts[far]


def remove_objects(world: Any, objects: Iterable[str]) -> None:
    """Set-up: take objects off the table (onto the floor, out of every view)."""
    for k, name in enumerate(objects):
        T = np.eye(4)
        T[:3, 3] = _PARKING + np.array([0.15 * k, 0.0, 0.0])
        world.set_object_pose(name, T)
    world.settle(50)
    world.mark_initial()


class GraspRunner:
    """The closed loop for one object in an existing world (used by episodes and the demo).

    Args:
        world: the world (``mks_sim.sim.world.World``).
        task: the grasp task.
        controller: the arm/hand controller bound to ``world``.
        localize_fn: sensor-based localization.
        monitor: ground-truth hold monitor (evaluation only; the loop never reads it for
            decisions).
    """

    def __init__(
        self,
        world: Any,
        task: TaskSpec,
        controller: ArmHandController,
        localize_fn: LocalizeFn,
        monitor: HoldMonitor | None = None,
        scene_points_fn: Callable[[], np.ndarray | None] | None = None,
    ) -> None:
        self.world = world
        self.scene_points_fn = scene_points_fn
        self.task = task
        self.ctl = controller
        self.localize_fn = localize_fn
        self.geometry = geometry_for(task.model)
        self.monitor = monitor
        self.home_pos = controller.pinch_pos()
        self.home_yaw = controller.pinch_yaw()
        self.log: list[str] = []
        self.estimate: np.ndarray | None = None
        self.plan: GraspPlan | None = None
        self.errors: tuple[float, float] = (float("nan"), float("nan"))
        self.on_localized: Callable[[np.ndarray | None], None] | None = None

    def _note(self, msg: str) -> None:
        logger.debug("%s: %s", self.task.object, msg)
        self.log.append(msg)

    def _retreat(self) -> None:
        self.ctl.open(15)
        up = self.ctl.pinch_pos() + np.array([0.0, 0.0, 0.10])
        self.ctl.move_to(up, self.ctl.pinch_yaw(), spacing_m=0.02)
        self.ctl.move_to(self.home_pos, self.home_yaw, spacing_m=0.03)

    def attempt(self) -> tuple[bool, str]:
        """One sense-plan-grasp-lift-verify cycle. Returns (believed success, reason)."""
        est = self.localize_fn(self.world, self.task.object)
        self.estimate = est
        if self.on_localized is not None:
            self.on_localized(est)
        if est is None:
            return False, "not localized"
        act = self.task.action
        obstacles = None
        if self.scene_points_fn is not None:
            g = self.geometry
            radius = g.radius_m if g.kind == "sphere" else float(np.linalg.norm(g.half_extents_m))
            obstacles = obstacle_points(
                self.scene_points_fn(), est, radius + 0.012, names.TABLE_TOP_Z
            )
        try:
            plans = rank_grasps(est, act, self.geometry, preferred_yaw=self.ctl.pinch_yaw(),
                                table_z=names.TABLE_TOP_Z, obstacles_world=obstacles)  # fmt: skip
        except MksError as exc:
            return False, f"no grasp: {exc}"
        ctl = self.ctl
        reason = "pre-grasp unreachable"
        for plan in plans[:4]:  # the next candidate when the arm cannot reach one
            self.plan = plan
            ctl.preshape(plan.preshape_q, 10)
            if not ctl.move_to(plan.pregrasp_world, plan.yaw_rad, spacing_m=0.03):
                self._note(f"pre-grasp at yaw {plan.yaw_rad:.2f} rad unreachable")
                continue
            if ctl.move_to(np.asarray(plan.grasp_point_world), plan.yaw_rad, spacing_m=0.01):
                break
            reason = "descent blocked"
            self._note(f"descent at yaw {plan.yaw_rad:.2f} rad blocked")
            ctl.move_to(plan.pregrasp_world, plan.yaw_rad, spacing_m=0.02)
        else:
            return False, reason
        closed = ctl.close(threshold=TOUCH_THRESHOLD_N, yaw=plan.yaw_rad)
        a, b = closed.sides(TOUCH_THRESHOLD_N)
        if not (a and b):
            return False, f"no two-sided contact (finger 1: {a}, fingers 2/3: {b})"
        z0 = float(est[2, 3])
        ctl.move_to(plan.lifted_world, plan.yaw_rad, spacing_m=0.01)
        steps = max(1, int(round(HOLD_S / ctl.control_dt)))
        for _ in range(steps):
            ctl.step()
            if self.monitor is not None:
                self.monitor.sample()
        t = ctl.touch()
        a, b = (
            np.nan_to_num(t, nan=-1.0)[0] > TOUCH_THRESHOLD_N,
            np.nanmax(np.nan_to_num(t[1:], nan=-1.0)) > TOUCH_THRESHOLD_N,
        )
        if not (a and b):
            return False, "contact lost while lifting"
        again = self.localize_fn(self.world, self.task.object)
        if again is not None and again[2, 3] - z0 < 0.5 * act.lift_height_m:
            return False, f"re-sensed object only {1000 * (again[2, 3] - z0):.0f} mm higher"
        return True, "held (touch" + (
            ", re-sensed)" if again is not None else "; re-sensing found nothing)"
        )

    def run(self) -> tuple[bool, int, str]:
        """Attempts up to ``1 + retries`` times. Returns (believed success, retries, reason)."""
        reason = ""
        retries = self.task.action.retries
        for k in range(retries + 1):
            if self.monitor is not None:
                self.monitor.samples.clear()
            ok, reason = self.attempt()
            self._note(f"attempt {k + 1}: {'ok' if ok else 'failed'}: {reason}")
            if ok:
                return True, k, reason
            if k < retries:
                self._retreat()
        return False, retries, reason


def run_episode(
    object: str,
    seed: int,
    faults: Iterable[str] = (),
    *,
    localize_fn: LocalizeFn | None = None,
    task: TaskSpec | None = None,
    frame_sink: FrameSink | None = None,
    frame_size: tuple[int, int] = (320, 240),
    frame_every: int = 3,
    setup: Callable[[Any], None] | None = None,
) -> EpisodeResult:
    """Run one grasp episode from ``seed`` (deterministic).

    Args:
        object: ``cube`` | ``sphere`` | ``part`` (task ``grasp_<object>``).
        seed: world randomisation and device noise seed.
        faults: device names failed for the whole episode (e.g. ``range_finder``).
        localize_fn: localization override (tests of the controller alone); default the
            sensor-based workstation pipeline.
        task: task override (default ``tasks/grasp_<object>.toml``).
        frame_sink: receives (H, W, 3) uint8 frames of the episode (video).
        frame_size: (width, height) of the frames.
        frame_every: control steps between frames.
        setup: called with the world after the seeded placement, before anything is sensed
            (e.g. to put the object at a known pose for regression tests).

    Raises:
        NotFound: unknown object / task.
        SpecError: unknown device in ``faults``.
    """
    from mks_sim.devices.factory import make_devices
    from mks_sim.devices.faults import DeviceFaults

    if object not in OBJECTS:
        raise NotFound(f"unknown object {object!r}; expected one of {OBJECTS}")
    t_start = time.perf_counter()
    task = task or task_for_object(object)
    faults = tuple(faults)
    world = build_episode_world(task, np.random.default_rng(seed))
    if setup is not None:
        setup(world)
    rng = np.random.default_rng([seed, 1])
    devices = make_devices(
        world.model, world.data, rng, faults={f: DeviceFaults(failed=True) for f in faults}
    )
    renderer = None
    try:
        if localize_fn is None:
            localize_fn = sensor_localize_fn(devices)
        on_frame = None
        if frame_sink is not None:
            renderer, on_frame = _frame_hook(world, frame_sink, frame_size)
        ctl = ArmHandController(world.physics, RobotNames.from_model(world.model),
                                make_touch_reader(devices), on_frame=on_frame,
                                frame_every=frame_every)  # fmt: skip
        monitor = HoldMonitor(world, task.object, names.TABLE_TOP_Z)
        runner = GraspRunner(world, task, ctl, localize_fn, monitor, make_scene_points_fn(devices))
        errors = [(float("nan"), float("nan"))]

        def on_localized(est: np.ndarray | None) -> None:
            e = localization_error(world, task.object, est)  # evaluation only
            errors.append((e.position_mm, e.rotation_deg))

        runner.on_localized = on_localized
        believed, retries, reason = runner.run()
        success = monitor.success()
        est = runner.estimate
        return EpisodeResult(
            object=object,
            seed=seed,
            success=success,
            retries=retries,
            position_error_mm=errors[-1][0],
            rotation_error_deg=errors[-1][1],
            time_s=time.perf_counter() - t_start,
            sim_time_s=ctl.time,
            believed_success=believed,
            min_clearance_m=monitor.min_clearance_m,
            failure="" if success else reason,
            faults=faults,
            estimate=None if est is None else tuple(float(v) for v in np.ravel(est)),
            attempts_log=tuple(runner.log),
        )
    finally:
        if renderer is not None:
            renderer.close()
        devices.close()


def _frame_hook(world: Any, sink: FrameSink, size: tuple[int, int]):
    import mujoco

    w, h = size
    renderer = mujoco.Renderer(world.model, height=h, width=w)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (0.0, 0.1, names.TABLE_TOP_Z + 0.1)
    cam.distance = 1.1
    cam.azimuth = 150.0
    cam.elevation = -25.0

    def hook() -> None:
        renderer.update_scene(world.data, camera=cam)
        sink(renderer.render().copy())

    return renderer, hook
