"""mks_sim: the Multi-sensor Kernel System (Henderson & Wu) in a simulated robotics workstation.

Importing the package sets ``MUJOCO_GL=egl`` for headless rendering unless the user chose a
backend already, and registers the gymnasium environments (``mks_sim/Grasp-v0``, ``-v1``, ``-v2``).
"""

from __future__ import annotations

import os

# Headless software rendering (Mesa EGL) is what every machine of ours has; respect a user's
# explicit choice (e.g. MUJOCO_GL=glfw on a desktop).
os.environ.setdefault("MUJOCO_GL", "egl")

from mks_sim.errors import (  # noqa: E402
    DataError,
    DeviceFailure,
    MksError,
    NotFound,
    SensorFailure,
    SpecError,
)

__all__ = [
    "DataError",
    "DeviceFailure",
    "MksError",
    "NotFound",
    "SensorFailure",
    "SpecError",
]
__version__ = "0.1.0"
__import__("mks_sim.envs", fromlist=["register_envs"]).register_envs()  # gymnasium envs
