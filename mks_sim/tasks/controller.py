"""Joint-space control of the Jaco arm and hand toward Cartesian pinch-point targets.

The arm's targets come from dm_control's damped-least-squares IK
(:func:`dm_control.utils.inverse_kinematics.qpos_from_site_pose`) on the hand's pinch site,
solved on a copy of the state (``inplace=False``) and warm-started from the current joints.
The arm tracks them with a saturated proportional law on its actuators (dm_control's Jaco has
velocity actuators: ``ctrl`` is a joint velocity, capped at the datasheet's 36 / 48 deg/s;
position actuators get the target directly). Straight-line moves are cut into waypoints so
the descent is vertical.

The hand closes with its velocity actuators until the fingertip touch pads report contact
(``read_touch``: the touch *devices*, never the simulator's contact list), re-centres when
only one side touches, and holds.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
from dm_control.utils import inverse_kinematics as ik
from scipy.spatial.transform import Rotation, Slerp

from mks_sim.errors import NotFound

logger = logging.getLogger(__name__)

TouchReader = Callable[[], np.ndarray]
FrameHook = Callable[[], None]
# Called after every control period; returning True interrupts the current motion.
StepHook = Callable[[], bool]

# Jaco arm velocity limits (dm_control jaco_arm.py, from Kinova's datasheet).
_MAX_VEL = np.deg2rad([36.0, 36.0, 36.0, 48.0, 48.0, 48.0])


@dataclass(frozen=True)
class RobotNames:
    """MuJoCo names of the arm and hand (as compiled in the world).

    Attributes:
        arm_joints: the six arm joints, base to wrist.
        arm_actuators: their actuators, same order.
        finger_joints: finger_1 (alone on the site's +x side), finger_2, finger_3.
        finger_actuators: their actuators, same order.
        pinch_site: the site between the fingertips the IK drives.
    """

    arm_joints: tuple[str, ...]
    arm_actuators: tuple[str, ...]
    finger_joints: tuple[str, ...]
    finger_actuators: tuple[str, ...]
    pinch_site: str

    @classmethod
    def jaco(
        cls, arm_prefix: str = "jaco_arm/", hand_prefix: str = "jaco_arm/jaco_hand/"
    ) -> RobotNames:
        """Names of dm_control's JacoArm with a JacoHand attached (prefixes as compiled)."""
        arm = tuple(f"{arm_prefix}joint_{i}" for i in range(1, 7))
        fingers = tuple(f"{hand_prefix}finger_{i}" for i in range(1, 4))
        return cls(arm, arm, fingers, fingers, f"{hand_prefix}pinchsite")

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> RobotNames:
        """Find the Jaco's names in a compiled model (whatever the attachment prefixes)."""
        joints = [model.joint(i).name for i in range(model.njnt)]
        sites = [model.site(i).name for i in range(model.nsite)]
        pinch = [s for s in sites if s.endswith("pinchsite")]
        arm = [next((j for j in joints if j.endswith(f"joint_{i}")), "") for i in range(1, 7)]
        fingers = [next((j for j in joints if j.endswith(f"finger_{i}")), "") for i in range(1, 4)]
        if not pinch or not all(arm) or not all(fingers):
            raise NotFound(
                "the world has no Jaco arm + hand (expected joints '*joint_1..6', "
                f"'*finger_1..3' and a site '*pinchsite'); joints: {joints}"
            )
        acts = [model.actuator(i).name for i in range(model.nu)]

        def act_for(joint: str) -> str:
            jid = model.joint(joint).id
            for a in range(model.nu):
                if (
                    model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                    and model.actuator_trnid[a, 0] == jid
                ):
                    return acts[a]
            raise NotFound(f"no actuator drives joint {joint!r}; actuators: {acts}")

        return cls(
            tuple(arm),
            tuple(act_for(j) for j in arm),
            tuple(fingers),
            tuple(act_for(j) for j in fingers),
            pinch[0],
        )


def quat_down(yaw: float) -> np.ndarray:
    """(4,) wxyz quaternion of a pinch-site frame pointing down (z = -world z) with its
    closing (x) axis at ``yaw`` radians about world z."""
    z = np.array([0.0, 0.0, -1.0])
    x = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    R = np.stack([x, np.cross(z, x), z], axis=1)
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, R.ravel())
    return q


