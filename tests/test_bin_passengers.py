"""Passengers: parts lifted with the held one, seen by the range finder and carried as a
bundle into the output box (``mks_sim.tasks.bin``: :func:`held_and_passengers`,
:func:`_carry_to_box` with ``passengers``). Constructed geometry; one slow test on a tuning
bin against the simulator's truth."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mks_sim.tasks import bin as binmod
from mks_sim.tasks.grasp import down_rotation

TABLE_Z = 0.75
SIZE = np.array([0.10, 0.06, 0.03])  # a box part, metres


def _faces(step: float = 0.0025) -> dict[str, np.ndarray]:
    """The box part's six faces sampled every ``step`` (model frame, centred): name -> (K, 3)."""
    h = SIZE / 2
    out = {}
    for axis, sign in itertools.product(range(3), (-1.0, 1.0)):
        u, v = [a for a in range(3) if a != axis]
        gu = np.arange(-h[u], h[u] + 1e-9, step)
        gv = np.arange(-h[v], h[v] + 1e-9, step)
        uu, vv = np.meshgrid(gu, gv, indexing="ij")
        P = np.zeros((uu.size, 3))
        P[:, u], P[:, v], P[:, axis] = uu.ravel(), vv.ravel(), sign * h[axis]
        out[f"{'-+'[sign > 0]}{'xyz'[axis]}"] = P
    return out


