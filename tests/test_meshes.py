"""Meshes: watertightness, volumes against closed forms, the industrial part's properties."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.geometry import meshes as M
from mks_sim.geometry.meshes import (
    Mesh,
    blob_mesh,
    box_mesh,
    icosphere,
    industrial_part_boxes,
    industrial_part_control_points,
    industrial_part_mesh,
    sample_surface,
    torus_mesh,
    uv_sphere,
)


def _polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


@pytest.mark.parametrize(
    "mesh",
    [box_mesh((0.1, 0.2, 0.3)), uv_sphere(1.0), icosphere(1.0, 2), torus_mesh(), blob_mesh()],
)
def test_primitives_are_watertight_and_outward(mesh: Mesh) -> None:
    assert mesh.is_watertight()
    assert mesh.volume > 0


def test_box_volume_area_inertia_closed_form() -> None:
    a, b, c = 0.1, 0.2, 0.3
    m = box_mesh((a, b, c))
    assert m.volume == pytest.approx(a * b * c)
    assert m.area == pytest.approx(2 * (a * b + b * c + a * c))
    vol = a * b * c
    expected = vol / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(m.inertia(), expected, atol=1e-12)


def test_sphere_volume_converges_to_closed_form() -> None:
    exact = 4 / 3 * np.pi
    errs = [abs(icosphere(1.0, k).volume - exact) for k in (1, 2, 3, 4)]
    assert all(e2 < e1 for e1, e2 in zip(errs, errs[1:]))
    assert errs[-1] / exact < 3e-3
    assert uv_sphere(1.0, 64, 128).volume == pytest.approx(exact, rel=2e-3)


def test_torus_volume_closed_form() -> None:
    R, r = 0.04, 0.012
    m = torus_mesh(R, r, 128, 64)
    assert m.volume == pytest.approx(2 * np.pi**2 * R * r * r, rel=3e-3)


def test_industrial_part_watertight_and_volume() -> None:
    m = industrial_part_mesh()
    assert m.is_watertight()
    # Closed form from the construction: plate + step - holes + boss (polygonal circles).
    vol = 0.1 * 0.06 * M._PLATE_H + 4 * M._CELL**2 * (M._STEP_H - M._PLATE_H)
    for (ix, iy), r in M._HOLES.items():
        per = M._tile_perimeter(ix, iy)
        ctr = np.array(M._cell_origin(ix, iy)) + M._CELL / 2
        vol -= _polygon_area(M._circle_like(per, ctr, r)) * M._PLATE_H
    (bx, by), r, top = M._BOSS
    per = M._tile_perimeter(bx, by)
    ctr = np.array(M._cell_origin(bx, by)) + M._CELL / 2
    vol += _polygon_area(M._circle_like(per, ctr, r)) * (top - M._PLATE_H)
    assert m.volume == pytest.approx(vol, rel=1e-9)
    lo, hi = m.bounds
    np.testing.assert_allclose(lo, [-0.05, -0.03, 0.0])
    np.testing.assert_allclose(hi, [0.05, 0.03, 0.03])


def test_industrial_part_has_no_rotational_symmetry() -> None:
    m = industrial_part_mesh()
    ev = np.linalg.eigvalsh(m.inertia())
    # distinct principal moments: no axis of rotational symmetry of order > 2 ...
    assert np.min(np.diff(ev)) / ev.max() > 0.05
    # ... and no 180-degree symmetry about any principal axis: the rotated surface
    # does not match itself.
    pts, _ = sample_surface(m, 3000, rng=np.random.default_rng(1))
    dense, _ = sample_surface(m, 40000, rng=np.random.default_rng(2))
    c = m.centroid
    _, vecs = np.linalg.eigh(m.inertia())
    tree = cKDTree(dense)
    assert np.mean(tree.query(pts)[0] > 1.5e-3) < 0.01  # the identity does match
    for k in range(3):
        ax = vecs[:, k]
        rot = 2 * np.outer(ax, ax) - np.eye(3)  # 180 degrees about ax
        moved = (pts - c) @ rot.T + c
        d, _ = tree.query(moved)
        assert np.mean(d > 1.5e-3) > 0.4


def test_blob_is_not_nearly_symmetric() -> None:
    # A blob close to a 180-degree symmetry makes a flipped pose as good as the true one.
    m = blob_mesh()
    pts, _ = sample_surface(m, 3000, rng=np.random.default_rng(1))
    dense, _ = sample_surface(m, 40000, rng=np.random.default_rng(2))
    tree = cKDTree(dense)
    c = m.centroid
    _, vecs = np.linalg.eigh(m.inertia())
    for k in range(3):
        rot = 2 * np.outer(vecs[:, k], vecs[:, k]) - np.eye(3)
        d, _ = tree.query((pts - c) @ rot.T + c)
        assert np.median(d) > 1.2e-3


def test_control_points_on_surface_and_distinct_distances() -> None:
    m = industrial_part_mesh()
    cp = industrial_part_control_points()
    assert cp.shape == (4, 3)
    pts, _ = sample_surface(m, 200000, rng=np.random.default_rng(2))
    d, _ = cKDTree(pts).query(cp)
    assert np.all(d < 1.5e-3)
    # Each is a mesh vertex (a corner where three planes meet).
    dv, _ = cKDTree(m.vertices).query(cp)
    assert np.all(dv < 1e-9)
    dist = np.linalg.norm(cp[:, None] - cp[None], axis=-1)[np.triu_indices(4, 1)]
    assert np.min(np.diff(np.sort(dist))) > 1e-3
    assert abs(np.linalg.det(np.column_stack([cp[1:] - cp[0]]))) > 1e-9  # not coplanar


def test_boxes_cover_the_part_volume() -> None:
    prims = industrial_part_boxes()
    vol = 0.0
    for p in prims:
        if p.kind == "box":
            vol += 8 * np.prod(p.half_sizes)
        else:
            assert p.kind == "cylinder"
            vol += np.pi * p.half_sizes[0] ** 2 * 2 * p.half_sizes[2]
    # Square hole cut-outs remove a bit more than the round holes: within 3 %.
    assert vol == pytest.approx(industrial_part_mesh().volume, rel=0.03)
    for p in prims:
        lo, hi = p.centre - p.half_sizes, p.centre + p.half_sizes
        assert np.all(lo >= [-0.05 - 1e-12, -0.03 - 1e-12, -1e-12])
        assert np.all(hi <= [0.05 + 1e-12, 0.03 + 1e-12, 0.03 + 1e-12])


def test_sample_surface_area_weighted_and_on_surface() -> None:
    m = box_mesh((0.1, 0.2, 0.4))
    p, n = sample_surface(m, 20000, rng=np.random.default_rng(3))
    # Fraction on the +-z faces = their share of the area.
    frac = np.mean(np.abs(n[:, 2]) > 0.9)
    assert frac == pytest.approx(2 * 0.02 / m.area, abs=0.015)
    on_face = np.isclose(np.abs(p), [0.05, 0.1, 0.2]).any(axis=1)
    assert on_face.all()
    ps, _ = sample_surface(m, spacing=0.01)
    assert len(ps) == round(m.area / 1e-4)
    with pytest.raises(DataError, match="exactly one"):
        sample_surface(m)


def test_bad_meshes_rejected() -> None:
    with pytest.raises(DataError, match=r"\(V, 3\)"):
        Mesh(np.zeros((4, 2)), np.zeros((1, 3), int))
    with pytest.raises(DataError, match="indices"):
        Mesh(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    open_mesh = Mesh(box_mesh().vertices, box_mesh().faces[:-1])
    assert not open_mesh.is_watertight()
