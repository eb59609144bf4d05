"""Re-localization during the approach (issue 9 section 4), in the simulator.

The object is pushed a few centimetres through the simulator (its free joint moved by
``World.set_object_pose``) right after the first localization, before the arm moves. With
re-sensing every 0.2 s of simulated time the episode corrects its target and lifts the object
on the first attempt; the control run, identical but without re-sensing, closes on the empty
spot and fails. Both use the real sensor-based localization (range finder, workstation
pipeline): the push is found by sensing, never read from the simulator.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mks_sim.tasks.episode import RESENSE_PERIOD_S, run_episode
from mks_sim.tasks.spec import task_for_object

PUSH_M = np.array([-0.03, 0.03, 0.0])  # toward the robot's side of the object region


def _pusher():
    """``on_localized`` hook: after the first localization, shove the object by PUSH_M."""
    from mks_sim.sim import truth

    pushed: list[np.ndarray] = []

    def push(world, estimate) -> None:
        if pushed:
            return
        # The test's hand, not the robot's: it may read the simulator.
        T = np.asarray(truth.object_to_world(world, "cube"), dtype=float).copy()
        T[:3, 3] += PUSH_M
        world.set_object_pose("cube", T)
        pushed.append(T)

    return push, pushed


def _single_attempt_task():
    task = task_for_object("cube")
    return dataclasses.replace(task, action=dataclasses.replace(task.action, retries=0))


@pytest.mark.slow
def test_pushed_object_is_still_grasped_when_re_sensing() -> None:
    push, pushed = _pusher()
    r = run_episode("cube", 3, task=_single_attempt_task(), on_localized=push)
    assert pushed, "the push hook never ran"
    assert r.success, r.attempts_log
    assert r.retries == 0
    assert r.corrections >= 1
    first = next(x for x in r.relocalizations if x.corrected)
    assert first.shift_mm == pytest.approx(1000 * np.linalg.norm(PUSH_M), abs=3.0)
    assert r.position_error_mm < 3.0  # the corrected estimate, against the pushed truth
    # Re-sensed at least every 0.2 s of simulated time while approaching.
    times = np.array([x.sim_time_s for x in r.relocalizations])
    assert len(times) >= 5
    gaps = np.diff(times)
    assert np.all(gaps[gaps < 1.0] <= RESENSE_PERIOD_S + 1e-6)
    doc = r.to_json()
    assert doc["relocalizations"] == len(r.relocalizations) and doc["corrections"] >= 1


@pytest.mark.slow
def test_control_without_re_sensing_misses_the_pushed_object() -> None:
    push, pushed = _pusher()
    r = run_episode(
        "cube", 3, task=_single_attempt_task(), on_localized=push, resense_period_s=None
    )
    assert pushed
    assert not r.success
    assert r.relocalizations == ()
