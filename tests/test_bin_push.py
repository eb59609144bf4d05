"""A push away from the wall (issue 13): a part no grasp can reach beside a bin wall is
pushed toward the bin's middle with the closed hand (``mks_sim.tasks.bin.plan_push``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from _bin_stubs import StubPicker, patch_loop

from mks_sim.tasks import bin as binmod
from mks_sim.tasks.bin import plan_push

# the bin of worlds/bin.toml: the walls' inner faces (scene region 340 x 260 mm)
WALLS_LO, WALLS_HI = np.array([-0.17, -0.13]), np.array([0.17, 0.13])
TABLE_Z = 0.75


def _box(lo, hi):
    """(8, 3) the corners of an axis-aligned box."""
    return np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )


def _tips_middle(plan):
    """(2,) the closed fingertips' middle under the pinch point (the pinch frame's y is
    (sin yaw, -cos yaw) for a top-down hand)."""
    y_axis = np.array([np.sin(plan.yaw_rad), -np.cos(plan.yaw_rad)])
    return plan.start_world[:2] + binmod.CLOSED_TIPS_MIDDLE_Y_M * y_axis


def test_a_part_against_the_minus_x_wall_is_pushed_toward_plus_x():
    """A 60 x 100 x 30 mm box 5 mm from the -x wall: pushed along +x, the closed fingertips'
    middle PUSH_INSET_M inside its edge at the wall, in the middle of its length, pressing
    PUSH_PRESS_M into its top; 50 mm (room ahead: 250 mm)."""
    part = _box((-0.165, -0.05, TABLE_Z), (-0.105, 0.05, TABLE_Z + 0.03))
    plan = plan_push(part, WALLS_LO, WALLS_HI, TABLE_Z)
    assert plan is not None
    np.testing.assert_allclose(plan.direction, [1.0, 0.0], atol=1e-12)
    assert plan.wall_gap_m == pytest.approx(0.005)
    np.testing.assert_allclose(_tips_middle(plan), [-0.165 + binmod.PUSH_INSET_M, 0.0], atol=1e-9)
    tips_z = plan.start_world[2] - binmod.CLOSED_TIPS_BELOW_PINCH_M
    assert tips_z == pytest.approx(TABLE_Z + 0.03 - binmod.PUSH_PRESS_M)
    np.testing.assert_allclose(plan.end_world - plan.start_world, [0.05, 0.0, 0.0], atol=1e-12)
    # the closing axis along the push: the closed fingers' wide side across it
    np.testing.assert_allclose([np.cos(plan.yaw_rad), np.sin(plan.yaw_rad)], [1.0, 0.0], atol=1e-12)
    # the closed fingers (15 mm either side of the pinch point along the closing axis) keep
    # off the wall
    assert plan.start_world[0] - 0.015 > WALLS_LO[0]


def test_a_part_in_the_middle_is_not_pushed():
    part = _box((-0.03, -0.05, TABLE_Z), (0.03, 0.05, TABLE_Z + 0.03))
    assert plan_push(part, WALLS_LO, WALLS_HI, TABLE_Z) is None
    # just beyond the near-wall distance from the +y wall: no push; just within: pushed -y
    gap = binmod.PUSH_NEAR_WALL_M
    far = _box((-0.03, 0.0, TABLE_Z), (0.03, 0.13 - gap - 0.001, TABLE_Z + 0.03))
    assert plan_push(far, WALLS_LO, WALLS_HI, TABLE_Z) is None
    near = _box((-0.03, 0.0, TABLE_Z), (0.03, 0.13 - gap + 0.001, TABLE_Z + 0.03))
    plan = plan_push(near, WALLS_LO, WALLS_HI, TABLE_Z)
    assert plan is not None
    np.testing.assert_allclose(plan.direction, [0.0, -1.0], atol=1e-12)


def test_a_part_in_a_corner_is_pushed_diagonally_out_of_it():
    part = _box((0.10, 0.07, TABLE_Z), (0.16, 0.12, TABLE_Z + 0.03))  # +x, +y corner
    plan = plan_push(part, WALLS_LO, WALLS_HI, TABLE_Z)
    assert plan is not None
    np.testing.assert_allclose(plan.direction, [-np.sqrt(0.5), -np.sqrt(0.5)], atol=1e-12)
    assert plan.wall_gap_m == pytest.approx(0.01)


def test_the_closed_hand_comes_down_inside_the_walls_in_a_corner():
    """A part 10 mm from two walls is pushed diagonally; the closed fingers (measured: 15 mm
    either side of the pinch point along the closing axis, -44.6 .. +15.3 mm across it)
    come down inside both walls, still over the part, and further in than
    PUSH_INSET_M (there the fingers would reach over the walls: tuning bin 11). Against one
    wall the inset stays PUSH_INSET_M."""
    part = _box((0.06, 0.06, TABLE_Z), (0.16, 0.12, TABLE_Z + 0.03))  # +x, +y corner
    plan = plan_push(part, WALLS_LO, WALLS_HI, TABLE_Z)
    assert plan is not None
    c, s = np.cos(plan.yaw_rad), np.sin(plan.yaw_rad)
    x_axis, y_axis = np.array([c, s]), np.array([s, -c])
    tips = np.array(
        [plan.start_world[:2] + a * x_axis + b * y_axis for a in (-0.015, 0.015)
         for b in (-0.0446, 0.0153)]
    )  # fmt: skip
    assert np.all(tips >= WALLS_LO - 1e-9) and np.all(tips <= WALLS_HI + 1e-9), tips
    middle = _tips_middle(plan)
    assert np.all(middle >= [0.06, 0.06]) and np.all(middle <= [0.16, 0.12])
    # along the push, further in than the part's edge + PUSH_INSET_M
    edge = (part[:, :2] @ plan.direction).min()
    assert middle @ plan.direction > edge + binmod.PUSH_INSET_M + 0.001
    one_wall = _box((0.06, -0.05, TABLE_Z), (0.16, 0.01, TABLE_Z + 0.03))  # +x wall only
    plan = plan_push(one_wall, WALLS_LO, WALLS_HI, TABLE_Z)
    assert plan is not None
    assert _tips_middle(plan)[0] == pytest.approx(0.16 - binmod.PUSH_INSET_M)


def test_a_push_stops_short_of_the_opposite_wall():
    """A bin 120 mm across x and a 60 mm part against its -x wall: 60 mm of room ahead,
    PUSH_FAR_MARGIN_M of it kept, the push is shorter than PUSH_DISTANCE_M."""
    lo, hi = np.array([-0.06, -0.13]), np.array([0.06, 0.13])
    part = _box((-0.06, -0.05, TABLE_Z), (0.0, 0.05, TABLE_Z + 0.03))
    plan = plan_push(part, lo, hi, TABLE_Z)
    assert plan is not None
    length = float(np.linalg.norm(plan.end_world - plan.start_world))
    assert length == pytest.approx(0.06 - binmod.PUSH_FAR_MARGIN_M)
    assert length < binmod.PUSH_DISTANCE_M
    # no room at all: no push
    wide = _box((-0.06, -0.05, TABLE_Z), (0.06 - binmod.PUSH_FAR_MARGIN_M, 0.05, TABLE_Z + 0.03))
    assert plan_push(wide, lo, hi, TABLE_Z) is None


def test_a_push_goes_away_from_the_nearest_wall_for_turned_parts():
    """Property over random turns and places of a 100 x 60 x 30 mm box: a push exactly
    when a wall is within PUSH_NEAR_WALL_M of its corners; then away from every such wall,
    the hand coming down over the part's footprint (brute force over the corners)."""
    rng = np.random.default_rng(0)
    part = _box((-0.05, -0.03, 0.0), (0.05, 0.03, 0.03))
    normals = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    pushed = 0
    for _ in range(300):
        a = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
        P = part @ R.T
        P[:, :2] += rng.uniform(WALLS_LO - P[:, :2].min(0), WALLS_HI - P[:, :2].max(0))
        P[:, 2] += TABLE_Z
        gaps = np.array([
            P[:, 0].min() - WALLS_LO[0], WALLS_HI[0] - P[:, 0].max(),
            P[:, 1].min() - WALLS_LO[1], WALLS_HI[1] - P[:, 1].max(),
        ])  # fmt: skip
        plan = plan_push(P, WALLS_LO, WALLS_HI, TABLE_Z)
        if gaps.min() >= binmod.PUSH_NEAR_WALL_M:
            assert plan is None
            continue
        assert plan is not None
        pushed += 1
        near = gaps < binmod.PUSH_NEAR_WALL_M
        assert np.all(normals[near] @ plan.direction > 0.0), (gaps, plan.direction)
        assert plan.wall_gap_m == pytest.approx(gaps.min())
        assert (
            0.0
            < np.linalg.norm(plan.end_world - plan.start_world)
            <= binmod.PUSH_DISTANCE_M + 1e-12
        )
        tips = _tips_middle(plan)
        assert np.all(tips >= P[:, :2].min(0) - 1e-9) and np.all(tips <= P[:, :2].max(0) + 1e-9)
    assert pushed > 20


