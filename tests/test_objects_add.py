"""`mks-sim objects add` on meshes the project does not ship (generated here with trimesh)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import trimesh

from mks_sim.cli import main
from mks_sim.errors import DataError
from mks_sim.geometry.meshes import Mesh
from mks_sim.models.importer import add_object, pinch_fraction, stable_poses
from mks_sim.models.objects import load_object, object_names

sys.path.insert(0, str(Path(__file__).parent))
import _gen_meshes as gen  # noqa: E402


def _export_mm(tm: trimesh.Trimesh, path: Path) -> Path:
    tm = tm.copy()
    tm.apply_scale(1000.0)  # the file is in millimetres
    tm.export(path)
    return path


def test_wedge_convex_polyhedral(tmp_path: Path) -> None:
    src = _export_mm(gen.wedge(), tmp_path / "wedge.stl")
    rep = add_object(src, "wedge", tmp_path / "m", units="mm", density=500.0)
    assert rep.kinds == ("polyhedral",) and rep.collision_parts == 1
    assert not any(f.suffix == ".npz" for f in rep.files)  # a polyhedron needs no tables
    obj = load_object("wedge", models=[tmp_path / "m"])
    assert obj.collision == "mesh" and obj.symmetry == "none"
    ext = obj.mesh.bounds[1] - obj.mesh.bounds[0]
    assert ext == pytest.approx([0.06, 0.035, 0.03], abs=1e-6)  # mm -> m
    assert np.allclose(obj.mesh.centroid, 0.0, atol=1e-9)  # body origin at the centre of mass
    # mass: analytic prism volume x density, as MuJoCo computes it from the exported scene
    mass = 0.5 * 0.06 * 0.035 * 0.03 * 500.0
    assert rep.mass_kg == pytest.approx(mass, rel=1e-6)
    xml = tmp_path / "x" / "w.xml"
    xml.parent.mkdir()
    assert main(["scene", "export", "--object", "wedge", "--models", str(tmp_path / "m"),
                 "--out", str(xml)]) == 0  # fmt: skip
    m = mujoco.MjModel.from_xml_path(str(xml))
    assert m.body_mass[m.body("wedge").id] == pytest.approx(mass, rel=1e-3)


def test_l_bracket_convex_decomposition(tmp_path: Path) -> None:
    src = _export_mm(gen.l_bracket(), tmp_path / "l.stl")
    rep = add_object(src, "bracket", tmp_path, units="mm")
    assert rep.kinds == ("polyhedral",) and rep.symmetry == "none"
    # 10 mm walls with 25 mm faces: the hand pinches across a wall (>= 8 mm)
    assert not any("walls thinner than the pads" in w for w in rep.warnings)
    # 6 mm walls: narrower than the hand closes on, and every wider pair ends on a 6 mm face
    # that a 13 mm pad overhangs
    thin_src = _export_mm(gen.l_bracket(0.006), tmp_path / "t.stl")
    thin = add_object(thin_src, "thin", tmp_path, units="mm")
    assert any("walls thinner than the pads" in w for w in thin.warnings)
    obj = load_object("bracket", models=[tmp_path])
    assert isinstance(obj.collision, tuple) and len(obj.collision) >= 2
    # every part is convex and the parts together cover the bracket (volume within 15 %)
    parts = [trimesh.load(p, force="mesh") for p in obj.collision]
    assert all(p.is_convex for p in parts)
    volume = (0.06 * 0.01 + 0.01 * 0.03) * 0.025
    assert sum(p.volume for p in parts) == pytest.approx(volume, rel=0.15)
    assert obj.mesh.volume == pytest.approx(volume, rel=1e-6)
    # two of its resting poses are the L lying flat (the 60 x 40 outline down, 25 mm high)
    heights = [
        float(np.ptp((obj.mesh.vertices @ T[:3, :3].T)[:, 2])) for T, _ in stable_poses(obj.mesh)
    ]
    assert sum(abs(h - 0.025) < 1e-6 for h in heights) == 2


@pytest.mark.slow
def test_cylinder_axial_symmetry_and_tables(tmp_path: Path) -> None:
    src = _export_mm(gen.cylinder(), tmp_path / "can.stl")
    rep = add_object(src, "can", tmp_path, units="mm")
    assert rep.kinds == ("freeform",) and rep.symmetry == "detected"
    obj = load_object("can", models=[tmp_path])
    assert obj.symmetry == "axial" and abs(obj.symmetries[1][2, 2]) > 0.999  # about z
    assert (tmp_path / "can_freeform.npz").is_file() and obj.models["freeform"] == "can_freeform"
    assert obj.model("freeform") is not None  # loads from the cached tables


def _open_box(path: Path) -> Path:
    box = trimesh.creation.box((30.0, 30.0, 30.0))
    box.update_faces(np.arange(len(box.faces)) != 0)  # one triangle missing
    box.export(path)
    return path


@pytest.mark.parametrize(
    ("make", "units", "match"),
    [
        (lambda p: _open_box(p / "open.stl"), "mm", "not watertight"),
        (lambda p: _export_mm(gen.wedge(), p / "big.stl"), "m", r"absurd size.*--units mm"),
        (
            lambda p: (p / "empty.stl").write_text("solid x\nendsolid x\n") and p / "empty.stl",
            "mm",
            "no triangles|empty",
        ),  # fmt: skip
    ],
)
def test_bad_meshes_are_rejected(tmp_path: Path, make, units: str, match: str) -> None:
    with pytest.raises(DataError, match=match):
        add_object(make(tmp_path), "bad", tmp_path / "out", units=units)
    assert not (tmp_path / "out" / "bad.toml").exists()


def test_existing_name_is_refused(tmp_path: Path) -> None:
    from mks_sim.errors import SpecError

    src = _export_mm(gen.wedge(), tmp_path / "w.stl")
    with pytest.raises(SpecError, match="'cube' already exists in .*cube_5cm.toml"):
        add_object(src, "cube", tmp_path / "m", units="mm")


def _mesh(tm: trimesh.Trimesh) -> Mesh:
    return Mesh(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64))


def test_pinch_sites_need_a_pad_on_both_faces() -> None:
    """Geometry the hand's limits decide by hand: a 6 mm plate (pairs across it are narrower
    than the 8 mm the hand closes on, pairs across 60 mm end on 6 mm edges) and the 6 mm
    bracket have no pinch site; a 30 mm cube (6 faces, each pair 30 mm apart) has one almost
    everywhere, and so have the brackets with 10 mm and 22 mm walls on their leg faces."""
    assert pinch_fraction(_mesh(trimesh.creation.box((0.06, 0.06, 0.006)))) == 0.0
    assert pinch_fraction(_mesh(gen.l_bracket(0.006))) == 0.0
    assert pinch_fraction(_mesh(gen.l_bracket())) > 0.1
    # a 13 mm pad fits where the contact is 6.5 mm or more from every edge: (17/30)^2
    assert pinch_fraction(_mesh(trimesh.creation.box((0.03, 0.03, 0.03)))) == pytest.approx(
        (17 / 30) ** 2, abs=0.08
    )
    assert pinch_fraction(_mesh(gen.l_bracket(0.022))) > 0.1


def test_small_object_warns(tmp_path: Path) -> None:
    src = tmp_path / "tiny.stl"
    trimesh.creation.box((3.0, 3.0, 3.0)).export(src)  # 3 mm: smaller than the hand handles
    with pytest.warns(UserWarning, match="outside what the Jaco hand grasps"):
        add_object(src, "tiny", tmp_path, units="mm")


def test_cli_add_list_show(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = _export_mm(gen.wedge(), tmp_path / "w.stl")
    out = tmp_path / "models"
    assert main(["objects", "add", str(src), "--name", "w", "--units", "mm", "--out",
                 str(out), "--json"]) == 0  # fmt: skip
    rec = json.loads(capsys.readouterr().out)
    assert rec["kinds"] == ["polyhedral"] and Path(rec["toml"]).is_file()
    assert main(["objects", "list", "--models", str(out), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {r["name"] for r in rows} == set(object_names([out]))
    assert main(["objects", "show", "w", "--models", str(out), "--out", str(tmp_path)]) == 0
    assert (tmp_path / "w.png").stat().st_size > 10_000
    # a bad mesh: exit 2 with one line naming the problem
    capsys.readouterr()
    assert main(["objects", "add", str(_open_box(tmp_path / "o.stl")), "--name", "o",
                 "--out", str(out)]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not watertight" in err[0]


@pytest.mark.slow
def test_default_task_for_an_added_object(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from mks_sim.errors import NotFound
    from mks_sim.sim.world import build_world
    from mks_sim.tasks.spec import task_for_object

    src = _export_mm(gen.wedge(), tmp_path / "w.stl")
    add_object(src, "wedge", tmp_path / "m", units="mm")
    monkeypatch.setenv("MKS_SIM_MODELS", str(tmp_path / "m"))
    task = task_for_object("wedge")
    assert task.object == "wedge" and task.matcher == "polyhedral"
    assert task.scene.endswith("default_wedge.toml")
    world = build_world(task.scene, seed=0)  # the wedge alone, dropped and settled
    assert world.object_names == ("wedge",)
    assert task_for_object("cube").scene == "scene2"  # a task file still wins
    with pytest.raises(NotFound):
        task_for_object("no_such_object")
