"""The scripted grasp as a policy over ``mks_sim/Grasp-v0`` observations.

It reads only observations (the localization estimate, the pinch point, the touch pads, and
range points when the env observes them) and emits the env's actions, phase by phase:
approach above the grasp point, descend, close until both sides touch, lift, hold.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mks_sim.envs.grasp_env import MAX_STEP_M, MAX_YAW_RAD
from mks_sim.sim import names
from mks_sim.tasks.episode import TOUCH_THRESHOLD_N, obstacle_points
from mks_sim.tasks.grasp import GraspPlan, plan_grasp, wrap_angle
from mks_sim.tasks.objects import geometry_for


class ScriptedGraspPolicy:
    """Callable ``policy(obs) -> action`` for a :class:`~mks_sim.envs.grasp_env.GraspEnv`.

    Args:
        env: the (unwrapped) env, for its task and object geometry only.
        gain: fraction of the remaining distance commanded per step.
    """

    def __init__(self, env: Any, gain: float = 0.7) -> None:
        self.task = env.task
        self.geometry = geometry_for(self.task.model)
        self.gain = gain
        self.phase = "approach"
        self.plan: GraspPlan | None = None
        self._count = 0

    def _goal_action(
        self, obs: dict[str, Any], goal: np.ndarray, yaw: float, grip: float
    ) -> np.ndarray:
        delta = (goal - obs["pinch_pos"]) * self.gain / MAX_STEP_M
        dyaw = wrap_angle(yaw - float(obs["pinch_yaw"][0])) * self.gain / MAX_YAW_RAD
        a = np.clip(np.array([*delta, dyaw, grip]), -1.0, 1.0)
        return a.astype(np.float32)

    def __call__(self, obs: dict[str, Any]) -> np.ndarray:
        if self.plan is None:
            if not obs["pose_valid"][0]:
                return np.array([0, 0, 0, 0, -1], np.float32)
            est = np.asarray(obs["pose_estimate"], dtype=float)
            obstacles = None
            if "points" in obs:
                pts = np.asarray(obs["points"], dtype=float)[: int(obs["n_points"][0])]
                g = self.geometry
                r = g.radius_m if g.kind == "sphere" else float(np.linalg.norm(g.half_extents_m))
                obstacles = obstacle_points(pts, est, r + 0.012, names.TABLE_TOP_Z)
            self.plan = plan_grasp(est, self.task.action, self.geometry,
                                   preferred_yaw=float(obs["pinch_yaw"][0]),
                                   table_z=names.TABLE_TOP_Z, obstacles_world=obstacles)  # fmt: skip
        plan = self.plan
        pinch = np.asarray(obs["pinch_pos"], dtype=float)
        grasp = np.asarray(plan.grasp_point_world)
        yaw_err = abs(wrap_angle(plan.yaw_rad - float(obs["pinch_yaw"][0])))
        if self.phase == "approach":
            if np.linalg.norm(plan.pregrasp_world - pinch) < 0.006 and yaw_err < 0.05:
                self.phase = "descend"
            return self._goal_action(obs, plan.pregrasp_world, plan.yaw_rad, -1.0)
        if self.phase == "descend":
            if np.linalg.norm(grasp - pinch) < 0.004:
                self.phase, self._count = "close", 0
            return self._goal_action(obs, grasp, plan.yaw_rad, -1.0)
        if self.phase == "close":
            self._count += 1
            t = np.nan_to_num(np.asarray(obs["touch"], dtype=float), nan=-1.0)
            if (
                self._count >= 4
                and t[0] > TOUCH_THRESHOLD_N
                and max(t[1], t[2]) > TOUCH_THRESHOLD_N
            ):
                self.phase = "lift"
            return self._goal_action(obs, grasp, plan.yaw_rad, 1.0)
        return self._goal_action(obs, plan.lifted_world, plan.yaw_rad, 1.0)
