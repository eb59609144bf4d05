"""Simulated fingertip touch pad: an array of taxels, each a MuJoCo ``touch`` sensor.

A MuJoCo touch sensor reports the summed normal contact force (N) of the contacts inside its
site's volume. A taxel's pressure is that force divided by the taxel's area (Pa): the area of
a box site's largest face (``4 * s_a * s_b`` of its two largest half-sizes), ``pi r^2`` for a
sphere / cylinder / capsule site, ``pi a b`` for an ellipsoid. Taxel positions are the site
origins in the world frame (``data.site_xpos``).

Noise: Gaussian pressure noise ``sigma_pa`` (times the fault's ``noise_scale``), clipped at 0;
dropped taxels read 0 Pa.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mks_sim.devices.faults import DeviceFaults, SimDevice, combined_dropout
from mks_sim.errors import SpecError


@dataclass(frozen=True, eq=False)
class TouchReading:
    """One touch-pad reading.

    Attributes:
        pressure: (T,) float64 pressure per taxel, Pa (>= 0).
        positions_world: (T, 3) float64 taxel centres in the world frame, metres.
        force: (T,) float64 normal force per taxel, N (pressure * area, with the same noise).
        name: the device name.
    """

    pressure: np.ndarray
    positions_world: np.ndarray
    force: np.ndarray
    name: str


def site_area(model: mujoco.MjModel, site_id: int) -> float:
    """Sensing area (m^2) of a taxel site, from its type and size."""
    size = np.asarray(model.site_size[site_id], dtype=float)
    st = int(model.site_type[site_id])
    if st == mujoco.mjtGeom.mjGEOM_BOX:
        a, b = np.sort(size)[-2:]
        return float(4.0 * a * b)
    if st == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        a, b = np.sort(size)[-2:]
        return float(np.pi * a * b)
    return float(np.pi * size[0] ** 2)  # sphere, capsule, cylinder: radius is size[0]


class TouchPad(SimDevice):
    """A fingertip pad; ``read()`` -> :class:`TouchReading`.

    Args:
        model, data: the MuJoCo model and data.
        sensors: names of the pad's MuJoCo touch sensors, one per taxel.
        rng: generator for noise and dropout.
        name: device name, e.g. ``touch_finger_1``.
        sigma_pa: nominal pressure noise, Pa.
        dropout: nominal fraction of dead taxels per reading.
        faults: initial fault state.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        sensors: Sequence[str],
        rng: np.random.Generator,
        *,
        name: str,
        sigma_pa: float = 20.0,
        dropout: float = 0.0,
        faults: DeviceFaults | None = None,
    ) -> None:
        super().__init__(name, rng, faults)
        if not sensors:
            raise SpecError(f"device {name!r}: expected at least one taxel touch sensor, got none")
        self.model, self.data = model, data
        adr, site_ids, areas = [], [], []
        for s in sensors:
            sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, s)
            if sid < 0:
                raise SpecError(f"device {name!r}: {s!r} is not a sensor of the model")
            if model.sensor_type[sid] != mujoco.mjtSensor.mjSENS_TOUCH:
                raise SpecError(f"device {name!r}: sensor {s!r} is not a touch sensor")
            adr.append(int(model.sensor_adr[sid]))
            site = int(model.sensor_objid[sid])
            site_ids.append(site)
            areas.append(site_area(model, site))
        self.sensors = tuple(sensors)
        self._adr = np.asarray(adr)
        self._sites = np.asarray(site_ids)
        self.area_m2 = np.asarray(areas)
        self.sigma_pa, self.dropout = float(sigma_pa), float(dropout)

    @property
    def n_taxels(self) -> int:
        """Number of taxels."""
        return len(self._adr)

    def _measure(self) -> TouchReading:
        force = self.data.sensordata[self._adr].astype(np.float64)
        pressure = force / self.area_m2
        s = self.faults.noise_scale * self.sigma_pa
        if s > 0:
            pressure = np.maximum(pressure + self.rng.normal(0.0, s, pressure.shape), 0.0)
        p_drop = combined_dropout(self.dropout, self.faults)
        if p_drop > 0:
            pressure = np.where(self.rng.random(pressure.shape) < p_drop, 0.0, pressure)
        positions = self.data.site_xpos[self._sites].copy()
        return TouchReading(pressure, positions, pressure * self.area_m2, self.name)
