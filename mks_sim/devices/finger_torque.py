"""Simulated finger joint-torque sensing: "finger i is pressing on something", from the
finger's own motor and encoder (proprioception), never from the simulator's contact list.

The Jaco hand's fingers are velocity-servoed and force-limited (dm_control: ``kv = 10``,
force range +-1 N m). Closing in free air, the motor's torque is spent on the joint's viscous
damping (``b * qdot``); a finger stopped by an object stalls (``qdot`` ~ 0, or is pushed back)
while its motor still drives at the limit, so the torque the joint does not spend on its
damping is the torque it exerts on the object. The device reads, per reading, the finger's
actuator torque (the motor current, ``data.actuator_force``), its joint angle and velocity
(the encoder, ``qpos`` / ``qvel``) and, by forward kinematics, its fingertip pad's centre.

A finger is *pressing* when its motor drives toward closing at more than ``drive_fraction``
of its force limit, the finger has stalled (``qdot < stall_rad_s``), and it is more than
``limit_margin_rad`` short of its closed limit (there the joint's stop, not an object, holds
it). Fingers closed on nothing meet each other short of the limit: that is a contact too,
which the pads report as well. The external torque ``max(tau - b * qdot, 0)`` divided by
the lever (joint axis to pad centre, perpendicular to the axis) is the equivalent fingertip
force (N); over the pad's area (the taxel sites' areas) it is an equivalent pressure (Pa).
Readings have the same fields as a touch pad (``pressure``, ``positions_world``, ``force``):
one "taxel" at the pad centre, so the ``touch_contacts`` program reads them unchanged and a
``Touch_Contacts`` alternate can stand a finger's torque in for its failed pad.

Noise: Gaussian torque noise ``sigma_nm`` (times the fault's ``noise_scale``); a dropped
reading (``dropout``) reads 0 N.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from mks_sim.devices.faults import DeviceFaults, SimDevice, combined_dropout
from mks_sim.devices.touch import site_area
from mks_sim.errors import SpecError


@dataclass(frozen=True, eq=False)
class FingerTorqueReading:
    """One finger's joint-torque reading, shaped like a one-taxel touch pad.

    Attributes:
        pressure: (1,) equivalent pad pressure, Pa (0 when the finger is not pressing).
        positions_world: (1, 3) the fingertip pad's centre, world frame, metres.
        force: (1,) equivalent fingertip force, N (pressure * pad area).
        torque_nm: the motor's measured torque, N m (closing positive).
        qpos: the joint angle, rad.
        qvel: the joint velocity, rad/s.
        pressing: the finger is stalled on something (see the module docstring).
        name: the device name.
    """

    pressure: np.ndarray
    positions_world: np.ndarray
    force: np.ndarray
    torque_nm: float
    qpos: float
    qvel: float
    pressing: bool
    name: str


class FingerTorque(SimDevice):
    """One finger's torque sensing; ``read()`` -> :class:`FingerTorqueReading`.

    Args:
        model, data: the MuJoCo model and data.
        joint: the finger's joint name.
        actuator: the actuator driving it (closing = toward the joint's upper limit).
        pad_sites: the finger's taxel site names (the pad whose centre and area are used).
        rng: generator for noise and dropout.
        name: device name, e.g. ``finger_torque_1``.
        sigma_nm: torque noise, N m.
        dropout: nominal fraction of dropped readings.
        drive_fraction: minimum closing drive, as a fraction of the actuator's force limit.
        stall_rad_s: the finger counts as stalled below this closing velocity, rad/s.
        limit_margin_rad: not pressing within this much of the joint's closed limit, rad.
        faults: initial fault state.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        joint: str,
        actuator: str,
        pad_sites: tuple[str, ...],
        rng: np.random.Generator,
        *,
        name: str,
        sigma_nm: float = 0.005,
        dropout: float = 0.0,
        drive_fraction: float = 0.5,
        stall_rad_s: float = 0.1,
        limit_margin_rad: float = 0.03,
        faults: DeviceFaults | None = None,
    ) -> None:
        super().__init__(name, rng, faults)
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
        aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
        if jid < 0 or aid < 0:
            raise SpecError(
                f"device {name!r}: expected joint {joint!r} and actuator {actuator!r} in the "
                f"model, got joint id {jid}, actuator id {aid}"
            )
        sites = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, s) for s in pad_sites]
        if not sites or min(sites) < 0:
            raise SpecError(f"device {name!r}: expected the pad sites {pad_sites} in the model")
        self.model, self.data = model, data
        self._jid, self._aid = jid, aid
        self._qadr = int(model.jnt_qposadr[jid])
        self._dof = int(model.jnt_dofadr[jid])
        self._sites = np.asarray(sites)
        self.damping = float(model.dof_damping[self._dof])
        self.closed_limit = float(model.jnt_range[jid, 1])
        limited = bool(model.actuator_forcelimited[aid])
        self.force_limit = float(model.actuator_forcerange[aid, 1]) if limited else 1.0
        self.pad_area_m2 = float(sum(site_area(model, int(s)) for s in sites))
        self.sigma_nm, self.dropout = float(sigma_nm), float(dropout)
        self.drive_fraction = float(drive_fraction)
        self.stall_rad_s = float(stall_rad_s)
        self.limit_margin_rad = float(limit_margin_rad)

    def _lever_m(self, centre: np.ndarray) -> float:
        """Distance from the joint axis to the pad centre, metres."""
        anchor = self.data.xanchor[self._jid]
        axis = self.data.xaxis[self._jid]
        r = centre - anchor
        return float(np.linalg.norm(r - np.dot(r, axis) * axis))

    def _measure(self) -> FingerTorqueReading:
        d = self.data
        tau = float(d.actuator_force[self._aid])
        s = self.faults.noise_scale * self.sigma_nm
        if s > 0:
            tau += float(self.rng.normal(0.0, s))
        q, qd = float(d.qpos[self._qadr]), float(d.qvel[self._dof])
        centre = d.site_xpos[self._sites].mean(axis=0)
        pressing = (
            tau > self.drive_fraction * self.force_limit
            and qd < self.stall_rad_s
            and q < self.closed_limit - self.limit_margin_rad
        )
        p_drop = combined_dropout(self.dropout, self.faults)
        if p_drop > 0 and self.rng.random() < p_drop:
            pressing = False
        force = 0.0
        if pressing:
            force = max(tau - self.damping * qd, 0.0) / max(self._lever_m(centre), 1e-3)
        return FingerTorqueReading(
            pressure=np.array([force / self.pad_area_m2]),
            positions_world=centre[None, :].copy(),
            force=np.array([force]),
            torque_nm=tau,
            qpos=q,
            qvel=qd,
            pressing=bool(pressing),
            name=self.name,
        )