def _pose(xyz, yaw_deg: float, tilt_deg: float = 0.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zx", [yaw_deg, tilt_deg], degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T


def _posed(P: np.ndarray, T: np.ndarray) -> np.ndarray:
    return P @ T[:3, :3].T + T[:3, 3]


def _floor(z: float = TABLE_Z) -> np.ndarray:
    x, y = np.meshgrid(np.arange(-0.17, 0.17, 0.005), np.arange(-0.13, 0.13, 0.005))
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _held_truth(pinch: np.ndarray, shift_m: float, turn_deg: float) -> np.ndarray:
    """Where the held box of :func:`_scene` really hangs: its estimate moved ``shift_m``
    along x, turned ``turn_deg`` about the vertical and tilted 3 degrees."""
    return _pose(pinch - [0.0, 0.0, 0.02] + [shift_m, 0.0, 0.0], 35.0 + turn_deg, 3.0)


def _scene(shift_m: float, turn_deg: float, passenger: bool):
    """A picked box held at the travel height, its estimate ``shift_m`` and ``turn_deg`` off
    its true pose (turned in the grasp), a box left lying in the pile and maybe a passenger
    hanging beside the held one: (sensed now, sensed before, samples, the estimate, pinch,
    the passenger's points seen)."""
    faces = _faces()
    samples = np.concatenate(list(faces.values()))
    seen = np.concatenate([faces["+z"], faces["+x"]])  # the scanner's view: top and one side
    lying = _pose([0.05, -0.06, TABLE_Z + SIZE[2] / 2], 20.0)
    held_before = _pose([-0.02, 0.02, TABLE_Z + SIZE[2] / 2], 35.0)
    rider_before = _pose([-0.02, 0.09, TABLE_Z + SIZE[2] / 2], -10.0)
    before = np.concatenate(
        [_floor(), _posed(seen, lying), _posed(seen, held_before), _posed(seen, rider_before)]
    )
    pinch = np.array([-0.02, 0.02, TABLE_Z + 0.16])
    estimate = _pose(pinch - [0.0, 0.0, 0.02], 35.0)
    truth = _held_truth(pinch, shift_m, turn_deg)
    rider = _posed(seen, _pose(pinch + [0.01, 0.09, -0.07], -10.0, 25.0))
    now = [_floor()[np.linalg.norm(_floor()[:, :2] - pinch[:2], axis=1) > 0.07]]
    # lifted above the pile, the held box shows a third side to the scanner's two mounts
    now += [_posed(seen, lying), _posed(np.concatenate([seen, faces["-y"]]), truth)]
    if passenger:
        now.append(rider)
    noise = np.random.default_rng(1).normal(0.0, 0.0005, (sum(map(len, now)), 3))
    return np.concatenate(now) + noise, before, samples, estimate, pinch, rider


@pytest.mark.parametrize("shift_m, turn_deg", [(0.0, 0.0), (0.008, 5.0)])
def test_a_passenger_is_told_from_the_held_part_and_the_pile(shift_m, turn_deg):
    """Of the points sensed with the hand up, those of a part hanging beside the held one are
    the passenger's; the held part's (its estimate up to 8 mm and 5 deg off) and those of a
    part lying in the pile are not (brute force: the distance to each part's seen points)."""
    from scipy.spatial import cKDTree

    now, before, samples, estimate, pinch, rider = _scene(shift_m, turn_deg, passenger=True)
    got = binmod.held_and_passengers(now, before, samples, estimate, pinch, TABLE_Z)[1]
    d = cKDTree(rider).query(got)[0]
    assert np.all(d < 0.003)  # every point returned is the passenger's
    assert len(got) >= 0.95 * len(rider)  # and nearly all of the passenger's


@pytest.mark.parametrize("shift_m, turn_deg", [(0.0, 0.0), (0.008, 5.0)])
def test_no_passenger_is_seen_when_the_held_part_is_alone(shift_m, turn_deg):
    now, before, samples, estimate, pinch, _ = _scene(shift_m, turn_deg, passenger=False)
    got = binmod.held_and_passengers(now, before, samples, estimate, pinch, TABLE_Z)[1]
    assert got.shape == (0, 3)


def _pose_error(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """(mm, degrees) between two poses."""
    R = A[:3, :3].T @ B[:3, :3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    return 1000.0 * float(np.linalg.norm(A[:3, 3] - B[:3, 3])), float(np.degrees(np.arccos(cos)))


@pytest.mark.parametrize("passenger", [False, True])
@pytest.mark.parametrize("shift_m, turn_deg", [(0.0, 0.0), (0.015, 8.0), (0.025, -6.0)])
def test_the_held_part_is_refined_on_its_points_seen_at_the_travel_height(
    shift_m, turn_deg, passenger
):
    """The held box turned and slid in the grasp (up to 25 mm and 8 degrees from the
    estimate it was grasped at): the pose returned is within 2 mm and 1 degree of where it
    really hangs (the scene's truth; the box is placed 15 mm inside the walls,
    PLACE_MARGIN_M), with or without a passenger beside it; the passengers' points returned
    with it are the passenger's (brute force: the distance to its seen points)."""
    from scipy.spatial import cKDTree

    now, before, samples, estimate, pinch, rider = _scene(shift_m, turn_deg, passenger)
    held, riders = binmod.held_and_passengers(now, before, samples, estimate, pinch, TABLE_Z)
    assert held is not None
    mm, deg = _pose_error(held, _held_truth(pinch, shift_m, turn_deg))
    assert mm < 2.0 and deg < 1.0
    assert _pose_error(estimate, _held_truth(pinch, shift_m, turn_deg))[0] >= 1000 * shift_m - 1e-6
    if passenger:
        assert np.all(cKDTree(rider).query(riders)[0] < 0.003)
        assert len(riders) >= 0.95 * len(rider)
    else:
        assert riders.shape == (0, 3)


def test_too_few_points_of_the_held_part_keep_its_estimate():
    """Fewer than HELD_FIT_MIN_POINTS lifted points (the hand hides the part, or the
    scanner's view misses it): no refined pose, the estimate it was grasped at is carried."""
    now, before, samples, estimate, pinch, _ = _scene(0.015, 8.0, passenger=False)
    lifted = binmod.lifted_points(now, before, pinch, TABLE_Z)
    keep = np.flatnonzero(lifted)[: binmod.HELD_FIT_MIN_POINTS - 1]
    sparse_now = np.concatenate([now[~lifted], now[keep]])
    held, riders = binmod.held_and_passengers(sparse_now, before, samples, estimate, pinch, TABLE_Z)
    assert held is None and riders.shape == (0, 3)
    held, _ = binmod.held_and_passengers(now, before, samples, estimate, pinch, TABLE_Z)
    assert held is not None  # all of them: refined


def test_the_picker_carries_the_held_part_as_seen():
    """``BinPicker._passengers`` on one range finder reading at the travel height returns
    the held part's pose in the pinch frame as it really hangs (the scene's truth moved into
    the hand's frame, within 2 mm and 1 degree), which ``pick`` carries to the box instead of
    the estimate; without a reading (the range finder failed), nothing."""
    from types import SimpleNamespace

    from mks_sim.errors import DeviceFailure

    now, before, samples, estimate, pinch, _ = _scene(0.02, 8.0, passenger=False)
    hand = _TurningHand(pinch, np.radians(35.0))
    P = np.eye(4)
    P[:3, :3], P[:3, 3] = hand.pinch_rotation(), hand.pinch_pos()

    class Scanner:
        failed = False

        def read(self):
            if self.failed:
                raise DeviceFailure("range_finder", "no reading")
            return [SimpleNamespace(hit_points=now, view=0)]

    robot = object.__new__(binmod.BinPicker)
    scanner = Scanner()
    robot.devices, robot.ctl, robot.samples = {"range_finder": scanner}, hand, samples
    robot.sensed, robot.table_z = SimpleNamespace(scene_points=before), TABLE_Z
    robot.faults_seen = {}
    riders, seen = robot._passengers(np.linalg.inv(P) @ estimate)
    assert riders.shape == (0, 3) and seen is not None
    mm, deg = _pose_error(P @ seen, _held_truth(pinch, 0.02, 8.0))
    assert mm < 2.0 and deg < 1.0
    scanner.failed = True
    riders, seen = robot._passengers(np.linalg.inv(P) @ estimate)
    assert riders.shape == (0, 3) and seen is None
    assert "range_finder" in robot.faults_seen


def test_points_not_lifted_are_no_passenger():
    """Points no higher than what was sensed there before the pick (the pile, the floor) are
    not lifted, however near the hand; a point above a cell never sensed is."""
    before = np.array([[0.0, 0.0, TABLE_Z + 0.05], [0.1, 0.0, TABLE_Z]])
    pinch = np.array([0.0, 0.0, TABLE_Z + 0.16])
    P = np.array(
        [
            [0.004, 0.0, TABLE_Z + 0.06],  # 10 mm above the pile: not lifted
            [0.004, 0.0, TABLE_Z + 0.07],  # 20 mm above it: lifted
            [0.1, 0.0, TABLE_Z + 0.01],  # 10 mm above the floor: not lifted
            [-0.1, 0.0, TABLE_Z + 0.02],  # nothing sensed there before: above the table
            [0.3, 0.0, TABLE_Z + 0.1],  # beyond the hand's reach
        ]
    )
    lifted = binmod.lifted_points(P, before, pinch, TABLE_Z)
    assert lifted.tolist() == [False, True, False, True, False]


def test_lifted_points_match_a_brute_force_over_every_point_sensed_before():
    """Random scenes: a point is lifted exactly when it is within reach of the hand and more
    than LIFTED_ABOVE_M above the table and above every point sensed before whose cell is its
    own or one of the eight around it (each pair checked, no grid)."""
    rng = np.random.default_rng(5)
    cell, above = binmod.LIFTED_CELL_M, binmod.LIFTED_ABOVE_M
    for _ in range(5):
        before = rng.uniform([-0.2, -0.2, TABLE_Z], [0.2, 0.2, TABLE_Z + 0.08], size=(300, 3))
        P = rng.uniform([-0.35, -0.35, TABLE_Z], [0.35, 0.35, TABLE_Z + 0.15], size=(400, 3))
        pinch = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), TABLE_Z + 0.16])
        cb, cp = np.floor(before[:, :2] / cell), np.floor(P[:, :2] / cell)
        want = []
        for k in range(len(P)):
            if np.hypot(*(P[k, :2] - pinch[:2])) >= binmod.LIFTED_REACH_M:
                want.append(False)
                continue
            around = np.all(np.abs(cb - cp[k]) <= 1, axis=1)
            floor = max([TABLE_Z, *before[around, 2]])
            want.append(bool(P[k, 2] > floor + above))
        got = binmod.lifted_points(P, before, pinch, TABLE_Z)
        assert got.tolist() == want
        assert 0 < sum(want) < len(P)
    assert not binmod.lifted_points(P, np.zeros((0, 3)), pinch, P[:, 2].max()).any()


