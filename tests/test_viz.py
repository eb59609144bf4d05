"""Rerun recordings (`--rerun`): spec parsing, wireframes, recordings read back with Rerun's
own reader, and no `rerun` import when the option is not given."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.errors import SpecError
from mks_sim.geometry.meshes import box_mesh
from mks_sim.viz import NullRecorder, RerunSpec, open_recorder, parse_rerun_spec
from mks_sim.viz.scene import feature_edges, wireframe

# The recording tests need the viz extra (rerun-sdk); without it they skip with this reason.
needs_rerun = pytest.mark.skipif(
    importlib.util.find_spec("rerun") is None, reason="rerun-sdk (the viz extra) not installed"
)

# --------------------------------------------------------------------------- helpers


def read_recording(path: Path) -> dict[str, dict[str, list[Any]]]:
    """entity path -> component column -> the logged values (one entry per row), read with
    Rerun's own reader (``rerun.chunk.RrdReader``; 0.41 has no ``rerun.dataframe``)."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list[Any]]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        cols = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if ":" in name and not name.startswith("rerun."):
                cols.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


def last(rec: dict[str, dict[str, list[Any]]], entity: str, column: str) -> Any:
    values = [v for v in rec[entity][column] if v is not None]
    return values[-1]


# --------------------------------------------------------------------------- the spec


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("spawn", RerunSpec("spawn", None, False)),
        ("spawn,normals", RerunSpec("spawn", None, True)),
        ("spawn,all,normals", RerunSpec("spawn", None, True, True)),
        ("connect:localhost:9876", RerunSpec("connect", "rerun+http://localhost:9876/proxy")),
        ("connect:rerun+http://10.0.0.2:9876/proxy",
         RerunSpec("connect", "rerun+http://10.0.0.2:9876/proxy")),
    ],
)  # fmt: skip
def test_spec_forms(text: str, expected: RerunSpec) -> None:
    assert parse_rerun_spec(text) == expected


def test_save_spec_validates_the_path(tmp_path: Path) -> None:
    spec = parse_rerun_spec(f"save:{tmp_path}/sub/run.rrd,normals")
    assert spec == RerunSpec("save", f"{tmp_path}/sub/run.rrd", True)
    with pytest.raises(SpecError, match=r"--rerun: save expected a path ending in \.rrd"):
        parse_rerun_spec(f"save:{tmp_path}/run.txt")
    (tmp_path / "folder.rrd").mkdir()
    with pytest.raises(SpecError, match="expected a file path, got the folder"):
        parse_rerun_spec(f"save:{tmp_path}/folder.rrd")
    (tmp_path / "a_file").write_text("")
    with pytest.raises(SpecError, match="not a writable folder"):
        parse_rerun_spec(f"save:{tmp_path}/a_file/run.rrd")


@pytest.mark.parametrize("text", ["", "save", "save:", "spawn:now", "record:x.rrd", "connect:"])
def test_bad_spec_forms(text: str) -> None:
    with pytest.raises(SpecError, match=r"^--rerun: .*expected"):
        parse_rerun_spec(text)


def test_cli_rejects_a_bad_spec_before_any_work(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["localize", "--object", "cube", "--rerun", "save:/tmp/run.png"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "argument --rerun" in err and "ending in .rrd" in err


def test_null_recorder_passes_everything_through() -> None:
    rec = open_recorder(None)
    assert isinstance(rec, NullRecorder) and not rec.enabled
    devices = {"a": object()}
    assert rec.tap_devices(devices) is devices
    assert rec.tap_graph(None) is None


# --------------------------------------------------------------------------- wireframes


def test_box_wireframe_is_its_twelve_edges() -> None:
    mesh = box_mesh((0.02, 0.04, 0.06))
    edges = feature_edges(mesh.faces, mesh.vertices)
    assert len(edges) == 12  # not the 6 face diagonals of the triangulation
    lengths = np.sort(np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]],
                                     axis=1))  # fmt: skip
    np.testing.assert_allclose(lengths, np.repeat([0.02, 0.04, 0.06], 4), atol=1e-12)
    assert wireframe(mesh.vertices, mesh.faces).shape == (12, 2, 3)


