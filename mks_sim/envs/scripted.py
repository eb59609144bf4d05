"""The scripted grasp as a policy over ``mks_sim/Grasp-v0`` / ``-v1`` observations.

It reads only observations (the localization estimate, the pinch point, the touch pads, and
range points when the env observes them) and emits the env's actions, phase by phase:
approach above the grasp point, descend, close until both sides touch, lift, hold.

The env integrates the actions into a pinch-point target that the velocity-limited arm
follows with a lag; a policy that commanded from the *observed* pinch point would integrate
that lag and overshoot (the yaw swung past the plan by more than a radian). So the policy
keeps the target it has commanded (its own actions, from the first observed pinch point)
and steers that to the goal; the observations decide when a phase is done.

On ``Grasp-v1`` (continuous grip) it does what the closed loop does: it pre-shapes the
fingers to the grasp width plus a margin while approaching (``GraspPlan.preshape_q``; a fully
open hand lands its fingertips on neighbouring objects), closes gently until both sides
touch, then squeezes (``ArmHandController.close``). On v0 the hand is either fully open or
closing at full speed.

On ``Grasp-v2`` (a full hand rotation per step) it flies the plan's whole hand rotation
(``GraspPlan.hand_rotation``), tilted approaches included, steering its commanded
orientation to the plan's as it steers the position. v0 and v1 can only turn the hand about
the vertical, so there it takes the best top-down grasp the synthesis offers (a tilted plan
flown at its yaw alone would close on the wrong faces).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from mks_sim.envs.grasp_env import MAX_ROT_RAD, MAX_STEP_M, MAX_YAW_RAD
from mks_sim.models.objects import load_object
from mks_sim.sim import names
from mks_sim.tasks.controller import quat_of
from mks_sim.tasks.episode import TOUCH_THRESHOLD_N, object_radius_m, obstacle_points
from mks_sim.tasks.grasp import MAX_TILTED, GraspPlan, synthesize_grasps, wrap_angle

# Phase ends: the pinch point within these of the pre-grasp / grasp point, the hand's
# rotation within ROT_TOL_RAD of the plan's (the yaw tolerance of v0/v1 before v2).
PREGRASP_TOL_M = 0.006
GRASP_TOL_M = 0.004
ROT_TOL_RAD = 0.05


class ScriptedGraspPolicy:
    """Callable ``policy(obs) -> action`` for a :class:`~mks_sim.envs.grasp_env.GraspEnv`.

    Args:
        env: the (unwrapped) env, for its task only (the object's mesh comes from the model
            database).
        gain: fraction of the remaining distance (commanded target to goal) per step.
        slow: fraction of the env's largest step used while descending and lifting (the
            arm interpolates in joint space, so a fast Cartesian descent bows sideways: at
            2 cm per step a fingertip strayed 8 mm and landed on the cube).
        close_grip: finger velocity while closing before both sides touch (v1 only).
        squeeze_grip: finger velocity once both sides touch and while lifting (v1 only).
    """

    def __init__(
        self,
        env: Any,
        gain: float = 0.7,
        close_grip: float = 0.6,
        squeeze_grip: float = 1.0,
        slow: float = 0.4,
    ) -> None:
        self.task = env.task
        self.obj = load_object(self.task.object)
        self.gain = gain
        self.slow = slow
        self.continuous = continuous = bool(getattr(env, "continuous_grip", False))
        self.close_grip = close_grip if continuous else 1.0
        self.squeeze_grip = squeeze_grip if continuous else 1.0
        self.phase = "approach"
        self.plan: GraspPlan | None = None
        self._count = 0
        self._target: np.ndarray | None = None  # (3,) commanded pinch point, world, metres
        self._yaw = 0.0  # commanded yaw, radians
        self.rotates = bool(getattr(env, "rotation_action", False))  # v2: full rotations
        self._quat: np.ndarray | None = None  # (4,) commanded hand orientation, wxyz (v2)

    def _goal_action(
        self, obs: dict[str, Any], goal: np.ndarray, grip: float, speed: float = 1.0
    ) -> np.ndarray:
        assert self.plan is not None
        if self._target is None:
            self._target = np.asarray(obs["pinch_pos"], dtype=float).copy()
            self._yaw = float(obs["pinch_yaw"][0])
            if self.rotates:
                self._quat = quat_of(np.asarray(obs["pinch_rotation"], dtype=float))
        delta = np.clip((goal - self._target) * self.gain / MAX_STEP_M, -speed, speed)
        # The env's own update (grasp_env.GraspEnv.step), so the model stays in step with it.
        self._target = self._target + delta * MAX_STEP_M
        self._target[2] = max(self._target[2], names.TABLE_TOP_Z + 0.01)
        if self.rotates:
            turn = self._turn_action(self.plan.hand_rotation)
            return np.array([*delta, *turn, grip], dtype=np.float32)
        yaw = self.plan.yaw_rad
        dyaw = float(np.clip(wrap_angle(yaw - self._yaw) * self.gain / MAX_YAW_RAD, -1.0, 1.0))
        self._yaw = wrap_angle(self._yaw + dyaw * MAX_YAW_RAD)
        return np.array([*delta, dyaw, grip], dtype=np.float32)

    def _turn_action(self, rotation_world: np.ndarray) -> np.ndarray:
        """(3,) v2 rotation action turning the commanded orientation ``gain`` of the way to
        ``rotation_world`` (3, 3), at most ``MAX_ROT_RAD`` about the shortest axis."""
        assert self._quat is not None
        goal, conj, diff, rotvec = np.empty(4), np.empty(4), np.empty(4), np.zeros(3)
        mujoco.mju_mat2Quat(goal, np.ascontiguousarray(rotation_world, dtype=float).ravel())
        mujoco.mju_negQuat(conj, self._quat)
        mujoco.mju_mulQuat(diff, goal, conj)  # world-frame: goal * commanded^-1
        mujoco.mju_quat2Vel(rotvec, diff, 1.0)  # shortest rotation vector
        turn = rotvec * self.gain / MAX_ROT_RAD
        biggest = float(np.max(np.abs(turn)))
        if biggest > 1.0:
            turn /= biggest  # keep the axis; the env clips per component
        # The env's update (grasp_env.GraspEnvV2._turn).
        step, quat = np.array([1.0, 0.0, 0.0, 0.0]), np.empty(4)
        mujoco.mju_quatIntegrate(step, turn, MAX_ROT_RAD)
        mujoco.mju_mulQuat(quat, step, self._quat)
        mujoco.mju_normalize4(quat)
        self._quat = quat
        return turn

    def _rotation_error(self, obs: dict[str, Any]) -> float:
        """Angle (rad) between the observed hand and the plan's (v2: the whole rotation;
        v0/v1: the yaw)."""
        assert self.plan is not None
        if not self.rotates:
            return abs(wrap_angle(self.plan.yaw_rad - float(obs["pinch_yaw"][0])))
        R = np.asarray(obs["pinch_rotation"], dtype=float)
        cos = (np.trace(self.plan.hand_rotation.T @ R) - 1.0) / 2.0
        return float(np.arccos(np.clip(cos, -1.0, 1.0)))

    def _plan(self, obs: dict[str, Any], est: np.ndarray) -> GraspPlan | None:
        obstacles = None
        if "points" in obs:
            pts = np.asarray(obs["points"], dtype=float)[: int(obs["n_points"][0])]
            r = object_radius_m(self.obj) + 0.012
            obstacles = obstacle_points(pts, est, r, names.TABLE_TOP_Z)
        # v0/v1: the hand points down, so no tilted candidates.
        cands = synthesize_grasps(self.obj, est, table_z=names.TABLE_TOP_Z,
                                  obstacles=obstacles, preferred_yaw=float(obs["pinch_yaw"][0]),
                                  max_tilted=MAX_TILTED if self.rotates else 0)  # fmt: skip
        return cands[0].plan(self.task.action) if cands else None

    def _wait(self) -> np.ndarray:
        """Stay put with the hand open (no estimate or no grasp yet); v2's action is longer."""
        action = np.zeros(7 if self.rotates else 5, np.float32)
        action[-1] = -1.0
        return action

    def _preshape_grip(self, obs: dict[str, Any], q: float) -> float:
        """Grip holding the fingers at angle ``q`` (rad): v1 steers the finger velocity there
        (a step is 0.1 s at up to 5 rad/s, so ``grip = dq / 0.5`` would close the gap in
        one step; 0.8 of that does not overshoot); v0 can only open fully."""
        if not self.continuous:
            return -1.0
        dq = q - float(np.mean(obs["finger_qpos"]))
        return float(np.clip(0.8 * dq / 0.5, -1.0, 1.0))

    def __call__(self, obs: dict[str, Any]) -> np.ndarray:
        if self.plan is None:
            if not obs["pose_valid"][0]:
                return self._wait()
            self.plan = self._plan(obs, np.asarray(obs["pose_estimate"], dtype=float))
            if self.plan is None:  # no grasp fits the estimate: wait for the next one
                return self._wait()
        plan = self.plan
        pinch = np.asarray(obs["pinch_pos"], dtype=float)
        grasp = np.asarray(plan.grasp_point_world)
        open_grip = self._preshape_grip(obs, plan.preshape_q)
        if self.phase == "approach":
            if (
                np.linalg.norm(plan.pregrasp_world - pinch) < PREGRASP_TOL_M
                and self._rotation_error(obs) < ROT_TOL_RAD
            ):
                self.phase = "descend"
            return self._goal_action(obs, plan.pregrasp_world, open_grip)
        if self.phase == "descend":
            if np.linalg.norm(grasp - pinch) < GRASP_TOL_M:
                self.phase, self._count = "close", 0
            return self._goal_action(obs, grasp, open_grip, self.slow)
        if self.phase == "close":
            self._count += 1
            t = np.nan_to_num(np.asarray(obs["touch"], dtype=float), nan=-1.0)
            if (
                self._count >= 4
                and t[0] > TOUCH_THRESHOLD_N
                and max(t[1], t[2]) > TOUCH_THRESHOLD_N
            ):
                self.phase, self._count = "squeeze", 0
            return self._goal_action(obs, grasp, self.close_grip)
        if self.phase == "squeeze":  # as ArmHandController.close: squeeze before lifting
            self._count += 1
            if self._count >= 3:
                self.phase = "lift"
            return self._goal_action(obs, grasp, self.squeeze_grip)
        return self._goal_action(obs, plan.lifted_world, self.squeeze_grip, self.slow)
