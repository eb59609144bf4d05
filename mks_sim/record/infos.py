"""One fixed per-step ``info`` for recorded episodes.

Minari stores infos column-wise, so every step of every episode (the reset included) must
carry the same keys with the same types and shapes. :class:`StepInfo` wraps a
``mks_sim/Grasp-v*`` env and replaces its info by one flat dict (flat because Minari 0.5.4's
Arrow reader returns nested info dicts as arrays of dicts):

- ``success``: bool, the env's ground-truth verdict (evaluation only);
- ``estimate``: (4, 4) float64, the localization estimate ``object_to_world`` the policy
  sees (NaN when localization found nothing);
- ``estimate_valid``: bool;
- ``position_error_mm``, ``rotation_error_deg``: float, that estimate against ground truth
  (NaN when there is no estimate) -- evaluation only;
- ``provenance.<sensor>``: str, the way that served the logical sensor at the last sensing
  (``"primary"``, an alternate's name, or ``""`` when it did not run), for every logical
  sensor of the default sensor graph (``sensors/*.toml``);
- ``failed.<device>``: bool, the device is failed for the episode, for every declared device.

The sensor and device names are also in the dataset's metadata.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

__all__ = ["StepInfo", "default_names"]


def default_names() -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(logical sensor names, device names) of the default sensor graph, in file order."""
    from mks_sim.sensing import SensorGraph

    graph = SensorGraph.from_dir()
    return tuple(graph.sensor_names), tuple(sorted(graph.device_names))


def _float(x: Any) -> float:
    return float("nan") if x is None or not math.isfinite(float(x)) else float(x)


class StepInfo(gym.Wrapper):
    """Replace a grasp env's ``info`` by the fixed structure of this module.

    Args:
        env: a ``mks_sim/Grasp-v*`` env (``gym.make`` result).
        sensors: logical sensors reported in ``provenance`` (default: the sensor graph's).
        devices: devices reported in ``faults`` (default: the sensor graph's).
    """

    def __init__(
        self,
        env: gym.Env,
        sensors: Sequence[str] | None = None,
        devices: Sequence[str] | None = None,
    ) -> None:
        super().__init__(env)
        if sensors is None or devices is None:
            default_sensors, default_devices = default_names()
            sensors = default_sensors if sensors is None else sensors
            devices = default_devices if devices is None else devices
        self.sensors = tuple(sensors)
        self.devices = tuple(devices)
        failed = set(getattr(env.unwrapped, "faults", ()))
        self._faults = {d: d in failed for d in self.devices}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        return obs, self.fixed(obs, info)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self.fixed(obs, info)

    def fixed(self, obs: Mapping[str, Any], info: Mapping[str, Any]) -> dict[str, Any]:
        """The fixed-structure info of one step from the env's observation and info."""
        valid = bool(np.asarray(obs["pose_valid"]).reshape(-1)[0])
        estimate = np.array(obs["pose_estimate"], dtype=np.float64).reshape(4, 4)
        if not valid:
            estimate[:] = np.nan
        err = info.get("localization_error") or {}
        served = info.get("provenance") or {}
        out: dict[str, Any] = {
            "success": bool(info.get("success", False)),
            "estimate": estimate,
            "estimate_valid": valid,
            "position_error_mm": _float(err.get("position_mm")),
            "rotation_error_deg": _float(err.get("rotation_deg")),
        }
        out.update({f"provenance.{s}": str(served.get(s, "")) for s in self.sensors})
        out.update({f"failed.{d}": failed for d, failed in self._faults.items()})
        return out