def _stub_clear_bin(monkeypatch, moves: bool, flange: bool = False):
    """clear_bin with a stub robot: one part 5 mm from the -x wall, a pair only without
    obstacles (and, with ``flange``, in the "partial" round); a push moves it to the middle
    (``moves``) or leaves it where it was."""
    part = _box((-0.05, -0.03, 0.0), (0.05, 0.03, 0.03))
    robots: list = []
    pushes: list = []

    class Robot(StubPicker):
        instances = robots

        def __init__(self, world, devices, **kw):
            super().__init__(world, devices)
            robots.append(self)
            self.table_z = 0.0
            self.at = np.array([-0.115, 0.0, 0.0])  # 5 mm from the -x wall
            self.obj = SimpleNamespace(mesh=SimpleNamespace(vertices=part))
            self.ctl, self.home_pos, self.home_yaw = None, np.zeros(3), 0.0

        def sense(self):
            T = np.eye(4)
            T[:3, 3] = self.at
            return [] if self.in_box else [SimpleNamespace(matrix=T, score=1.0)]

        def grasps(self, i, obstacles="all"):
            free = self.at[0] > -0.1 or (flange and obstacles == "partial")
            self.tried.append(obstacles)
            return ["grasp"] if obstacles == "none" or free else []

        def pick(self, cands, index, perturb, instance=None):
            self.in_box = True
            return True, ""

    def push(ctl, plan, home_pos, home_yaw):
        pushes.append(plan)
        if moves:
            robots[-1].at = np.array([0.0, 0.0, 0.0])
        return True

    patch_loop(monkeypatch, binmod, Robot, robots)
    monkeypatch.setattr(binmod, "bin_walls_xy", lambda world: (WALLS_LO, WALLS_HI))
    monkeypatch.setattr(binmod, "_push", push)
    return binmod.clear_bin(SimpleNamespace(step=lambda n: None), {}), pushes


