"""Devices on tiny inline MJCF worlds: truth is known from the XML."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mks_sim.devices import (
    Camera,
    CameraNoise,
    DeviceFaults,
    RangeFinder,
    ScanPattern,
    StereoPair,
    TouchPad,
    make_devices,
    merge_scans,
)
from mks_sim.devices.base import Device
from mks_sim.errors import DeviceFailure, NotFound, SpecError

# A 10 cm cube on the floor under a camera 1 m up looking straight down; a marker sphere at a
# known point; a second camera 0.1 m to the right (stereo); a range-finder mount beside the
# camera; an "arm" body the range finder must self-filter; a touch pad under a falling block.
XML = """
<mujoco>
  <visual><global offwidth="640" offheight="480"/></visual>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.5 0.5 0.5 1"/>
    <body name="box" pos="0 0 0.05">
      <geom name="box_geom" type="box" size="0.05 0.05 0.05" rgba="0.9 0.1 0.1 1"/>
    </body>
    <geom name="marker" type="sphere" size="0.01" pos="0.15 0.08 0.01" rgba="0 1 0 1"/>
    <camera name="cam" pos="0 0 1" fovy="60"/>
    <camera name="cam_right" pos="0.1 0 1" fovy="60"/>
    <site name="mount" pos="0.0 0.0 1.0" zaxis="0 0 -1"/>
    <body name="arm" pos="-0.25 0 0.3">
      <geom name="arm_link" type="capsule" size="0.03" fromto="0 0 0 0 0 0.3" rgba="0.2 0.2 0.8 1"/>
      <body name="forearm" pos="0 0 0.3">
        <geom type="box" size="0.04 0.04 0.04"/>
      </body>
    </body>
    <body name="pad" pos="1 1 0.01">
      <geom type="box" size="0.02 0.02 0.01"/>
      <site name="taxel_a" type="box" pos="-0.01 0 0.01" size="0.01 0.02 0.004"/>
      <site name="taxel_b" type="box" pos="0.01 0 0.01" size="0.01 0.02 0.004"/>
    </body>
    <body name="weight" pos="0.99 1 0.035">
      <freejoint/>
      <geom type="box" size="0.005 0.005 0.005" mass="0.1"/>
    </body>
  </worldbody>
  <sensor>
    <touch name="touch_finger_1_0" site="taxel_a"/>
    <touch name="touch_finger_1_1" site="taxel_b"/>
  </sensor>
