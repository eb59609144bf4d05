"""``mks_sim/Grasp-v0`` and ``mks_sim/Grasp-v1``: the workstation as a gymnasium environment.

The agent moves the Jaco's pinch point (Cartesian deltas and a yaw delta; the arm follows
through a damped-least-squares IK step on the raw MuJoCo model, :mod:`mks_sim.sim.ik`) and
drives the hand: v0 opens / closes it (binary grip), v1 commands the finger velocity
(continuous grip, a fraction of the finger actuators' range). It observes the logical-sensor
outputs: the localization estimate of the object (sensed at ``reset``, and again every
``resense_every`` steps when asked), the fingertip touch pads and the arm's proprioception;
camera images, depth and range points only when the constructor asks for them.

Example:
    >>> import gymnasium as gym, mks_sim
    >>> env = gym.make("mks_sim/Grasp-v1", object="cube")     # doctest: +SKIP
    >>> obs, info = env.reset(seed=0)                          # doctest: +SKIP
    >>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Reward and ``info`` are evaluation (ground truth): ``info["success"]`` is the issue-#5
criterion (object >= 8 cm above the table held for 1 s); the reward is that success (1.0)
minus a small distance-to-object shaping term. ``info`` after ``reset`` also has
``reset_timing_s`` (``localization``, ``other``, ``total``, wall-clock seconds).
``info["provenance"]`` (not ground truth) maps each logical sensor of the last sensing to the
way that served it (``{"Range_Points": "Stereo_Points"}`` with the range finder failed).
"""

from __future__ import annotations

import atexit
import math
import os
import time
import weakref
from collections.abc import Iterable
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from mks_sim.errors import MksError, NotFound
from mks_sim.sim import names
from mks_sim.sim.ik import SiteIK
from mks_sim.tasks.controller import ArmHandController, RobotNames, quat_down, quat_of
from mks_sim.tasks.episode import (
    EpisodeAssembly,
    LocalizeFn,
    sensor_localize_fn,
    set_up_world,
)
from mks_sim.tasks.evaluate import HOLD_S, MIN_CLEARANCE_M, lowest_point_z
from mks_sim.tasks.spec import task_for_object

MAX_STEP_M = 0.02  # pinch-point motion per step at |action| = 1
MAX_YAW_RAD = 0.15
MAX_ROT_RAD = 0.15  # Grasp-v2: hand rotation per step at |rotation action| = 1
CONTROL_PERIODS_PER_STEP = 5  # 5 x 20 ms = 0.1 s of simulated time per env step
# A step moves the target <= 2 cm and 0.15 rad from the last solution: DLS converges in 2-3
# iterations (measured); 20 leaves room for the reachable-set boundary.
IK_MAX_ITERS = 20
_INF = np.inf
_OPEN_ENVS: weakref.WeakSet[GraspEnv] = weakref.WeakSet()


def _close_open_envs() -> None:
    # Unclosed envs release their EGL renderers before mujoco.egl's eglTerminate exit hook
    # (registered when the first context is made; see _keep_exit_hook_last).
    for env in list(_OPEN_ENVS):
        env.close()


def _keep_exit_hook_last() -> None:
    # Exit hooks run last-registered first: re-registering after a renderer was made puts
    # ours ahead of eglTerminate, so an env that is never closed exits without tracebacks.
    atexit.unregister(_close_open_envs)
    atexit.register(_close_open_envs)


def _use_models(models: tuple[str, ...]) -> None:
    """Extra model folders into ``MKS_SIM_MODELS`` (as ``mks-sim grasp --models``): the task,
    scene and localization look objects up there, in this process and in its workers."""
    if not models:
        return
    from mks_sim.models.objects import MODELS_ENV, models_dirs

    dirs = [str(d) for d in models_dirs(models)[1:]]  # NotFound for a missing folder
    os.environ[MODELS_ENV] = os.pathsep.join(dirs)


