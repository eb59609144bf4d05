"""The bin scene (issue 13): walls as fixtures, N instances dropped into a pile."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.errors import SpecError
from mks_sim.sim import truth
from mks_sim.sim.scenes import scene_from_doc
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


def test_fixture_is_a_static_box_on_the_support():
    spec = scene_from_doc(
        {"object": [{"name": "cube"}], "fixture": [{"size": [0.01, 0.02, 0.03], "at": [0.2, 0.1]}]},
        "t.toml",
    )
    geom = spec.root.find("geom", "fixture_0")
    assert geom.parent is spec.root.worldbody  # static: no joint, no body
    np.testing.assert_allclose(geom.pos, (0.2, 0.1, 0.75 + 0.03))


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


@pytest.mark.slow
def test_bin_settles_deterministically_inside_the_tray():
    a = bin_world(3, count=6)
    b = bin_world(3, count=6)
    np.testing.assert_array_equal(a.data.qpos, b.data.qpos)
    assert instance_bodies(a) == ("part", "part_1", "part_2", "part_3", "part_4", "part_5")
    assert _inside_bin(a) == []
    poses = truth.all_object_poses(a)
    z = np.array([T[2, 3] for T in poses.values()])
    assert z.max() > 0.75 + 0.02  # a pile: some part rests on another or on its side
    # at rest: a further second of physics moves nothing by more than 2 mm
    a.step(500)
    a.forward()
    moved = [
        np.linalg.norm(truth.object_to_world(a, n)[:3, 3] - T[:3, 3]) for n, T in poses.items()
    ]
    assert max(moved) < 0.002
    c = bin_world(4, count=6)
    assert not np.array_equal(a.data.qpos, c.data.qpos)
    assert _inside_bin(c) == []
