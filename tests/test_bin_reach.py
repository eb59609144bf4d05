"""Reaching a part in the bin: the palm, not only the fingertips, clear of the part."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.sim.names import TABLE_TOP_Z

# Tuning bin 1 at 66753af, the state before its fourth pick (the arm at home, the pile
# settled): part_4 stands on its end, 100 mm tall. The estimate is the one that pick used
# (0.0 mm / 0.1 degrees from the truth); the grasp is its first candidate, pinching across
# the part's 60 mm width 17 mm above the table: the knuckles and the palm came down on the
# part's top and the descent stopped 8-14 mm short, three candidates in a row.
_BIN1_QPOS = (
    -1.107418117, 2.78855607, 1.170708587, 3.725257542, -1.845835353, 10.463830641,
    0.149602903, 0.149602853, 0.149602754, -0.262165934, 0.17797569, 0.778006381,
    0.821904182, 0.566458469, -0.034291094, -0.049218292, 0.094648873, -0.02225644,
    0.77789374, -0.053138582, -0.487415748, 0.871037576, -0.029928586, -0.291530719,
    0.243437943, 0.77999618, 0.537689478, 0.539095609, 0.458971729, 0.457832832,
    -0.412081764, 0.252225298, 0.769257221, 0.738538808, -0.170634558, 0.201748219,
    -0.620275691, 0.029843018, -0.012803231, 0.79995369, -0.600245176, 0.374138536,
    0.599640783, 0.374375501, -0.380701032, 0.178896561, 0.765901667, -0.763992214,
    0.19407615, -0.167169878, 0.592203155,
)  # fmt: skip
_BIN1_ESTIMATE = (
    (-0.00135888842, 0.898559847, -0.438848897, 0.0298205494),
    (-0.0014721709, 0.438847029, 0.898560581, -0.0128098584),
    (0.999997993, 0.00186710414, 0.000726489512, 0.799952339),
    (0.0, 0.0, 0.0, 1.0),
)
_BIN1_GRASP = dict(
    pinch_world=(0.0270508865, -0.00696531873, 0.767166732),
    yaw_rad=0.456982257,
    width_m=0.0600031769,
    contacts_world=(
        (0.000127816903, -0.0202032806, 0.759932377),
        (0.0539739561, 0.00627264316, 0.758401086),
    ),
    normals_world=(
        (-0.898559847, -0.438847029, -0.00186710414),
        (0.898559847, 0.438847029, 0.00186710414),
    ),
    antipodal=0.999994702,
    com_distance_m=0.0305248528,
    cost=0.0305257571,
)


def _replay_bin1(cands_of):
    """The captured state, ``_pick`` with the candidates ``cands_of(robot)``: (believed held,
    failure)."""
    from _bin_replay import replayed_bin

    from mks_sim.tasks.bin import _pick
    from mks_sim.tasks.episode import TOUCH_THRESHOLD_N

    with replayed_bin(1, _BIN1_QPOS) as robot:
        ok, failure, _, _ = _pick(
            robot.ctl, cands_of(robot), robot.action, 0, None, robot.table_z, TOUCH_THRESHOLD_N
        )
        return ok, failure


def _synthesized(robot):
    """The top-down candidates synthesised from the captured estimate (no obstacles)."""
    from mks_sim.tasks.bin import BIN_MAX_FACE_LEAN_DEG, BIN_MIN_WIDTH_M
    from mks_sim.tasks.grasp import synthesize_grasps

    cands = synthesize_grasps(
        robot.obj, np.asarray(_BIN1_ESTIMATE), table_z=robot.table_z,
        rng=np.random.default_rng(1), preferred_yaw=_BIN1_GRASP["yaw_rad"],
        min_width_m=BIN_MIN_WIDTH_M, max_face_lean_deg=BIN_MAX_FACE_LEAN_DEG,
    )  # fmt: skip
    return [c for c in cands if c.rotation_world is None]


@pytest.mark.slow
def test_a_part_standing_on_end_is_not_pinched_under_the_palm():
    """The captured grasp of tuning bin 1 is blocked in the simulator (the hand on the part's
    own top); the synthesis no longer offers it nor one like it (before, one of 24 top-down
    candidates was), and the first one it offers reaches the part and holds it."""
    from mks_sim.tasks.bin import _alike
    from mks_sim.tasks.grasp import GraspCandidate

    blocked = GraspCandidate(**_BIN1_GRASP)  # type: ignore[arg-type]
    ok, failure = _replay_bin1(lambda robot: [blocked])
    assert not ok and failure == "unreachable (0 pre-grasp, 1 descent blocked)", failure

    seen: list = []

    def offered(robot):
        seen.extend(_synthesized(robot))
        return seen[:1]

    ok, failure = _replay_bin1(offered)
    assert seen and not any(_alike(c, blocked) for c in seen)
    # the palm is 72 mm above the pinch point: over a 100 mm tall part it pinches above 28 mm
    assert all(c.pinch_world[2] > TABLE_TOP_Z + 0.028 for c in seen)
    assert ok and failure == "", failure