class _TurningHand:
    """A hand that goes where it is told, turning top-down to the yaw asked for."""

    def __init__(self, pos, yaw):
        self.pos, self.R, self.path = np.asarray(pos, float), down_rotation(yaw), []
        self.spacings: list[float] = []

    def pinch_pos(self):
        return self.pos.copy()

    def pinch_rotation(self):
        return self.R.copy()

    def pinch_yaw(self):
        return float(np.arctan2(self.R[1, 0], self.R[0, 0]))

    def move_to(self, pos, yaw, spacing_m=0.01, rotation=None):
        self.R = down_rotation(yaw) if rotation is None else rotation
        self.pos = np.asarray(pos, dtype=float).copy()
        self.path.append((self.pos.copy(), self.R.copy()))
        self.spacings.append(spacing_m)
        return True

    def finger_qpos(self):
        return np.full(3, 0.9)  # closed on a part


@pytest.mark.parametrize("before", [0, 2, "full"])
def test_the_bundle_is_let_go_inside_the_box(before):
    """A held 100 x 60 x 30 mm box with a passenger hanging 150 mm beside it and 60 mm lower
    is let go with the whole bundle inside the box's walls, and carried over both walls
    (brute force over the corners). Placed for the held part alone, the passenger hung over
    the wall (tuning bins 22, 35, 36). Let go where no part was let go before (the robot's
    record, ``before`` parts placed first), the bundle's lowest point is
    BUNDLE_FLOOR_GAP_M above the box's floor; with the box's whole floor taken ("full"),
    RELEASE_GAP_M above its rim."""
    table_z = 0.5
    corners = np.array(list(itertools.product(*[(-s / 2, s / 2) for s in SIZE])))
    held = corners + [0.0, 0.0, -0.03]  # pinch frame
    turned = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    rider = corners @ turned.T + np.array([0.0, 0.15, -0.09])
    from _bin_stubs import bin_box

    box = bin_box()
    inside = np.asarray(box.inner_half_xy)
    c = np.asarray(box.center_xy)
    rim = table_z + box.wall_height_m

    def carried(passengers):
        placed: list[np.ndarray] = []
        if before == "full":
            placed.append(np.concatenate([c - box.half_xy, c + box.half_xy]))
        for _ in range(0 if before == "full" else before):
            m = binmod.place_middle(np.array([0.05, 0.03]), placed, box)
            placed.append(np.concatenate([m - [0.05, 0.03], m + [0.05, 0.03]]))
        taken = np.array(placed).reshape(-1, 4)
        hand = _TurningHand([0.05, -0.02, table_z + 0.16], 0.4)
        assert (
            binmod._carry_to_box(hand, held, table_z, None, box, placed=placed, **passengers) == ""
        )
        # brute force: did the bundle's footprint overlap a footprint placed before?
        mine = placed[-1]
        hand.free = not any(
            min(mine[2], r[2]) > max(mine[0], r[0]) and min(mine[3], r[3]) > max(mine[1], r[1])
            for r in taken
        )
        return hand

    hand = carried({"passengers": rider})
    B = np.concatenate([held, rider]) @ hand.R.T + hand.pos
    assert np.all(np.abs(B[:, :2] - c) <= inside)
    assert hand.free == (before != "full") or before == 2
    # the lowest of the bundle and the fingertips
    lowest = min(B[:, 2].min(), hand.pos[2] - binmod.TIPS_BELOW_PINCH_M)
    if hand.free:
        assert lowest == pytest.approx(table_z + binmod.BUNDLE_FLOOR_GAP_M)
    else:
        assert lowest == pytest.approx(rim + binmod.RELEASE_GAP_M)
    for pos, R in hand.path:  # over the walls, until it is over its place
        if np.allclose(pos[:2], hand.pos[:2]):
            continue
        low = (np.concatenate([held, rider]) @ R.T + pos)[:, 2].min()
        assert (
            low
            >= table_z + max(binmod.BIN_WALL_M, box.wall_height_m) + binmod.CARRY_MARGIN_M - 1e-9
        )
    alone = carried({})
    B = np.concatenate([held, rider]) @ alone.R.T + alone.pos
    assert not (np.all(np.abs(B[:, :2] - c) <= inside) and B[:, 2].min() > rim)


