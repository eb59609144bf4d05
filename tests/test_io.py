"""Point-cloud and mesh files: round trips of every format, malformed files, LZF, NaNs."""

from __future__ import annotations

import logging
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from mks_sim.errors import DataError, NotFound
from mks_sim.geometry.meshes import box_mesh, industrial_part_mesh, torus_mesh
from mks_sim.io import (
    read_mesh,
    read_point_cloud,
    write_npy,
    write_npz,
    write_obj,
    write_pcd,
    write_ply,
    write_ply_mesh,
    write_stl,
)
from mks_sim.io.lzf import LZFError, lzf_compress, lzf_decompress

RNG = np.random.default_rng(0)
PTS = RNG.uniform(-0.5, 0.5, (200, 3))
NRM = RNG.normal(size=(200, 3))
NRM /= np.linalg.norm(NRM, axis=1, keepdims=True)


def _close32(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(a, b.astype(np.float32), rtol=0, atol=1e-7)


@pytest.mark.parametrize("binary", [True, False])
@pytest.mark.parametrize("normals", [None, NRM])
def test_ply_round_trip(tmp_path: Path, binary: bool, normals) -> None:
    f = tmp_path / "c.ply"
    write_ply(f, PTS, normals, binary=binary)
    pc = read_point_cloud(f)
    _close32(pc.points, PTS)
    if normals is None:
        assert pc.normals is None
    else:
        _close32(pc.normals, normals)
    assert pc.dropped_nan == 0 and pc.organized_shape is None


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_pcd_round_trip_with_normals(tmp_path: Path, data: str) -> None:
    f = tmp_path / "c.pcd"
    write_pcd(f, PTS, NRM, data=data)
    pc = read_point_cloud(f)
    _close32(pc.points, PTS)
    _close32(pc.normals, NRM)


def test_organised_pcd_with_nans(tmp_path: Path, caplog) -> None:
    grid = RNG.uniform(0, 1, (6, 8, 3))
    grid[1, 2] = np.nan
    grid[4, :3] = np.nan
    for data in ("binary", "binary_compressed", "ascii"):
        f = tmp_path / f"org_{data}.pcd"
        write_pcd(f, grid, data=data)
        with caplog.at_level(logging.WARNING):
            pc = read_point_cloud(f)
        assert pc.organized_shape == (6, 8)
        assert pc.dropped_nan == 4
        assert len(pc) == 44
        assert "dropped 4 of 48" in caplog.text
        np.testing.assert_array_equal(np.isnan(pc.organized()), np.isnan(grid))
        ok = ~np.isnan(grid[..., 0])
        _close32(pc.organized()[ok], grid[ok])


def test_handwritten_pcl_binary_compressed(tmp_path: Path) -> None:
    # 2 points, x y z float32, field-major, LZF stream built by hand: one literal run of 24 bytes.
    x = np.array([1.0, 2.0], "<f4")
    y = np.array([3.0, 4.0], "<f4")
    z = np.array([5.0, 6.0], "<f4")
    raw = x.tobytes() + y.tobytes() + z.tobytes()
    stream = bytes([len(raw) - 1]) + raw
    head = (
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\n"
        "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA binary_compressed\n"
    )
    f = tmp_path / "hand.pcd"
    f.write_bytes(head.encode() + struct.pack("<II", len(stream), len(raw)) + stream)
    np.testing.assert_array_equal(read_point_cloud(f).points, [[1, 3, 5], [2, 4, 6]])


def test_lzf_known_stream_and_round_trip() -> None:
    # "abcabcabcX": literal "abc" (ctrl 2), back-ref length 6 offset 3 (ctrl (4<<5)|0, 2), "X".
    stream = bytes([2]) + b"abc" + bytes([4 << 5, 2]) + bytes([0]) + b"X"
    assert lzf_decompress(stream, 10) == b"abcabcabcX"
    data = np.repeat(np.arange(50, dtype="<f4"), 7).tobytes() + bytes(range(256)) * 3
    comp = lzf_compress(data)
    assert len(comp) < len(data)
    assert lzf_decompress(comp, len(data)) == data
    with pytest.raises(LZFError, match="before the start"):
        lzf_decompress(bytes([1 << 5, 9]), 3)
    with pytest.raises(LZFError, match="header says 11"):
        lzf_decompress(stream, 11)


def test_numpy_formats(tmp_path: Path) -> None:
    write_npy(tmp_path / "a.npy", PTS)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "a.npy").points, PTS)
    np.save(tmp_path / "b.npy", np.column_stack([PTS, NRM]))
    pc = read_point_cloud(tmp_path / "b.npy")
    np.testing.assert_array_equal(pc.normals, NRM)
    write_npz(tmp_path / "c.npz", PTS, NRM)
    pc = read_point_cloud(tmp_path / "c.npz")
    np.testing.assert_array_equal(pc.points, PTS)
    np.testing.assert_array_equal(pc.normals, NRM)
    grid = PTS[:120].reshape(10, 12, 3).copy()
    grid[0, 0] = np.nan
    write_npy(tmp_path / "d.npy", grid)
    pc = read_point_cloud(tmp_path / "d.npy")
    assert pc.organized_shape == (10, 12) and pc.dropped_nan == 1
    np.save(tmp_path / "bad.npy", np.zeros((5, 4)))
    with pytest.raises(DataError, match=r"bad\.npy: expected an array of shape"):
        read_point_cloud(tmp_path / "bad.npy")