def _positive_size(value: Any, field: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise MksError(f"{field}: expected (width, height) of two ints, got {value!r}") from exc
    if w <= 0 or h <= 0:
        raise MksError(f"{field}: expected (width, height) > 0 pixels, got {value!r}")
    return w, h


class GraspEnv(gym.Env):
    """``mks_sim/Grasp-v0``: pick up ``object`` from the workstation table; binary grip
    (``action[4] < 0`` opens at full speed, ``>= 0`` closes).

    Args:
        object: any object of the model database (``mks_sim.models.objects.object_names``):
            its task file ``tasks/grasp_<object>.toml`` when there is one (``cube``,
            ``sphere``, ``part``), else the default task (the object alone on the table,
            dropped from a random orientation).
        render_mode: ``None`` or ``"rgb_array"``.
        faults: device names failed for every episode (e.g. ``("range_finder",)``).
        observe_image: add ``"image"``, the overhead camera RGB, (H, W, 3) uint8.
        observe_depth: add ``"depth"``, the depth camera, (H, W) float32 metres (0 = none).
        observe_points: add ``"points"``, ``n_points`` range-finder points (N, 3) float32
            (zero-padded) and their count.
        image_size: (width, height) of images and depth maps.
        n_points: number of range points observed.
        max_episode_steps: truncation horizon (also enforced by the registration).
        resense_every: re-localize every this many steps (0 = only at reset).
        localize_fn: localization override (tests of the env API alone); default the
            sensor-based workstation pipeline.
        render_size: (width, height) of ``render()`` frames.
        models: extra model-database folders, as the CLI's ``--models DIR``; like
            ``mks-sim grasp --models`` they are put into ``MKS_SIM_MODELS`` (with the folders
            already there), which the task, scene and localization read -- so vector-env
            subprocesses see them too.
        sleep: let resting bodies sleep (MuJoCo's ``mjENBL_SLEEP``, :class:`World`): resting
            clutter and a resting object cost nothing per step until something touches them
            (about twice the simulated seconds per wall second with random actions). On by
            default since issue 11 (the scripted grasps' success on the tuning seeds is the
            same with it, docs/env.md "Speed"); it changes the contact solution (MuJoCo
            solves per island), so ``sleep=False`` reproduces rollouts of earlier versions.

    Raises:
        NotFound: ``object`` is not in the model database (the message lists the known
            names), or a ``models`` folder does not exist.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    continuous_grip = False  # what the grip action means (read by the scripted policy)
    rotation_action = False  # v2: a full hand rotation per step instead of a yaw only
    action_names: tuple[str, ...] = ("dx", "dy", "dz", "dyaw", "grip")

    def __init__(
        self,
        object: str = "cube",
        render_mode: str | None = None,
        faults: Iterable[str] = (),
        observe_image: bool = False,
        observe_depth: bool = False,
        observe_points: bool = False,
        image_size: tuple[int, int] = (64, 48),
        n_points: int = 256,
        max_episode_steps: int = 200,
        resense_every: int = 0,
        localize_fn: LocalizeFn | None = None,
        render_size: tuple[int, int] = (160, 120),
        models: Iterable[str | os.PathLike[str]] = (),
        sleep: bool = True,
    ) -> None:
        model_dirs = tuple(str(p) for p in models)
        _use_models(model_dirs)
        from mks_sim.models.objects import object_names

        known = object_names()
        if object not in known:
            raise NotFound(
                f"unknown object {object!r}; expected a model-database name "
                f"({', '.join(known)}) -- add one with `mks-sim objects add` and pass models=(DIR,)"
            )
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise MksError(f"render_mode: expected None or 'rgb_array', got {render_mode!r}")
        image_size = _positive_size(image_size, "image_size")
        render_size = _positive_size(render_size, "render_size")
        if int(n_points) < 1:
            raise MksError(f"n_points: expected >= 1, got {n_points!r}")
        self._kwargs = dict(
            object=object, render_mode=render_mode, faults=tuple(faults),
            observe_image=observe_image, observe_depth=observe_depth,
            observe_points=observe_points, image_size=tuple(image_size), n_points=n_points,
            max_episode_steps=max_episode_steps, resense_every=resense_every,
            localize_fn=localize_fn, render_size=tuple(render_size), models=model_dirs,
            sleep=bool(sleep),
        )  # fmt: skip
        from mks_sim.sim.world import build_world

        self.object = object
        self.render_mode = render_mode
        self.faults = tuple(faults)
        self.task = task_for_object(object)
        self.max_episode_steps = max_episode_steps
        self.resense_every = resense_every
        self._localize_override = localize_fn
        self.image_size = (int(image_size[0]), int(image_size[1]))
        self.n_points = int(n_points)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        self.world = build_world(self.task.scene, sleep=bool(sleep))
        self._names = RobotNames.from_model(self.world.model)
        # ArmHandController's default 20 ms control period in model timesteps.
        self._ctl_substeps = max(1, round(0.02 / self.world.model.opt.timestep))
        m = self.world.model
        self._arm_dofs = np.array([m.jnt_dofadr[m.joint(j).id] for j in self._names.arm_joints])
        self._ik = SiteIK(self.world.model, self._names.pinch_site, self._names.arm_joints)
        self._devices: Any = None
        self._renderer: mujoco.Renderer | None = None
        self._ctl: ArmHandController | None = None
        self._assembly: EpisodeAssembly | None = None
        self._provenance: dict[str, str] = {}

        w, h = self.image_size
        obs: dict[str, spaces.Space] = {
            "pose_estimate": spaces.Box(-10.0, 10.0, (4, 4), np.float64),
            "pose_valid": spaces.MultiBinary(1),
            "touch": spaces.Box(-1.0, _INF, (3,), np.float64),
            "arm_qpos": spaces.Box(-_INF, _INF, (6,), np.float64),
            "arm_qvel": spaces.Box(-_INF, _INF, (6,), np.float64),
            "finger_qpos": spaces.Box(-_INF, _INF, (3,), np.float64),
            "pinch_pos": spaces.Box(-_INF, _INF, (3,), np.float64),
            "pinch_yaw": spaces.Box(-math.pi, math.pi, (1,), np.float64),
        }
        self._observed_devices = ["touch_finger_1", "touch_finger_2", "touch_finger_3",
                                  "range_finder", "stereo_left", "stereo_right"]  # fmt: skip
        if observe_image:
            obs["image"] = spaces.Box(0, 255, (h, w, 3), np.uint8)
            self._observed_devices.append("overhead_camera")
        if observe_depth:
            obs["depth"] = spaces.Box(0.0, _INF, (h, w), np.float32)
            self._observed_devices.append("depth_camera")
        if observe_points:
            obs["points"] = spaces.Box(-_INF, _INF, (self.n_points, 3), np.float32)
            obs["n_points"] = spaces.Box(0, self.n_points, (1,), np.int64)
        self.observation_space = spaces.Dict(obs)
        self._obs_keys = frozenset(obs)
        # dx, dy, dz, dyaw (scaled by MAX_STEP_M / MAX_YAW_RAD), grip (< 0 open, >= 0 close).
        self.action_space = spaces.Box(-1.0, 1.0, (len(self.action_names),), np.float32)

        self._estimate: np.ndarray | None = None
        self._target = np.zeros(3)
        self._yaw = 0.0
        self._steps = 0
        self._held_steps = 0
        self._clearance_at: tuple[np.ndarray, float] | None = None  # (body pose (7,), m)
        _OPEN_ENVS.add(self)

    # --- pickling: rebuild from the constructor arguments ---------------------------------
    def __getstate__(self) -> dict[str, Any]:
        return dict(self._kwargs)

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(**state)  # type: ignore[misc]

    @property
    def dt(self) -> float:
        """Simulated seconds per env step (as gymnasium's ``MujocoEnv.dt``)."""
        return float(CONTROL_PERIODS_PER_STEP * self._ctl_substeps * self.world.model.opt.timestep)

    # --- gymnasium API --------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        t_start = time.perf_counter()
        from mks_sim.devices.factory import make_devices
        from mks_sim.devices.faults import DeviceFaults

        world = self.world
        mujoco.mj_resetData(world.model, world.data)
        set_up_world(world, self.task, self.np_random)
        if self._devices is None:
            # Built once (camera renderers are costly); every reset re-seeds their noise.
            options_ = {
                "overhead_camera": {"width": self.image_size[0], "height": self.image_size[1]},
                "depth_camera": {"width": self.image_size[0], "height": self.image_size[1]},
            }
            self._devices = make_devices(
                world.model, world.data, np.random.default_rng(0),
                faults={f: DeviceFaults(failed=True) for f in self.faults},
                names=self._observed_devices, options=options_,
            )  # fmt: skip
        for dev, child in zip(
            self._devices.values(), self.np_random.spawn(len(self._devices)), strict=True
        ):
            dev.rng = child
        if self._assembly is None:
            # The one episode assembly (tasks.episode) also behind run_episode and the demo:
            # controller, touch reader and localization wired the same way. The env's agent
            # decides the motions, so the assembly's re-sensing during approaches is off.
            fn = self._localize_override or sensor_localize_fn(
                self._devices, on_result=self._keep_provenance
            )
            self._assembly = EpisodeAssembly(
                self.task, faults=self.faults, localize_fn=fn, resense_period_s=None
            )
        self._assembly.initialize_episode(world, self.np_random, devices=self._devices)
        assert self._assembly.controller is not None
        self._ctl = self._assembly.controller
        self._ctl.set_arm(self._ctl.arm_qpos())
        self._ctl.grip = -1.0
        self._target = self._ctl.pinch_pos()
        self._yaw = self._ctl.pinch_yaw()
        self._steps = 0
        self._held_steps = 0
        t_sense = time.perf_counter()
        self._sense()
        t_sensed = time.perf_counter()
        obs, info = self._observation(), self._info()
        _keep_exit_hook_last()  # the devices may have made their first EGL contexts
        total = time.perf_counter() - t_start
        info["reset_timing_s"] = {
            "localization": t_sensed - t_sense,
            "other": total - (t_sensed - t_sense),
            "total": total,
        }
        return obs, info

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        if self._ctl is None:
            raise MksError("GraspEnv.step() before reset()")
        # Before any state changes: a bad action changes nothing.
        a = _checked_action(action, self.action_names)
        ctl = self._ctl
        self._target = self._target + a[:3] * MAX_STEP_M
        self._target[2] = max(self._target[2], names.TABLE_TOP_Z + 0.01)
        quat = self._turn(a[3:-1])
        # Warm-started at the last commanded joints: the commanded path stays continuous
        # (no unlimited joint jumps a turn) and DLS needs 2-3 iterations.
        res = self._ik.solve(self.world.data.qpos, self._target, quat,
                             q_init=ctl.q_target, max_iters=IK_MAX_ITERS)  # fmt: skip
        ctl.q_target = res.qpos  # limited joints clamped: the reachable point nearest the target
        if not res.converged:  # out of reach: the target follows what the arm can reach
            self._target = res.site_pos
        ctl.grip = self._grip(float(a[-1]))
        ctl.step(CONTROL_PERIODS_PER_STEP)
        self._steps += 1
        if self.resense_every and self._steps % self.resense_every == 0:
            self._sense()
        clearance = self._clearance()  # ground truth, evaluation only: success and info
        self._held_steps = self._held_steps + 1 if clearance >= MIN_CLEARANCE_M else 0
        success = self._held_steps * self.dt >= HOLD_S - 1e-9
        dist = float(np.linalg.norm(ctl.pinch_pos() - self.world.data.body(self.object).xpos))
        reward = (1.0 if success else 0.0) - 0.1 * dist
        truncated = self._steps >= self.max_episode_steps and not success
        return (
            self._observation(),
            float(reward),
            bool(success),
            bool(truncated),
            self._info(success, clearance),
        )

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        w, h = self.render_size
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.world.model, height=h, width=w)
            _keep_exit_hook_last()
        cam = mujoco.MjvCamera()
        cam.lookat[:] = (0.0, 0.1, names.TABLE_TOP_Z + 0.1)
        cam.distance, cam.azimuth, cam.elevation = 1.1, 150.0, -25.0
        self._renderer.update_scene(self.world.data, camera=cam)
        return self._renderer.render().copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._devices is not None:
            self._devices.close()
            self._devices = None
        self._assembly = None  # bound to the closed devices
        _OPEN_ENVS.discard(self)

    # --- internals ------------------------------------------------------------------------
    def _turn(self, rotation_action: np.ndarray) -> np.ndarray:
        """The hand's new target orientation (4,) wxyz for the action's rotation part (v0/v1:
        ``(dyaw,)``, the hand kept pointing down)."""
        self._yaw = float(
            (self._yaw + rotation_action[0] * MAX_YAW_RAD + math.pi) % (2 * math.pi) - math.pi
        )
        return quat_down(self._yaw)

    def _grip(self, command: float) -> float:
        """The controller's grip (-1 open .. +1 close at full finger speed) for ``action[4]``."""
        return 1.0 if command >= 0 else -1.0

    def _sense(self) -> None:
        assert self._assembly is not None
        self._provenance = {}
        self._estimate = self._assembly.sense()
        # Evaluation only: the estimate's error at the time it was sensed (mm, degrees).
        self._loc_error = self._assembly.errors[-1]

    def _keep_provenance(self, result: Any) -> None:
        self._provenance = dict(getattr(result, "provenance", {}))

    def _clearance(self) -> float:
        # The lowest point loops over the object's geoms in Python (22 convex pieces for the
        # part): recomputed only when the body moved. A resting object sleeps (sleep=True)
        # and keeps its pose bit for bit, so this skips most of the steps before the grasp.
        body = self.world.data.body(self.object)
        pose = np.concatenate([body.xpos, body.xquat])
        if self._clearance_at is None or not np.array_equal(pose, self._clearance_at[0]):
            z = lowest_point_z(self.world.model, self.world.data, self.object)
            self._clearance_at = (pose, z - names.TABLE_TOP_Z)
        return self._clearance_at[1]

    def _observation(self) -> dict[str, Any]:
        ctl = self._ctl
        assert ctl is not None
        est = self._estimate
        raw = ctl.touch()
        touch = np.where(np.isnan(raw), -1.0, raw)  # np.nan_to_num costs ~10x more
        d = self.world.data
        qvel = d.qvel[self._arm_dofs].copy()
        obs: dict[str, Any] = {
            "pose_estimate": np.clip(est, -10, 10) if est is not None else np.zeros((4, 4)),
            "pose_valid": np.array([est is not None], dtype=np.int8),
            "touch": np.maximum(touch, -1.0),
            "arm_qpos": ctl.arm_qpos(),
            "arm_qvel": qvel,
            "finger_qpos": ctl.finger_qpos(),
            "pinch_pos": ctl.pinch_pos(),
            "pinch_yaw": np.array([ctl.pinch_yaw()]),
        }
        space = self._obs_keys
        if "image" in space:
            obs["image"] = self._image()
        if "depth" in space:
            obs["depth"] = self._depth()
        if "points" in space:
            obs["points"], obs["n_points"] = self._points()
        return obs

    def _read(self, name: str) -> Any:
        from mks_sim.errors import DeviceFailure

        dev = self._devices.get(name) if self._devices is not None else None
        if dev is None:
            return None
        try:
            return dev.read()
        except DeviceFailure:
            return None

    def _image(self) -> np.ndarray:
        w, h = self.image_size
        frame = self._read("overhead_camera")
        if frame is None:
            return np.zeros((h, w, 3), np.uint8)
        return _resize(np.asarray(frame.rgb, dtype=np.uint8), w, h)

    def _depth(self) -> np.ndarray:
        w, h = self.image_size
        frame = self._read("depth_camera")
        if frame is None or frame.depth is None:
            return np.zeros((h, w), np.float32)
        depth = np.nan_to_num(np.asarray(frame.depth, dtype=np.float32), nan=0.0)
        return _resize(depth, w, h)

    def _points(self) -> tuple[np.ndarray, np.ndarray]:
        out = np.zeros((self.n_points, 3), np.float32)
        reading = self._read("range_finder")
        if reading is None:
            return out, np.array([0])
        readings = reading if isinstance(reading, (list, tuple)) else [reading]
        pts = np.concatenate(
            [
                np.asarray(r.points_world, dtype=float).reshape(-1, 3)[
                    np.asarray(r.hit).reshape(-1)
                ]
                for r in readings
            ]
        )
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) > self.n_points:
            idx = np.linspace(0, len(pts) - 1, self.n_points).astype(int)
            pts = pts[idx]
        out[: len(pts)] = pts
        return out, np.array([len(pts)])

    def _info(self, success: bool = False, clearance: float | None = None) -> dict[str, Any]:
        position_mm, rotation_deg = self._loc_error
        return {
            "success": bool(success),
            "localization_error": {"position_mm": position_mm, "rotation_deg": rotation_deg},
            "clearance_m": self._clearance() if clearance is None else clearance,
            # Logical sensor -> the way that served it at the last sensing (fallbacks visible).
            "provenance": dict(self._provenance),
        }