def test_a_bundle_is_carried_higher_and_slower_than_a_part_alone():
    """A passenger hangs lower than the points seen of it (tuning bins 45, 47: dragged over
    the walls, it pulled the held part out of the grasp): the bundle's lowest seen point
    crosses the walls BUNDLE_LIFT_M higher than a part alone needs, at BUNDLE_SPACING_M a
    waypoint; the same part carried alone at CARRY_SPACING_M and no higher than the margin
    asks."""
    table_z = 0.5
    corners = np.array(list(itertools.product(*[(-s / 2, s / 2) for s in SIZE])))
    held = corners + [0.0, 0.0, 0.03]  # pinch frame (z down): 30 mm below the pinch point
    rider = corners + np.array([0.0, 0.07, 0.06])  # beside it and 30 mm lower
    from _bin_stubs import bin_box

    box = bin_box()
    wall_top = table_z + max(binmod.BIN_WALL_M, box.wall_height_m)

    def crossing(passengers):
        """(lowest point of what is carried, spacing) of the move from the bin to the box."""
        hand = _TurningHand([0.05, -0.02, table_z + 0.16], 0.0)
        load = held if passengers is None else np.concatenate([held, passengers])
        why = binmod._carry_to_box(hand, held, table_z, None, box, placed=[], passengers=passengers)
        assert why == ""
        k = next(
            k for k, (pos, _) in enumerate(hand.path) if not np.allclose(pos[:2], [0.05, -0.02])
        )
        pos, R = hand.path[k]
        return (load @ R.T + pos)[:, 2].min(), hand.spacings[k]

    low, spacing = crossing(rider)
    assert low >= wall_top + binmod.CARRY_MARGIN_M + binmod.BUNDLE_LIFT_M - 1e-9
    assert spacing == binmod.BUNDLE_SPACING_M < binmod.CARRY_SPACING_M
    low_alone, spacing_alone = crossing(None)
    assert spacing_alone == binmod.CARRY_SPACING_M == 0.02
    # alone: at the pick's travel height, or the margin over the walls, whichever is higher
    hangs = 0.03 + SIZE[2] / 2
    assert low_alone == pytest.approx(max(table_z + 0.16 - hangs, wall_top + binmod.CARRY_MARGIN_M))
    assert low_alone < wall_top + binmod.CARRY_MARGIN_M + binmod.BUNDLE_LIFT_M