def test_truncated_and_garbage_files(tmp_path: Path) -> None:
    f = tmp_path / "scan.pcd"
    write_pcd(f, PTS, data="binary")
    raw = f.read_bytes()
    f.write_bytes(raw[: len(raw) - 12 * 50])
    with pytest.raises(
        DataError, match=r"scan\.pcd: header says POINTS 200 but the data holds 150"
    ):
        read_point_cloud(f)
    write_pcd(f, PTS, data="ascii")
    lines = f.read_text().splitlines()
    f.write_text("\n".join(lines[:-10]) + "\n")
    with pytest.raises(
        DataError, match=r"scan\.pcd: header says POINTS 200 but the data holds 190"
    ):
        read_point_cloud(f)
    write_pcd(f, PTS, data="binary_compressed")
    raw = f.read_bytes()
    f.write_bytes(raw[:-20])
    with pytest.raises(DataError, match=r"scan\.pcd: binary_compressed PCD"):
        read_point_cloud(f)
    g = tmp_path / "cloud.ply"
    write_ply(g, PTS)
    raw = g.read_bytes()
    g.write_bytes(raw[:-100])
    with pytest.raises(DataError, match=r"cloud\.ply: header says element vertex has 200 rows"):
        read_point_cloud(g)
    g.write_bytes(b"\x00\x01garbage" * 20)
    with pytest.raises(DataError, match=r"cloud\.ply: not a PLY file"):
        read_point_cloud(g)
    h = tmp_path / "noxyz.pcd"
    h.write_text(
        "FIELDS a b\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n1 2\n"
    )
    with pytest.raises(DataError, match=r"noxyz\.pcd: PCD has no x, y, z"):
        read_point_cloud(h)
    with pytest.raises(NotFound, match="not found"):
        read_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(DataError, match=r"x\.xyz: unknown point-cloud type"):
        (tmp_path / "x.xyz").write_text("1 2 3")
        read_point_cloud(tmp_path / "x.xyz")


def test_ply_extra_properties_ignored(tmp_path: Path) -> None:
    f = tmp_path / "extra.ply"
    f.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nproperty float intensity\nend_header\n"
        "1 2 3 255 0.5\n4 5 6 0 0.1\n"
    )
    np.testing.assert_array_equal(read_point_cloud(f).points, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize(
    "writer,ext", [(write_stl, "stl"), (write_obj, "obj"), (write_ply_mesh, "ply")]
)
@pytest.mark.parametrize("mesh", [box_mesh((0.1, 0.2, 0.3)), industrial_part_mesh(), torus_mesh()])
def test_mesh_round_trip(tmp_path: Path, writer, ext, mesh) -> None:
    f = tmp_path / f"m.{ext}"
    writer(f, mesh)
    back = read_mesh(f)
    assert len(back.faces) == len(mesh.faces)
    assert back.is_watertight()
    assert back.volume == pytest.approx(mesh.volume, rel=1e-5)
    tri_a = np.sort(np.round(mesh.triangles.reshape(len(mesh.faces), -1), 6), axis=0)
    tri_b = np.sort(np.round(back.triangles.reshape(len(back.faces), -1), 6), axis=0)
    assert np.allclose(tri_a, tri_b, atol=2e-6)


def test_binary_ply_mesh_ascii_and_quads(tmp_path: Path) -> None:
    f = tmp_path / "q.ply"
    write_ply_mesh(f, box_mesh(1.0), binary=False)
    assert read_mesh(f).is_watertight()
    obj = tmp_path / "quad.obj"
    obj.write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1 4/1/1\n"
    )
    m = read_mesh(obj)
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert m.area == pytest.approx(1.0)


