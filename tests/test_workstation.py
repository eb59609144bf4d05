"""End-to-end localization from simulated sensors (mks_sim.workstation), checked against the
simulator's ground truth (read here, for evaluation only)."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.errors import NotFound
from mks_sim.geometry.meshes import box_mesh, sample_surface
from mks_sim.geometry.transforms import cube_rotations, make_transform, pose_error
from mks_sim.localization.verify import consistency
from mks_sim.workstation import find_table, localize, localize_object

# Tolerances of the end-to-end tests (the benchmark's success criterion is 5 mm / 5 deg).
TOL_MM = {"healthy": 2.0, "stereo": 3.5}
TOL_DEG = {"healthy": 1.0, "stereo": 3.0}


def _localize(obj: str, seed: int, fail: tuple[str, ...] = ()):  # noqa: ANN202
    from mks_sim.devices import DeviceFaults, make_devices
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world
    from mks_sim.tasks.spec import object_scene

    world = build_world(object_scene(obj), seed=seed, objects=[obj])
    faults = {d: DeviceFaults(failed=True) for d in fail}
    with make_devices(world.model, world.data, np.random.default_rng(seed), faults) as devs:
        result = localize_object(world, obj, devs, rng=np.random.default_rng(seed))
    return result, truth.object_to_world(world, obj)


def _errors(obj: str, T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    pos, rot = pose_error(T_est, T_true, cube_rotations() if obj == "cube" else None)
    return 1000.0 * pos, 0.0 if obj == "sphere" else rot


@pytest.mark.slow
@pytest.mark.parametrize(("obj", "seed"), [("cube", 1), ("sphere", 2), ("part", 3)])
def test_localizes_within_tolerance_of_ground_truth(obj: str, seed: int) -> None:
    result, T_true = _localize(obj, seed)
    assert result.found and result.object_to_world is not None
    assert result.object_to_world.shape == (4, 4)
    pos_mm, rot_deg = _errors(obj, result.object_to_world, T_true)
    assert pos_mm < TOL_MM["healthy"], (obj, seed, pos_mm)
    assert rot_deg < TOL_DEG["healthy"], (obj, seed, rot_deg)
    assert result.provenance["Range_Points"] == "primary"
    assert result.diagnostics["sensor"] in result.provenance  # the model's sensor ran
    assert result.time_s > 0


@pytest.mark.slow
@pytest.mark.parametrize(("obj", "seed"), [("sphere", 3), ("part", 2)])
def test_range_finder_failed_stereo_serves_range_points(obj: str, seed: int) -> None:
    result, T_true = _localize(obj, seed, fail=("range_finder",))
    assert result.provenance["Range_Points"] == "Stereo_Points"
    assert result.found and result.object_to_world is not None
    pos_mm, rot_deg = _errors(obj, result.object_to_world, T_true)
    assert pos_mm < TOL_MM["stereo"], (obj, seed, pos_mm)
    assert rot_deg < TOL_DEG["stereo"], (obj, seed, rot_deg)


def test_unknown_object_is_a_clear_error() -> None:
    with pytest.raises(NotFound, match=r"unknown object 'pyramid'.*'cube'"):
        localize_object(None, "pyramid", {})
    assert localize is localize_object  # the grasp episode's entry point


def _box_scene(T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points of a 5 cm cube's top and two side faces at pose T plus a table around it."""
    pts, nrm = sample_surface(box_mesh(0.05), 3000, rng=rng)
    world_n = nrm @ T[:3, :3].T
    seen = (world_n[:, 2] > 0.5) | (world_n[:, 0] > 0.5) | (world_n[:, 1] > 0.5)
    obj = pts[seen] @ T[:3, :3].T + T[:3, 3]
    g = np.mgrid[-0.15:0.15:0.003, -0.15:0.15:0.003].reshape(2, -1).T
    table = np.c_[g, np.full(len(g), 0.75)]
    inside = np.all(np.abs(table[:, :2] - T[:2, 3]) < 0.03, axis=1)
    return np.concatenate([obj, table[~inside]])


