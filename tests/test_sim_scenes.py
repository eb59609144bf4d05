"""Scenes: every scene loads and renders, seeded randomisation, resting objects, layouts."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mks_sim.errors import NotFound
from mks_sim.sim import flatparts, names, truth
from mks_sim.sim.robot import arm_qpos_for_pinch
from mks_sim.sim.scenes import build_scene
from mks_sim.sim.world import World, build_world

FLAT_PARTS = build_scene("scene1").flat_parts  # worlds/scene1.toml's [[flat_part]] entries
TRAY_TOP_Z = names.TABLE_TOP_Z + 0.006  # the table + the 6 mm tray (scene1.toml [tray])

# Resting height of each body origin above its support when at rest (from the object
# definitions: half the cube edge, cube edge + sphere radius, the part's origin is its
# bottom face, flat parts' origin is mid-thickness).
RESTING = {
    names.CUBE: names.TABLE_TOP_Z + names.CUBE_SIZE_M / 2,
    names.SPHERE: names.TABLE_TOP_Z + names.CUBE_SIZE_M + names.SPHERE_RADIUS_M,
    names.PART: names.TABLE_TOP_Z,
    **{p.name: TRAY_TOP_Z + 0.004 / 2 for p in FLAT_PARTS},  # 4 mm parts
}


PAPER_SCENES = ("scene1", "scene2", "part")  # worlds/*.toml of the paper's section 4.1


@pytest.fixture(scope="module", params=PAPER_SCENES)
def world(request) -> World:
    return build_world(request.param, seed=7)


def _qpos_objects(world: World) -> np.ndarray:
    return np.concatenate([world.data.joint(names.free_joint(n)).qpos for n in world.object_names])


def test_scene_names(world: World) -> None:
    m = world.model
    for cam in names.CAMERAS:
        assert m.camera(cam).id >= 0
    for site in names.RANGE_FINDER_MOUNTS:
        assert m.site(site).id >= 0
    expected = {
        "scene1": {f"flat_{i:02d}" for i in range(1, 13)},
        "scene2": {names.CUBE, names.SPHERE, *names.CLUTTER},
        "part": {names.PART},
    }[world.name]
    assert set(world.object_names) == expected


def test_objects_rest_where_expected(world: World) -> None:
    for name in world.object_names:
        T = truth.object_to_world(world, name)
        if name in RESTING:
            assert T[2, 3] == pytest.approx(RESTING[name], abs=1.5e-3), name
        assert abs(T[2, 2]) > 0.999 or name == names.SPHERE, f"{name} tipped over"
    # at rest: another half second moves nothing by more than 1 mm
    before = {n: truth.object_to_world(world, n)[:3, 3] for n in world.object_names}
    world.step(250)
    for n in world.object_names:
        moved = np.linalg.norm(truth.object_to_world(world, n)[:3, 3] - before[n])
        assert moved < 1e-3, (n, moved)
    world.reset()


def test_sphere_on_cube() -> None:
    for seed in (0, 1, 2):
        w = build_world("scene2", seed=seed)
        cube = truth.object_to_world(w, names.CUBE)[:3, 3]
        sphere = truth.object_to_world(w, names.SPHERE)[:3, 3]
        assert np.linalg.norm(sphere[:2] - cube[:2]) < 0.005
        assert sphere[2] - cube[2] == pytest.approx(
            names.CUBE_SIZE_M / 2 + names.SPHERE_RADIUS_M, abs=1.5e-3
        )


def test_randomize_is_seeded() -> None:
    a = _qpos_objects(build_world("scene2", seed=11))
    b = _qpos_objects(build_world("scene2", seed=11))
    c = _qpos_objects(build_world("scene2", seed=12))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0.01


def test_objects_inside_region_and_apart(world: World) -> None:
    scene = world.scene
    cx, cy = scene.region_center_xy
    hx, hy = scene.region_half_xy
    specs = {s.name: s for s in scene.objects}
    xy = {n: truth.object_to_world(world, n)[:2, 3] for n in world.object_names}
    for n, p in xy.items():
        assert abs(p[0] - cx) <= hx + 1e-3 and abs(p[1] - cy) <= hy + 1e-3, n
    tops = {t for t, _ in scene.stacked} | {b for _, b in scene.stacked}
    free = [n for n in xy if n not in tops or n == names.CUBE]
    for i, a in enumerate(free):
        for b in free[i + 1 :]:
            gap = np.linalg.norm(xy[a] - xy[b])
            assert gap > specs[a].footprint_radius_m + specs[b].footprint_radius_m, (a, b)


def test_reset_restores_initial_state() -> None:
    w = build_world("scene2", seed=3)
    q0 = w.data.qpos.copy()
    w.randomize(np.random.default_rng(99))
    assert np.abs(w.data.qpos - q0).max() > 1e-3
    w.reset()
    np.testing.assert_array_equal(w.data.qpos, q0)


def test_set_object_pose_round_trip() -> None:
    w = build_world("scene2")
    T = np.eye(4)
    c, s = np.cos(0.3), np.sin(0.3)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (0.05, -0.02, 0.9)
    w.set_object_pose(names.CUBE, T)
    np.testing.assert_allclose(truth.object_to_world(w, names.CUBE), T, atol=1e-9)


def test_scene1_default_layout_matches_paper_tables() -> None:
    # Tables 4-1 / 4-3 of the paper: centroids (pixels), radii, corners, holes.
    table = {
        1: (256, 86, 0, 6, 0),
        2: (371, 137, 0, 4, 0),
        3: (269, 171, 0, 8, 0),
        4: (397, 223, 1, 0, 0),
        5: (320, 224, 2, 0, 0),
        6: (128, 240, 3, 0, 0),
        7: (230, 257, 5, 0, 0),
        8: (358, 309, 0.5, 4, 1),
        9: (333, 343, 0.5, 6, 1),
        10: (256, 429, 0, 8, 0),
        11: (384, 429, 0.5, 6, 1),
    }
    w = build_world("scene1")
    rows = {r.paper_index: r for r in truth.scene1_manifest(w) if r.paper_index}
    assert set(rows) == set(table)
    for idx, (u, v, radius, corners, holes) in table.items():
        r = rows[idx]
        assert r.uv_paper == pytest.approx((u, v), abs=1.0), idx
        assert (r.corners, r.holes) == (corners, holes), idx
        if r.kind == "disc":
            assert r.radius_m == pytest.approx(radius / 100), idx
    assert sum(r.kind == "disc" and r.radius_m == 0.02 for r in rows.values()) == 1
    with pytest.raises(NotFound, match="expected world 'scene1'"):
        truth.scene1_manifest(build_world("part"))


def test_flat_part_meshes_are_closed() -> None:
    from mks_sim.geometry.meshes import Mesh

    for part in FLAT_PARTS:
        if part.holes:
            v, f = flatparts.annular_prism(part.outline(), part.hole_radius_m, 0.004)
            mesh = Mesh(v, f)
            assert mesh.is_watertight(), part.name
            outer = part.outline()
            x, y = outer[:, 0], outer[:, 1]
            area = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
            expected = 0.004 * (area - np.pi * part.hole_radius_m**2 * 0.997)
            assert mesh.volume == pytest.approx(expected, rel=0.01), part.name


def test_part_mesh_and_collision_decomposition() -> None:
    from mks_sim.geometry.meshes import industrial_part_boxes, industrial_part_mesh

    mesh = industrial_part_mesh()
    assert mesh.is_watertight()
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    w = build_world("part")
    m, d = w.model, w.data
    body = m.body(names.PART).id
    T = truth.object_to_world(w, names.PART)
    n_coll = 0
    for g in range(m.ngeom):
        if m.geom_bodyid[g] != body:
            continue
        if m.geom_group[g] == names.GROUP_COLLISION_ONLY:
            n_coll += 1
            assert m.geom_contype[g] and m.geom_conaffinity[g]
            # the primitive's corners, in the object frame, lie inside the bounding box
            size = m.geom_size[g]
            half = size if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX else size[[0, 0, 1]]
            signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
            corners_world = d.geom_xpos[g] + (signs * half) @ d.geom_xmat[g].reshape(3, 3).T
            corners = (corners_world - T[:3, 3]) @ T[:3, :3]
            assert np.all(corners >= lo - 1e-6) and np.all(corners <= hi + 1e-6)
        else:
            assert m.geom_group[g] == names.GROUP_VISUAL
            assert m.geom_contype[g] == 0 and m.geom_conaffinity[g] == 0
    assert n_coll == len(industrial_part_boxes())
    # the body carries the mesh's mass (exact inertia of a watertight mesh)
    assert m.body_mass[body] == pytest.approx(mesh.volume * 1200.0, rel=0.02)


def test_stereo_pair_is_rectified() -> None:
    w = build_world("scene2")
    left, right = w.data.cam(names.STEREO_LEFT), w.data.cam(names.STEREO_RIGHT)
    np.testing.assert_allclose(left.xmat, right.xmat, atol=1e-12)
    x_axis = left.xmat.reshape(3, 3)[:, 0]
    np.testing.assert_allclose(right.xpos - left.xpos, names.STEREO_BASELINE_M * x_axis, atol=1e-9)
    # optical axis (-z) points down at the object region
    look = -left.xmat.reshape(3, 3)[:, 2]
    assert look[2] < -0.5


def test_range_finder_mounts_look_at_region() -> None:
    w = build_world("scene2")
    target = np.array([*names.OBJECT_REGION_CENTER_XY, names.TABLE_TOP_Z])
    geomid = np.zeros(1, dtype=np.int32)
    for site in names.RANGE_FINDER_MOUNTS:
        s = w.data.site(site)
        z = s.xmat.reshape(3, 3)[:, 2]
        x = s.xmat.reshape(3, 3)[:, 0]
        assert abs(x[2]) < 1e-9  # +x horizontal
        to_target = target - s.xpos
        off_axis = np.linalg.norm(np.cross(z, to_target / np.linalg.norm(to_target)))
        assert off_axis < 0.1
        dist = mujoco.mj_ray(
            w.model, w.data, s.xpos, z, np.array([1, 1, 1, 0, 0, 0], np.uint8), 1, -1, geomid
        )
        assert 0.3 < dist < 0.8
        assert w.model.geom(geomid[0]).name in {"cube_geom", "sphere_geom", names.TABLE_TOP_GEOM}


@pytest.mark.parametrize(
    "xy", [(-0.12, -0.10), (0.12, -0.10), (-0.12, 0.10), (0.12, 0.10), (0.0, 0.0)]
)
def test_arm_reaches_region_hand_down(xy) -> None:
    w = build_world("scene2")
    target = np.array([*xy, names.TABLE_TOP_Z + 0.05])
    q, ok = arm_qpos_for_pinch(w.physics, target, yaw=0.0)
    assert ok
    for joint, value in zip(names.ARM_JOINTS, q, strict=True):
        w.data.joint(joint).qpos[0] = value
    w.forward()
    site = w.data.site(names.PINCH_SITE)
    np.testing.assert_allclose(site.xpos, target, atol=1e-3)
    assert site.xmat.reshape(3, 3)[2, 2] < -0.999  # fingers point down


def _render(world: World, camera: str) -> np.ndarray:
    try:
        renderer = mujoco.Renderer(world.model, 240, 320)
    except Exception as exc:  # pragma: no cover - no GL on this machine
        pytest.skip(f"no OpenGL: {exc}")
    try:
        renderer.update_scene(world.data, camera=camera)
        return renderer.render()
    finally:
        renderer.close()


def test_overhead_render_shows_dark_parts_on_light_tray() -> None:
    w = build_world("scene1")
    img = _render(w, names.OVERHEAD_CAMERA).astype(float).mean(axis=2)  # (240, 320)
    depth = names.TABLE_TOP_Z + 0.8 - (TRAY_TOP_Z + 0.004)
    f = 120 / np.tan(np.radians(16))
    for part in FLAT_PARTS:
        x, y = part.default_xy
        u, v = 160 + f * x / depth, 120 - f * y / depth
        if part.kind in ("disc", "square_plate"):
            assert img[int(round(v)), int(round(u))] < 140, part.name
    assert np.median(img[60:180, 80:240]) > 200  # the light tray


def test_render_each_scene(world: World) -> None:
    for cam in (names.STEREO_LEFT, names.DEPTH_CAMERA):
        img = _render(world, cam)
        assert img.shape == (240, 320, 3) and img.std() > 10