def test_a_push_that_frees_a_grasp_is_followed_by_the_pick(monkeypatch):
    rec, pushes = _stub_clear_bin(monkeypatch, moves=True)
    assert [p["failure"] for p in rec["picks"]] == [binmod.PUSHED, ""], rec
    assert rec["pushes"] == 1 and rec["picked"] == 1 and rec["stopped"] == "nothing found"
    np.testing.assert_allclose(pushes[0].direction, [1.0, 0.0])


def test_a_part_that_stays_at_the_wall_is_pushed_at_most_twice(monkeypatch):
    rec, pushes = _stub_clear_bin(monkeypatch, moves=False)
    assert len(pushes) == binmod.PUSHES_PER_INSTANCE == rec["pushes"]
    assert [p["failure"] for p in rec["picks"]][:-1] == [binmod.PUSHED] * len(pushes)
    assert rec["stopped"] == "no collision-free grasp for any instance found", rec


def test_pads_reaching_over_an_edge_come_after_the_pushes(monkeypatch):
    """A part the pushes leave at the wall, with a grasp only in the "partial" round: that
    round is asked for only once no push is left, and its grasp is picked."""
    rec, pushes = _stub_clear_bin(monkeypatch, moves=False, flange=True)
    assert [p["failure"] for p in rec["picks"]] == [binmod.PUSHED] * 2 + [""], rec
    assert rec["picked"] == 1 and rec["stopped"] == "nothing found"
    asked = binmod.BinPicker.instances[-1].tried
    first = asked.index("partial")
    assert asked.count("partial") == 1 and "partial" not in asked[:first]
    assert len(pushes) == binmod.PUSHES_PER_INSTANCE