def quat_of(rotation: np.ndarray) -> np.ndarray:
    """(4,) wxyz quaternion of a rotation matrix (3, 3) (a tilted hand's orientation)."""
    q = np.empty(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=float).ravel())
    return q


@dataclass(frozen=True)
class CloseResult:
    """Outcome of closing the hand.

    Attributes:
        touch: (3,) last touch readings (finger 1, 2, 3), newtons; nan = pad failed.
        finger_qpos: (3,) finger joint angles, radians (0.15 open .. 1.35 closed).
        recentred: how many re-centring moves were made.
    """

    touch: np.ndarray
    finger_qpos: np.ndarray
    recentred: int

    def sides(self, threshold: float) -> tuple[bool, bool]:
        """(finger-1 side touches, finger-2/3 side touches); a failed pad counts as unknown
        and is replaced by the other pads of its side."""
        t = np.nan_to_num(self.touch, nan=-1.0)
        return bool(t[0] > threshold), bool(max(t[1], t[2]) > threshold)


class ArmHandController:
    """Drives the arm's pinch site through Cartesian targets and the hand open / closed.

    Args:
        physics: dm_control ``mjcf.Physics`` of the world (advanced by this controller).
        names: the robot's MuJoCo names.
        read_touch: returns (3,) fingertip pad readings (N); nan for a failed pad.
        control_dt: control period, seconds (a multiple of the model timestep).
        on_frame: called once per ``frame_every`` control steps (video capture).
        frame_every: control steps between ``on_frame`` calls.

    Attributes:
        after_step: called after every control period (the episode's re-sensing); when it
            returns True, :attr:`interrupted` is set and :meth:`move_to` stops early.
    """

    def __init__(
        self,
        physics,
        names: RobotNames,
        read_touch: TouchReader,
        control_dt: float = 0.02,
        on_frame: FrameHook | None = None,
        frame_every: int = 2,
    ) -> None:
        self.physics = physics
        self.names = names
        self.read_touch = read_touch
        m = physics.model.ptr
        self._m = m
        self._d = physics.data.ptr
        self.n_sub = max(1, round(control_dt / m.opt.timestep))
        self._qadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in names.arm_joints])
        self._fqadr = np.array([m.jnt_qposadr[m.joint(j).id] for j in names.finger_joints])
        self._aid = np.array([m.actuator(a).id for a in names.arm_actuators])
        self._fid = np.array([m.actuator(a).id for a in names.finger_actuators])
        self._site = m.site(names.pinch_site).id
        # Position actuators carry -kp in biasprm[1]; velocity actuators have it 0.
        self._position_ctrl = bool(np.all(m.actuator_biasprm[self._aid, 1] != 0))
        self._limited = m.jnt_limited[[m.joint(j).id for j in names.arm_joints]].astype(bool)
        self._range = m.jnt_range[[m.joint(j).id for j in names.arm_joints]]
        self._fctrl = m.actuator_ctrlrange[self._fid]
        self.grip = -1.0  # -1 open .. +1 close (fraction of the finger actuator range)
        self.finger_target: float | None = None  # pre-shape angle (rad) overriding grip
        self.on_frame = on_frame
        self.frame_every = max(1, frame_every)
        self._steps = 0
        self.q_target = self.arm_qpos()
        self.after_step: StepHook | None = None
        self.interrupted = False

    # -- state ---------------------------------------------------------------------------
    def arm_qpos(self) -> np.ndarray:
        """(6,) arm joint angles, radians."""
        return self._d.qpos[self._qadr].copy()

    def finger_qpos(self) -> np.ndarray:
        """(3,) finger joint angles, radians."""
        return self._d.qpos[self._fqadr].copy()

    def pinch_pos(self) -> np.ndarray:
        """(3,) pinch-site position, world frame, metres (the robot's own forward kinematics)."""
        return self._d.site_xpos[self._site].copy()

    def pinch_rotation(self) -> np.ndarray:
        """(3, 3) pinch-site rotation in the world (columns: closing axis, across, approach)."""
        return self._d.site_xmat[self._site].reshape(3, 3).copy()

    def pinch_yaw(self) -> float:
        """Yaw of the pinch site's closing (x) axis about world z, radians."""
        R = self._d.site_xmat[self._site].reshape(3, 3)
        return math.atan2(R[1, 0], R[0, 0])

    # -- IK ------------------------------------------------------------------------------
    def solve_ik(
        self,
        pos: np.ndarray,
        yaw: float,
        max_steps: int = 200,
        rotation: np.ndarray | None = None,
    ) -> tuple[np.ndarray, bool]:
        """Joint angles (6,) putting the pinch site at ``pos`` pointing down at ``yaw``, or at
        the orientation ``rotation`` (3, 3; columns: closing axis, across, approach) when
        given (a tilted grasp).

        Warm-started at the current joints; unlimited joints are unwrapped to the nearest
        turn so the arm never spins a full revolution. Returns (q, converged).
        """
        res = ik.qpos_from_site_pose(
            self.physics,
            self.names.pinch_site,
            target_pos=np.asarray(pos, dtype=float),
            target_quat=quat_down(yaw) if rotation is None else quat_of(rotation),
            joint_names=list(self.names.arm_joints),
            tol=1e-6,
            max_steps=max_steps,
            inplace=False,
        )
        q = res.qpos[self._qadr]
        cur = self.arm_qpos()
        q = np.where(self._limited, q, cur + (q - cur + np.pi) % (2 * np.pi) - np.pi)
        within = np.all(~self._limited | ((q >= self._range[:, 0]) & (q <= self._range[:, 1])))
        return q, bool(res.success and within)

    # -- stepping ------------------------------------------------------------------------
    def _apply(self) -> None:
        d = self._d
        if self._position_ctrl:
            d.ctrl[self._aid] = self.q_target
        else:
            err = self.q_target - d.qpos[self._qadr]
            d.ctrl[self._aid] = np.clip(8.0 * err, -_MAX_VEL, _MAX_VEL)
        lo, hi = self._fctrl[:, 0], self._fctrl[:, 1]
        if self.finger_target is not None:
            d.ctrl[self._fid] = np.clip(10.0 * (self.finger_target - d.qpos[self._fqadr]), lo, hi)
        else:
            d.ctrl[self._fid] = np.where(self.grip >= 0, self.grip * hi, -self.grip * lo)

    def step(self, n: int = 1) -> None:
        """Advance ``n`` control periods."""
        for _ in range(n):
            self._apply()
            self.physics.step(self.n_sub)
            self._steps += 1
            if self.on_frame is not None and self._steps % self.frame_every == 0:
                self.on_frame()
            if self.after_step is not None and self.after_step():
                self.interrupted = True

    @property
    def control_dt(self) -> float:
        """Control period, seconds."""
        return float(self.n_sub * self._m.opt.timestep)

    @property
    def time(self) -> float:
        """Simulated time, seconds."""
        return float(self._d.time)

    def settle(self, tol: float = 3e-3, max_steps: int = 150) -> bool:
        """Step until the arm is within ``tol`` rad of its target; True if it got there
        (False as well when :attr:`after_step` interrupts)."""
        for _ in range(max_steps):
            self.step()
            if self.interrupted:
                return False
            if np.max(np.abs(self.q_target - self.arm_qpos())) < tol:
                return True
        return False

    # -- motions -------------------------------------------------------------------------
    def set_arm(self, q: np.ndarray) -> None:
        """Teleport the arm to ``q`` (episode set-up only) and hold it there."""
        self._d.qpos[self._qadr] = q
        self._d.qvel[:] = 0.0
        self.q_target = np.asarray(q, dtype=float).copy()
        mujoco.mj_forward(self._m, self._d)

    def move_to(
        self,
        pos: np.ndarray,
        yaw: float,
        spacing_m: float = 0.01,
        steps_per_wp: int = 3,
        rotation: np.ndarray | None = None,
    ) -> bool:
        """Move the pinch site in a straight line to ``pos`` at ``yaw`` (pointing down), or
        to the orientation ``rotation`` (3, 3) when given: turned from the current one
        along the way (spherical interpolation), ``yaw`` then unused.

        Returns:
            False when IK fails for a waypoint, the arm does not reach the end, or
            :attr:`after_step` interrupted the motion (then :attr:`interrupted` is True).
            An interrupt stays set, and every later move returns at once, until the caller
            clears :attr:`interrupted`.
        """
        if self.interrupted:
            return False
        start = self.pinch_pos()
        pos = np.asarray(pos, dtype=float)
        n = max(1, int(math.ceil(np.linalg.norm(pos - start) / spacing_m)))
        yaw0 = self.pinch_yaw()
        dyaw = (yaw - yaw0 + math.pi) % (2 * math.pi) - math.pi
        turn = None
        if rotation is not None:
            ends = Rotation.from_matrix(np.stack([self.pinch_rotation(), np.asarray(rotation)]))
            turn = Slerp([0.0, 1.0], ends)
        ok = True
        for s in np.linspace(0.0, 1.0, n + 1)[1:]:
            if turn is None:
                q, converged = self.solve_ik(start + (pos - start) * s, yaw0 + dyaw * s)
            else:
                R = turn([s]).as_matrix()[0]
                q, converged = self.solve_ik(start + (pos - start) * s, yaw, rotation=R)
            if not converged:
                logger.debug("IK did not converge for waypoint %s", start + (pos - start) * s)
                ok = False
                continue
            self.q_target = q
            self.step(steps_per_wp)
            if self.interrupted:
                return False
        reached = self.settle()
        return ok and reached and float(np.linalg.norm(self.pinch_pos() - pos)) < 0.01

    def open(self, steps: int = 25) -> None:
        """Open the hand fully."""
        self.finger_target = None
        self.grip = -1.0
        self.step(steps)

    def preshape(self, q: float, steps: int = 25) -> None:
        """Hold the fingers at angle ``q`` (rad) and wait ``steps`` control periods."""
        self.finger_target = float(q)
        self.step(steps)

    def close(
        self,
        threshold: float = 0.05,
        max_steps: int = 60,
        recentre: int = 2,
        recentre_step_m: float = 0.012,
        yaw: float | None = None,
        rotation: np.ndarray | None = None,
    ) -> CloseResult:
        """Close until the pads of both sides report contact (or the fingers stop).

        When only one side touches after the fingers stopped, the hand opens, shifts
        ``recentre_step_m`` toward the touching side along its closing axis (horizontal at
        ``yaw``, or the x axis of ``rotation`` for a tilted hand, which it keeps), and closes
        again (at most ``recentre`` times).
        """
        recentred = 0
        while True:
            self.finger_target = None
            self.grip = 0.6
            touch = self.touch()
            last = self.finger_qpos()
            for k in range(max_steps):
                self.step()
                touch = self.touch()
                res = CloseResult(touch, self.finger_qpos(), recentred)
                a, b = res.sides(threshold)
                if a and b and k > 3:
                    self.grip = 1.0
                    self.step(15)
                    return CloseResult(self.touch(), self.finger_qpos(), recentred)
                q = self.finger_qpos()
                if k > 8 and np.max(np.abs(q - last)) < 1e-4:
                    break
                last = q
            res = CloseResult(touch, self.finger_qpos(), recentred)
            a, b = res.sides(threshold)
            if a == b or recentred >= recentre:
                return res
            recentred += 1
            y = self.pinch_yaw() if yaw is None else yaw
            axis = np.array([math.cos(y), math.sin(y), 0.0])
            if rotation is not None:
                axis = np.asarray(rotation, dtype=float)[:, 0]
            direction = axis * (1.0 if a else -1.0)
            logger.debug("one-sided contact (finger 1: %s); re-centring", a)
            self.preshape(float(np.min(self.finger_qpos())) - 0.3, 15)
            self.move_to(self.pinch_pos() + recentre_step_m * direction, y, rotation=rotation)

    def touch(self) -> np.ndarray:
        """(3,) fingertip pad readings (N) of fingers 1, 2, 3; nan for a failed pad."""
        t = np.asarray(self.read_touch(), dtype=float).reshape(-1)
        if t.size != 3:
            t = np.resize(t, 3)
        return t

    def hold(self, seconds: float) -> None:
        """Keep the current targets for ``seconds`` of simulated time."""
        self.step(max(1, int(round(seconds / self.control_dt))))