</mujoco>
"""

BOX_HALF = 0.05


@pytest.fixture(scope="module")
def world() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


@pytest.fixture(scope="module")
def camera(world):
    model, data = world
    cam = Camera(model, data, "cam", np.random.default_rng(0), width=320, height=240)
    yield cam
    cam.close()


# --- camera ----------------------------------------------------------------------------------


def test_camera_satisfies_device_protocol(camera) -> None:
    assert isinstance(camera, Device)
    assert camera.name == "cam"


def test_camera_depth_equals_truth(camera) -> None:
    camera.faults = DeviceFaults(noise_scale=0.0)
    frame = camera.read()
    assert frame.rgb.shape == (240, 320, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth is not None
    h, w = frame.shape
    # Centre pixel sees the cube's top face at z = 0.1: depth 0.9 m along the optical axis.
    assert frame.depth[h // 2, w // 2] == pytest.approx(1.0 - 2 * BOX_HALF, abs=2e-3)
    # A corner pixel sees the floor; depth is along the axis (z), not the ray length.
    assert frame.depth[5, 5] == pytest.approx(1.0, abs=2e-3)


def test_camera_K_matches_pinhole_projection_of_marker(camera) -> None:
    camera.faults = DeviceFaults(noise_scale=0.0)
    frame = camera.read()
    f_expected = 120 / np.tan(np.deg2rad(30))
    assert frame.K[0, 0] == pytest.approx(f_expected) and frame.K[1, 1] == pytest.approx(f_expected)
    # Project the marker centre (top of the sphere seen from above is near its centre).
    p_world = np.array([0.15, 0.08, 0.01, 1.0])
    p_cam = np.linalg.inv(frame.camera_to_world) @ p_world
    assert p_cam[2] == pytest.approx(0.99)  # z forward
    uv = (frame.K @ p_cam[:3])[:2] / p_cam[2]
    green = (frame.rgb[..., 1] > 150) & (frame.rgb[..., 0] < 80) & (frame.rgb[..., 2] < 80)
    vs, us = np.nonzero(green)
    assert len(us) > 5
    assert us.mean() == pytest.approx(uv[0], abs=0.5)
    assert vs.mean() == pytest.approx(uv[1], abs=0.5)
    # World +x is image right, world +y is image up (v decreases): OpenCV y down.
    assert uv[0] > 159.5 and uv[1] < 119.5


def test_camera_background_depth_is_nan(world) -> None:
    model, data = world
    with Camera(model, data, "cam", np.random.default_rng(0), width=64, height=48) as cam:
        cam.faults = DeviceFaults(noise_scale=0.0)
        d = cam.read().depth
        assert d is not None and np.isfinite(d).all()  # floor everywhere
    assert cam.closed


def test_camera_noise_seeded(world) -> None:
    model, data = world
    frames = []
    for seed in (1, 1, 2):
        with Camera(model, data, "cam", np.random.default_rng(seed), width=64, height=48) as cam:
            frames.append(cam.read())
    np.testing.assert_array_equal(frames[0].rgb, frames[1].rgb)
    np.testing.assert_array_equal(frames[0].depth, frames[1].depth)
    assert not np.array_equal(frames[0].depth, frames[2].depth)


def test_camera_errors(world) -> None:
    model, data = world
    with pytest.raises(SpecError, match="no MuJoCo camera named 'nope'"):
        Camera(model, data, "nope", np.random.default_rng(0))
    with pytest.raises(SpecError, match="exceeds the offscreen buffer"):
        Camera(model, data, "cam", np.random.default_rng(0), width=1280, height=960)


def test_camera_dropout_and_rgb_noise_scale(world) -> None:
    model, data = world
    noise = CameraNoise(rgb_sigma=5.0, depth_sigma_m=0.0, depth_sigma_rel=0.0)
    with Camera(
        model, data, "cam", np.random.default_rng(3), width=160, height=120, noise=noise
    ) as cam:
        cam.faults = DeviceFaults(dropout=0.25, noise_scale=0.0)
        d = cam.read().depth
        assert np.isnan(d).mean() == pytest.approx(0.25, abs=0.02)
        cam.faults = DeviceFaults(noise_scale=0.0)
        clean = cam.read().rgb.astype(float)
        cam.faults = DeviceFaults(noise_scale=2.0)
        noisy = cam.read().rgb.astype(float)
        interior = (clean > 20) & (clean < 235)
        assert np.std((noisy - clean)[interior]) == pytest.approx(10.0, rel=0.1)


# --- stereo ----------------------------------------------------------------------------------


def test_stereo_baseline_and_relative_pose(world) -> None:
    model, data = world
    rng = np.random.default_rng(0)
    left = Camera(model, data, "cam", rng, width=64, height=48, depth=False)
    right = Camera(model, data, "cam_right", rng, width=64, height=48, depth=False)
    with StereoPair(left, right, rng) as pair:
        sf = pair.read()
        assert sf.baseline == pytest.approx(0.1)
        assert pair.baseline_m == pytest.approx(0.1)
        np.testing.assert_allclose(sf.right_to_left[:3, 3], [0.1, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(sf.right_to_left[:3, :3], np.eye(3), atol=1e-12)
        left.faults = DeviceFaults(failed=True)
        with pytest.raises(DeviceFailure, match="'cam' failed"):
            pair.read()
    assert left.closed and right.closed


# --- range finder ----------------------------------------------------------------------------


def _rf(world, **kw) -> RangeFinder:
    model, data = world
    kw.setdefault("pattern", ScanPattern(n_pan=40, n_tilt=30, pan_deg=20, tilt_deg=15))
    return RangeFinder(model, data, ["mount"], np.random.default_rng(kw.pop("seed", 0)), **kw)


def _box_surface_distance(p: np.ndarray) -> np.ndarray:
    """Distance of points to the cube's surface (cube centred at (0, 0, 0.05), half 0.05)."""
    q = np.abs(p - np.array([0.0, 0.0, BOX_HALF])) - BOX_HALF
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return np.abs(outside + inside)


def test_range_points_on_known_surfaces(world) -> None:
    rf = _rf(world, sigma_m=0.0, self_bodies=["arm"])
    (scan,) = rf.read()
    assert scan.ranges.shape == (40 * 30,) and scan.points_world.shape == (1200, 3)
    assert scan.grid_shape == (30, 40)
    pts = scan.hit_points
    assert len(pts) > 0.5 * 1200
    on_floor = np.abs(pts[:, 2]) < 1e-9
    on_box = _box_surface_distance(pts) < 1e-9
    on_marker = np.abs(np.linalg.norm(pts - [0.15, 0.08, 0.01], axis=1) - 0.01) < 1e-9
    assert np.all(on_floor | on_box | on_marker)
    assert on_box.sum() > 20 and on_floor.sum() > 500
    # The ray nearest the boresight hits the top face 0.9 m below the mount, along its slant.
    centre = np.argmin(np.linalg.norm(scan.directions_sensor[:, :2], axis=1))
    assert scan.ranges[centre] == pytest.approx(0.9 / scan.directions_sensor[centre, 2])