@pytest.mark.slow
def test_passengers_on_a_tuning_bin_are_seen_and_land_in_the_box(monkeypatch):
    """Tuning bin 22's first two picks lift one and two parts with the held one (the
    simulator's truth: they stand 7 cm above the table as the carry begins): the range
    finder sees them, and all five end in the output box (placed for the held part alone,
    the second pick's two passengers hung beyond the box's +y wall and were lost)."""
    from mks_sim.devices import make_devices
    from mks_sim.sim import truth

    seed = 22
    world = binmod.bin_world(seed)
    bodies = binmod.instance_bodies(world)
    lifted: list[list[str]] = []
    carry = binmod._carry_to_box

    def watched(ctl, part_pinch, table_z, rotation, box, **kw):
        z = {b: truth.object_to_world(world, b)[2, 3] for b in bodies}
        lifted.append([b for b in bodies if z[b] > table_z + 0.07])
        return carry(ctl, part_pinch, table_z, rotation, box, **kw)

    monkeypatch.setattr(binmod, "_carry_to_box", watched)
    with make_devices(world.model, world.data, np.random.default_rng(seed), {}) as devices:
        rec = binmod.clear_bin(world, devices, rng=np.random.default_rng(seed), budget=2)
    assert [len(up) for up in lifted] == [2, 3]  # the held part and its passengers
    assert all(p["passenger_points"] >= binmod.PASSENGER_POINTS for p in rec["picks"])
    assert all(binmod.in_output_box(world, b) for up in lifted for b in up)