class GraspEnvV1(GraspEnv):
    """``mks_sim/Grasp-v1``: v0 with a continuous grip and the range points of the last
    sensing.

    ``action[4]`` in [-1, 1] is the finger velocity as a fraction of the finger actuators'
    range (+1 closes at full speed, -1 opens at full speed, 0 holds the fingers where they
    are), so a policy can close gently until the pads touch and then squeeze.

    ``observe_points`` defaults to True and ``obs["points"]`` holds the range finder's scan
    taken with the localization (at ``reset`` and every ``resense_every`` steps), like
    ``pose_estimate``: a scan is a sensing act, not a per-step read (v0 scans on every step,
    which cost two thirds of a step). The scripted policy needs the points to keep its
    fingertips off the clutter (the closed loop uses them the same way). Everything else is
    as in :class:`GraspEnv`.
    """

    continuous_grip = True

    def __init__(self, object: str = "cube", observe_points: bool = True, **kwargs: Any) -> None:
        self._scan: tuple[np.ndarray, np.ndarray] | None = None
        super().__init__(object=object, observe_points=observe_points, **kwargs)

    def _grip(self, command: float) -> float:
        return command

    def _sense(self) -> None:
        super()._sense()
        self._scan = super()._points() if "points" in self._obs_keys else None

    def _points(self) -> tuple[np.ndarray, np.ndarray]:
        assert self._scan is not None
        points, count = self._scan
        return points.copy(), count.copy()


