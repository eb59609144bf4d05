"""``mks_sim/BinPick-v0``: bin picking as a gymnasium environment (issue 13).

Each step the agent chooses which of the localized instances to pick; the robot plans a
collision-free grasp from the estimate, lifts the part out of the bin and drops it in the
output box, then senses again (:class:`mks_sim.tasks.bin.BinPicker`). The observation is
what the sensors say, padded to ``count`` rows with a validity mask:

- ``poses``: (count, 7) float64, each estimate's position (metres, world) and orientation
  quaternion (w, x, y, z; w >= 0); zeros where ``valid`` is 0;
- ``scores``: (count,) localization scores in [0, 1];
- ``valid``: (count,) int8, 1 for an estimate, best score first.

Action: ``Discrete(count)``: the row to pick (an invalid row wastes the step). Reward and
``info`` are evaluation (ground truth): reward 1.0 when the picked part ended in the output
box, else 0; ``info``: ``picked``, ``present``, ``failure``, ``provenance``, ``picks``,
``views`` (of the last sensing: 2 when the wrist camera took a second look), ``faults``
(wall-clock seconds of the last reset / step: ``env.unwrapped.last_time_s``). The
episode terminates when sensing finds nothing; gymnasium's ``max_episode_steps`` (2 x 12 + 2)
truncates it.

Example:
    >>> import gymnasium as gym, mks_sim
    >>> env = gym.make("mks_sim/BinPick-v0", count=3)           # doctest: +SKIP
    >>> obs, info = env.reset(seed=0)                            # doctest: +SKIP
    >>> obs, reward, terminated, truncated, info = env.step(0)   # doctest: +SKIP
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy.spatial.transform import Rotation

from mks_sim.errors import MksError

__all__ = ["BinPickEnv"]


class BinPickEnv(gym.Env[dict[str, np.ndarray], np.int64]):
    """Pick parts out of a bin, one chosen instance per step.

    Args:
        count: parts dropped into the bin (1..12): also the number of observation rows.
        object: the database object in the bin (default the scene's, the part).
        fail: devices failed for every episode (e.g. ``("range_finder",)``).
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        count: int = 6,
        object: str | None = None,  # noqa: A002 - the scene files' word
        fail: tuple[str, ...] = (),
    ) -> None:
        from mks_sim.tasks.bin import MAX_INSTANCES

        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_INSTANCES:
            raise ValueError(f"count: expected an integer in 1..{MAX_INSTANCES}, got {count!r}")
        self.count = count
        self.object_name = object
        self.fail = tuple(fail)
        self.observation_space = spaces.Dict(  # type: ignore[assignment]
            {
                "poses": spaces.Box(-np.inf, np.inf, (count, 7), dtype=np.float64),
                "scores": spaces.Box(0.0, 1.0, (count,), dtype=np.float64),
                "valid": spaces.MultiBinary(count),
            }
        )
        self.action_space = spaces.Discrete(count)
        self._world: Any = None
        self._devices: Any = None
        self._robot: Any = None
        self._found: list[Any] = []
        self._picks = 0
        self.last_time_s = 0.0

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        from mks_sim.devices import DeviceFaults, make_devices
        from mks_sim.tasks.bin import BinPicker, bin_world

        super().reset(seed=seed)
        self._close_devices()
        episode_seed = int(self.np_random.integers(2**31))
        self._world = bin_world(episode_seed, count=self.count, object=self.object_name)
        faults = {d: DeviceFaults(failed=True) for d in self.fail}
        rng = np.random.default_rng(episode_seed)
        self._devices = make_devices(self._world.model, self._world.data, rng, faults)
        self._robot = BinPicker(self._world, self._devices, object_name=self.object_name, rng=rng)
        self._picks = 0
        t = time.perf_counter()
        self._sense()
        return self._obs(), self._info("", time.perf_counter() - t)

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        from mks_sim.tasks.bin import in_output_box

        if self._robot is None:
            raise MksError("BinPickEnv.step: call reset() first")
        i = int(np.asarray(action).reshape(()))
        if not 0 <= i < self.count:
            raise ValueError(f"action: expected an instance row in 0..{self.count - 1}, got {i}")
        t = time.perf_counter()
        self._picks += 1
        reward, failure = 0.0, ""
        if i >= len(self._found):
            failure = "no such instance"
        else:
            cands = self._robot.grasps(i)
            if not cands:
                failure = "no grasp"
            else:
                body = self._robot.body_of(self._found[i].matrix)  # evaluation only
                ok, failure = self._robot.pick(cands)
                if body is not None and in_output_box(self._world, body):
                    reward, failure = 1.0, ""
                elif ok:
                    failure = "not in the box"
        self._sense()
        terminated = not self._found
        return self._obs(), reward, terminated, False, self._info(failure, time.perf_counter() - t)

    def close(self) -> None:
        self._close_devices()
        super().close()

    # -- helpers ------------------------------------------------------------------------------
    def _close_devices(self) -> None:
        if self._devices is not None:
            self._devices.close()
        self._devices = None

    def _sense(self) -> None:
        try:
            self._found = self._robot.sense()[: self.count]
        except MksError:
            self._found = []

    def _obs(self) -> dict[str, np.ndarray]:
        poses = np.zeros((self.count, 7), dtype=np.float64)
        scores = np.zeros(self.count, dtype=np.float64)
        valid = np.zeros(self.count, dtype=np.int8)
        for k, inst in enumerate(self._found):
            T = np.asarray(inst.matrix, dtype=np.float64)
            x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
            q = np.array([w, x, y, z])
            poses[k] = (*T[:3, 3], *(q if w >= 0 else -q))
            scores[k] = float(np.clip(inst.score, 0.0, 1.0))
            valid[k] = 1
        return {"poses": poses, "scores": scores, "valid": valid}

    def _info(self, failure: str, seconds: float) -> dict[str, Any]:
        # wall-clock time is no part of info: it would differ between identical steps
        self.last_time_s = seconds
        sensed = self._robot.sensed
        return {
            "picked": self._robot.picked(),
            "present": len(self._robot.bodies),
            "failure": failure,
            "provenance": {} if sensed is None else dict(sensed.provenance),
            "picks": self._picks,
            "views": self._robot.views,
            "faults": dict(self._robot.faults),
        }