def test_range_finder_self_filter(world) -> None:
    (plain,) = _rf(world, sigma_m=0.0).read()
    (filtered,) = _rf(world, sigma_m=0.0, self_bodies=["arm"]).read()
    assert filtered.self_hit.sum() > 0
    assert not np.any(filtered.hit & filtered.self_hit)
    # Self hits are exactly the rays that hit the arm (incl. its child body) in the plain scan.
    arm_pts = plain.points_world[filtered.self_hit]
    assert np.all(arm_pts[:, 0] < -0.2)
    assert plain.hit.sum() == filtered.hit.sum() + filtered.self_hit.sum()


def test_range_finder_max_range_and_dropout(world) -> None:
    (near,) = _rf(world, sigma_m=0.0, max_range_m=0.95, self_bodies=["arm"]).read()
    assert near.hit.sum() > 0
    assert np.allclose(near.hit_points[:, 2], 2 * BOX_HALF)  # only the cube's top face
    assert np.all(np.isinf(near.ranges[~near.hit])) and np.all(
        np.isnan(near.points_world[~near.hit])
    )
    rf = _rf(world, sigma_m=0.0, pattern=ScanPattern(n_pan=100, n_tilt=100, pan_deg=5, tilt_deg=5))
    full = rf.read()[0].hit.mean()
    assert full == 1.0
    rf.faults = DeviceFaults(dropout=0.3)
    assert rf.read()[0].hit.mean() == pytest.approx(0.7, abs=0.02)


def test_range_noise_seeded_and_sized(world) -> None:
    a = _rf(world, sigma_m=0.01, seed=5).read()[0]
    b = _rf(world, sigma_m=0.01, seed=5).read()[0]
    c = _rf(world, sigma_m=0.01, seed=6).read()[0]
    clean = _rf(world, sigma_m=0.0).read()[0]
    np.testing.assert_array_equal(a.ranges, b.ranges)
    assert not np.array_equal(a.ranges, c.ranges)
    both = a.hit & clean.hit
    assert np.std(a.ranges[both] - clean.ranges[both]) == pytest.approx(0.01, rel=0.1)


def test_range_merge_views(world) -> None:
    model, data = world
    rf = RangeFinder(
        model, data, ["mount", "mount"], np.random.default_rng(0),
        pattern=ScanPattern(n_pan=10, n_tilt=10), sigma_m=0.0,
    )  # fmt: skip
    scans = rf.read()
    assert [s.view for s in scans] == [0, 1]
    pts, views = merge_scans(scans)
    assert len(pts) == scans[0].hit.sum() + scans[1].hit.sum()
    assert set(np.unique(views)) == {0, 1}


def test_range_finder_errors(world) -> None:
    model, data = world
    with pytest.raises(SpecError, match="mount site 'nope'"):
        RangeFinder(model, data, ["nope"], np.random.default_rng(0))
    with pytest.raises(SpecError, match="self body 'nope'"):
        RangeFinder(model, data, ["mount"], np.random.default_rng(0), self_bodies=["nope"])


# --- faults (generic, on the range finder: cheap) --------------------------------------------


def test_fault_failed_and_recovery(world) -> None:
    rf = _rf(world)
    rf.faults = DeviceFaults(failed=True)
    with pytest.raises(DeviceFailure, match="'range_finder' failed"):
        rf.read()
    rf.faults = DeviceFaults()
    assert rf.read()[0].hit.any()


def test_fault_stuck_repeats_last_reading(world) -> None:
    # The scene is unchanged, but range noise differs on every fresh read.
    rf = _rf(world, sigma_m=0.01)
    first = rf.read()
    rf.faults = DeviceFaults(stuck=True)
    assert rf.read() is first
    rf.faults = DeviceFaults()
    assert not np.array_equal(rf.read()[0].ranges, first[0].ranges)


def test_faults_validation() -> None:
    with pytest.raises(SpecError, match="dropout"):
        DeviceFaults(dropout=1.5)
    with pytest.raises(SpecError, match="noise_scale"):
        DeviceFaults(noise_scale=-1)
    assert DeviceFaults().healthy and not DeviceFaults(stuck=True).healthy


