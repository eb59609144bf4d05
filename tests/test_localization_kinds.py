"""Model kinds from a mesh: ``localize-cloud --kind auto`` picks the free-form model for a
curved mesh (issue 9, section 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.geometry.meshes import (
    blob_mesh,
    box_mesh,
    industrial_part_mesh,
    torus_mesh,
    uv_sphere,
)
from mks_sim.geometry.scan import synthetic_scan
from mks_sim.geometry.transforms import make_transform, pose_error
from mks_sim.io.mesh import write_stl
from mks_sim.io.pointcloud import write_ply
from mks_sim.localization.model import mesh_kind, model_from_mesh, planar_area_fraction


@pytest.mark.parametrize(
    ("mesh", "kind"),
    [
        (box_mesh(0.05), "polyhedral"),
        (industrial_part_mesh(), "polyhedral"),
        (torus_mesh(), "freeform"),
        (blob_mesh(), "freeform"),
        (uv_sphere(0.03, 16, 32), "sphere"),
    ],
)
def test_mesh_kind(mesh, kind: str) -> None:
    assert mesh_kind(mesh) == kind


def test_planar_area_fraction_of_a_box_and_a_torus() -> None:
    assert planar_area_fraction(box_mesh(0.05)) == pytest.approx(1.0)
    assert planar_area_fraction(torus_mesh()) < 0.1  # every facet is tiny


def test_forced_kind_and_bad_kind() -> None:
    from mks_sim.errors import DataError

    model, kind = model_from_mesh(box_mesh(0.05), "cube", "polyhedral")
    assert kind == "polyhedral" and len(model.corners) == 8
    with pytest.raises(DataError, match="expected one of"):
        model_from_mesh(box_mesh(0.05), "cube", "pyramid")
    with pytest.raises(DataError, match="not a sphere"):
        model_from_mesh(box_mesh(0.05), "cube", "sphere")


def test_cli_auto_kind_finds_a_scanned_torus_with_the_freeform_model(tmp_path, capsys) -> None:
    mesh = torus_mesh()
    a = 0.5
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    T = make_transform(R, [0.005, -0.004, 0.03])
    table = (box_mesh((0.6, 0.6, 0.02)), make_transform(np.eye(3), [0.0, 0.0, -0.01]))
    eye = np.array([0.25, -0.15, 0.3])
    pts = synthetic_scan(
        mesh, T, eye, [0.0, 0.0, 0.02], width=160, height=120, fov_deg=40,
        noise_sigma=0.0003, rng=np.random.default_rng(5), extra=[table],
    )  # fmt: skip
    scene, model = tmp_path / "scan.ply", tmp_path / "torus.stl"
    write_ply(scene, pts)
    write_stl(model, mesh)
    args = ["localize-cloud", "--model", str(model), "--scene", str(scene), "--json"]
    code = main([*args, "--viewpoint", *map(str, eye)])
    out = json.loads(capsys.readouterr().out)
    assert out["kind"] == "freeform"
    assert code == 0 and out["found"] is True
    from mks_sim.models.freeform import axial_symmetries

    M = np.array(out["hypotheses"][0]["matrix"])
    pos, rot = pose_error(M, T, axial_symmetries())
    assert pos < 0.003 and rot < 3.0, (pos, rot)
    assert set(out["timing_s"]) >= {"representation", "hypotheses", "verification", "total"}