@pytest.mark.slow
def test_a_part_leaning_on_the_wall_is_pushed_off_it_and_has_a_grasp():
    """Tuning bin 7's last part (its stall replayed): upside down, leaning on the -x wall,
    no grasp even at the grazing clearance. The push (planned from its estimate) moves it
    away from the wall by more than 10 mm (ground truth: the true pose's footprint) and
    the next sensing finds a grasp."""
    from _bin_replay import replayed_bin

    from mks_sim.sim import truth

    with replayed_bin(7, _BIN7_QPOS) as robot:
        found = robot.sense()
        push = binmod._push_candidate(robot, found, range(len(found)), [])
        assert push is not None
        i, plan = push
        assert not robot.grasps(i, obstacles="touch")  # the stall
        np.testing.assert_allclose(plan.direction, [1.0, 0.0], atol=1e-6)
        body = robot.body_of(found[i].matrix)
        V = np.asarray(robot.obj.mesh.vertices)

        def true_gap():
            T = truth.object_to_world(robot.world, body)
            return float((V @ T[:3, :3].T + T[:3, 3])[:, 0].min() - WALLS_LO[0])

        before = true_gap()
        binmod._push(robot.ctl, plan, robot.home_pos, robot.home_yaw)
        robot.world.step(100)
        assert true_gap() > before + 0.01, (before, true_gap())
        found = robot.sense()
        j = min(range(len(found)), key=lambda k: found[k].matrix[0, 3])  # nearest the -x wall
        assert robot.grasps(j, obstacles="tight") or robot.grasps(j, obstacles="touch")


_BIN7_QPOS = (
    -1.10739803,
    2.78866755,
    1.17070855,
    3.7252577,
    -1.84581365,
    4.18518774,
    0.14960304,
    0.149602939,
    0.149602945,
    -0.274255733,
    0.215448717,
    0.780196449,
    0.00936187834,
    -0.0496756877,
    0.998720735,
    -0.0012550407,
    -0.313887884,
    0.159518178,
    0.781183357,
    -0.18014739,
    0.982769163,
    0.0405856517,
    -0.00803082696,
    -0.123019404,
    -0.0174902877,
    0.781367163,
    0.142716562,
    -0.770961831,
    -0.599293859,
    0.161544757,
    -0.414609835,
    0.161617954,
    0.802072289,
    -0.572744872,
    -0.0275283711,
    -0.35762414,
    0.737095974,
    -0.275035543,
    0.161473152,
    0.82341029,
    0.0823469211,
    -0.666972504,
    -0.289752789,
    0.681476328,
    -0.345745886,
    0.204180423,
    0.780827853,
    0.944134118,
    -0.23420971,
    0.0929170902,
    -0.212421736,
)


