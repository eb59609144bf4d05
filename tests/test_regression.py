"""End-to-end regression: known poses (tests/regression_poses.toml) are localized from the
simulated sensors within tolerance and grasped successfully (ground-truth verdict)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

TABLE = Path(__file__).with_name("regression_poses.toml")
_DOC = tomllib.loads(TABLE.read_text())
POSES = _DOC["pose"]
TOL = _DOC["tolerance"]


def _place(obj: str, x: float, y: float, yaw_deg: float):
    """Setup hook: the object (the sphere: its cube, with the sphere on top) at (x, y, yaw)."""

    def setup(world) -> None:
        from mks_sim.sim import names

        def pose(z: float, yaw: float) -> np.ndarray:
            c, s = math.cos(yaw), math.sin(yaw)
            T = np.eye(4)
            T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
            T[:3, 3] = (x, y, z)
            return T

        yaw = math.radians(yaw_deg)
        top = names.TABLE_TOP_Z
        if obj == "cube":
            world.set_object_pose("cube", pose(top + names.CUBE_SIZE_M / 2, yaw))
        elif obj == "sphere":
            world.set_object_pose("cube", pose(top + names.CUBE_SIZE_M / 2, yaw))
            world.set_object_pose(
                "sphere", pose(top + names.CUBE_SIZE_M + names.SPHERE_RADIUS_M, 0.0)
            )
        else:
            z = world.data.body("part").xpos[2]
            world.set_object_pose("part", pose(z, yaw))
        _clear_clutter(world, x, y)
        world.settle(150)
        world.mark_initial()

    return setup


def _clear_clutter(world, x: float, y: float) -> None:
    """Park clutter that the seeded placement put within 9 cm of the known pose."""
    for k, name in enumerate(n for n in world.object_names if n.startswith("clutter")):
        p = world.data.body(name).xpos
        if math.hypot(p[0] - x, p[1] - y) < 0.09:
            T = np.eye(4)
            T[:3, 3] = (-1.6, 1.6 + 0.15 * k, 0.05)
            world.set_object_pose(name, T)


def test_table_is_well_formed() -> None:
    assert len(POSES) >= 6
    assert {p["object"] for p in POSES} == {"cube", "sphere", "part"}
    for p in POSES:
        assert abs(p["x"]) <= 0.12 and abs(p["y"]) <= 0.10  # inside the object region


@pytest.mark.slow
@pytest.mark.parametrize("entry", POSES, ids=[f"{p['object']}-{p['seed']}" for p in POSES])
def test_known_pose_localized_and_grasped(entry: dict) -> None:
    from mks_sim.tasks.episode import run_episode

    # Re-sensing during the approach (15-25 localizations an episode) is tested in
    # test_relocalize.py; here the known poses are localized and grasped without it, which
    # keeps these six episodes within the suite's time budget.
    r = run_episode(entry["object"], entry["seed"], resense_period_s=None,
                    setup=_place(entry["object"], entry["x"], entry["y"], entry["yaw_deg"]))  # fmt: skip
    assert r.position_error_mm <= TOL["position_mm"], r
    if entry["object"] != "sphere":
        assert r.rotation_error_deg <= TOL["rotation_deg"], r
    assert r.success, r.attempts_log
