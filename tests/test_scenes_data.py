"""Scenes are data: worlds/*.toml, the default scene (objects dropped), MJCF export."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mks_sim.errors import NotFound, SpecError
from mks_sim.models.objects import load_object
from mks_sim.sim import names, truth
from mks_sim.sim.scenes import build_scene, export_scene, scene_names
from mks_sim.sim.world import build_world


def test_shipped_scene_files() -> None:
    assert {"scene1", "scene2", "part"} <= set(scene_names())
    for name in ("scene1", "scene2", "part"):
        spec = build_scene(name)
        assert spec.source is not None and spec.source.name == f"{name}.toml"
    assert build_scene("scene2").models == {"cube": "cube", "sphere": "sphere"}


def test_scene_file_path_counts_and_ranges(tmp_path) -> None:
    f = tmp_path / "two_cubes.toml"
    f.write_text(
        '[[object]]\nname = "cube"\ncount = 2\nx = [0.0, 0.15]\ny = [-0.1, 0.1]\nyaw = [0, 0]\n',
        encoding="utf-8",
    )
    w = build_world(str(f), seed=4)
    assert w.object_names == ("cube", "cube_1")
    for n in w.object_names:
        T = truth.object_to_world(w, n)
        # the footprint (radius 25 mm x sqrt 2) inside the ranges
        assert 0.035 <= T[0, 3] <= 0.115 and -0.065 <= T[1, 3] <= 0.065
        assert T[2, 3] == pytest.approx(names.TABLE_TOP_Z + 0.025, abs=1.5e-3)
        # yaw range [0, 0]: the cube's axes stay aligned with the world's
        assert abs(T[0, 0]) > 0.999


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[[object]]\nname = "cube"\ncolour = 1\n', "unknown field.*colour"),
        ('[[object]]\nname = "cube"\npose = "flying"\n', "field 'pose'"),
        ('[[object]]\nname = "cube"\ncount = 0\n', "field 'count'"),
        ('[[object]]\nname = "sphere"\non = "cube"\n', "field 'on'"),
        ('[[clutter]]\nshape = "cone"\nsize = [1, 2]\n', "field 'shape'"),
        ("[scene]\n", "at least one"),
    ],
)
def test_bad_scene_files(tmp_path, text: str, match: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(SpecError, match=match):
        build_scene(str(f))


def test_unknown_scene_and_object(tmp_path) -> None:
    with pytest.raises(NotFound, match="unknown scene 'nope'.*scene2"):
        build_scene("nope")
    f = tmp_path / "s.toml"
    f.write_text('[[object]]\nname = "teapot"\n', encoding="utf-8")
    with pytest.raises(NotFound, match="teapot.*known objects"):
        build_scene(str(f))


@pytest.mark.slow
def test_default_scene_drops_onto_stable_faces() -> None:
    """The part alone, dropped from random orientations: at rest on the table (its lowest
    point there, not moving) and not always on the same face."""
    part = load_object("part")
    up = set()
    for seed in range(6):
        w = build_world(objects=["part"], seed=seed)
        T = truth.object_to_world(w, "part")
        lowest = (part.mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min()
        assert lowest == pytest.approx(names.TABLE_TOP_Z, abs=1.5e-3)
        cx, cy = names.OBJECT_REGION_CENTER_XY
        hx, hy = names.OBJECT_REGION_HALF_XY
        assert abs(T[0, 3] - cx) < hx + 0.02 and abs(T[1, 3] - cy) < hy + 0.02
        before = T[:3, 3].copy()
        w.step(250)
        assert np.linalg.norm(truth.object_to_world(w, "part")[:3, 3] - before) < 1e-3
        up.add(tuple(np.round(T[:3, :3].T @ [0, 0, 1.0], 1)))  # world up in the part frame
    assert len(up) >= 2


def test_export_loads_in_mujoco(tmp_path) -> None:
    xml = export_scene("part", tmp_path / "part")
    m = mujoco.MjModel.from_xml_path(str(xml))
    assert m.body("part").id > 0 and m.camera(names.OVERHEAD_CAMERA).id >= 0
    # the exported part carries the database density (1200 kg/m^3) on its exact mesh volume
    part = load_object("part")
    assert m.body_mass[m.body("part").id] == pytest.approx(1200.0 * part.mesh.volume, rel=0.02)


def test_object_scene_comes_from_the_task_file(tmp_path) -> None:
    """The scene of an object is its task file's ``scene`` (no table in code); an object
    without a task file gets the default scene (None: the object alone, dropped)."""
    from mks_sim.tasks.spec import default_task, object_scene

    assert object_scene("cube") == "scene2" and object_scene("part") == "part"
    (tmp_path / "grasp_cube.toml").write_text(
        '[[task]]\nname = "grasp_cube"\nscene = "part"\nobject = "cube"\nmodel = "cube_5cm"\n'
        '[task.action]\nkind = "grasp"\n',
        encoding="utf-8",
    )
    assert object_scene("cube", tmp_path) == "part"
    assert object_scene("cube", tmp_path / "empty") is None
    assert default_task("cube").scene.endswith("default_cube.toml")


def test_table_height_is_a_sensor_parameter(tmp_path) -> None:
    """The nominal table height the localization flow uses is read from the sensor files
    (``sensors/points.toml``), not a constant: edit the file, the flow's value follows."""
    import shutil

    from mks_sim.resources import data_dir
    from mks_sim.sensing import SensorGraph
    from mks_sim.workstation import table_z_m, workstation_representation

    assert table_z_m() == pytest.approx(names.TABLE_TOP_Z)
    for f in data_dir("sensors").glob("*.toml"):
        shutil.copy(f, tmp_path / f.name)
    pts = tmp_path / "points.toml"
    text = pts.read_text(encoding="utf-8")
    assert text.count("table_z_m = 0.75") >= 1
    pts.write_text(text.replace("table_z_m = 0.75", "table_z_m = 0.8"), encoding="utf-8")
    graph = SensorGraph.from_dir(tmp_path)
    assert table_z_m(graph) == pytest.approx(0.8)
    assert workstation_representation(graph).table_z_m == pytest.approx(0.8)


