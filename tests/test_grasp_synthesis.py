"""Grasp synthesis from the mesh (issue 10 section 4), checked by brute-force geometry.

Every candidate's contacts are located on the mesh independently with trimesh (closest point
over all triangles); the normals found there must oppose each other within the friction cone
around the closing axis, the width must fit the hand, and the pinch point must keep its
clearance above the table.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh  # only to build a cylinder mesh the project does not ship
from scipy.spatial.transform import Rotation

from mks_sim.errors import DataError, SpecError
from mks_sim.geometry.meshes import Mesh, box_mesh, industrial_part_mesh, uv_sphere
from mks_sim.models.objects import ObjectModel
from mks_sim.tasks import grasp
from mks_sim.tasks.grasp import fingertips_xy, synthesize_grasps

TABLE_Z = 0.75


def _object(mesh: Mesh, mu: float = 1.0, **grasp_hints: float) -> ObjectModel:
    return ObjectModel(name="thing", mesh=mesh, symmetries=np.eye(4)[None],
                       friction=(mu, 0.01, 0.0002), grasp=grasp_hints)  # fmt: skip


def _cylinder() -> Mesh:
    c = trimesh.creation.cylinder(radius=0.022, height=0.07, sections=64)
    return Mesh(np.asarray(c.vertices), np.asarray(c.faces))


def _resting(mesh: Mesh, R: np.ndarray, xy: tuple[float, float]) -> np.ndarray:
    """A pose with rotation R whose lowest vertex touches the table."""
    T = np.eye(4)
    T[:3, :3] = R
    z = -(mesh.vertices @ R.T)[:, 2].min()
    T[:3, 3] = (xy[0], xy[1], TABLE_Z + z)
    return T


MESHES = {
    "box": lambda: box_mesh((0.05, 0.04, 0.06)),
    "sphere": lambda: uv_sphere(0.03),
    "cylinder": _cylinder,
    "part": industrial_part_mesh,
}


def _faces_containing(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Brute force over all triangles (F, 3, 3): outward unit normals of those containing
    point p (on their plane within 1e-7 m, barycentric coordinates >= -1e-7)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    on_plane = np.abs(np.einsum("fi,fi->f", p - a, n)) < 1e-7
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    inside = (v >= -1e-7) & (w >= -1e-7) & (v + w <= 1 + 1e-7)
    return n[on_plane & inside]


def _check(obj: ObjectModel, T: np.ndarray, cands: list[grasp.GraspCandidate]) -> None:
    mu = obj.friction[0]
    tri = obj.mesh.transformed(T).triangles
    clearance = obj.grasp.get("min_clearance_m", grasp.MIN_CLEARANCE_M)
    half_angle = math.atan(mu)
    tilted_seen = False
    for c in cands:
        contacts = np.asarray(c.contacts_world)  # fingers 2/3, finger 1
        axis = c.axis_world
        if c.rotation_world is None:
            assert not tilted_seen, "a top-down candidate after a tilted one"
            assert abs(axis[2]) < 1e-9  # top-down hand: horizontal closing axis
        else:
            tilted_seen = True
            _check_tilted(c, TABLE_Z)
            d = contacts[1] - contacts[0]
            assert np.linalg.norm(d) == pytest.approx(c.width_m, abs=1e-9)
            assert np.linalg.norm(np.cross(d, axis)) < 1e-9 and d @ axis > 0
        # On the surface, and every face there has its inward normal within the friction
        # cone of the closing force (+axis at fingers 2/3, -axis at finger 1).
        for k, direction in ((0, axis), (1, -axis)):
            normals = _faces_containing(tri, contacts[k])
            assert len(normals), f"contact {contacts[k]} is not on the surface"
            angles = np.arccos(np.clip(-normals @ direction, -1, 1))
            assert np.all(angles <= half_angle + 1e-6), np.degrees(angles)
        assert grasp.MIN_WIDTH_M <= c.width_m <= float(grasp.PAD_APERTURE_M[0]) - 0.035
        if c.rotation_world is not None:
            continue
        # The line of the contacts is the closing axis; the width fits the opening.
        d = contacts[1] - contacts[0]
        assert np.linalg.norm(d[:2]) == pytest.approx(c.width_m, abs=1e-9)
        assert abs(d[2]) <= grasp.PAIR_DZ_M
        assert np.cross(np.append(d[:2], 0.0), axis)[2] == pytest.approx(0.0, abs=1e-9)
        assert d[:2] @ axis[:2] > 0  # finger 1 on the +axis side
        assert grasp.MIN_WIDTH_M <= c.width_m <= float(grasp.PAD_APERTURE_M[0]) - 0.035
        # Above the table.
        assert c.pinch_world[2] >= TABLE_Z + clearance - 1e-9
        assert np.all(contacts[:, 2] > TABLE_Z)


def _check_tilted(c: grasp.GraspCandidate, table_z: float) -> None:
    """A tilted candidate's hand: a rotation whose x axis is the closing axis, whose z axis
    (the approach) is within MAX_TILT_DEG of straight down, the pinch point 8 mm back along
    it from the contacts' midpoint, and the open fingertips above the table."""
    H = np.asarray(c.rotation_world)
    assert H @ H.T == pytest.approx(np.eye(3), abs=1e-9) and np.linalg.det(H) == pytest.approx(1)
    approach = H[:, 2]
    tilt = math.degrees(math.acos(-approach[2]))
    assert tilt <= grasp.MAX_TILT_DEG + 1e-6 and tilt == pytest.approx(c.tilt_deg)
    mid = np.mean(np.asarray(c.contacts_world), axis=0)
    assert np.asarray(c.pinch_world) == pytest.approx(mid - 0.008 * approach, abs=1e-9)
    half = (c.width_m + grasp.PRESHAPE_MARGIN_M) / 2
    for x, y in zip((half, -half, -half), grasp.FINGERTIPS_Y, strict=True):
        tip = np.asarray(c.pinch_world) + H @ np.array([x, y, grasp.FINGERTIP_DROP_M])
        assert tip[2] >= table_z + grasp.TILT_TIP_ABOVE_TABLE_M - 1e-9