def test_ascii_stl_and_bad_meshes(tmp_path: Path) -> None:
    f = tmp_path / "a.stl"
    tri = box_mesh(1.0).triangles
    body = "".join(
        "facet normal 0 0 0\nouter loop\n"
        + "".join(f"vertex {x} {y} {z}\n" for x, y, z in t)
        + "endloop\nendfacet\n"
        for t in tri
    )
    f.write_text("solid cube\n" + body + "endsolid cube\n")
    m = read_mesh(f)
    assert m.is_watertight() and m.volume == pytest.approx(1.0)
    f.write_text("solid cube\n" + body[: len(body) // 2])
    with pytest.raises(DataError, match=r"a\.stl: ascii STL"):
        read_mesh(f)
    b = tmp_path / "b.stl"
    write_stl(b, box_mesh(1.0))
    b.write_bytes(b.read_bytes()[:-7])
    with pytest.raises(DataError, match=r"b\.stl: binary STL header says 12 triangles"):
        read_mesh(b)
    o = tmp_path / "bad.obj"
    o.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    with pytest.raises(DataError, match=r"bad\.obj: face index out of range"):
        read_mesh(o)
    o.write_text("v 0 0 zero\n")
    with pytest.raises(DataError, match=r"bad\.obj: line 1"):
        read_mesh(o)
    p = tmp_path / "pts.ply"
    write_ply(p, PTS)
    with pytest.raises(DataError, match=r"pts\.ply: PLY has no face element"):
        read_mesh(p)


def test_check_scale_flags_unit_mixups(caplog) -> None:
    from mks_sim.io.units import check_scale

    model = industrial_part_mesh().vertices  # metres, ~0.12 m
    scene = model + 0.3  # same units
    assert check_scale(model, np.vstack([scene, [[0.0, 0.0, 0.0]]])) is None
    with caplog.at_level(logging.WARNING):
        msg = check_scale(model * 1000.0, scene)  # model in mm, scene in m
    assert msg is not None and "--scale 0.001" in msg
    assert "are the units the same" in caplog.text
    assert check_scale(model * 1000.0, scene, scale=0.001) is None
    msg = check_scale(model, scene * 1000.0)  # scene in mm
    assert msg is not None and "--scale 1000" in msg


def test_extent_of_a_dense_cloud_matches_its_full_percentile_box() -> None:
    """``extent`` reads 4,000 points drawn from a larger cloud: on a 300k-point scan-like
    cloud (rows of a sheet with a box on it, NaN holes) it is within 1 % of the diagonal of
    the full cloud's 2nd-98th percentile box."""
    from mks_sim.io.units import extent

    rng = np.random.default_rng(4)
    u, v = np.meshgrid(np.linspace(-0.3, 0.3, 600), np.linspace(-0.2, 0.2, 500))
    z = np.where((np.abs(u) < 0.05) & (np.abs(v) < 0.05), 0.05, 0.0) + rng.normal(0, 3e-4, u.shape)
    pts = np.column_stack([u.ravel(), v.ravel(), z.ravel()])
    pts[rng.choice(len(pts), 5000, replace=False)] = np.nan
    finite = pts[np.all(np.isfinite(pts), axis=1)]
    lo, hi = np.percentile(finite, [2, 98], axis=0)
    assert extent(pts) == pytest.approx(float(np.linalg.norm(hi - lo)), rel=0.01)
    small = finite[:1000]
    lo, hi = np.percentile(small, [2, 98], axis=0)
    assert extent(small) == float(np.linalg.norm(hi - lo))  # small clouds: every point


def test_extent_percentiles_are_numpys() -> None:
    """``extent``'s 2nd and 98th percentiles (one partition per column and numpy's linear
    interpolation) equal ``np.percentile``'s, on short and long clouds, with ties."""
    from mks_sim.io.units import _percentiles

    rng = np.random.default_rng(6)
    for trial in range(400):
        p = rng.normal(size=(int(rng.integers(2, 5000)), 3)) * 10.0 ** rng.integers(-4, 4)
        if trial % 3 == 0:
            p = np.round(p, 1)  # ties
        for q in (0.02, 0.98):
            np.testing.assert_array_equal(_percentiles(p, q), np.percentile(p, 100 * q, axis=0))


# --------------------------------------------------------------------------- issue 12


def _ascii_ply(path: Path, header_count: str, rows: int) -> Path:
    body = "".join(f"{i} {i * 2} {i * 3}\n" for i in range(rows))
    path.write_text(
        "ply\nformat ascii 1.0\n"
        f"element vertex {header_count}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n" + body
    )
    return path


@pytest.mark.parametrize(
    ("count", "rows", "message"),
    [
        ("3", 5, r"2 more row\(s\) than the header declares"),
        ("-5", 3, r"expected a row count >= 0, got -5"),
        ("5", 3, r"header says element vertex has 5 rows but the data holds 3"),
    ],
)
def test_ply_header_counts_must_match_the_data(tmp_path: Path, count, rows, message) -> None:
    with pytest.raises(DataError, match=message):
        read_point_cloud(_ascii_ply(tmp_path / "c.ply", count, rows))
    assert len(read_point_cloud(_ascii_ply(tmp_path / "ok.ply", "4", 4)).points) == 4


def test_binary_ply_with_more_data_than_declared(tmp_path: Path) -> None:
    pts = np.random.default_rng(0).random((10, 3))
    write_ply(tmp_path / "b.ply", pts, binary=True)
    raw = (tmp_path / "b.ply").read_bytes()
    (tmp_path / "short.ply").write_bytes(raw.replace(b"element vertex 10", b"element vertex 7"))
    with pytest.raises(DataError, match=r"more byte\(s\) than the header declares"):
        read_point_cloud(tmp_path / "short.ply")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"POINTS 6": "POINTS 4", "WIDTH 6": "WIDTH 4"}, r"POINTS 4 but the data holds 6"),
        ({"WIDTH 6": "WIDTH -3", "HEIGHT 1": "HEIGHT -2"}, r"expected WIDTH >= 0, got -3"),
        ({"POINTS 6": "POINTS -6", "WIDTH 6": "WIDTH -6"}, r"expected WIDTH >= 0, got -6"),
    ],
)
@pytest.mark.parametrize("data", ["ascii", "binary"])
def test_pcd_header_counts_must_match_the_data(tmp_path: Path, data, edit, message) -> None:
    path = tmp_path / "c.pcd"
    write_pcd(path, np.random.default_rng(1).random((6, 3)), data=data)
    raw = path.read_bytes()
    head, sep, body = raw.partition(b"DATA")
    text = head.decode()
    for a, b in edit.items():
        assert a in text
        text = text.replace(a, b)
    path.write_bytes(text.encode() + sep + body)
    with pytest.raises(DataError, match=message):
        read_point_cloud(path)


