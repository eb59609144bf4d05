"""The bin scene (issue 13): walls as fixtures, N instances dropped into a pile."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.errors import SpecError
from mks_sim.sim import truth
from mks_sim.sim.scenes import CONTACT_OPTIONS, scene_from_doc
from mks_sim.tasks.bin import bin_world, instance_bodies

INNER_HALF = (0.17, 0.13)  # worlds/bin.toml: the walls' inner faces
WALL_HEIGHT = 0.04


def test_fixture_and_gap_fields_are_checked():
    base = {"object": [{"name": "cube"}]}
    with pytest.raises(SpecError, match=r"fixture 0: field 'size': expected 3 finite"):
        scene_from_doc({**base, "fixture": [{"size": [0.1, 0.1]}]}, "t.toml")
    with pytest.raises(SpecError, match=r"fixture 0: field 'size': expected 3 half extents > 0"):
        scene_from_doc({**base, "fixture": [{"size": [0.1, 0.0, 0.1]}]}, "t.toml")
    with pytest.raises(SpecError, match=r"fixture 0: unknown field"):
        scene_from_doc({**base, "fixture": [{"size": [0.1, 0.1, 0.1], "pos": [0, 0]}]}, "t.toml")
    with pytest.raises(SpecError, match=r"field 'gap_m': expected a number"):
        scene_from_doc({"object": [{"name": "cube", "gap_m": "x"}]}, "t.toml")
    with pytest.raises(SpecError, match=r"count: expected an integer in 1..12"):
        bin_world(0, count=13)
    for bad in (-1, 1001, 2.5, True, "10"):
        with pytest.raises(SpecError, match=r"field 'noslip_iterations': expected an integer"):
            scene_from_doc({**base, "scene": {"noslip_iterations": bad}}, "t.toml")


def test_noslip_iterations_reach_the_model():
    base = {"object": [{"name": "cube"}]}
    default = scene_from_doc(base, "t.toml")
    assert default.root.option.noslip_iterations == CONTACT_OPTIONS["noslip_iterations"]
    spec = scene_from_doc({**base, "scene": {"noslip_iterations": 37}}, "t.toml")
    assert spec.root.option.noslip_iterations == 37


def test_fixture_is_a_static_box_on_the_support():
    spec = scene_from_doc(
        {"object": [{"name": "cube"}], "fixture": [{"size": [0.01, 0.02, 0.03], "at": [0.2, 0.1]}]},
        "t.toml",
    )
    geom = spec.root.find("geom", "fixture_0")
    assert geom.parent is spec.root.worldbody  # static: no joint, no body
    np.testing.assert_allclose(geom.pos, (0.2, 0.1, 0.75 + 0.03))


def test_output_box_fields_are_checked():
    base = {"object": [{"name": "cube"}]}
    box = {"center": [-0.3, 0.2], "half": [0.1, 0.08]}
    for extra, match in [
        ({"center": [0.1]}, r"\[output_box\]: field 'center': expected \[a, b\]"),
        ({"half": [0.1, 0.004]}, r"\[output_box\]: field 'half': expected half sides over"),
        ({"wall_height": 0}, r"\[output_box\]: field 'wall_height': expected metres"),
        ({"wall_thickness": True}, r"\[output_box\]: field 'wall_thickness': expected metres"),
        ({"depth": 0.1}, r"\[output_box\]: unknown field"),
    ]:
        with pytest.raises(SpecError, match=match):
            scene_from_doc({**base, "output_box": {**box, **extra}}, "t.toml")
    assert scene_from_doc(base, "t.toml").output_box is None


def test_output_box_walls_stand_where_the_scene_says():
    """The compiled model's four wall boxes (MuJoCo's geom sizes and positions) enclose
    exactly the declared inner rectangle, from the table up to the declared rim."""
    import mujoco

    from mks_sim.sim import names

    spec = scene_from_doc(
        {
            "object": [{"name": "cube"}],
            "output_box": {"center": [-0.3, 0.2], "half": [0.1, 0.08], "wall_height": 0.05},
        },
        "t.toml",
    )
    box = spec.output_box
    assert box is not None and box.wall_thickness_m == 0.008
    model = mujoco.MjModel.from_xml_string(spec.root.to_xml_string(), spec.root.get_assets())
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    lo, hi = [], []
    for i in range(4):
        g = model.geom(f"output_box_wall_{i}")
        p, h = data.geom_xpos[g.id], model.geom_size[g.id]
        assert p[2] - h[2] == pytest.approx(names.TABLE_TOP_Z)
        assert p[2] + h[2] == pytest.approx(names.TABLE_TOP_Z + 0.05)
        lo.append(p - h)
        hi.append(p + h)
    lo_a, hi_a = np.array(lo), np.array(hi)
    # inner faces: the walls' sides that face the middle
    c = np.array([-0.3, 0.2])
    inner = np.array(box.inner_half_xy)
    assert inner == pytest.approx([0.096, 0.076])
    for axis in (0, 1):
        faces = [hi_a[i, axis] for i in range(4) if hi_a[i, axis] < c[axis]]
        faces += [lo_a[i, axis] for i in range(4) if lo_a[i, axis] > c[axis]]
        assert sorted(faces) == pytest.approx([c[axis] - inner[axis], c[axis] + inner[axis]])
    # closed: every corner of the inner rectangle is covered by two walls
    for sx in (-1, 1):
        for sy in (-1, 1):
            q = c + [sx * (inner[0] + 0.002), sy * (inner[1] + 0.002)]
            inside = (lo_a[:, 0] <= q[0]) & (q[0] <= hi_a[:, 0])
            inside &= (lo_a[:, 1] <= q[1]) & (q[1] <= hi_a[:, 1])
            assert inside.sum() == 2, q


class _Reached(Exception):
    pass


def _reached(*args, **kwargs):
    raise _Reached


def test_clear_bin_needs_an_output_box_and_localization_does_not(tmp_path, monkeypatch):
    """A bin scene without [output_box]: clearing it is a one-line error before the devices
    are made (nothing moves), localizing it goes on to make them."""
    import mks_sim.devices
    from mks_sim.sim.scenes import scene_file
    from mks_sim.tasks.bin import run_clear_bin, run_localize_all

    text = scene_file("bin").read_text(encoding="utf-8")
    f = tmp_path / "no_box.toml"
    f.write_text(text.split("\n[output_box]")[0], encoding="utf-8")
    monkeypatch.setattr(mks_sim.devices, "make_devices", _reached)
    with pytest.raises(SpecError, match=r"no \[output_box\]: clear_bin needs one"):
        run_clear_bin(0, scene=f, count=1)
    with pytest.raises(_Reached):
        run_localize_all(0, scene=f, count=1)


def _inside_bin(world) -> list[str]:
    """Instances not in the bin (evaluation from ground truth): the hull's centroid outside
    the walls' inner box, the lowest point above the walls' top (resting on a rim) or below
    the table. A part leaning against a wall may reach over its rim: that is in the bin."""
    bad = []
    for spec in world.scene.objects:
        T = truth.object_to_world(world, spec.name)
        hull = spec.hull @ T[:3, :3].T + T[:3, 3]
        c = hull.mean(axis=0)
        if (
            abs(c[0]) > INNER_HALF[0]
            or abs(c[1]) > INNER_HALF[1]
            or hull[:, 2].min() > 0.75 + WALL_HEIGHT
            or hull[:, 2].min() < 0.75 - 0.002
        ):
            bad.append(spec.name)
    return bad


def _rotation_deg(A: np.ndarray, B: np.ndarray) -> float:
    c = (np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _assert_at_rest(world) -> None:
    """2 s more of physics, nothing touching the pile, moves no part by 3 mm or 3 deg."""
    poses = truth.all_object_poses(world)
    world.step(1000)
    world.forward()
    for name, T in poses.items():
        now = truth.object_to_world(world, name)
        assert np.linalg.norm(now[:3, 3] - T[:3, 3]) < 0.003, name
        assert _rotation_deg(T, now) < 3.0, name


@pytest.mark.slow
def test_bin_settles_deterministically_inside_the_tray_and_at_rest():
    """Tuning bin 0 kept moving after the fixed settle (a part 28 mm / 63 deg over the next
    4 s, ground truth); bin_world now settles until at rest. The same seed twice gives the
    same pile, to the bit."""
    a = bin_world(0, count=6, cache=False)  # settled here, not restored (sim.piles)
    # the same seed twice, the same pile to the bit (tuning bin 5: the same drop and settle
    # until at rest, in 5 s instead of bin 0's 25 s)
    b, c = bin_world(5, count=6, cache=False), bin_world(5, count=6, cache=False)
    assert b.rest_steps > 0
    np.testing.assert_array_equal(b.data.qpos, c.data.qpos)
    assert instance_bodies(a) == ("part", "part_1", "part_2", "part_3", "part_4", "part_5")
    assert _inside_bin(a) == []
    z = np.array([T[2, 3] for T in truth.all_object_poses(a).values()])
    assert z.max() > 0.75 + 0.02  # a pile: some part rests on another or on its side
    assert a.rest_steps > 0
    _assert_at_rest(a)


@pytest.mark.slow
def test_another_seed_drops_another_pile_also_at_rest():
    """Tuning bin 7 kept moving after the fixed settle (a part 78 mm / 92 deg over the next
    4 s); another seed drops its parts elsewhere; this pile is inside the tray too."""
    a = bin_world(7, count=6, cache=False)
    assert a.rest_steps > 0
    assert _inside_bin(a) == []
    one = [truth.object_to_world(bin_world(seed, count=1, cache=False), "part") for seed in (0, 7)]
    assert np.linalg.norm(one[0][:3, 3] - one[1][:3, 3]) > 0.005  # a part drops elsewhere
    _assert_at_rest(a)