@pytest.mark.parametrize("name", sorted(MESHES))
@pytest.mark.parametrize("seed", range(3))
def test_candidates_are_antipodal_fit_the_hand_and_clear_the_table(name: str, seed: int) -> None:
    mesh = MESHES[name]()
    obj = _object(mesh, mu=0.8 if seed else 1.0)
    # Any yaw; tilted up to 25 degrees (leaning), except the part, which rests flat.
    tilt = 0.0 if name == "part" else 12.5 * seed
    R = Rotation.from_euler("zx", [70 * seed, tilt], degrees=True).as_matrix()
    T = _resting(mesh, R, (0.1, -0.05))
    cands = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(seed))
    assert cands, f"no grasp of the {name}"
    _check(obj, T, cands)


def test_a_narrow_friction_cone_admits_only_opposed_faces() -> None:
    """A box tilted 20 degrees about x: with mu = 0.2 (cone 11 degrees) only the x faces
    (vertical) oppose each other; with mu = 1 the tilted y faces qualify as well."""
    obj_slippery = _object(box_mesh((0.05, 0.05, 0.05)), mu=0.2)
    R = Rotation.from_euler("x", 20, degrees=True).as_matrix()
    T = _resting(obj_slippery.mesh, R, (0.0, 0.0))
    slippery = synthesize_grasps(obj_slippery, T, table_z=TABLE_Z, max_tilt_deg=0)
    assert slippery
    for c in slippery:  # the closing axis within the 11-degree cone of the x faces' normals
        assert abs(c.axis_world[0]) >= math.cos(math.atan(0.2)) - 1e-9
    # A tilted hand closes along the y faces' normals (20 degrees from horizontal) instead.
    normal_y = R[:, 1]
    tilted = [c for c in synthesize_grasps(obj_slippery, T, table_z=TABLE_Z) if c.rotation_world]
    assert any(abs(c.axis_world @ normal_y) >= math.cos(math.atan(0.2)) for c in tilted)
    grippy = synthesize_grasps(
        _object(obj_slippery.mesh, mu=1.0), T, table_z=TABLE_Z, max_candidates=500
    )
    assert any(abs(c.axis_world[1]) > 0.9 for c in grippy)


def _tip_distance_to(c: grasp.GraspCandidate, wall: np.ndarray) -> float:
    """Brute force: the smallest xy distance from an open fingertip to a wall point."""
    yaw = c.yaw_rad
    x = np.array([math.cos(yaw), math.sin(yaw)])
    y = np.array([math.sin(yaw), -math.cos(yaw)])  # the pinch site's y (z points down)
    tips = np.asarray(c.pinch_world[:2]) + fingertips_xy(
        c.width_m + grasp.PRESHAPE_MARGIN_M
    ) @ np.stack([x, y])
    return float(np.min(np.linalg.norm(wall[None, :, :2] - tips[:, None, :], axis=2)))


