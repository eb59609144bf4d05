"""Objects as data: load_object, object_names, models_dirs, symmetries (issue 10)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import trimesh

from mks_sim.errors import NotFound, SpecError
from mks_sim.geometry.meshes import Mesh, box_mesh, sample_surface
from mks_sim.models.database import ModelDatabase
from mks_sim.models.objects import load_object, models_dirs, object_names, parse_symmetry
from mks_sim.models.symmetry import detect_symmetries
from mks_sim.sim import names


def _maps_points_onto(T: np.ndarray, pts: np.ndarray) -> bool:
    moved = pts @ T[:3, :3].T + T[:3, 3]
    d = np.linalg.norm(moved[:, None] - pts[None], axis=2).min(axis=1)
    return bool(d.max() < 1e-9)


def test_builtin_objects_are_in_the_database() -> None:
    assert {"cube", "sphere", "part"} <= set(object_names())


def test_cube_entry_matches_the_simulated_cube() -> None:
    cube = load_object("cube")
    half = names.CUBE_SIZE_M / 2
    corners = np.array(list(itertools.product((-half, half), repeat=3)))
    assert np.allclose(np.sort(cube.mesh.vertices, axis=0), np.sort(corners, axis=0))
    assert cube.kind == "polyhedral" and cube.sensor == "Vertex_Detector"
    # 24 distinct proper rotations, identity first, each mapping the corners onto themselves.
    S = cube.symmetries
    assert S.shape == (24, 4, 4) and np.allclose(S[0], np.eye(4))
    assert all(np.isclose(np.linalg.det(T[:3, :3]), 1.0) for T in S)
    assert len({tuple(np.round(T.ravel(), 6)) for T in S}) == 24
    assert all(_maps_points_onto(T, corners) for T in S)
    assert cube.model().name == "cube_5cm"


def test_sphere_and_part_entries() -> None:
    sphere = load_object("sphere")
    r = np.linalg.norm(sphere.mesh.vertices, axis=1)
    assert np.allclose(r, names.SPHERE_RADIUS_M)
    assert not sphere.orientation_observable and sphere.kinds == ("sphere",)
    part = load_object("part")
    assert part.symmetries.shape == (1, 4, 4) and part.density == 1200.0
    assert part.mesh.is_watertight() and part.mesh.bounds[0, 2] == pytest.approx(0.0)
    assert "rotinv" in part.kinds and part.models["rotinv"] == "part"


def test_unknown_object_lists_the_known_ones() -> None:
    with pytest.raises(NotFound, match="known objects: .*cube"):
        load_object("no_such_object")


def _write_cylinder_mm(folder, name="can", extra=""):
    cyl = trimesh.creation.cylinder(radius=20.0, height=60.0, sections=48)  # millimetres
    cyl.export(folder / f"{name}.stl")
    (folder / f"{name}.toml").write_text(
        f'[[object]]\nname = "{name}"\nmesh = "{name}.stl"\nunits = "mm"\n'
        f"symmetry = {{ axis = [0, 0, 1], order = 0, flip = true }}\n{extra}",
        encoding="utf-8",
    )


def test_extra_folder_and_env(tmp_path, monkeypatch) -> None:
    _write_cylinder_mm(tmp_path)
    can = load_object("can", models=[tmp_path])
    ext = can.mesh.bounds[1] - can.mesh.bounds[0]
    assert ext == pytest.approx([0.04, 0.04, 0.06], abs=1e-3)  # mm -> m
    assert can.symmetry == "axial" and len(can.symmetries) == 720
    assert can.source == tmp_path / "can.toml"
    with pytest.raises(NotFound):
        load_object("can")
    monkeypatch.setenv("MKS_SIM_MODELS", str(tmp_path))
    assert "can" in object_names()
    assert tmp_path.resolve() in models_dirs()
    # the model database reads the same folders (a file with only [[object]] is fine)
    assert "cube_5cm" in ModelDatabase.from_dirs(models_dirs())


def test_missing_folder_and_bad_fields(tmp_path) -> None:
    with pytest.raises(NotFound, match="--models"):
        models_dirs([tmp_path / "nope"])
    _write_cylinder_mm(tmp_path, extra="densty = 3.0\n")
    with pytest.raises(SpecError, match=r"can\.toml: object 'can': unknown field.*densty"):
        load_object("can", models=[tmp_path])
    _write_cylinder_mm(tmp_path, extra='kinds = ["magic"]\n')
    with pytest.raises(SpecError, match="field 'kinds'"):
        load_object("can", models=[tmp_path])
    _write_cylinder_mm(tmp_path, extra="density = 500.0\nmass = 0.1\n")
    with pytest.raises(SpecError, match="'density' and 'mass'"):
        load_object("can", models=[tmp_path])
    _write_cylinder_mm(tmp_path)
    (tmp_path / "dup.toml").write_text('[[object]]\nname = "cube"\nmesh = "builtin:box"\n')
    with pytest.raises(SpecError, match="duplicate object name"):
        load_object("can", models=[tmp_path])


def test_declared_symmetry_forms() -> None:
    name, S = parse_symmetry({"axis": [0, 0, 1], "order": 4}, None, "t")
    assert name == "declared" and len(S) == 4
    sq = np.array([[1, 1, 0], [-1, 1, 0], [-1, -1, 0], [1, -1, 0]], float)
    assert all(_maps_points_onto(T, sq) for T in S)
    name, S = parse_symmetry([[1, 0, 0, 180]], None, "t")
    assert len(S) == 2 and np.allclose(S[1][:3, :3], np.diag([1, -1, -1]))
    with pytest.raises(SpecError, match="symmetry"):
        parse_symmetry("octahedral", None, "t")


def _box_gap(half: np.ndarray):
    """Exact distance from a point on/in an axis-aligned box to its surface."""
    return lambda p: np.abs((np.abs(p) - half).max(axis=1))


def _cyl_gap(r: float, h: float):
    """Distance from the surface of a z-axis cylinder (centred) for points on it or inside."""
    return lambda p: np.minimum(
        np.abs(np.hypot(p[:, 0], p[:, 1]) - r) + np.maximum(np.abs(p[:, 2]) - h / 2, 0),
        np.abs(np.abs(p[:, 2]) - h / 2) + np.maximum(np.hypot(p[:, 0], p[:, 1]) - r, 0),
    )


def _on_surface(mesh: Mesh, T: np.ndarray, gap, tol: float) -> bool:
    """Checked with the analytic surface (not the detector's sampled one)."""
    pts, _ = sample_surface(mesh, 300, rng=np.random.default_rng(7))
    moved = pts @ T[:3, :3].T + T[:3, 3]
    return bool(gap(moved).max() < tol)


@pytest.mark.parametrize(
    ("mesh", "count"),
    [
        (box_mesh((0.06, 0.04, 0.02)), 4),  # D2: identity + three half-turns
        (box_mesh(0.05), 24),
    ],
)
def test_detected_symmetries_finite(mesh: Mesh, count: int) -> None:
    S = detect_symmetries(mesh)
    assert len(S) == count and np.allclose(S[0], np.eye(4))
    gap = _box_gap(mesh.bounds[1])
    assert all(_on_surface(mesh, T, gap, 1e-6) for T in S)


def test_detected_symmetries_asymmetric_and_axial() -> None:
    wedge = trimesh.convex.convex_hull(
        np.array(
            [[0, 0, 0], [0.05, 0, 0], [0, 0.03, 0], [0, 0, 0.02], [0.05, 0, 0.02], [0, 0.03, 0.02]]
        )
    )
    assert len(detect_symmetries(Mesh(wedge.vertices, wedge.faces))) == 1  # a mirror is no rotation
    cyl = trimesh.creation.cylinder(radius=0.02, height=0.06, sections=64)
    mesh = Mesh(cyl.vertices, cyl.faces)
    S = detect_symmetries(mesh)
    assert len(S) == 720  # continuous about z, sampled per degree, with the flips
    gap = _cyl_gap(0.02, 0.06)
    assert all(_on_surface(mesh, T, gap, 1e-4) for T in S[::37])  # 64-gon chord: 24 um
    # a rotation the detector must reject: a quarter turn about x
    R = np.eye(4)
    R[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    assert not _on_surface(mesh, R, gap, 1e-4)