# --------------------------------------------------------------------------- recordings


@needs_rerun
@pytest.mark.slow
def test_localize_recording_reads_back(tmp_path: Path) -> None:
    from mks_sim.cli.localize import run_trial

    path = tmp_path / "loc.rrd"
    with open_recorder(parse_rerun_spec(f"save:{path}"), "test") as recorder:
        trial = run_trial("cube", 3, recorder=recorder)
    rec = read_recording(path)
    # every camera read for the context views: RGB images of the device's size
    fmt = last(rec, "/world/cameras/overhead_camera/rgb", "Image:format")[0]
    assert (fmt["width"], fmt["height"]) == (640, 480)
    fmt = last(rec, "/world/cameras/depth_camera/depth", "DepthImage:format")[0]
    assert (fmt["width"], fmt["height"]) == (320, 240)
    assert "/stereo/disparity" in rec
    # range finder: one point set per view (the default world has two mounts)
    for view in (0, 1):
        pts = np.asarray(last(rec, f"/world/range_finder/view_{view}/points",
                              "Points3D:positions"))  # fmt: skip
        assert pts.ndim == 2 and pts.shape[1] == 3 and len(pts) > 100
    # the logical sensors the localization ran, and the grouping of their points
    assert np.asarray(last(rec, "/world/sensors/Range_Points", "Points3D:positions")).shape[1] == 3
    assert len(last(rec, "/world/sensors/Vertex_Detector", "Points3D:positions")) >= 3
    assert len(last(rec, "/world/spg/edges", "LineStrips3D:strips")) > 100
    assert "/world/segmentation/regions" in rec
    # hypotheses: a 12-edge cube wireframe each; the chosen pose is the reported one
    hyps = [e for e in rec if e.startswith("/world/localization/cube/hypotheses/")]
    assert len(hyps) >= 1
    strips = np.asarray(last(rec, hyps[0], "LineStrips3D:strips"))
    assert strips.shape == (12, 2, 3)
    M = np.asarray(trial["matrix"])
    t = last(rec, "/world/localization/cube/chosen", "Transform3D:translation")[0]
    np.testing.assert_allclose(t, M[:3, 3], atol=1e-5)
    # the truth on its own path equals the simulator's pose the CLI evaluated against
    T = np.asarray(trial["truth"])
    t = last(rec, "/eval/truth/cube", "Transform3D:translation")[0]
    np.testing.assert_allclose(t, T[:3, 3], atol=1e-5)
    R = np.asarray(last(rec, "/eval/truth/cube", "Transform3D:mat3x3")[0]).reshape(3, 3).T
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-5)  # Rerun stores 3x3 column-major
    # the robot: its meshes and joint state
    assert any(e.startswith("/world/robot/") and "Mesh3D:triangle_indices" in c
               for e, c in rec.items())  # fmt: skip
    assert len([e for e in rec if e.startswith("/robot/joints/")]) == 9
    texts = [t for v in rec["/log"]["TextLog:text"] for t in v]
    assert any(t.startswith("localize cube: found") for t in texts)