def test_a_wall_of_sensed_points_removes_the_grasps_whose_fingers_hit_it() -> None:
    obj = _object(box_mesh((0.05, 0.05, 0.05)))
    T = _resting(obj.mesh, np.eye(3), (0.0, 0.0))
    gy, gz = np.meshgrid(np.linspace(-0.1, 0.1, 41), np.linspace(TABLE_Z, TABLE_Z + 0.1, 21))
    wall = np.column_stack([np.full(gy.size, 0.06), gy.ravel(), gz.ravel()])  # x = 6 cm
    free = synthesize_grasps(obj, T, table_z=TABLE_Z)
    hitting = [c for c in free if _tip_distance_to(c, wall) < grasp.FINGER_CLEARANCE_M]
    assert any(abs(c.axis_world[0]) > 0.99 for c in hitting)  # a fingertip 17.5 mm from it
    walled = synthesize_grasps(obj, T, table_z=TABLE_Z, obstacles=wall)
    assert walled
    assert all(_tip_distance_to(c, wall) >= grasp.FINGER_CLEARANCE_M for c in walled)
    assert not any(abs(c.axis_world[0]) > 0.99 for c in walled)  # straight along x: gone


def test_the_part_is_pinched_low_on_its_step() -> None:
    """The pads (top edge 7 mm above their centre) must not overhang the 22 mm step: every
    candidate's pinch point is below the step's top, and the plate (8 mm) is never gripped."""
    from mks_sim.models.objects import load_object

    part = load_object("part")
    for seed in range(3):
        R = Rotation.from_euler("z", 50 * seed, degrees=True).as_matrix()
        T = _resting(part.mesh, R, (0.0, 0.1))
        cands = synthesize_grasps(part, T, table_z=TABLE_Z, rng=np.random.default_rng(seed))
        assert cands
        for c in cands:
            contact_z = np.asarray(c.contacts_world)[:, 2] - TABLE_Z
            assert np.all(contact_z + grasp.PAD_TOP_ABOVE_CENTRE_M <= 0.022 + 1e-3)
            assert c.pinch_world[2] - TABLE_Z >= part.grasp["min_clearance_m"] - 1e-9


def test_deterministic_for_a_seed_and_ranked_by_cost_then_wrist_turn() -> None:
    obj = _object(uv_sphere(0.03))
    T = _resting(obj.mesh, np.eye(3), (0.1, 0.0))
    a = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(5))
    b = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(5))
    assert a == b
    a = [c for c in a if c.rotation_world is None]  # the tilted ones follow, by cost
    best = min(c.cost for c in a)
    near = [c for c in a if c.cost <= best + grasp.COST_TOLERANCE_M]
    assert a[: len(near)] == sorted(near, key=lambda c: abs(c.yaw_rad))
    c = synthesize_grasps(obj, T, table_z=TABLE_Z, preferred_yaw=2.0)
    assert all(abs(x.yaw_rad - 2.0) <= math.pi for x in c)


def test_too_wide_or_too_thin_gives_no_grasp_and_errors() -> None:
    wide = _object(box_mesh((0.2, 0.2, 0.05)))
    assert synthesize_grasps(wide, _resting(wide.mesh, np.eye(3), (0, 0)), table_z=TABLE_Z) == []
    with pytest.raises(DataError, match="expected a finite 4x4 matrix"):
        synthesize_grasps(wide, np.full((4, 4), np.nan), table_z=TABLE_Z)
    bad = _object(box_mesh((0.05, 0.05, 0.05)), min_clearance_m="low")  # type: ignore[arg-type]
    with pytest.raises(SpecError, match="grasp hint 'min_clearance_m': expected a number"):
        synthesize_grasps(bad, _resting(bad.mesh, np.eye(3), (0, 0)), table_z=TABLE_Z)


@pytest.mark.parametrize("euler", [(30, 150, 0), (100, 35, 0), (0, 200, 40)])
def test_a_tumbled_part_gets_tilted_antipodal_grasps(euler: tuple[int, int, int]) -> None:
    """The part tumbled (on its side, upside down and leaning): tilted candidates exist and
    each is antipodal on the mesh (brute force over its triangles, in 3-D), fits the hand and
    keeps its fingertips above the table."""
    from mks_sim.models.objects import load_object

    part = load_object("part")
    R = Rotation.from_euler("xyz", euler, degrees=True).as_matrix()
    T = _resting(part.mesh, R, (0.0, 0.1))
    cands = synthesize_grasps(part, T, table_z=TABLE_Z)
    tilted = [c for c in cands if c.rotation_world is not None]
    assert tilted, f"no tilted grasp of the part at {euler}"
    _check(part, T, cands)
    tri = part.mesh.transformed(T).triangles
    half_angle = math.atan(part.friction[0])
    for c in tilted:
        axis = c.axis_world
        for k, direction in ((0, axis), (1, -axis)):
            normals = _faces_containing(tri, np.asarray(c.contacts_world[k]))
            assert len(normals)
            angles = np.arccos(np.clip(-normals @ direction, -1, 1))
            assert np.all(angles <= half_angle + 1e-6), np.degrees(angles)


