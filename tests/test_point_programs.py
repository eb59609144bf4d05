"""Point programs on synthetic inputs (no simulator), and the Range_Points alternates through
the sensor graph with fake devices. One slow test on the simulated scene2."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mks_sim.errors import DeviceFailure, SensorFailure
from mks_sim.geometry.meshes import (
    box_mesh,
    industrial_part_control_points,
    industrial_part_mesh,
    sample_surface,
    uv_sphere,
)
from mks_sim.resources import data_dir
from mks_sim.sensing import SensorGraph, get_program
from mks_sim.sensing.programs.points import depth_to_points, postprocess

TABLE_Z = 0.75
F, W, H = 500.0, 320, 240
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])


def _rot_z(deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def _looking_down(eye: tuple[float, float, float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = eye
    return T


# --- stereo ----------------------------------------------------------------------------------


def _stereo_pair(disparity: int, baseline: float = 0.08, seed: int = 0):
    """A rectified random-dot pair of a fronto-parallel plane at depth F * b / d."""
    rng = np.random.default_rng(seed)
    wide = rng.integers(0, 256, (H, W + disparity)).astype(np.uint8)
    # A scene point at left column u appears at right column u - d (right camera at +x).
    left = np.repeat(wide[:, :W, None], 3, axis=2)
    right = np.repeat(wide[:, disparity:, None], 3, axis=2)
    left_T = _looking_down((0.1, -0.05, TABLE_Z + F * baseline / disparity))
    right_T = left_T.copy()
    right_T[:3, 3] += left_T[:3, :3] @ np.array([baseline, 0.0, 0.0])
    mk = lambda rgb, T, n: SimpleNamespace(rgb=rgb, depth=None, K=K, camera_to_world=T, name=n)  # noqa: E731
    return mk(left, left_T, "stereo_left"), mk(right, right_T, "stereo_right")


@pytest.mark.parametrize("disparity", [24, 40])
def test_stereo_points_depth_from_known_disparity(disparity: int) -> None:
    left, right = _stereo_pair(disparity)
    pts = get_program("stereo_points")(
        {"stereo_left": left, "stereo_right": right}, {"num_disparities": 64, "block_size": 5}
    )
    assert len(pts) > 0.5 * W * H * (W - 64) / W
    # The textured plane is the table: z = TABLE_Z in the world, across the image.
    assert np.median(np.abs(pts[:, 2] - TABLE_Z)) < 1e-3
    assert np.percentile(np.abs(pts[:, 2] - TABLE_Z), 95) < 0.01
    # x, y spread over the camera's footprint (not collapsed).
    assert np.ptp(pts[:, 0]) > 0.5 * (W - 64) * (F * 0.08 / disparity) / F


def test_stereo_points_rejects_mismatched_cameras() -> None:
    left, right = _stereo_pair(30)
    bad = SimpleNamespace(**{**vars(right), "K": K * 1.1})
    with pytest.raises(SensorFailure, match="equal image size and intrinsics"):
        get_program("stereo_points")({"stereo_left": left, "stereo_right": bad}, {})
    same = SimpleNamespace(**{**vars(right), "camera_to_world": left.camera_to_world})
    with pytest.raises(SensorFailure, match="share one optical centre"):
        get_program("stereo_points")({"stereo_left": left, "stereo_right": same}, {})


# --- depth -----------------------------------------------------------------------------------


def test_depth_points_backprojects_a_plane() -> None:
    T = _looking_down((0.0, 0.0, TABLE_Z + 0.6))
    depth = np.full((H, W), 0.6)
    depth[:10] = np.nan  # unseen rows are skipped
    frame = SimpleNamespace(rgb=None, depth=depth, K=K, camera_to_world=T, name="depth_camera")
    pts = depth_to_points(frame)
    assert pts.shape == ((H - 10) * W, 3)
    np.testing.assert_allclose(pts[:, 2], TABLE_Z)
    # Pixel (0, H-1) (bottom-left) sees world -x and -y (image down = world -y).
    corner = pts[np.argmin(pts[:, 0] + pts[:, 1])]
    np.testing.assert_allclose(corner[:2], [-(W - 1) / 2 * 0.6 / F, -(H - 1) / 2 * 0.6 / F])
    out = get_program("depth_points")({"depth_camera": frame}, {"stride": 2})
    assert len(out) == (H - 10) // 2 * W // 2
    with pytest.raises(SensorFailure, match="gives no depth"):
        get_program("depth_points")({"c": SimpleNamespace(**{**vars(frame), "depth": None})}, {})


# --- range points ----------------------------------------------------------------------------


def _scan(points: np.ndarray, hit: np.ndarray, view: int):
    return SimpleNamespace(points_world=np.where(hit[:, None], points, np.nan), hit=hit, view=view)


def test_range_points_merges_views_crops_and_thins() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-0.5, 0.5, (100, 3)), rng.uniform(-0.5, 0.5, (80, 3))
    ha, hb = rng.random(100) < 0.7, rng.random(80) < 0.9
    scans = [_scan(a, ha, 0), _scan(b, hb, 1)]
    out = get_program("range_points")({"range_finder": scans}, {})
    np.testing.assert_array_equal(out, np.concatenate([a[ha], b[hb]]))
    crop = {"crop_min": [-0.2, -0.2, -0.2], "crop_max": [0.2, 0.2, 0.2]}
    cropped = get_program("range_points")({"range_finder": scans}, crop)
    assert (
        np.all(np.abs(cropped) <= 0.2) and len(cropped) == np.all(np.abs(out) <= 0.2, axis=1).sum()
    )
    with pytest.raises(SensorFailure, match="no range returns"):
        get_program("range_points")({"range_finder": [_scan(a, np.zeros(100, bool), 0)]}, {})


def test_postprocess_voxel_keeps_one_point_per_voxel() -> None:
    pts = np.array([[0.001, 0.001, 0.001], [0.002, 0.003, 0.004], [0.012, 0, 0], [np.nan, 0, 0]])
    out = postprocess(pts, {"voxel_m": 0.01})
    np.testing.assert_array_equal(out, pts[[0, 2]])


def test_postprocess_voxel_matches_brute_force_first_point_per_cell() -> None:
    """A workspace-sized cloud (negative coordinates, several points per cell) keeps exactly
    the first point of each cell, in input order, as a per-point scan of cells does."""
    rng = np.random.default_rng(7)
    pts = rng.uniform([-0.3, -0.3, 0.74], [0.3, 0.3, 1.0], (3000, 3))
    pts = np.vstack([pts, pts[:1500] + 1e-4])[rng.permutation(4500)]
    out = postprocess(pts, {"voxel_m": 0.02})
    seen: set[tuple[int, ...]] = set()
    want = []
    for p in pts:
        cell = tuple(int(v) for v in np.floor(p / 0.02))
        if cell not in seen:
            seen.add(cell)
            want.append(p)
    np.testing.assert_array_equal(out, np.array(want))


# --- touch -----------------------------------------------------------------------------------


def test_touch_contacts_thresholds() -> None:
    pos = np.arange(27.0).reshape(9, 3)
    pads = {
        "touch_finger_1": SimpleNamespace(
            pressure=np.array([0, 400, 600, 0, 0, 0, 0, 0, 5000.0]), positions_world=pos
        ),
        "touch_finger_2": SimpleNamespace(pressure=np.zeros(9), positions_world=pos + 100),
        "touch_finger_3": SimpleNamespace(pressure=np.full(9, 501.0), positions_world=pos + 200),
    }
    out = get_program("touch_contacts")(pads, {"min_pressure_pa": 500.0})
    assert out.shape == (2 + 9, 4)
    np.testing.assert_array_equal(out[:2], [[6, 7, 8, 600], [24, 25, 26, 5000]])
    np.testing.assert_array_equal(out[2:, :3], pos + 200)
    with pytest.raises(SensorFailure, match="not a touch reading"):
        get_program("touch_contacts")({"x": object()}, {})


# --- descriptions over points ------------------------------------------------------------------


def _on_table(
    mesh, R: np.ndarray, xy: tuple[float, float], spacing: float, seed: int
) -> np.ndarray:
    pts, _ = sample_surface(mesh, spacing=spacing, rng=np.random.default_rng(seed))
    pts = pts @ R.T
    pts[:, :2] += xy
    pts[:, 2] += TABLE_Z - pts[:, 2].min()
    return pts


def _table(seed: int = 9) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-0.2, 0.2, (4000, 2)), np.full(4000, TABLE_Z)]


PARAMS = {"table_z_m": TABLE_Z, "table_margin_m": 0.004, "gap_m": 0.012, "m": 12}
CUBE_XY, SPHERE_XY = (0.05, -0.03), (-0.08, 0.06)


@pytest.fixture(scope="module")
def cube_sphere_cloud() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cube = _on_table(box_mesh((0.05, 0.05, 0.05)), _rot_z(25), CUBE_XY, 0.0025, 1)
    cube = cube[cube[:, 2] > TABLE_Z + 1e-6]  # the bottom face is not seen
    sphere = _on_table(uv_sphere(0.03, 32, 64), np.eye(3), SPHERE_XY, 0.0025, 2)
    sphere = sphere[sphere[:, 2] > TABLE_Z + 0.01]
    return np.concatenate([cube, sphere, _table()]), cube, sphere


def _stream_input(pts: np.ndarray) -> dict:
    return {"Range_Points": pts}


def test_surface_curvature_codes_cube_planar_sphere_curved(cube_sphere_cloud) -> None:
    pts, cube, sphere = cube_sphere_cloud
    out = get_program("surface_curvature")(_stream_input(pts), PARAMS)
    objects = np.concatenate([cube, sphere])
    kept = objects[:, 2] > TABLE_Z + PARAMS["table_margin_m"]
    assert out.shape == (kept.sum(), 4)  # the table (and a margin above it) is dropped
    assert set(np.unique(out[:, 3])) <= {-1.0, 1.0}
    on_sphere = np.hypot(out[:, 0] - SPHERE_XY[0], out[:, 1] - SPHERE_XY[1]) < 0.031
    assert np.mean(out[on_sphere, 3] == 1) > 0.9
    # Cube face interiors (away from the edges, whose neighbourhoods bend) are planar.
    local = (out[~on_sphere, :2] - CUBE_XY) @ _rot_z(25)[:2, :2]
    interior = np.all(np.abs(local) < 0.017, axis=1) & (out[~on_sphere, 2] > TABLE_Z + 0.049)
    assert np.mean(out[~on_sphere][interior, 3] == -1) > 0.9


def test_vertex_detector_recovers_cube_corners(cube_sphere_cloud) -> None:
    pts, _, _ = cube_sphere_cloud
    # Planar regions of >= 40 points: a 6 mm cap of the sphere is flat within the region
    # growing's tolerances and would otherwise make a (table, cap, cap) vertex.
    out = get_program("vertex_detector")(_stream_input(pts), {**PARAMS, "min_points": 40})
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (0, 2)]) * 0.025
    corners = corners @ _rot_z(25).T + [*CUBE_XY, TABLE_Z]
    d = np.linalg.norm(out[:, None, :] - corners[None], axis=2)  # (V, 8)
    assert np.all(d.min(axis=0) < 0.003), d.min(axis=0)  # every corner found
    assert len(out) == 8  # and nothing else (the sphere has no planar faces)


def test_sphere_detector_fits_the_sphere(cube_sphere_cloud) -> None:
    pts, _, _ = cube_sphere_cloud
    out = get_program("sphere_detector")(_stream_input(pts), PARAMS)
    assert out.shape == (1, 4)
    np.testing.assert_allclose(out[0, :3], [*SPHERE_XY, TABLE_Z + 0.03], atol=0.001)
    assert out[0, 3] == pytest.approx(0.03, abs=0.001)


def test_control_point_detector_finds_the_part_control_points() -> None:
    R, xy = _rot_z(-40), (0.02, 0.01)
    part = _on_table(industrial_part_mesh(), R, xy, 0.0015, 3)
    part = part[part[:, 2] > TABLE_Z + 1e-6]
    pts = np.concatenate([part, _table()])
    # The plate's walls are 8 mm high: a 2 mm table margin and 1.5 mm sampling leave enough of
    # them for planar regions (at 2 mm sampling the plate corner is lost).
    out = get_program("control_point_detector")(
        _stream_input(pts), {**PARAMS, "table_margin_m": 0.002}
    )
    truth = industrial_part_control_points() @ R.T + [*xy, TABLE_Z]
    d = np.linalg.norm(out[:, None, :] - truth[None], axis=2)
    assert np.all(d.min(axis=0) < 0.003), d.min(axis=0)


def test_description_programs_need_points() -> None:
    with pytest.raises(SensorFailure, match=">= 4 object points"):
        get_program("surface_curvature")(_stream_input(_table()), PARAMS)
    assert get_program("vertex_detector")(_stream_input(_table()), PARAMS).shape == (0, 3)


# --- the alternate through the sensor graph ----------------------------------------------------


class FakeDevice:
    def __init__(self, name: str, reading=None, failed: bool = False) -> None:
        self.name, self.reading, self.failed, self.reads = name, reading, failed, 0

    def read(self):
        self.reads += 1
        if self.failed:
            raise DeviceFailure(self.name)
        return self.reading


def test_failed_range_finder_is_served_by_stereo_points() -> None:
    graph = SensorGraph.from_files([data_dir("sensors") / "points.toml"])
    left, right = _stereo_pair(40)
    devices = {
        "range_finder": FakeDevice("range_finder", failed=True),
        "stereo_left": FakeDevice("stereo_left", left),
        "stereo_right": FakeDevice("stereo_right", right),
        "depth_camera": FakeDevice("depth_camera", failed=True),
    }
    snap = graph.snapshot(devices)
    stream = snap.get("Range_Points")
    assert snap.provenance["Range_Points"] == "Stereo_Points"
    assert stream.served_by == "Stereo_Points" and len(stream) > 200
    assert np.median(np.abs(stream.data[:, 2] - TABLE_Z)) < 1e-3
    assert devices["depth_camera"].reads == 0
    # where the points were seen from: the two cameras' centres
    centres = [left.camera_to_world[:3, 3], right.camera_to_world[:3, 3]]
    np.testing.assert_allclose(snap.origins("Range_Points"), centres)
    # With stereo gone too, the depth camera serves.
    devices["stereo_left"].failed = True
    depth = np.full((H, W), 0.5)
    devices["depth_camera"] = FakeDevice(
        "depth_camera",
        SimpleNamespace(
            rgb=None,
            depth=depth,
            K=K,
            camera_to_world=_looking_down((0, 0, TABLE_Z + 0.5)),
            name="d",
        ),
    )
    snap = graph.snapshot(devices)
    assert snap.origins("Range_Points").shape == (0, 3)  # not served yet: seen from nowhere
    assert snap.get("Range_Points").served_by == "Depth_Points"
    np.testing.assert_allclose(snap.origins("Range_Points"), [(0, 0, TABLE_Z + 0.5)])
    devices["depth_camera"].failed = True
    with pytest.raises(SensorFailure, match="all 3 way"):
        graph.snapshot(devices).get("Range_Points")


# --- simulator ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_scene2_points_lie_on_the_objects() -> None:
    from mks_sim.devices import make_devices
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world

    world = build_world("scene2", seed=0)
    cube_T, sphere_T = truth.object_to_world(world, "cube"), truth.object_to_world(world, "sphere")

    def surface_distance(p: np.ndarray) -> np.ndarray:
        local = (p - cube_T[:3, 3]) @ cube_T[:3, :3]
        q = np.abs(local) - 0.025
        d_box = np.abs(np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))
        d_sphere = np.abs(np.linalg.norm(p - sphere_T[:3, 3], axis=1) - 0.03)
        return np.minimum(d_box, d_sphere)

    graph = SensorGraph.from_dir()
    origins: dict[str, np.ndarray] = {}
    with make_devices(world.model, world.data, np.random.default_rng(0)) as devices:
        results = {}
        for failed in ((), ("range_finder",)):
            devices.clear_faults()
            for name in failed:
                devices.set_fault(name, failed=True)
            snap = graph.snapshot(devices)
            results[snap.get("Range_Points").served_by] = snap.get("Range_Points").data
            origins[snap.get("Range_Points").served_by] = snap.origins("Range_Points")
            if not failed:
                spheres = snap.get("Sphere_Detector").data
                origins["Sphere_Detector"] = snap.origins("Sphere_Detector")  # via its input
    assert set(results) == {"primary", "Stereo_Points"}
    # the points were seen from the range finder's two mount sites, else the stereo cameras
    sites = [world.data.site(m).xpos for m in ("range_finder_mount_0", "range_finder_mount_1")]
    cams = [world.data.cam(c).xpos for c in ("stereo_left", "stereo_right")]
    np.testing.assert_allclose(origins["primary"], sites, atol=1e-9)
    np.testing.assert_allclose(origins["Sphere_Detector"], sites, atol=1e-9)
    np.testing.assert_allclose(origins["Stereo_Points"], cams, atol=1e-9)
    for served_by, pts in results.items():
        near = (np.hypot(pts[:, 0] - cube_T[0, 3], pts[:, 1] - cube_T[1, 3]) < 0.033) & (
            pts[:, 2] > TABLE_Z + 0.005
        )
        d = surface_distance(pts[near])
        assert near.sum() > 300, served_by
        assert np.median(d) < 0.002 and np.percentile(d, 90) < 0.004, served_by
    best = spheres[np.argmin(np.linalg.norm(spheres[:, :3] - sphere_T[:3, 3], axis=1))]
    np.testing.assert_allclose(best[:3], sphere_T[:3, 3], atol=0.003)
    assert best[3] == pytest.approx(0.03, abs=0.003)


# --- the sphere model kind -----------------------------------------------------------------------


def test_sphere_model_from_the_database(cube_sphere_cloud) -> None:
    from mks_sim.models.database import ModelDatabase

    model = ModelDatabase.from_dir().get("sphere_3cm")
    assert model.radius_m == 0.03 and model.sensor == "Sphere_Detector"
    _, cube, sphere = cube_sphere_cloud
    (hyp,) = model.hypotheses(sphere, None)
    np.testing.assert_allclose(hyp.matrix[:3, 3], [*SPHERE_XY, TABLE_Z + 0.03], atol=1e-3)
    assert model.hypotheses(cube, None) == []  # a cube is no 3 cm sphere
    rows = np.array([[0, 0, 0, 0.03], [0, 0, 0, 0.05], [1, 1, 1, 0.031]])
    np.testing.assert_array_equal(model.match(rows), [0, 2])
    assert model.surface_points().shape == model.surface_normals().shape
    np.testing.assert_allclose(np.linalg.norm(model.surface_points(), axis=1), 0.03)


def test_sphere_model_entry_errors(tmp_path) -> None:
    from mks_sim.errors import SpecError
    from mks_sim.models.database import ModelDatabase

    bad = tmp_path / "bad.toml"
    bad.write_text('[[model]]\nname = "s"\nkind = "sphere"\nradius_m = -1\ntolerance_m = 0.01\n')
    with pytest.raises(SpecError, match=r"model 's': field 'radius_m': expected a number > 0"):
        ModelDatabase.from_files([bad])
    bad.write_text(
        '[[model]]\nname = "s"\nkind = "sphere"\nradius_m = 1\ntolerance_m = 0.01\nradius = 2\n'
    )
    with pytest.raises(SpecError, match=r"unknown field\(s\) \['radius'\]"):
        ModelDatabase.from_files([bad])


def test_outline_corners_of_a_sampled_l_shape() -> None:
    from mks_sim.sensing.programs.points import outline_corners

    rng = np.random.default_rng(5)
    uv = rng.uniform(0, 0.06, (6000, 2))
    uv = uv[~((uv[:, 0] > 0.03) & (uv[:, 1] > 0.03))]  # an L: the (+, +) quarter cut away
    R = _rot_z(30)
    pts = np.c_[uv, np.full(len(uv), 0.02)] @ R.T + [0.1, 0.0, TABLE_Z]
    corners = outline_corners(pts, np.array([0.0, 0.0, 1.0]), spacing=0.0015)
    convex = np.array([[0, 0], [0.06, 0], [0.06, 0.03], [0.03, 0.06], [0, 0.06]])
    truth = np.c_[convex, np.full(5, 0.02)] @ R.T + [0.1, 0.0, TABLE_Z]
    d = np.linalg.norm(corners[:, None] - truth[None], axis=2)  # (k, 5)
    assert np.all(d.min(axis=0) < 0.003)  # every convex corner found ...
    assert np.all(d.min(axis=1) < 0.003)  # ... and nothing else (not the concave corner)
    assert len(corners) <= 6  # a rasterised corner may be cut into two close vertices


@pytest.mark.slow
def test_part_scene_control_point_candidates() -> None:
    from mks_sim.devices import make_devices
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world

    graph = SensorGraph.from_dir()
    for seed in (None, 1):
        world = build_world("part", seed=seed)
        T = truth.object_to_world(world, "part")
        control = industrial_part_control_points() @ T[:3, :3].T + T[:3, 3]
        with make_devices(
            world.model, world.data, np.random.default_rng(0), names=["range_finder"]
        ) as devices:
            candidates = graph.snapshot(devices).get("Control_Point_Detector").data
        assert 4 <= len(candidates) <= 16
        d = np.linalg.norm(control[:, None] - candidates[None], axis=2).min(axis=1)
        assert np.all(d < 0.007), (seed, d)


# --- the Hough models over the detectors' output -----------------------------------------------


def test_cube_5cm_model_on_vertex_detector_output(cube_sphere_cloud) -> None:
    from mks_sim.geometry.transforms import cube_rotations, pose_error
    from mks_sim.models.database import ModelDatabase

    pts, _, _ = cube_sphere_cloud
    verts = get_program("vertex_detector")(_stream_input(pts), {**PARAMS, "min_points": 40})
    hyps = ModelDatabase.from_dir().get("cube_5cm").detect(verts)
    truth = np.eye(4)
    truth[:3, :3] = _rot_z(25)
    truth[:3, 3] = [*CUBE_XY, TABLE_Z + 0.025]
    best = max(hyps, key=lambda h: h.votes)
    pos, rot = pose_error(best.matrix, truth, cube_rotations())
    assert pos < 0.002 and rot < 2.0


def test_part_model_on_control_point_candidates() -> None:
    from mks_sim.geometry.transforms import pose_error
    from mks_sim.models.database import ModelDatabase

    R, xy = _rot_z(-40), (0.02, 0.01)
    part = _on_table(industrial_part_mesh(), R, xy, 0.0015, 3)
    pts = np.concatenate([part[part[:, 2] > TABLE_Z + 1e-6], _table()])
    candidates = get_program("control_point_detector")(
        _stream_input(pts), {**PARAMS, "table_margin_m": 0.002}
    )
    hyps = ModelDatabase.from_dir().get("part").detect(candidates)
    truth = np.eye(4)
    truth[:3, :3] = R
    truth[:3, 3] = [*xy, TABLE_Z]
    # Outline corners lie up to a spacing inside the true edges: a coarse pose for ICP to polish.
    errors = [pose_error(h.matrix, truth) for h in hyps]
    assert min(e[0] for e in errors) < 0.002 and min(e[1] for e in errors) < 4.0