class GraspEnvV2(GraspEnvV1):
    """``mks_sim/Grasp-v2``: v1 with a full hand rotation per step, so tilted grasps can be
    flown.

    ``action`` is ``(dx, dy, dz, drx, dry, drz, grip)``: the pinch-point motion as in v0
    (``MAX_STEP_M`` at 1), a rotation vector in the world frame turning the hand's target
    orientation (``MAX_ROT_RAD`` per component at 1; ``R_target <- exp(dr) R_target``), and
    v1's continuous grip. ``obs["pinch_rotation"]`` is the pinch site's (3, 3) rotation in
    the world (columns: closing axis, across, approach; the robot's own forward
    kinematics). Everything else is as in :class:`GraspEnvV1`.

    v0 and v1 keep the hand pointing down (``dyaw`` only): a grasp synthesised with a tilted
    approach (``GraspPlan.tilted``) cannot be flown there.
    """

    rotation_action = True
    action_names = ("dx", "dy", "dz", "drx", "dry", "drz", "grip")

    def __init__(self, object: str = "cube", **kwargs: Any) -> None:
        self._quat = np.array([1.0, 0.0, 0.0, 0.0])  # commanded hand orientation, wxyz
        super().__init__(object=object, **kwargs)
        assert isinstance(self.observation_space, spaces.Dict)
        spaces_ = dict(self.observation_space.spaces)
        spaces_["pinch_rotation"] = spaces.Box(-1.0, 1.0, (3, 3), np.float64)
        self.observation_space = spaces.Dict(spaces_)
        self._obs_keys = frozenset(spaces_)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        obs, info = super().reset(seed=seed, options=options)
        assert self._ctl is not None
        self._quat = quat_of(self._ctl.pinch_rotation())
        return obs, info

    def _turn(self, rotation_action: np.ndarray) -> np.ndarray:
        turn = np.array([1.0, 0.0, 0.0, 0.0])  # becomes exp(dr): identity integrated by dr
        mujoco.mju_quatIntegrate(turn, np.asarray(rotation_action, dtype=float), MAX_ROT_RAD)
        quat = np.empty(4)
        mujoco.mju_mulQuat(quat, turn, self._quat)  # world-frame turn: exp(dr) * q
        mujoco.mju_normalize4(quat)
        self._quat = quat
        return quat.copy()

    def _observation(self) -> dict[str, Any]:
        obs = super()._observation()
        assert self._ctl is not None
        obs["pinch_rotation"] = np.clip(self._ctl.pinch_rotation(), -1.0, 1.0)
        return obs


def _checked_action(action: Any, fields: tuple[str, ...]) -> np.ndarray:
    """(len(fields),) float action clipped to [-1, 1]; ValueError for a wrong shape or
    NaN / Inf."""
    a = np.asarray(action, dtype=float)
    n, named = len(fields), ", ".join(fields)
    if a.size != n:
        raise ValueError(f"action: expected {n} numbers ({named}), got {a.shape}")
    a = a.reshape(n)
    if not np.all(np.isfinite(a)):
        raise ValueError(
            f"action: expected finite numbers ({named}), got {a.tolist()}; "
            "the step was not taken and the env is unchanged"
        )
    return np.clip(a, -1.0, 1.0)


def _resize(image: np.ndarray, w: int, h: int) -> np.ndarray:
    if image.shape[1] == w and image.shape[0] == h:
        return image
    import cv2

    return cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