def test_folder_and_device_are_not_clouds(tmp_path: Path) -> None:
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(DataError, match="expected a point cloud file, got a folder"):
        read_point_cloud(tmp_path / "d.ply")
    with pytest.raises(DataError, match="got a special file"):
        read_point_cloud("/dev/null")
    with pytest.raises(NotFound, match="not found"):
        read_point_cloud(tmp_path / "nothing.ply")


def test_complex_npy_is_an_error_without_warnings(tmp_path: Path) -> None:
    np.save(tmp_path / "c.npy", np.ones((5, 3), dtype=complex))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match=r"expected a real .* got dtype complex128"):
            read_point_cloud(tmp_path / "c.npy")


def test_require_spread_rejects_degenerate_clouds() -> None:
    from mks_sim.io.units import require_spread

    same = np.tile([0.1, 0.2, 0.3], (200_000, 1))
    with pytest.raises(DataError, match=r"all 200000 points at \(0.1, 0.2, 0.3\)"):
        require_spread(same, "s.npy")
    line = np.c_[np.linspace(0, 1, 500), np.zeros(500), np.zeros(500)]
    with pytest.raises(DataError, match="on one line"):
        require_spread(line, "s.npy")
    with pytest.raises(DataError, match="at least 3 finite points, got 2"):
        require_spread(np.array([[0, 0, 0], [1, 1, 1], [np.nan, 0, 0]]), "s.npy")
    require_spread(np.random.default_rng(0).random((100, 3)), "s.npy")  # fine


def test_ply_mesh_with_a_bad_face_index_shows_the_real_error(tmp_path: Path) -> None:
    from mks_sim.localize import load_model

    path = tmp_path / "mesh_badidx.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 9\n"
    )
    with pytest.raises(DataError, match=r"face index out of range \[0, 3\]"):
        load_model(str(path))