# --- touch -----------------------------------------------------------------------------------


def test_touch_pressure_is_force_over_area() -> None:
    model = mujoco.MjModel.from_xml_string(XML)
    data = mujoco.MjData(model)
    for _ in range(600):  # let the 0.1 kg block settle on taxel_a
        mujoco.mj_step(model, data)
    pad = TouchPad(
        model, data, ["touch_finger_1_0", "touch_finger_1_1"], np.random.default_rng(0),
        name="touch_finger_1", sigma_pa=0.0,
    )  # fmt: skip
    r = pad.read()
    area = 0.02 * 0.04
    np.testing.assert_allclose(pad.area_m2, [area, area])
    weight = 0.1 * 9.81
    assert r.force.sum() == pytest.approx(weight, rel=0.05)
    assert r.pressure[0] == pytest.approx(weight / area, rel=0.05) and r.pressure[1] == 0.0
    np.testing.assert_allclose(r.positions_world, [[0.99, 1, 0.02], [1.01, 1, 0.02]], atol=1e-9)
    pad.faults = DeviceFaults(dropout=1.0)
    assert np.all(pad.read().pressure == 0)


def test_touch_errors(world) -> None:
    model, data = world
    with pytest.raises(SpecError, match="not a sensor"):
        TouchPad(model, data, ["nope"], np.random.default_rng(0), name="t")


# --- factory ---------------------------------------------------------------------------------


def test_make_devices_on_partial_world(world) -> None:
    model, data = world
    with make_devices(
        model, data, np.random.default_rng(0), {"touch_finger_1": DeviceFaults(stuck=True)}
    ) as devs:
        # Only the touch pad exists in this model (no workstation cameras or mounts).
        assert set(devs) == {"touch_finger_1"}
        assert devs["touch_finger_1"].faults.stuck
        devs.set_fault("touch_finger_1", failed=True)
        with pytest.raises(DeviceFailure):
            devs["touch_finger_1"].read()
        devs.clear_faults()
        devs["touch_finger_1"].read()
        with pytest.raises(NotFound, match="no device named 'x'"):
            devs.set_fault("x", failed=True)
    with pytest.raises(SpecError, match="unknown device 'bogus'"):
        make_devices(model, data, np.random.default_rng(0), {"bogus": DeviceFaults()})


@pytest.mark.slow
def test_workstation_devices_on_scene2() -> None:
    from mks_sim.devices import DEVICE_NAMES, stereo_frame
    from mks_sim.sensing.programs.points import depth_to_points
    from mks_sim.sim import names
    from mks_sim.sim.world import build_world

    world = build_world("scene2")
    with make_devices(world.model, world.data, np.random.default_rng(0)) as devs:
        assert set(devs) == set(DEVICE_NAMES)
        sf = stereo_frame(devs["stereo_left"].read(), devs["stereo_right"].read())
        assert sf.baseline == pytest.approx(names.STEREO_BASELINE_M, abs=1e-6)
        np.testing.assert_allclose(sf.right_to_left[:3, :3], np.eye(3), atol=1e-6)  # rectified
        # Depth pixels far from the objects see the table top.
        pts = depth_to_points(devs["depth_camera"].read())
        region = (np.abs(pts[:, 0]) < 0.3) & (pts[:, 1] < -0.15) & (pts[:, 1] > -0.3)
        assert region.sum() > 500
        assert np.median(np.abs(pts[region, 2] - names.TABLE_TOP_Z)) < 0.002
        # Range finder: both views hit the object region, the robot's returns are self-filtered.
        scans = devs["range_finder"].read()
        assert [s.view for s in scans] == [0, 1]
        for s in scans:
            assert s.hit.mean() > 0.9
        # Touch pads: 9 taxels at their sites, no contact with the hand open.
        touch = devs["touch_finger_2"].read()
        sites = [world.data.site(names.touch_site(2, i)).xpos for i in range(names.TAXELS_PER_PAD)]
        np.testing.assert_allclose(touch.positions_world, sites)
        assert touch.pressure.shape == (9,) and np.all(touch.pressure < 500.0)


def test_camera_read_after_close_is_an_error(world) -> None:
    model, data = world
    cam = Camera(model, data, "cam", np.random.default_rng(0), width=32, height=24)
    cam.close()  # never read: no renderer was made
    assert cam.closed
    with pytest.raises(SpecError, match="read after close"):
        cam.read()
