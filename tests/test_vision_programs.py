"""Circle_Detector and Corner_Holes_Detector on synthetic images under a known pinhole camera.

Shapes are drawn by projecting metric polygons on the table plane through the camera, so the
expected outputs (metres on the table, corner and hole counts) are known exactly.
"""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from mks_sim.errors import SensorFailure
from mks_sim.sensing import get_program
from mks_sim.sensing.programs.vision import backproject_to_plane, find_blobs

W, H, F = 640, 480, 800.0
K = np.array([[F, 0, (W - 1) / 2], [0, F, (H - 1) / 2], [0, 0, 1.0]])
TABLE_Z = 0.75


def _camera(tilt_deg: float = 0.0, height: float = 1.0) -> np.ndarray:
    """OpenCV camera over (0, 0, TABLE_Z + height) looking down, tilted about world x."""
    down = np.diag([1.0, -1.0, -1.0])  # x right = world x, y down = world -y, z = world -z
    t = np.deg2rad(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    T = np.eye(4)
    T[:3, :3] = rx @ down
    T[:3, 3] = [0.0, -height * np.tan(t), TABLE_Z + height]
    return T


def _project(xy: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    pw = np.c_[xy, np.full(len(xy), TABLE_Z), np.ones(len(xy))]
    pc = (np.linalg.inv(cam_to_world) @ pw.T)[:3]
    uv = (K @ pc)[:2] / pc[2]
    return uv.T


def _ngon(cx: float, cy: float, r: float, n: int, phase: float = 0.3) -> np.ndarray:
    a = phase + np.arange(n) * 2 * np.pi / n
    return np.c_[cx + r * np.cos(a), cy + r * np.sin(a)]


def _draw(shapes, cam_to_world, seed: int = 0):
    """shapes: list of (outer polygon (n, 2) metres, [hole polygons]) -> frame."""
    rng = np.random.default_rng(seed)
    img = np.clip(rng.normal(90, 8, (H, W)), 0, 255).astype(np.uint8)
    shift = 4  # sub-pixel drawing: 1/16 px
    for outer, holes in shapes:
        pts = np.rint(_project(outer, cam_to_world) * 2**shift).astype(np.int32)
        cv2.fillPoly(img, [pts], 210, lineType=cv2.LINE_AA, shift=shift)
        for hole in holes:
            hp = np.rint(_project(hole, cam_to_world) * 2**shift).astype(np.int32)
            cv2.fillPoly(img, [hp], 90, lineType=cv2.LINE_AA, shift=shift)
    rgb = np.repeat(img[..., None], 3, axis=2)
    return SimpleNamespace(
        rgb=rgb, depth=None, K=K, camera_to_world=cam_to_world, name="overhead_camera"
    )


PARAMS = {"plane_z_m": TABLE_Z}
DISCS = [(-0.15, 0.10, 0.02), (0.05, -0.08, 0.03), (0.18, 0.12, 0.015), (-0.05, -0.15, 0.025)]


@pytest.mark.parametrize("tilt", [0.0, 25.0])
def test_circle_detector_recovers_centres_and_radii(tilt: float) -> None:
    cam = _camera(tilt)
    frame = _draw([(_ngon(x, y, r, 720), []) for x, y, r in DISCS], cam)
    out = get_program("circle_detector")({"overhead_camera": frame}, PARAMS)
    assert out.shape == (len(DISCS), 3)
    for x, y, r in DISCS:
        row = out[np.argmin(np.hypot(out[:, 0] - x, out[:, 1] - y))]
        assert row[0] == pytest.approx(x, abs=0.001) and row[1] == pytest.approx(y, abs=0.001)
        assert row[2] == pytest.approx(r, rel=0.03)


def test_backprojection_inverts_projection() -> None:
    cam = _camera(30.0)
    xy = np.array([[0.1, -0.2], [0.0, 0.0], [-0.3, 0.25]])
    back = backproject_to_plane(_project(xy, cam), K, cam, TABLE_Z)
    np.testing.assert_allclose(back[:, :2], xy, atol=1e-12)
    np.testing.assert_allclose(back[:, 2], TABLE_Z)


def _scene_shapes():
    square_nut = (_ngon(-0.15, 0.1, 0.03, 4), [_ngon(-0.15, 0.1, 0.009, 360)])
    hex_nut = (_ngon(0.15, 0.1, 0.028, 6), [_ngon(0.15, 0.1, 0.01, 360)])
    hexagon = (_ngon(0.0, -0.12, 0.03, 6), [])
    disc = (_ngon(0.15, -0.1, 0.02, 720), [])
    square_2holes = (
        np.array([[-0.19, -0.13], [-0.11, -0.13], [-0.11, -0.07], [-0.19, -0.07]]),
        [_ngon(-0.17, -0.1, 0.01, 4), _ngon(-0.13, -0.1, 0.008, 360)],
    )
    triangle = (_ngon(0.0, 0.12, 0.03, 3), [])
    return {
        (-0.15, 0.1): (4, 1, 0.009),
        (0.15, 0.1): (6, 1, 0.01),
        (0.0, -0.12): (6, 0, 0.0),
        (0.15, -0.1): (0, 0, 0.02),
        (-0.15, -0.1): (4, 2, 0.008),
        (0.0, 0.12): (3, 0, 0.0),
    }, [square_nut, hex_nut, hexagon, disc, square_2holes, triangle]


@pytest.mark.parametrize("tilt", [0.0, 20.0])
def test_corner_holes_detector_counts(tilt: float) -> None:
    expected, shapes = _scene_shapes()
    frame = _draw(shapes, _camera(tilt), seed=1)
    out = get_program("corner_holes_detector")({"overhead_camera": frame}, PARAMS)
    assert out.shape == (len(shapes), 4)
    for (x, y), (corners, holes, _) in expected.items():
        row = out[np.argmin(np.hypot(out[:, 0] - x, out[:, 1] - y))]
        assert np.hypot(row[0] - x, row[1] - y) < 0.01
        assert (row[2], row[3]) == (corners, holes), (x, y)


def test_circle_detector_reports_hole_radius_like_table_4_1() -> None:
    # Table 4-1: polygons have radius 0, objects with a hole report the hole's radius.
    expected, shapes = _scene_shapes()
    frame = _draw(shapes, _camera(), seed=2)
    out = get_program("circle_detector")({"overhead_camera": frame}, PARAMS)
    for (x, y), (_, _, radius) in expected.items():
        row = out[np.argmin(np.hypot(out[:, 0] - x, out[:, 1] - y))]
        assert row[2] == pytest.approx(radius, rel=0.08, abs=1e-9), (x, y)
    only = get_program("circle_detector")(
        {"overhead_camera": frame}, {**PARAMS, "report_all": False}
    )
    assert len(only) == sum(r > 0 for _, _, r in expected.values())


def test_polarity_and_border() -> None:
    cam = _camera()
    frame = _draw([(_ngon(0.0, 0.0, 0.03, 720), [])], cam)
    dark = SimpleNamespace(**{**vars(frame), "rgb": 255 - frame.rgb})
    for f in (frame, dark):
        assert len(find_blobs(f, PARAMS)) == 1
    # A disc cut by the image border is dropped (seen only in part).
    half_w = (W / 2) / F * 1.0
    cut = _draw([(_ngon(half_w, 0.0, 0.03, 720), []), (_ngon(0.0, 0.0, 0.03, 720), [])], cam)
    assert len(find_blobs(cut, PARAMS)) == 1


def test_no_objects_and_bad_inputs() -> None:
    empty = SimpleNamespace(
        rgb=np.full((H, W, 3), 90, np.uint8), K=K, camera_to_world=_camera(), name="c"
    )
    assert get_program("circle_detector")({"c": empty}, PARAMS).shape == (0, 3)
    with pytest.raises(SensorFailure, match="expected exactly one camera reading"):
        get_program("corner_holes_detector")({}, PARAMS)


def test_workstation_feature_models_pick_their_objects() -> None:
    from mks_sim.models.database import ModelDatabase

    db = ModelDatabase.from_dir()
    discs = [(-0.15, 0.10, 0.02), (0.05, -0.08, 0.025), (0.18, 0.12, 0.015), (-0.05, -0.15, 0.02)]
    frame = _draw([(_ngon(x, y, r, 720), []) for x, y, r in discs], _camera(15.0), seed=4)
    circles = get_program("circle_detector")({"overhead_camera": frame}, PARAMS)
    hit = db.get("disc_2cm").matches(circles)
    assert hit.sum() == 2 and np.allclose(np.sort(circles[hit, 2]), 0.02, atol=0.001)
    expected, shapes = _scene_shapes()
    rows = get_program("corner_holes_detector")(
        {"overhead_camera": _draw(shapes, _camera())}, PARAMS
    )
    nut = rows[db.get("square_nut").matches(rows)]
    assert len(nut) == 1 and np.hypot(nut[0, 0] + 0.15, nut[0, 1] - 0.1) < 0.005


@pytest.mark.slow
def test_scene1_overhead_camera_matches_the_manifest() -> None:
    from mks_sim.devices import make_devices
    from mks_sim.models.database import ModelDatabase
    from mks_sim.sensing import SensorGraph
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world

    db, graph = ModelDatabase.from_dir(), SensorGraph.from_dir()
    for seed in (None, 2):
        world = build_world("scene1", seed=seed)
        manifest = truth.scene1_manifest(world)
        with make_devices(
            world.model, world.data, np.random.default_rng(0), names=["overhead_camera"]
        ) as devs:
            snap = graph.snapshot(devs)
            circles = snap.get("Circle_Detector").data
            shapes = snap.get("Corner_Holes_Detector").data
        assert len(shapes) == len(manifest) == len(circles)
        for part in manifest:
            i = np.argmin(
                np.hypot(shapes[:, 0] - part.xy_world[0], shapes[:, 1] - part.xy_world[1])
            )
            assert np.hypot(*(shapes[i, :2] - part.xy_world)) < 0.002, part.name
            assert (shapes[i, 2], shapes[i, 3]) == (part.corners, part.holes), part.name
            if part.radius_m > 0:
                assert circles[i, 2] == pytest.approx(part.radius_m, abs=0.001), part.name
            elif part.holes == 0:
                assert circles[i, 2] == 0.0, part.name
        nut = shapes[db.get("square_nut").matches(shapes)]
        (square,) = [p for p in manifest if p.kind == "square_nut"]
        assert len(nut) == 1 and np.hypot(*(nut[0, :2] - square.xy_world)) < 0.002
        discs = circles[db.get("disc_2cm").matches(circles)]
        expected = [p for p in manifest if abs(p.radius_m - 0.02) < 1e-9]
        assert len(discs) == len(expected) == 1
