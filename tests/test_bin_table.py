"""clear_bin's search of the table around the bin (issue 13): parts lifted out with a picked
one or dropped on the way are picked from the table when the bin is done."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mks_sim.tasks import bin as binmod


def _geom_rects(world, prefix):
    """World xy (lo, hi) of the model's box geoms named ``prefix*`` (read from the compiled
    model: the simulator's geometry, not the code under test)."""
    m, d = world.model, world.data
    out = []
    for g in range(m.ngeom):
        if m.geom(g).name.startswith(prefix):
            R = d.geom_xmat[g].reshape(3, 3)
            corners = np.array(
                [
                    d.geom_xpos[g] + R @ (m.geom_size[g] * (2 * np.array(s) - 1))
                    for s in np.ndindex(2, 2, 2)
                ]  # fmt: skip
            )
            out.append((corners[:, :2].min(0), corners[:, :2].max(0)))
    return out


def _in_any(p, regions):
    return any(np.all(p >= lo) and np.all(p <= hi) for lo, hi in regions)


@pytest.fixture(scope="module")
def hand():
    from test_bin_clear import _finger_vertices, _preshaped_hand

    out = {}
    for w in (0.02, 0.06):
        world, R, pinch = _preshaped_hand(w)
        out[w] = (world, R, pinch, np.concatenate(_finger_vertices(world)) - pinch)
    return out


def test_the_table_search_leaves_out_the_bin_the_box_and_their_walls():
    """Every corner of the bin's wall geoms and the box's, read from the model, lies in a
    region :func:`table_roi` leaves out, as does the bin's middle; the table top's corners
    lie in its region of interest, and a point on the table 30 mm beyond the bin's +x wall
    is searched."""
    from mks_sim.sim import names

    world = binmod.bin_world(None, count=1)
    roi, excluded = binmod.table_roi(world)
    walls = _geom_rects(world, "fixture_") + _geom_rects(world, "output_box_wall_")
    assert len(walls) == 8
    for lo, hi in walls:
        for corner in ((lo[0], lo[1]), (lo[0], hi[1]), (hi[0], lo[1]), (hi[0], hi[1])):
            assert _in_any(np.array(corner), excluded), corner
    assert _in_any(np.zeros(2), excluded)
    ((top_lo, top_hi),) = _geom_rects(world, names.TABLE_TOP_GEOM)
    np.testing.assert_allclose(roi[0][:2], top_lo, atol=1e-9)
    np.testing.assert_allclose(roi[1][:2], top_hi, atol=1e-9)
    assert roi[0][2] < world.scene.support_z < roi[1][2]
    beside = np.array([max(hi[0] for lo, hi in walls[:4]) + 0.03, 0.0])
    assert not _in_any(beside, excluded)


