"""Damped-least-squares IK (mks_sim.sim.ik) on a tiny inline 6-dof arm.

The reference is MuJoCo itself: targets are the site pose of a known joint vector, and the
solution is checked by reading the site back after ``mj_kinematics`` on a fresh MjData.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mks_sim.errors import MksError, NotFound
from mks_sim.sim.ik import SiteIK

ARM = """
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="base" pos="0 0 0.1">
      <joint name="j1" type="hinge" axis="0 0 1"/>
      <geom type="capsule" size="0.03" fromto="0 0 0 0 0 0.2"/>
      <body pos="0 0 0.2">
        <joint name="j2" type="hinge" axis="0 1 0" limited="true" range="-1.6 1.6"/>
        <geom type="capsule" size="0.03" fromto="0 0 0 0.3 0 0"/>
        <body pos="0.3 0 0">
          <joint name="j3" type="hinge" axis="0 1 0" limited="true" range="-2.5 2.5"/>
          <geom type="capsule" size="0.025" fromto="0 0 0 0.25 0 0"/>
          <body pos="0.25 0 0">
            <joint name="j4" type="hinge" axis="1 0 0"/>
            <joint name="j5" type="hinge" axis="0 1 0"/>
            <joint name="j6" type="hinge" axis="0 0 1"/>
            <geom type="box" size="0.02 0.02 0.02"/>
            <site name="tcp" pos="0.06 0 0"/>
          </body>
        </body>
      </body>
    </body>
    <body name="ball" pos="0.5 0.5 0.5">
      <freejoint name="ball_free"/>
      <geom type="sphere" size="0.05"/>
    </body>
  </worldbody>
</mujoco>
"""
JOINTS = ("j1", "j2", "j3", "j4", "j5", "j6")
Q0 = np.array([0.1, -0.4, 1.0, 0.2, -0.3, 0.1])


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM)


def _site_pose(model: mujoco.MjModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth from MuJoCo: (pos (3,), quat wxyz (4,)) of the site at joints ``q``."""
    d = mujoco.MjData(model)
    for name, v in zip(JOINTS, q, strict=True):
        d.qpos[model.jnt_qposadr[model.joint(name).id]] = v
    mujoco.mj_kinematics(model, d)
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, d.site("tcp").xmat)
    return d.site("tcp").xpos.copy(), quat


def _angle(qa: np.ndarray, qb: np.ndarray) -> float:
    return float(2 * np.arccos(np.clip(abs(np.dot(qa, qb)), 0.0, 1.0)))


def _qpos(model: mujoco.MjModel, q: np.ndarray) -> np.ndarray:
    d = mujoco.MjData(model)
    d.qpos[[model.jnt_qposadr[model.joint(j).id] for j in JOINTS]] = q
    return d.qpos.copy()


@pytest.mark.parametrize("seed", range(8))
def test_converges_to_reachable_pose(model: mujoco.MjModel, seed: int) -> None:
    rng = np.random.default_rng(seed)
    q_goal = Q0 + rng.uniform(-0.3, 0.3, 6)  # a nearby pose: a per-step move and more
    target_pos, target_quat = _site_pose(model, q_goal)
    ik = SiteIK(model, "tcp", JOINTS)
    res = ik.solve(_qpos(model, Q0), target_pos, target_quat, max_iters=100)
    assert res.converged, res
    pos, quat = _site_pose(model, res.qpos)  # read back from MuJoCo, not from the solver
    assert np.linalg.norm(pos - target_pos) < 1e-4
    assert _angle(quat, target_quat) < 2e-3
    assert np.allclose(res.site_pos, pos)


def test_position_only(model: mujoco.MjModel) -> None:
    target_pos, _ = _site_pose(model, Q0 + 0.2)
    res = SiteIK(model, "tcp", JOINTS).solve(_qpos(model, Q0), target_pos)
    assert res.converged and res.rotation_error_rad == 0.0
    assert np.linalg.norm(_site_pose(model, res.qpos)[0] - target_pos) < 1e-4


def test_joint_limits_respected(model: mujoco.MjModel) -> None:
    # Only reachable with j2 = 2.2 rad, past its 1.6 rad limit: the solver stops at the
    # limit, reports no convergence and never returns an angle outside the range.
    q_goal = np.array([0.0, 2.2, 0.0, 0.0, 0.0, 0.0])
    target_pos, target_quat = _site_pose(model, q_goal)
    ik = SiteIK(model, "tcp", JOINTS)
    res = ik.solve(_qpos(model, Q0), target_pos, target_quat, max_iters=200)
    assert not res.converged
    lo, hi = model.jnt_range[model.joint("j2").id]
    assert lo - 1e-12 <= res.qpos[1] <= hi + 1e-12
    lo3, hi3 = model.jnt_range[model.joint("j3").id]
    assert lo3 - 1e-12 <= res.qpos[2] <= hi3 + 1e-12
    # ... and ends closer to the target than it started.
    start, _ = _site_pose(model, Q0)
    assert res.position_error_m < np.linalg.norm(start - target_pos)


def test_start_outside_limits_is_clamped(model: mujoco.MjModel) -> None:
    ik = SiteIK(model, "tcp", JOINTS)
    q = ik.clamp([0.0, 3.0, -3.0, 9.0, 0.0, 0.0])
    assert q[1] == pytest.approx(1.6) and q[2] == pytest.approx(-2.5) and q[3] == 9.0


def test_callers_state_untouched(model: mujoco.MjModel) -> None:
    d = mujoco.MjData(model)
    d.qpos[:] = _qpos(model, Q0)
    before = d.qpos.copy()
    target_pos, target_quat = _site_pose(model, Q0 + 0.1)
    SiteIK(model, "tcp", JOINTS).solve(d.qpos, target_pos, target_quat)
    assert np.array_equal(d.qpos, before)


def test_bad_names(model: mujoco.MjModel) -> None:
    with pytest.raises(NotFound, match="no site 'nope'"):
        SiteIK(model, "nope", JOINTS)
    with pytest.raises(NotFound, match="joint"):
        SiteIK(model, "tcp", ("j1", "missing"))
    with pytest.raises(MksError, match="expected hinge or slide joints"):
        SiteIK(model, "tcp", ("ball_free",))


def test_out_of_reach_stops_early_near_the_best_reach(model: mujoco.MjModel) -> None:
    """A target 3 m away: the arm (shoulder at z = 0.3 m, 0.61 m from shoulder to site)
    gets no closer than ``|target - shoulder| - 0.61``. The solver stops once an iteration
    gains < 1 %, far before ``max_iters``, within 1 % of that bound; the result is
    self-consistent (its ``site_pos`` is MuJoCo's forward kinematics of its ``qpos``)."""
    ik = SiteIK(model, "tcp", JOINTS)
    target = np.array([3.0, 0.5, 0.4])
    best = np.linalg.norm(target - [0.0, 0.0, 0.3]) - 0.61
    res = ik.solve(_qpos(model, Q0), target, max_iters=200)
    assert not res.converged and res.iterations < 20
    assert best - 1e-9 <= res.position_error_m < 1.01 * best
    pos, _ = _site_pose(model, res.qpos)
    assert np.allclose(res.site_pos, pos)
    assert res.position_error_m == pytest.approx(np.linalg.norm(target - pos))