@pytest.mark.slow
def test_logging_off_imports_no_rerun() -> None:
    code = (
        "import json, sys\n"
        "from mks_sim.cli import main\n"
        "rc = main(['localize', '--object', 'sphere', '--seed', '1', '--json'])\n"
        "print(json.dumps({'rc': rc, 'rerun': 'rerun' in sys.modules}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=300)  # fmt: skip
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result == {"rc": 0, "rerun": False}


@needs_rerun
def test_localize_cloud_recording_reads_back(tmp_path: Path) -> None:
    from mks_sim.geometry.scan import synthetic_scan
    from mks_sim.geometry.transforms import make_transform
    from mks_sim.io.mesh import write_stl
    from mks_sim.io.pointcloud import write_ply

    size = 0.05
    table = (box_mesh((0.6, 0.6, 0.02)), make_transform(np.eye(3), [0.0, 0.0, -0.01]))
    c, s = np.cos(0.4), np.sin(0.4)
    T = make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [0.01, -0.02, size / 2])
    pts = synthetic_scan(box_mesh(size), T, np.array([0.35, 0.25, 0.4]), [0.0, 0.0, 0.0],
                         width=200, height=150, fov_deg=30, noise_sigma=0.0002,
                         rng=np.random.default_rng(0), extra=[table])  # fmt: skip
    write_ply(tmp_path / "scan.ply", pts)
    write_stl(tmp_path / "cube.stl", box_mesh(size))
    path = tmp_path / "cloud.rrd"
    args = ["localize-cloud", "--model", str(tmp_path / "cube.stl"), "--scene",
            str(tmp_path / "scan.ply"), "--json", "--rerun", f"save:{path}"]  # fmt: skip
    assert main(args) == 0
    rec = read_recording(path)
    scene = np.asarray(last(rec, "/world/scene/points", "Points3D:positions"))
    assert scene.shape == (int(np.all(np.isfinite(pts), axis=1).sum()), 3)
    hyps = sorted(e for e in rec if e.startswith("/world/localization/cube/hypotheses/"))
    assert hyps
    # the best hypothesis's posed model points lie on the true cube's surface (brute force:
    # distance to the box in the true object frame)
    posed = np.asarray(last(rec, hyps[0], "Points3D:positions"))
    local = (posed - T[:3, 3]) @ T[:3, :3]
    outside = np.linalg.norm(np.maximum(np.abs(local) - size / 2, 0), axis=1)
    assert outside.max() < 0.002 and np.abs(np.abs(local).max(axis=1) - size / 2).max() < 0.002


class _Device:
    def __init__(self, reading: Any = None, fail: bool = False) -> None:
        self.reading, self.fail = reading, fail

    def read(self) -> Any:
        from mks_sim.errors import DeviceFailure

        if self.fail:
            raise DeviceFailure("ranger", "lens cap on")
        return self.reading


@needs_rerun
def test_fallbacks_streams_and_hypotheses_without_a_simulator(tmp_path: Path) -> None:
    """Fake devices on the test sensor files: the range finder fails, stereo serves; the
    text log says so, the stream is the stereo rows, hypotheses are posed cube wireframes."""
    from mks_sim.models.pose import PoseHypothesis
    from mks_sim.sensing import SensorGraph

    stereo_l, stereo_r = np.array([[1.0, 1.0, 1.0]]), np.array([[1.5, 1.5, 1.5]])
    devices = {"ranger": _Device(fail=True), "stereo_l": _Device(stereo_l),
               "stereo_r": _Device(stereo_r), "touch": _Device(np.zeros((1, 3)))}  # fmt: skip
    graph = SensorGraph.from_dir(Path(__file__).parent / "assets" / "sensors" / "good")
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.1, 0.2, 0.8]
    hyps = (PoseHypothesis(T, np.zeros(3), votes=7, score=0.9),)
    path = tmp_path / "fake.rrd"
    with open_recorder(parse_rerun_spec(f"save:{path}"), "test") as recorder:
        snap = recorder.tap_graph(graph).snapshot(recorder.tap_devices(devices))
        assert snap.get("Range_Points").served_by == "Stereo_Points"

        class Result:  # the fields of WorkstationLocalization the recorder reads
            object, found, object_to_world, hypotheses, diagnostics = "cube", True, T, hyps, {}

        recorder.log_localization(Result())
    rec = read_recording(path)
    texts = [t for v in rec["/log"]["TextLog:text"] for t in v]
    assert any("Range_Points: primary failed (device 'ranger' failed: lens cap on); served by "
               "Stereo_Points" in t for t in texts), texts  # fmt: skip
    rows = np.asarray(last(rec, "/world/sensors/Range_Points", "Points3D:positions"))
    np.testing.assert_allclose(rows, np.vstack([stereo_l, stereo_r]))
    strips = np.asarray(last(rec, "/world/localization/cube/hypotheses/0", "LineStrips3D:strips"))
    assert strips.shape == (12, 2, 3)
    # every end is a corner of the 5 cm cube at T, every edge 5 cm long (brute force)
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * 0.025
    corners = corners @ T[:3, :3].T + T[:3, 3]
    ends = strips.reshape(-1, 3)
    assert np.linalg.norm(ends[:, None] - corners[None], axis=2).min(axis=1).max() < 1e-6
    np.testing.assert_allclose(np.linalg.norm(strips[:, 0] - strips[:, 1], axis=1), 0.05, atol=1e-6)
    label = last(rec, "/world/localization/cube/hypotheses/0", "LineStrips3D:labels")
    assert "score 0.900 votes 7" in label[0]