@pytest.mark.parametrize("width_m", [0.02, 0.06])
def test_table_grasps_keep_the_fingers_off_the_bin_and_box_walls(hand, width_m):
    """Brute force against the simulator's hand: the fingers' lowest 25 mm (its meshes,
    pre-shaped to ``width_m``), turned to 8 yaws, at pinch points 15 mm above the table
    outside the bin and the box, 0-80 mm from their walls' outer faces (the wall geoms,
    read from the model): :func:`walls_block_outside` is true whenever a vertex lies over a
    wall or inside the container, and then a vertex comes within 7 mm of its outer faces.
    Above the walls' top nothing blocks; a pinch point inside the bin always does."""
    world, R, pinch, V = hand[width_m]
    yaw0 = float(np.arctan2(R[1, 0], R[0, 0]))
    table_z = world.scene.support_z
    containers = binmod.containers(world)
    outer = []
    for prefix in ("fixture_", "output_box_wall_"):
        rects = _geom_rects(world, prefix)
        outer.append((np.min([r[0] for r in rects], 0), np.max([r[1] for r in rects], 0)))
    heights = [binmod.BIN_WALL_M, world.scene.output_box.wall_height_m]
    n_blocked = n_over = 0
    for turn in np.radians(np.arange(0, 360, 45)):
        c, s = np.cos(turn), np.sin(turn)
        Vt = V[:, :2] @ np.array([[c, s], [-s, c]])
        for (lo, hi), mid_y in zip(outer, (0.0, None), strict=True):
            ym = 0.5 * (lo[1] + hi[1]) if mid_y is None else mid_y
            for gap in np.arange(0.0, 0.08, 0.004):
                # beside the +x and -x faces, and below the -y face (the bin's +y side faces
                # the box, the box's +y the robot)
                for x, y in ((hi[0] + gap, ym), (lo[0] - gap, ym),
                             (0.5 * (lo[0] + hi[0]), lo[1] - gap)):  # fmt: skip
                    at = np.array([x, y, table_z + 0.015])
                    if any(np.all(at[:2] >= o[0]) and np.all(at[:2] <= o[1]) for o in outer):
                        continue
                    cand = SimpleNamespace(
                        pinch_world=tuple(at), yaw_rad=yaw0 + turn, width_m=width_m
                    )
                    P = Vt + at[:2]
                    over = [
                        np.any(np.all((P >= o_lo) & (P <= o_hi), axis=1)) for o_lo, o_hi in outer
                    ]
                    dist = min(
                        float(np.min(np.linalg.norm(
                            np.maximum(np.maximum(o_lo - P, P - o_hi), 0.0), axis=1)))
                        for o_lo, o_hi in outer
                    )  # fmt: skip
                    blocked = binmod.walls_block_outside(cand, containers, table_z)
                    n_blocked += blocked
                    n_over += any(over)
                    if any(over):
                        assert blocked, (turn, x, y)
                    if blocked:
                        assert dist < 0.007, (turn, x, y, dist)
                    high = SimpleNamespace(
                        pinch_world=(x, y, table_z + max(heights) + 0.02),
                        yaw_rad=yaw0 + turn, width_m=width_m,
                    )  # fmt: skip
                    assert not binmod.walls_block_outside(high, containers, table_z)
    assert 0 < n_over <= n_blocked
    inside = SimpleNamespace(pinch_world=(0.0, 0.0, table_z + 0.015), yaw_rad=0.0, width_m=0.04)
    assert binmod.walls_block_outside(inside, containers, table_z)


def _part_on_the_table(seed, xy):
    """The one-part bin of ``seed`` with its part moved onto the table at ``xy`` and settled
    (the test's hand through the simulator; the robot is not told)."""
    import mujoco

    from mks_sim.sim import truth

    world = binmod.bin_world(seed, count=1)
    (body,) = binmod.instance_bodies(world)
    adr = world.model.jnt_qposadr[world.model.body(body).jntadr[0]]
    world.data.qpos[adr : adr + 3] = [*xy, world.scene.support_z + 0.06]
    world.data.qvel[:] = 0.0
    mujoco.mj_forward(world.model, world.data)
    world.step(1500)
    assert binmod.parts_left(world) == {"bin": 0, "box": 0, "outside": 1}
    assert abs(truth.object_to_world(world, body)[2, 3] - world.scene.support_z) < 0.04
    return world


@pytest.mark.slow
@pytest.mark.parametrize("table", [True, False])
def test_a_part_on_the_table_beside_the_bin_is_picked_from_the_table(table):
    """A part on the table in front of the bin (moved there through the simulator): the bin
    is found empty, the table is searched and the part picked into the box from there
    (ground truth: it is in the box). With the table search off (``--bin-only``) it stays."""
    from mks_sim.devices import make_devices

    seed = 21  # a tuning bin
    world = _part_on_the_table(seed, (0.0, 0.21))
    with make_devices(world.model, world.data, np.random.default_rng(seed), {}) as devices:
        rec = binmod.clear_bin(world, devices, rng=np.random.default_rng(seed), table=table)
    assert rec["stopped"] == "nothing found", rec
    if not table:
        assert rec["table_stopped"] is None and rec["picks"] == [] and rec["picked"] == 0
        assert binmod.parts_left(world)["outside"] == 1
        return
    assert rec["picked"] == 1 and rec["table_stopped"] == "nothing found", rec
    assert [p["region"] for p in rec["picks"]] == ["table"]
    assert rec["picks"][0]["success"]
    assert binmod.parts_left(world) == {"bin": 0, "box": 0, "outside": 0}
