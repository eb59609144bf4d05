"""Grasp planning (pure geometry) and the closed-loop controller in the simulator.

The planner tests check the chosen closing axis against brute force over the cube's faces.
The episode tests marked ``controller alone`` drive the loop from a ground-truth
``localize_fn``: they test the controller (IK, touch-based closing, lifting, evaluation),
not localization, which has its own tests and the regression table.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mks_sim.errors import DataError, NotFound, SpecError
from mks_sim.tasks.grasp import GraspFeature, ObjectGeometry, plan_grasp
from mks_sim.tasks.objects import geometry_for
from mks_sim.tasks.spec import GraspAction

BOX = ObjectGeometry("box", half_extents_m=(0.025, 0.025, 0.025))
CUBE_ACTION = GraspAction(grasp_type="opposite_faces")


def _pose(R: np.ndarray, t: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


@pytest.mark.parametrize("seed", range(20))
def test_cube_axis_is_a_most_horizontal_face_normal(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    pref = rng.uniform(-math.pi, math.pi)
    plan = plan_grasp(_pose(R, (0.1, 0.0, 0.8)), CUBE_ACTION, BOX, preferred_yaw=pref, table_z=0.75)
    axis = np.array([math.cos(plan.yaw_rad), math.sin(plan.yaw_rad), 0.0])
    # Brute force: the face normals with the smallest vertical component...
    tilt = np.abs(R[2, :])
    best = np.flatnonzero(tilt <= tilt.min() + 0.05)
    # ...one of them, projected on the table, is parallel to the closing axis.
    cos = [
        abs(axis @ (R[:, i] - R[2, i] * np.array([0, 0, 1.0]))) / np.linalg.norm(R[:2, i])
        for i in best
    ]
    assert max(cos) == pytest.approx(1.0, abs=1e-9)
    assert plan.width_m == pytest.approx(0.05)
    assert abs((plan.yaw_rad - pref + math.pi) % (2 * math.pi) - math.pi) <= math.pi / 2 + 1e-9


def test_flat_cube_picks_the_pair_nearest_the_preferred_yaw() -> None:
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    plan = plan_grasp(_pose(R, (0, 0, 0.775)), CUBE_ACTION, BOX, preferred_yaw=math.radians(100))
    # Candidates 30 + k*90 deg; nearest 100 deg is 120 deg.
    assert math.degrees(plan.yaw_rad) == pytest.approx(120.0)
    assert plan.grasp_point_world == pytest.approx((0, 0, 0.775))
    assert plan.pregrasp_world == pytest.approx((0, 0, 0.775 + 0.12))
    assert plan.lifted_world == pytest.approx((0, 0, 0.875))


def test_clearance_keeps_fingertips_off_the_table() -> None:
    plan = plan_grasp(
        _pose(np.eye(3), (0, 0, 0.76)), CUBE_ACTION, BOX, table_z=0.75, min_clearance_m=0.02
    )
    assert plan.grasp_point_world[2] == pytest.approx(0.77)


def test_sphere_and_feature() -> None:
    sphere = geometry_for("sphere_3cm")
    plan = plan_grasp(_pose(np.eye(3), (0.1, 0.2, 0.83)), GraspAction(grasp_type="through_centre"),
                      sphere, preferred_yaw=0.3)  # fmt: skip
    assert plan.yaw_rad == pytest.approx(0.3)
    assert plan.width_m == pytest.approx(0.06)
    part = geometry_for("part")
    R = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    act = GraspAction(grasp_type="feature", feature="boss")
    plan = plan_grasp(_pose(R, (0.0, 0.0, 0.75)), act, part, preferred_yaw=0.0, table_z=0.75)
    # The boss at (0.02, 0, 0.022) in the object frame, rotated 90 deg about z.
    assert plan.grasp_point_world == pytest.approx((0.0, 0.02, 0.772))
    assert abs(math.cos(plan.yaw_rad)) == pytest.approx(0.0, abs=1e-9)  # closes along world y


def test_planner_errors() -> None:
    with pytest.raises(DataError, match=r"expected a finite 4x4"):
        plan_grasp(np.full((4, 4), np.nan), CUBE_ACTION, BOX)
    with pytest.raises(
        NotFound, match=r"grasp feature 'handle' not in the model; known: \['boss', 'step'\]"
    ):
        plan_grasp(
            np.eye(4), GraspAction(grasp_type="feature", feature="handle"), geometry_for("part")
        )
    with pytest.raises(SpecError, match=r"needs a box model, got 'sphere'"):
        plan_grasp(np.eye(4), CUBE_ACTION, geometry_for("sphere_3cm"))
    with pytest.raises(NotFound, match=r"no grasp geometry for model 'torus'"):
        geometry_for("torus")
    assert isinstance(geometry_for("part").features["boss"], GraspFeature)


def _truth_localize(world, name):  # controller alone: ground truth stands in for sensing
    from mks_sim.sim import truth

    return truth.object_to_world(world, name)


@pytest.mark.slow
@pytest.mark.parametrize(("obj", "seed"), [("cube", 3), ("sphere", 4)])
def test_controller_alone_lifts_object(obj: str, seed: int) -> None:
    """Controller alone (ground-truth localize_fn): the object ends >= 8 cm up for 1 s."""
    from mks_sim.tasks.episode import run_episode

    r = run_episode(obj, seed, localize_fn=_truth_localize)
    assert r.success, r.attempts_log
    assert r.believed_success
    assert r.min_clearance_m >= 0.08
    assert r.position_error_mm < 1.0  # the estimate is the truth at sensing time


@pytest.mark.slow
def test_controller_alone_retries_after_a_bad_estimate() -> None:
    """A first estimate 6 cm off misses (no two-sided touch); the loop re-localizes and
    succeeds on the retry, and the ground-truth verdict agrees."""
    from mks_sim.tasks.episode import run_episode

    calls = []

    def localize(world, name):
        T = _truth_localize(world, name)
        calls.append(1)
        if len(calls) == 1:
            T = T.copy()
            T[0, 3] += 0.06
        return T

    r = run_episode("sphere", 5, localize_fn=localize)
    assert r.retries >= 1
    assert r.success, r.attempts_log
    assert any(line.startswith("attempt 1: failed") for line in r.attempts_log)


@pytest.mark.slow
def test_episode_is_deterministic_and_failed_touch_pad_tolerated() -> None:
    from mks_sim.tasks.episode import run_episode

    a = run_episode("cube", 7, localize_fn=_truth_localize)
    b = run_episode("cube", 7, localize_fn=_truth_localize)
    assert (a.success, a.sim_time_s, a.estimate) == (b.success, b.sim_time_s, b.estimate)
    c = run_episode("cube", 7, faults=("touch_finger_2",), localize_fn=_truth_localize)
    assert c.success, c.attempts_log


def test_unknown_object_and_device() -> None:
    from mks_sim.errors import SpecError as SE
    from mks_sim.tasks.episode import run_episode

    with pytest.raises(NotFound, match=r"unknown object 'pyramid'"):
        run_episode("pyramid", 0, localize_fn=_truth_localize)
    with pytest.raises(SE, match=r"unknown device 'laser'"):
        run_episode("cube", 0, faults=("laser",), localize_fn=_truth_localize)


def test_preshape_opens_wider_for_wider_objects() -> None:
    from mks_sim.tasks.grasp import FINGER_Q, PAD_APERTURE_M, preshape_q

    widths = np.linspace(0.0, 0.2, 21)
    q = [preshape_q(w) for w in widths]
    assert all(a >= b for a, b in zip(q, q[1:]))  # wider object -> more open (smaller q)
    assert min(q) == pytest.approx(FINGER_Q[0]) and max(q) <= FINGER_Q[-1]
    # The aperture at the pre-shape angle is the width plus the margin (table interpolation).
    assert np.interp(preshape_q(0.05), FINGER_Q, PAD_APERTURE_M) == pytest.approx(0.085, abs=1e-3)


@pytest.mark.slow
def test_cli_grasp_json_with_sensor_localization(capsys: pytest.CaptureFixture[str]) -> None:
    """The shipped command end to end (real sensor-based localization), JSON on stdout."""
    import json

    from mks_sim.cli import main

    assert main(["grasp", "--object", "sphere", "--episodes", "1", "--seed", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    (ep,) = doc["episodes"]
    assert set(ep) >= {"seed", "success", "retries", "error", "time_s"}
    assert set(ep["error"]) == {"position_mm", "rotation_deg"}
    assert ep["seed"] == 2 and ep["success"] is True
    assert ep["error"]["position_mm"] < 5.0
    assert doc["success_rate"] == 1.0


def test_cli_grasp_rejects_bad_counts(capsys: pytest.CaptureFixture[str]) -> None:
    from mks_sim.cli import main

    assert main(["grasp", "--object", "cube", "--episodes", "0"]) == 2
    assert "--episodes: expected >= 1, got 0" in capsys.readouterr().err