@pytest.mark.slow
def test_robot_meshes_are_posed_as_mujoco_poses_them() -> None:
    import mujoco

    from mks_sim.sim import names
    from mks_sim.sim.world import build_world
    from mks_sim.viz.scene import body_to_world, geom_meshes

    world = build_world("scene2", seed=0)
    world.data.qpos[world.model.joint(names.ARM_JOINTS[1]).qposadr[0]] += 0.4  # not home
    mujoco.mj_forward(world.model, world.data)
    meshes = geom_meshes(world.model, names.ROBOT_PREFIX)
    assert len({g.body for g in meshes}) >= 10 and any(g.name.endswith("finger_tip_1")
                                                      for g in meshes)  # fmt: skip
    for g in meshes:
        T = body_to_world(world.data, g.body_id) @ g.geom_to_body  # what the recording draws
        np.testing.assert_allclose(T[:3, 3], world.data.geom_xpos[g.geom_id], atol=1e-9)
        np.testing.assert_allclose(T[:3, :3], world.data.geom_xmat[g.geom_id].reshape(3, 3),
                                   atol=1e-9)  # fmt: skip


@needs_rerun
@pytest.mark.slow
def test_grasp_episode_recording_reads_back_and_changes_nothing(tmp_path: Path) -> None:
    from mks_sim.sim import names
    from mks_sim.tasks.episode import run_episode

    path = tmp_path / "grasp.rrd"
    # short: no re-sensing during the approach (localize, grasp, lift, re-sense once)
    plain = run_episode("cube", 0, resense_period_s=None)
    with open_recorder(parse_rerun_spec(f"save:{path}"), "test") as recorder:
        recorded = run_episode("cube", 0, resense_period_s=None, recorder=recorder)
    # recording reads the same devices in the same order: the same episode, bit for bit
    assert recorded.estimate == plain.estimate
    assert (recorded.success, recorded.retries, recorded.sim_time_s) == (
        plain.success, plain.retries, plain.sim_time_s)  # fmt: skip
    rec = read_recording(path)
    # per-step robot state: 9 joints, many samples, on the episode's timelines
    joints = [e for e in rec if e.startswith("/robot/joints/")]
    assert len(joints) == 9 and len(rec[joints[0]]["Scalars:scalars"]) > 50
    from rerun.chunk import RrdReader

    episodes = set()
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        if "episode" in batch.schema.names:
            episodes.update(batch.column("episode").to_pylist())
    assert episodes == {0}
    # fingertip taxels: one pressure per taxel of each pad
    for finger in names.FINGERS:
        bars = last(rec, f"/touch/touch_finger_{finger}/pressure_pa", "BarChart:values")[0]
        assert bars["shape"] == [names.TAXELS_PER_PAD]
        assert len(bars["buffer"]) == names.TAXELS_PER_PAD and min(bars["buffer"]) >= 0.0
    # grasp candidates with quality labels; the executed grasp is one of them
    cands = np.asarray(last(rec, "/world/grasp/candidates", "Points3D:positions"))
    chosen = np.asarray(last(rec, "/world/grasp/chosen", "Points3D:positions"))
    assert cands.ndim == 2 and len(cands) >= 1 and chosen.shape == (1, 3)
    assert np.linalg.norm(cands - chosen, axis=1).min() < 1e-6
    # the estimate the grasp used is one of the recorded chosen poses (the last one is the
    # re-sensing after the lift); the truth sits on eval/ near the first
    est = np.asarray(recorded.estimate).reshape(4, 4)
    chosen_t = np.array([v[0] for v in rec["/world/localization/cube/chosen"]
                         ["Transform3D:translation"] if v])  # fmt: skip
    assert len(chosen_t) >= 2
    assert np.linalg.norm(chosen_t - est[:3, 3], axis=1).min() < 1e-5
    first_chosen = rec["/world/localization/cube/chosen"]["Transform3D:translation"][0][0]
    first_truth = rec["/eval/truth/cube"]["Transform3D:translation"][0][0]
    assert np.linalg.norm(np.subtract(first_chosen, first_truth)) < 0.005