def test_the_part_on_its_side_has_no_top_down_grasp_but_tilted_ones() -> None:
    """Leaning 150 degrees over (measured: no horizontal antipodal pair passes the pads'
    support), only a tilted approach grasps it; max_tilt_deg=0 restores top-down only."""
    from mks_sim.models.objects import load_object

    part = load_object("part")
    R = Rotation.from_euler("xyz", (30, 150, 0), degrees=True).as_matrix()
    T = _resting(part.mesh, R, (0.0, 0.1))
    assert synthesize_grasps(part, T, table_z=TABLE_Z, max_tilt_deg=0) == []
    assert synthesize_grasps(part, T, table_z=TABLE_Z)


@pytest.mark.parametrize("name", sorted(MESHES))
def test_top_down_grasps_come_first_and_are_unchanged(name: str) -> None:
    """The tilted pass adds candidates after the top-down ones and leaves those as they were
    (same rng draws): the single-object grasps do not change."""
    obj = _object(MESHES[name]())
    R = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    T = _resting(obj.mesh, R, (0.05, 0.0))
    only = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(3), max_tilt_deg=0)
    both = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(3))
    assert only and both[: len(only)] == only
    assert all(c.rotation_world is not None for c in both[len(only) :])


def test_tilted_fingers_and_palm_keep_clear_of_sensed_points() -> None:
    """A wall of sensed points beside a leaning box: no tilted candidate sweeps a fingertip
    within FINGER_CLEARANCE_M of it (brute force over the approach line) or swings its palm
    through it."""
    obj = _object(box_mesh((0.05, 0.04, 0.06)))
    R = Rotation.from_euler("y", 35, degrees=True).as_matrix()
    T = _resting(obj.mesh, R, (0.0, 0.0))
    gy, gz = np.meshgrid(np.linspace(-0.1, 0.1, 41), np.linspace(TABLE_Z, TABLE_Z + 0.1, 21))
    wall = np.column_stack([np.full(gy.size, 0.07), gy.ravel(), gz.ravel()])

    def sweep_distance(c: grasp.GraspCandidate) -> float:
        H = np.asarray(c.rotation_world)
        half = (c.width_m + grasp.PRESHAPE_MARGIN_M) / 2
        gaps = []
        for x, y in zip((half, -half, -half), grasp.FINGERTIPS_Y, strict=True):
            for back in np.linspace(0.0, grasp.SWEEP_BACK_M, 80):
                p = np.asarray(c.pinch_world) + H @ np.array([x, y, grasp.FINGERTIP_DROP_M - back])
                gaps.append(np.min(np.linalg.norm(wall - p, axis=1)))
        return float(min(gaps))

    free = [c for c in synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilted=200)
            if c.rotation_world]  # fmt: skip
    assert any(sweep_distance(c) < grasp.FINGER_CLEARANCE_M - 2e-3 for c in free)
    walled = [c for c in synthesize_grasps(obj, T, table_z=TABLE_Z, obstacles=wall, max_tilted=200)
              if c.rotation_world]  # fmt: skip
    assert walled
    assert all(sweep_distance(c) >= grasp.FINGER_CLEARANCE_M - 1e-3 for c in walled)


def _bracket() -> ObjectModel:
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    import _gen_meshes as gen

    tm = gen.l_bracket()  # legs 60 and 40 mm, walls 10 mm, 25 mm deep
    return _object(Mesh(np.asarray(tm.vertices), np.asarray(tm.faces)))


def test_the_l_bracket_standing_on_its_short_leg_gets_tilted_grasps_too() -> None:
    """Issue 10's thin shape (tests/_gen_meshes.py): standing on its 40 mm leg's end, the
    bracket gets tilted candidates besides the top-down ones (antipodal by brute force)."""
    obj = _bracket()
    R = Rotation.from_euler("y", 90, degrees=True).as_matrix()  # the 40 mm leg down
    T = _resting(obj.mesh, R, (0.0, 0.1))
    cands = synthesize_grasps(obj, T, table_z=TABLE_Z)
    top = synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilt_deg=0)
    assert top and len(cands) > len(top)
    _check(obj, T, cands)