def test_flat_parts_are_scene_data(tmp_path) -> None:
    """A [[flat_part]] scene of one's own: a hexagonal plate without a hole (a fan-capped
    prism) and a washer on a tray, built from the file alone; the mesh is closed with the
    extruded polygon's volume (area 2 sqrt 3 a^2 for apothem a)."""
    from mks_sim.geometry.meshes import Mesh
    from mks_sim.sim import flatparts

    f = tmp_path / "plates.toml"
    f.write_text(
        '[scene]\nsupport = "tray"\n[tray]\nsize = [0.2, 0.15, 0.004]\n'
        "[flat_parts]\nthickness_mm = 5\n"
        '[[flat_part]]\nname = "hex"\nkind = "hex_plate"\nat_px = [30, -20]\ncorners = 6\n'
        'shape = "polygon"\nsides = 6\napothem_mm = 15\n'
        '[[flat_part]]\nname = "ring"\nkind = "washer"\nat_px = [-40, 0]\nholes = 1\n'
        'shape = "disc"\nradius_mm = 12\nhole_radius_mm = 4\n',
        encoding="utf-8",
    )
    spec = build_scene(str(f))
    assert [p.name for p in spec.flat_parts] == ["hex", "ring"]
    assert spec.support_z == pytest.approx(names.TABLE_TOP_Z + 0.008)
    hexp = spec.flat_parts[0]
    assert hexp.default_xy == pytest.approx((0.030, 0.020))  # 1 mm per pixel, v downwards
    mesh = Mesh(*flatparts.prism(hexp.outline(), hexp.thickness_m))
    assert mesh.is_watertight()
    assert mesh.volume == pytest.approx(2 * np.sqrt(3) * 0.015**2 * 0.005, rel=1e-6)
    w = build_world(str(f))
    assert truth.object_to_world(w, "hex")[2, 3] == pytest.approx(spec.support_z + 0.0025, abs=1e-3)
    rows = {r.name: r for r in truth.scene1_manifest(w)}
    assert rows["ring"].holes == 1 and rows["ring"].uv_paper == pytest.approx((-40, 0), abs=1)


@pytest.mark.parametrize(
    ("entry", "match"),
    [
        ('shape = "oval"\nradius_mm = 3\n', "field 'shape'"),
        ('shape = "disc"\n', "field 'radius_mm'"),
        ('shape = "polygon"\nsides = 5\napothem_mm = 9\n', "field 'sides'.*divisor"),
        ('shape = "disc"\nradius_mm = 5\nhole_radius_mm = 6\n', "hole inside the outline"),
        ('shape = "boxes"\nboxes_mm = [[0, 0, 1]]\n', "field 'boxes_mm'"),
        ('shape = "disc"\nradius_mm = 5\ncolour = 1\n', "unknown field.*colour"),
    ],
)
def test_bad_flat_parts(tmp_path, entry: str, match: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(
        f'[[flat_part]]\nname = "p"\nkind = "plate"\nat_px = [0, 0]\n{entry}', encoding="utf-8"
    )
    with pytest.raises(SpecError, match=match):
        build_scene(str(f))
