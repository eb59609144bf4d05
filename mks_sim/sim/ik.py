"""Damped-least-squares inverse kinematics of one site on the raw MuJoCo model and data.

dm_control's ``qpos_from_site_pose`` copies the physics and builds named indexers on every
call (1.04 s of 1.70 s per 100 env steps, issue 11). :class:`SiteIK` resolves names and
addresses once, owns one scratch ``MjData``, and per iteration runs only
``mj_kinematics`` + ``mj_comPos`` (what ``mj_jacSite`` reads: ``xpos``, ``xmat``, ``cdof``,
``subtree_com``) and a 6x6 solve. It suits small moves from a nearby start (a per-step
controller); a far target from a poor start is dm_control's full solve's job.

The step is the classic DLS update (Wampler 1986; Buss, "Introduction to inverse kinematics
with Jacobian transpose, pseudoinverse and damped least squares methods", 2004):
``dq = J^T (J J^T + lambda^2 I)^-1 e`` with ``e`` the (6,) position and rotation error in
the world frame, and limited joints clamped into their range after every step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from mks_sim.errors import MksError, NotFound


@dataclass(frozen=True)
class IkResult:
    """Outcome of :meth:`SiteIK.solve`.

    Attributes:
        qpos: (n,) joint angles, radians, in the solver's ``joints`` order.
        converged: both errors under their tolerances.
        position_error_m: remaining site position error, metres.
        rotation_error_rad: remaining site orientation error, radians (0 when no target
            orientation was given).
        site_pos: (3,) the site's position at ``qpos``, world frame, metres.
        iterations: DLS steps taken.
    """

    qpos: np.ndarray
    converged: bool
    position_error_m: float
    rotation_error_rad: float
    site_pos: np.ndarray
    iterations: int


class SiteIK:
    """DLS IK of ``site`` over the hinge/slide ``joints`` of ``model``.

    Args:
        model: the compiled model (shared, never modified).
        site: name of the site to place.
        joints: names of the joints the solver may move (one dof each).
        damping: ``lambda`` of the DLS step (metres / radians scale of the error).
        max_step_rad: largest change of any joint per iteration (keeps the linearisation
            honest far from the target).

    Raises:
        NotFound: an unknown site or joint name.
        MksError: a joint with more than one degree of freedom (free or ball joints).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        site: str,
        joints: Sequence[str],
        damping: float = 1e-2,
        max_step_rad: float = 0.3,
    ) -> None:
        try:
            self._site = model.site(site).id
            jids = [model.joint(j).id for j in joints]
        except KeyError as exc:
            raise NotFound(f"SiteIK: no site {site!r} or joint among {list(joints)}") from exc
        singles = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
        bad = [
            j for j, i in zip(joints, jids, strict=True) if int(model.jnt_type[i]) not in singles
        ]
        if bad:
            raise MksError(f"SiteIK: expected hinge or slide joints, got {bad}")
        self._model = model
        self._data = mujoco.MjData(model)  # scratch: the caller's data is never touched
        self._qadr = model.jnt_qposadr[jids].copy()
        self._dofadr = model.jnt_dofadr[jids].copy()
        self._limited = model.jnt_limited[jids].astype(bool)
        self._range = model.jnt_range[jids].copy()  # (n, 2)
        self._damping2 = float(damping) ** 2
        self._max_step = float(max_step_rad)
        # Unlimited joints get infinite bounds: one np.clip clamps every joint.
        self._lo = np.where(self._limited, self._range[:, 0], -np.inf)
        self._hi = np.where(self._limited, self._range[:, 1], np.inf)
        self._jac = np.zeros((6, model.nv))  # rows: position (3), rotation (3)
        self._reg = self._damping2 * np.eye(6)
        self.joints = tuple(joints)

    def clamp(self, q: ArrayLike) -> np.ndarray:
        """``q`` (n,) with the limited joints clamped into their ranges."""
        return np.clip(np.asarray(q, dtype=float), self._lo, self._hi)

    def site_pose(self, qpos: ArrayLike, q: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics: (position (3,), rotation matrix (3, 3)) of the site, world
        frame, for the full ``qpos`` (nq,) with the solver's joints set to ``q`` (n,)."""
        d = self._data
        d.qpos[:] = qpos
        d.qpos[self._qadr] = q
        mujoco.mj_kinematics(self._model, d)
        return d.site_xpos[self._site].copy(), d.site_xmat[self._site].reshape(3, 3).copy()

    def solve(
        self,
        qpos: ArrayLike,
        target_pos: ArrayLike,
        target_quat: ArrayLike | None = None,
        q_init: ArrayLike | None = None,
        max_iters: int = 30,
        tol_pos_m: float = 1e-4,
        tol_rot_rad: float = 1e-3,
        min_progress: float = 0.01,
    ) -> IkResult:
        """Joint angles putting the site at ``target_pos`` (and ``target_quat``).

        Args:
            qpos: (nq,) the world's current ``data.qpos`` (the other joints stay there).
            target_pos: (3,) site target, world frame, metres.
            target_quat: (4,) wxyz site orientation target, world frame; None = position only.
            q_init: (n,) start of the iteration; default the joints' values in ``qpos``.
            max_iters: most DLS steps.
            tol_pos_m: position tolerance, metres.
            tol_rot_rad: orientation tolerance, radians.
            min_progress: stop early when an iteration shrinks the error (metres + radians)
                by less than this fraction: the target is out of reach (a joint limit or
                the workspace boundary), and further steps only creep along it. With random
                env actions a third of the targets are out of reach, and each ran all
                ``max_iters`` (issue 11). 0 runs every iteration.

        Returns:
            The last iterate (limited joints always inside their ranges), converged or not.
        """
        m, d = self._model, self._data
        d.qpos[:] = np.asarray(qpos, dtype=float)
        q = self.clamp(d.qpos[self._qadr] if q_init is None else q_init)
        target = np.asarray(target_pos, dtype=float).reshape(3)
        quat = None if target_quat is None else np.asarray(target_quat, dtype=float).reshape(4)
        cur, conj, dquat, rot_err = np.empty(4), np.empty(4), np.empty(4), np.zeros(3)
        rows = 3 if quat is None else 6
        err = np.zeros(rows)
        it = 0
        last, last_errors, q_last = np.inf, (np.inf, np.inf), q
        while True:
            d.qpos[self._qadr] = q
            mujoco.mj_kinematics(m, d)
            err[:3] = target - d.site_xpos[self._site]
            if quat is not None:
                # World-frame rotation error: target * current^-1 as a rotation vector.
                mujoco.mju_mat2Quat(cur, d.site_xmat[self._site])
                mujoco.mju_negQuat(conj, cur)
                mujoco.mju_mulQuat(dquat, quat, conj)
                mujoco.mju_quat2Vel(rot_err, dquat, 1.0)
                err[3:] = rot_err
            # math on dot products: np.linalg.norm's overhead was a third of an iteration.
            pos_e = math.sqrt(float(err[:3] @ err[:3]))
            rot_e = math.sqrt(float(err[3:] @ err[3:])) if quat is not None else 0.0
            converged = pos_e < tol_pos_m and rot_e < tol_rot_rad
            total = pos_e + rot_e
            if not converged and total > last:  # the step made it worse: keep the one before
                q = q_last
                d.qpos[self._qadr] = q
                mujoco.mj_kinematics(m, d)
                pos_e, rot_e = last_errors
                break
            if converged or it >= max_iters or total > (1.0 - min_progress) * last:
                break
            last, last_errors, q_last = total, (pos_e, rot_e), q
            mujoco.mj_comPos(m, d)
            jac = self._jac
            mujoco.mj_jacSite(m, d, jac[:3], None if quat is None else jac[3:], self._site)
            J = jac[:rows, self._dofadr]  # (rows, n)
            dq = J.T @ np.linalg.solve(J @ J.T + self._reg[:rows, :rows], err)
            biggest = float(np.max(np.abs(dq)))
            if biggest > self._max_step:
                dq *= self._max_step / biggest
            q = np.clip(q + dq, self._lo, self._hi)
            it += 1
        return IkResult(
            qpos=q.copy(),
            converged=converged,
            position_error_m=pos_e,
            rotation_error_rad=rot_e,
            site_pos=d.site_xpos[self._site].copy(),
            iterations=it,
        )