@needs_rerun
def test_episodes_follow_one_another_on_sim_time(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    path = tmp_path / "t.rrd"
    with open_recorder(parse_rerun_spec(f"save:{path}"), "test") as recorder:
        for episode, times in ((4, (0.0, 2.5)), (5, (0.0, 1.0)), (5, (1.5,))):
            recorder.set_episode(episode, 1)
            for t in times:
                recorder.set_time(t)
                recorder.log_text(f"{episode} {t}")
    rows = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == "/log":
            batch = chunk.to_record_batch()
            rows += zip(batch.column("sim_time").to_pylist(), batch.column("episode").to_pylist())
    seconds = sorted((t.total_seconds() if hasattr(t, "total_seconds") else t / 1e9, e)
                     for t, e in rows)  # fmt: skip
    assert seconds == [(0.0, 4), (2.5, 4), (2.5, 5), (3.5, 5), (4.0, 5)]


@needs_rerun
def test_connect_to_no_viewer_fails_fast_before_work(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import socket

    import mks_sim.viz.rerun_recorder as rerun_recorder
    from mks_sim.viz.viewer import listening

    def no_stream(*args: object, **kwargs: object) -> None:
        raise AssertionError("a recording stream was opened to a viewer that is not there")

    monkeypatch.setattr(rerun_recorder, "CONNECT_WAIT_S", 0.3)
    # checked before any stream: a gRPC sink to nobody blocks 5 s connecting and 5 s on
    # disconnect, and logs errors past the one-line message
    monkeypatch.setattr(rerun_recorder.rr, "RecordingStream", no_stream)
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc = main(["localize", "--object", "cube", "--rerun", f"connect:127.0.0.1:{port}"])
    captured = capsys.readouterr()
    assert rc == 2 and captured.out == ""  # nothing localized
    (line,) = captured.err.strip().splitlines()
    assert "--rerun connect: no Rerun viewer listens there" in line and "save:PATH.rrd" in line
    assert not listening("rerun+http://127.0.0.1:99999/proxy", 0.0)  # no such port


@needs_rerun
@pytest.mark.slow
def test_snapshot_recording_reads_back(tmp_path: Path) -> None:
    from mks_sim.sim import names

    path = tmp_path / "snap.rrd"
    assert main(["snapshot", "--scene", "scene1", "--out", str(tmp_path / "snap"),
                 "--rerun", f"save:{path},normals"]) == 0  # fmt: skip
    rec = read_recording(path)
    # normals on request: unit normals drawn 1 cm long from their points
    vectors = np.asarray(last(rec, "/world/segmentation/normals", "Arrows3D:vectors"))
    np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), 0.01, atol=1e-5)
    for cam, size in (("overhead_camera", (640, 480)), ("depth_camera", (320, 240))):
        fmt = last(rec, f"/world/cameras/{cam}/rgb", "Image:format")[0]
        assert (fmt["width"], fmt["height"]) == size
    fmt = last(rec, "/stereo/disparity", "DepthImage:format")[0]
    assert (fmt["width"], fmt["height"]) == (640, 480)
    # 2-D table sensors (x, y, radius) drawn on the table top as spheres of their radius
    centers = np.asarray(last(rec, "/world/sensors/Circle_Detector", "Ellipsoids3D:centers"))
    half = np.asarray(last(rec, "/world/sensors/Circle_Detector", "Ellipsoids3D:half_sizes"))
    assert centers.shape[1] == 3 and len(centers) >= 1 and half.shape == centers.shape
    np.testing.assert_allclose(centers[:, 2], names.TABLE_TOP_Z, atol=1e-6)
    assert len(last(rec, "/world/spg/edges", "LineStrips3D:strips")) > 100