def test_the_l_bracket_lying_flat_is_pinched_across_a_wall() -> None:
    """Lying flat (25 mm tall) every face a 13 mm pad fits on pairs with one 10 mm away, the
    other side of a wall: the hand closes on 8 mm and up, so the candidates pinch a wall."""
    obj = _bracket()
    flat = _resting(obj.mesh, np.eye(3), (0.0, 0.1))
    cands = synthesize_grasps(obj, flat, table_z=TABLE_Z, max_tilt_deg=0)
    assert cands
    _check(obj, flat, cands)
    for c in cands:  # the contacts lie on a wall's two faces, 10 mm apart along their normal
        a, b = np.asarray(c.contacts_world)
        n = np.asarray(c.normals_world)[0]
        assert abs((b - a) @ n) == pytest.approx(0.010, abs=1e-6)
    # not at 20 mm, the former narrowest pinch
    assert synthesize_grasps(obj, flat, table_z=TABLE_Z, max_tilt_deg=0, min_width_m=0.02) == []


def test_faces_leaning_over_25_degrees_are_not_pinched_from_above() -> None:
    """The bracket on its two leg ends (its hull's plane through both ends on the table):
    its walls lean 31 degrees (atan(30/50), brute force from the profile), inside the 45
    degree friction cone at mu = 1 but over MAX_FACE_LEAN_DEG: no top-down pinch on them;
    with the lean allowed up to 45 degrees they come back."""
    obj = _bracket()
    n = np.array([30.0, 50.0, 0.0]) / np.hypot(30.0, 50.0)  # outward normal of that plane
    R = Rotation.align_vectors([[0.0, 0.0, -1.0]], [n])[0].as_matrix()
    T = _resting(obj.mesh, R, (0.0, 0.1))

    def lean(c: grasp.GraspCandidate) -> float:
        nz = max(abs(float(v[2])) for v in np.asarray(c.normals_world))
        return math.degrees(math.asin(min(nz, 1.0)))

    default = synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilt_deg=0, max_candidates=200)
    wide = synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilt_deg=0, max_candidates=200,
                             max_face_lean_deg=45.0)  # fmt: skip
    assert all(lean(c) <= grasp.MAX_FACE_LEAN_DEG + 1e-6 for c in default)
    assert any(lean(c) == pytest.approx(math.degrees(math.atan(30 / 50)), abs=0.5) for c in wide)


def test_a_tighter_finger_clearance_admits_grasps_beside_a_wall() -> None:
    """A box 17 mm (fingertip to wall, brute force) from a wall of sensed points: blocked at
    the default clearance (22 mm), admitted at 12 mm (clear_bin's last round, for walls)."""
    obj = _object(box_mesh((0.05, 0.05, 0.05)))
    T = _resting(obj.mesh, np.eye(3), (0.0, 0.0))
    gy, gz = np.meshgrid(np.linspace(-0.1, 0.1, 41), np.linspace(TABLE_Z, TABLE_Z + 0.1, 21))
    wall = np.column_stack([np.full(gy.size, 0.06), gy.ravel(), gz.ravel()])
    default = synthesize_grasps(obj, T, table_z=TABLE_Z, obstacles=wall, max_tilt_deg=0)
    tight = synthesize_grasps(obj, T, table_z=TABLE_Z, obstacles=wall, max_tilt_deg=0,
                              finger_clearance_m=0.012)  # fmt: skip
    along_x = [c for c in tight if abs(c.axis_world[0]) > 0.99]
    assert not any(abs(c.axis_world[0]) > 0.99 for c in default)
    assert along_x
    assert all(0.012 <= _tip_distance_to(c, wall) < grasp.FINGER_CLEARANCE_M for c in along_x)


def test_a_plate_thinner_than_the_pad_is_pinched_only_when_pads_may_reach_over_it() -> None:
    """A plate 8 mm thick lying flat: no top-down pinch covers the whole pad (the surface 9 mm
    above its centre); with ``pad_cover_m`` = 3 mm there are pinches, each contact on the
    plate's sides (brute force, :func:`_check`) and at least 3 mm below its top."""
    obj = _object(box_mesh((0.12, 0.05, 0.008)), min_clearance_m=0.009)
    T = _resting(obj.mesh, np.eye(3), (0.0, 0.1))
    assert synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilt_deg=0) == []
    cands = synthesize_grasps(obj, T, table_z=TABLE_Z, max_tilt_deg=0, pad_cover_m=0.003)
    assert cands
    _check(obj, T, cands)
    for c in cands:
        contact_z = np.asarray(c.contacts_world)[:, 2] - TABLE_Z
        assert np.all(contact_z + 0.003 <= 0.008 + grasp.PROBE_TOL_M)