def _turns_when_let_go(mesh, Rm: np.ndarray) -> float:
    """Degrees the body (``mesh``, uniform density) turns in 2 s of MuJoCo physics, set down
    at rotation ``Rm`` with its lowest point on a plane: the ground truth of standing."""
    import mujoco
    from scipy.spatial.transform import Rotation

    z0 = -(mesh.vertices @ Rm.T)[:, 2].min() + 1e-4
    x, y, z, w = Rotation.from_matrix(Rm).as_quat()
    vert = " ".join(map(str, np.asarray(mesh.vertices).ravel()))
    face = " ".join(map(str, np.asarray(mesh.faces).ravel()))
    xml = f"""<mujoco><option timestep="0.002"/>
      <asset><mesh name="m" vertex="{vert}" face="{face}"/></asset>
      <worldbody><geom type="plane" size="1 1 0.1"/>
        <body pos="0 0 {z0}" quat="{w} {x} {y} {z}"><freejoint/>
          <geom type="mesh" mesh="m" density="1000"/></body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    q0 = d.qpos[3:7].copy()
    mujoco.mj_step(m, d, 1000)
    return float(2.0 * np.degrees(np.arccos(min(1.0, abs(float(q0 @ d.qpos[3:7]))))))


@pytest.mark.parametrize("name", ["part", "box"])
def test_a_part_leans_exactly_when_physics_tips_it_over(name):
    """``leans`` against MuJoCo: each pose set down on a plane and let go for 2 s. A pose
    that leans turns by more than 5 deg (it falls onto a face); one that stands turns by at
    most 3 (settling from a tilt within LEAN_TOUCH_M onto its face). The poses: flat on
    faces, tilted 1-33 deg, on ends and sides, upside down (the part's rests tilted 7 deg)."""
    from scipy.spatial.transform import Rotation

    from mks_sim.geometry.meshes import box_mesh, industrial_part_mesh

    mesh = industrial_part_mesh() if name == "part" else box_mesh((0.05, 0.04, 0.06))
    poses = [(0, 0, 0), (1, 0, 0), (3, 0, 0), (8, 0, 0), (33, 0, 0), (0, 33, 0), (20, 20, 0),
             (90, 0, 0), (-90, 0, 0), (0, 90, 0), (0, -90, 0), (180, 0, 0), (180, 7, 0),
             (180, -7, 0)]  # fmt: skip
    falls = stands = 0
    for eul in poses:
        Rm = Rotation.from_euler("xyz", eul, degrees=True).as_matrix()
        turned = _turns_when_let_go(mesh, Rm)
        assert turned <= 3.1 or turned >= 5.0, (eul, turned)  # no pose on the fence
        got = binmod.leans(mesh.vertices @ Rm.T, Rm @ mesh.centroid)
        assert got == (turned >= 5.0), (eul, turned)
        falls += got
        stands += not got
    assert falls >= 5 and stands >= 5


def test_a_part_with_no_pair_is_pushed_only_when_it_leans(monkeypatch):
    """Two parts 5 mm from the -x wall, neither with an antipodal pair in any draw: the one
    whose estimate leans (a box tilted 33 deg onto its edge) gets a push away from the wall,
    whichever comes first in the order; the one flat on its face does not (a push cannot
    give it a pair)."""
    from scipy.spatial.transform import Rotation

    from mks_sim.geometry.meshes import box_mesh

    mesh = box_mesh((0.05, 0.04, 0.06))

    def at_wall(tilt_deg: float) -> SimpleNamespace:
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("y", tilt_deg, degrees=True).as_matrix()
        V = mesh.vertices @ T[:3, :3].T
        T[:3, 3] = [WALLS_LO[0] + 0.005 - V[:, 0].min(), 0.0, TABLE_Z - V[:, 2].min()]
        return SimpleNamespace(matrix=T, score=1.0)

    robot = SimpleNamespace(
        world=None, obj=SimpleNamespace(mesh=mesh), table_z=TABLE_Z,
        grasps=lambda i, obstacles="all": [], redraw=lambda: None,
    )  # fmt: skip
    monkeypatch.setattr(binmod, "bin_walls_xy", lambda world: (WALLS_LO, WALLS_HI))
    found = [at_wall(0.0), at_wall(33.0)]
    for order in ([0, 1], [1, 0]):
        push = binmod._push_candidate(robot, found, order, [])
        assert push is not None and push[0] == 1, order
        np.testing.assert_allclose(push[1].direction, [1.0, 0.0])
    assert binmod._push_candidate(robot, found[:1], [0], []) is None


@pytest.mark.slow
def test_a_part_with_its_step_against_a_wall_is_picked_by_its_plate():
    """Tuning bin 16's last part, its stall replayed (two pushes had left it where it was):
    upside down, its 22 mm step 14 mm from the -x wall. No round but "partial" has a grasp
    for it; the partial round's grasp (the pads reaching over the 8 mm plate's edge) lifts it
    out, and it ends in the output box (ground truth, evaluation only)."""
    from _bin_replay import replayed_bin

    with replayed_bin(16, _BIN16_QPOS) as robot:
        found = robot.sense()
        assert len(found) == 1
        for obstacles in ("all", "fixed", "tight", "touch"):
            assert not robot.grasps(0, obstacles=obstacles), obstacles
        chosen = binmod._partial_grasp(robot, [0], [False])
        assert chosen is not None
        i, cands = chosen
        body = robot.body_of(found[i].matrix)
        ok, why = robot.pick(cands, 0, None, instance=i)
        assert ok and binmod.in_output_box(robot.world, body), why


_BIN16_QPOS = (
    -1.10740938, 2.78642962, 1.17071268, 3.72525907, -1.84614727, -2.09524462, 0.14960295,
    0.14960300, 0.14960291, -0.24442701, 0.26271577, 0.80264552, 0.22185395, 0.22902597,
    -0.58590511, -0.74501217, -0.11546597, 0.04176076, 0.77789025, -0.02659880, 0.90118900,
    0.42912456, 0.05479964, -0.26196068, 0.21020952, 0.77585304, 0.14906096, 0.01913375,
    0.08850316, 0.98467351, -0.29028999, 0.13044187, 0.77998985, 0.00633425, 0.00646794,
    0.70746384, 0.70669156, -0.35618594, 0.25341916, 0.75000372, 0.15930578, -0.00148046,
    -0.00022862, -0.98722815, -0.25509182, 0.18345604, 0.75001752, -0.03908837, 0.00230470,
    -0.00095201, 0.99923265,
)  # fmt: skip