def test_consistency_check_rejects_floating_sunken_and_shifted_poses() -> None:
    rng = np.random.default_rng(0)
    T = make_transform(np.eye(3), [0.02, -0.01, 0.775])
    cloud = _box_scene(T, rng)
    table, _ = find_table(cloud, rng)
    assert table is not None and table.offset == pytest.approx(0.75, abs=1e-6)
    pts, nrm = sample_surface(box_mesh(0.05), 2000, rng=rng)
    good = consistency(T, pts, nrm, cloud, table, 0.003)
    assert good["ok"] and good["inside"] == 0 and good["penetration"] == 0.0
    sunk = consistency(
        make_transform(np.eye(3), [0.02, -0.01, 0.76]), pts, nrm, cloud, table, 0.003
    )
    assert not sunk["ok"] and sunk["penetration"] > 0.1
    moved = consistency(
        make_transform(np.eye(3), [0.05, -0.01, 0.775]), pts, nrm, cloud, table, 0.003
    )
    assert not moved["ok"] and moved["below"] + moved["inside"] > 0.05 * moved["explained"]


@pytest.mark.slow
def test_one_localization_computes_normals_and_segmentation_once(monkeypatch) -> None:
    """The sensors (Vertex_Detector, Sphere_Detector) and the matchers share the snapshot's
    one representation: one normals pass and one segmentation per localization (there were
    13 and 12)."""
    import mks_sim.lowlevel.grouping as grouping_mod
    import mks_sim.lowlevel.normals as normals_mod
    import mks_sim.lowlevel.regions as regions_mod
    from mks_sim.devices import make_devices
    from mks_sim.sim.world import build_world

    calls = {"normals": 0, "segment": 0}
    real_normals, real_segment = normals_mod.estimate_normals, regions_mod.segment_surfaces

    def count_normals(*a, **k):  # type: ignore[no-untyped-def]
        calls["normals"] += 1
        return real_normals(*a, **k)

    def count_segment(*a, **k):  # type: ignore[no-untyped-def]
        calls["segment"] += 1
        return real_segment(*a, **k)

    for mod in (normals_mod, regions_mod, grouping_mod):
        monkeypatch.setattr(mod, "estimate_normals", count_normals)
    for mod in (regions_mod, grouping_mod):
        monkeypatch.setattr(mod, "segment_surfaces", count_segment)
    world = build_world("scene2", seed=1)
    with make_devices(world.model, world.data, np.random.default_rng(1)) as devices:
        result = localize_object(world, "cube", devices, rng=np.random.default_rng(1))
    assert result.found
    assert {"Vertex_Detector", "Sphere_Detector"} <= set(result.provenance)
    assert calls == {"normals": 1, "segment": 1}
    timing = result.diagnostics["timing"]
    assert {"sensing", "representation", "hypotheses", "verification", "total"} <= set(timing)


def test_cli_timing_s_reports_the_engine_stages() -> None:
    from types import SimpleNamespace

    from mks_sim.cli.localize import TIMING_STAGES, _timing

    result = SimpleNamespace(
        time_s=0.5,
        diagnostics={"timing": {"sensing": 0.1, "representation": 0.2, "hypotheses": 0.05}},
    )
    out = _timing(result)
    assert tuple(out) == TIMING_STAGES
    assert {"sensing", "representation", "hypotheses", "verification", "total"} <= set(out)
    assert out["total"] == 0.5 and out["verification"] == 0.0 and out["sensing"] == 0.1
    assert _timing(None) == {}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("seed", "why"),
    [
        (5, "half the top hidden by the sphere: footprint rectangles at a corner"),
        (22, "touching a clutter box: support faces on its short-edge segment"),
        (21, "a pose around part of a taller box ranked first: unexplained points weigh 2"),
        (1044, "tilted 6.8 deg with a corner on the table: the cube set to rest on its face"),
        (1063, "tilted 6.4 deg: the rested pose lost the ranking to tilted copies of itself"),
        (1099, "the true pose sunk into the table failed its check: rested, it passes"),
        (1115, "the detector's too-large sphere on the cube took the cube's points"),
        (1192, "no vertex in the cube's segment: a box's pose settled before it was verified"),
    ],
)
def test_stereo_cube_cases_that_were_missed(seed: int, why: str) -> None:
    """Stereo tuning seeds the pipeline missed before (not found, or another object's pose):
    now within the stereo tolerances of the ground truth."""
    result, T_true = _localize("cube", seed, fail=("range_finder",))
    assert result.provenance["Range_Points"] == "Stereo_Points"
    assert result.found and result.object_to_world is not None, why
    pos_mm, rot_deg = _errors("cube", result.object_to_world, T_true)
    assert pos_mm < TOL_MM["stereo"] and rot_deg < TOL_DEG["stereo"], (why, pos_mm, rot_deg)
