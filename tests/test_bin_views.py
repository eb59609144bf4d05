"""View fusion (issue 13, active sensing): the fuse_views program and the Fused_Points sensor."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mks_sim.sensing.programs.points import range_points
from mks_sim.sensing.programs.views import HeldViews, Views, fuse_views, merge_views


def _scan(points: np.ndarray) -> SimpleNamespace:
    return SimpleNamespace(points_world=points, hit=np.ones(len(points), dtype=bool))


def _plane(spacing: float, offset: float, n: int = 40) -> np.ndarray:
    g = (np.arange(n) * spacing + offset) - 0.05
    x, y = np.meshgrid(g, g)
    return np.c_[x.ravel(), y.ravel(), np.full(x.size, 0.8)]


def _depth_frame(depth: np.ndarray, T: np.ndarray) -> SimpleNamespace:
    h, w = depth.shape
    K = np.array([[200.0, 0.0, (w - 1) / 2], [0.0, 200.0, (h - 1) / 2], [0.0, 0.0, 1.0]])
    return SimpleNamespace(depth=depth, K=K, camera_to_world=T, name="wrist_camera", rgb=None)


def test_one_view_passes_unchanged_and_equals_range_points() -> None:
    scans = [_scan(_plane(0.0025, 0.0)), _scan(_plane(0.0025, 0.001))]
    fused = fuse_views({"range_finder": scans}, {"merge_m": 0.0025})
    plain = range_points({"range_finder": scans}, {})
    assert np.array_equal(fused.data, plain)
    assert set(fused.source) == {"range_finder#0"}


def test_two_views_of_one_surface_do_not_double_density() -> None:
    a, b = _plane(0.0025, 0.0), _plane(0.0025, 0.0011)
    fused = fuse_views({"range_finder": Views([[_scan(a)], [_scan(b)]])}, {"merge_m": 0.0025})
    # brute force: every kept point of view 1 is farther than merge_m from all of view 0
    kept_b = fused.data[fused.source == "range_finder#1"]
    if len(kept_b):
        d = np.linalg.norm(kept_b[:, None, :] - a[None, :, :], axis=2).min(axis=1)
        assert d.min() > 0.0025
    assert len(fused.data) < 1.2 * len(a)  # a plain union would be 2x
    # a second view of a surface the first did not see adds all its points
    c = _plane(0.0025, 0.0) + [0.2, 0.0, 0.0]
    fused2 = fuse_views({"range_finder": Views([[_scan(a)], [_scan(c)]])}, {"merge_m": 0.0025})
    assert len(fused2.data) == len(a) + len(c)


def test_depth_view_back_projects_through_the_pose() -> None:
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
    T[:3, 3] = [0.0, 0.0, 1.2]
    depth = np.full((30, 40), 0.4)
    depth[0, 0] = np.nan
    fused = fuse_views({"wrist_camera": Views([_depth_frame(depth, T)])}, {})
    assert len(fused.data) == depth.size - 1
    assert np.allclose(fused.data[:, 2], 0.8)
    pts, which = merge_views([fused.data, fused.data + [0.0, 0.0, 0.01]], 0.0025)
    assert len(pts) == 2 * len(fused.data) and set(which) == {0, 1}


def test_held_views_serve_the_sensor_and_alternates_follow_failures() -> None:
    from mks_sim.errors import DeviceFailure
    from mks_sim.sensing import SensorGraph

    graph = SensorGraph.from_dir()
    a = _plane(0.0025, 0.0)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = [0.3, 0.0, 1.2]  # sees another patch: x in 0.3 +- 0.04
    frame = _depth_frame(np.full((30, 40), 0.4), T)

    class Failed:
        name = "range_finder"

        def read(self) -> None:
            raise DeviceFailure("range_finder", "failed (fault injected)")

    both = {"range_finder": HeldViews("range_finder", [[_scan(a)]]),
            "wrist_camera": HeldViews("wrist_camera", [frame])}  # fmt: skip
    snap = graph.snapshot(both)
    s = snap.get("Fused_Points")
    assert snap.provenance["Fused_Points"] == "primary"
    assert set(s.source) == {"range_finder#0", "wrist_camera#0"}
    only_wrist = graph.snapshot({"range_finder": Failed(), "wrist_camera": both["wrist_camera"]})
    only_wrist.get("Fused_Points")
    assert only_wrist.provenance["Fused_Points"] == "Wrist_Views"
    only_range = graph.snapshot({"range_finder": both["range_finder"]})
    only_range.get("Fused_Points")
    assert only_range.provenance["Fused_Points"] == "Range_View"


def test_bad_reading_is_a_sensor_failure() -> None:
    from mks_sim.errors import SensorFailure

    with pytest.raises(SensorFailure):
        fuse_views({"range_finder": [object()]}, {})
