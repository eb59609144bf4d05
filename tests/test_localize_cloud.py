"""The localize_cloud pipeline and `mks-sim localize-cloud`, against synthetic ground truth."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.errors import DataError, NotFound
from mks_sim.geometry.meshes import (
    box_mesh,
    industrial_part_control_points,
    industrial_part_mesh,
    sample_surface,
)
from mks_sim.geometry.scan import synthetic_scan
from mks_sim.geometry.transforms import (
    apply,
    cube_rotations,
    make_transform,
    pose_error,
    random_rotation,
)
from mks_sim.io.mesh import write_stl
from mks_sim.io.pointcloud import write_ply
from mks_sim.localize import (
    LocalizableModel,
    PolyhedralModel,
    load_model,
    localize_cloud,
)
from mks_sim.models.pose import PoseHypothesis

SIZE = 0.05  # 5 cm cube, metres
TABLE = (box_mesh((0.6, 0.6, 0.02)), make_transform(np.eye(3), [0.0, 0.0, -0.01]))
EYES = [np.array([0.35, 0.25, 0.4]), np.array([-0.3, 0.3, 0.45])]


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def cube_model() -> PolyhedralModel:
    return PolyhedralModel.from_mesh(box_mesh(SIZE), "cube")


def _table_scan(mesh, T, eye, rng, noise=0.0002, width=200, height=150):
    return synthetic_scan(
        mesh, T, eye, [0.0, 0.0, 0.0], width=width, height=height, fov_deg=30,
        noise_sigma=noise, rng=rng, extra=[TABLE],
    )  # fmt: skip


def test_polyhedral_model_of_a_cube(cube_model: PolyhedralModel) -> None:
    assert len(cube_model.corners) == 8
    assert len(cube_model.faces) == 6
    assert len(cube_model.symmetry_rotations) == 23  # the cube group minus the identity
    assert isinstance(cube_model, LocalizableModel)
    part = PolyhedralModel.from_mesh(industrial_part_mesh(), "part")
    assert part.symmetries() is None  # "No rotational symmetry" (meshes.py)
    # every control point of H's recipe is a model corner where three faces meet
    cp = industrial_part_control_points()
    d = np.linalg.norm(cp[:, None] - part.vertexes[None], axis=2).min(axis=1)
    assert d.max() < 1e-9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_full_cloud_random_rotation_modulo_cube_symmetry(
    cube_model: PolyhedralModel, seed: int
) -> None:
    rng = np.random.default_rng(100 + seed)
    T = make_transform(random_rotation(rng), rng.uniform(-0.2, 0.2, 3))
    pts = apply(T, sample_surface(box_mesh(SIZE), 2500, rng=rng)[0])
    pts += rng.normal(0.0, 0.0002, pts.shape)
    loc = localize_cloud(cube_model, pts, table="none")
    assert loc.found and loc.best is not None
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert rot < 1.0 and pos < 0.001
    assert loc.table is None and len(loc.segments) == 1
    # the matcher proposes (nearly) all 24 placements; they are reported once
    assert 20 <= len(loc.equivalents[0]) <= 23
    for E in loc.equivalents[0]:
        assert pose_error(E, T, cube_rotations())[1] < 1.0


@pytest.mark.parametrize("seed", [0, 1])
def test_one_sided_scan_on_table(cube_model: PolyhedralModel, seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    T = make_transform(_rot_z(rng.uniform(0, 2 * np.pi)), [*rng.uniform(-0.05, 0.05, 2), SIZE / 2])
    eye = EYES[seed]
    pts = _table_scan(box_mesh(SIZE), T, eye, rng)
    loc = localize_cloud(cube_model, pts, viewpoint=eye)
    assert loc.table is not None and abs(loc.table.normal[2]) > 0.999
    assert loc.table.offset == pytest.approx(0.0, abs=0.0005)
    assert loc.found
    assert loc.segments[0].on_table
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert rot < 1.0 and pos < 0.001


def test_industrial_part_one_sided_and_control_points_recoverable() -> None:
    part = industrial_part_mesh()
    model = PolyhedralModel.from_mesh(part, "part")
    cp = industrial_part_control_points()
    rng = np.random.default_rng(300)
    T = make_transform(_rot_z(0.7), [0.01, -0.02, 0.0])
    recovered = np.full(4, np.inf)
    # From one oblique view a control point is recovered when its three faces are in view;
    # the four oblique views around the part recover all four.
    for sx, sy in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
        eye_obj = np.array([0.3 * sx, 0.25 * sy, 0.4])
        eye = apply(T, eye_obj[None])[0]
        pts = synthetic_scan(
            part, T, eye, apply(T, np.array([[0.0, 0.0, 0.01]]))[0], width=240, height=180,
            fov_deg=25, noise_sigma=0.0002, rng=rng, extra=[TABLE],
        )  # fmt: skip
        loc = localize_cloud(model, pts, viewpoint=eye)
        assert loc.found
        pos, rot = pose_error(loc.best.matrix, T)
        assert rot < 1.0 and pos < 0.001
        v = loc.segments[0].vertexes.points
        d = np.linalg.norm(apply(T, cp)[:, None] - v[None], axis=2).min(axis=1)
        recovered = np.minimum(recovered, d)
    assert recovered.max() < 0.001


def _part_view() -> tuple[PolyhedralModel, np.ndarray, np.ndarray, np.ndarray]:
    """The industrial part seen obliquely (several vertexes in view)."""
    part = industrial_part_mesh()
    T = make_transform(_rot_z(0.7), [0.01, -0.02, 0.0])
    eye = apply(T, np.array([[0.3, -0.25, 0.4]]))[0]
    pts = synthetic_scan(
        part, T, eye, apply(T, np.array([[0.0, 0.0, 0.01]]))[0], width=240, height=180,
        fov_deg=25, noise_sigma=0.0002, rng=np.random.default_rng(301), extra=[TABLE],
    )  # fmt: skip
    return PolyhedralModel.from_mesh(part, "part"), T, eye, pts


@pytest.mark.parametrize("thorough", [False, True])
def test_industrial_part_found_with_either_verification(thorough: bool) -> None:
    model, T, eye, pts = _part_view()
    loc = localize_cloud(model, pts, viewpoint=eye, thorough=thorough)
    assert loc.found and loc.best is not None
    pos, rot = pose_error(loc.best.matrix, T)
    assert rot < 1.0 and pos < 0.001, (rot, pos)


def test_rotation_invariant_hough_is_the_fallback(monkeypatch: pytest.MonkeyPatch) -> None:
    """By default the rotation-invariant Hough runs only when the corner hypotheses score
    under ``min_score`` (``thorough``: on every segment with three or more vertexes), and
    the fallback's hypotheses are verified and can win."""
    import mks_sim.localization.hypotheses as hyp_mod
    import mks_sim.localization.pipeline as pipe

    model, T, eye, pts = _part_view()
    calls: list[str] = []
    real_rotinv = hyp_mod._rotinv_hypotheses

    def counted(*args, **kwargs):
        calls.append("rotinv")
        return real_rotinv(*args, **kwargs)

    monkeypatch.setattr(hyp_mod, "_rotinv_hypotheses", counted)
    loc = localize_cloud(model, pts, viewpoint=eye)
    assert loc.found and calls == []
    localize_cloud(model, pts, viewpoint=eye, thorough=True)
    assert calls == ["rotinv"]

    # The corner hypotheses (and the plane pairs) taken away: the first verification finds
    # nothing, the fallback is asked, and what it gives (here the corner hypotheses, moved
    # there by the test) is verified and found.
    calls.clear()
    real = pipe.vertex_hypotheses

    def moved_to_the_fallback(*args, **kwargs):
        if kwargs.get("corners") is False:
            calls.append("fallback")
            return real(*args, **{**kwargs, "corners": True, "rotinv": False})
        return []

    monkeypatch.setattr(pipe, "vertex_hypotheses", moved_to_the_fallback)
    monkeypatch.setattr(pipe, "_plane_pairs", lambda *a, **k: [])
    loc = localize_cloud(model, pts, viewpoint=eye)
    assert calls == ["fallback"]
    assert loc.found and loc.best is not None
    pos, rot = pose_error(loc.best.matrix, T)
    assert rot < 1.0 and pos < 0.001, (rot, pos)


@dataclass(frozen=True)
class _OracleModel:
    """A protocol model whose hypotheses are perturbed truths (tests the ICP path)."""

    name: str
    truth: np.ndarray
    pts: np.ndarray
    nrm: np.ndarray

    def hypotheses(self, scene_points, scene_normals):
        T = self.truth.copy()
        T[:3, 3] += [0.003, -0.002, 0.001]
        return [PoseHypothesis(T, T[:3, 3], votes=1)]

    def surface_points(self):
        return self.pts

    def surface_normals(self):
        return self.nrm

    def symmetries(self):
        return None


def test_protocol_model_is_refined_by_the_pipeline() -> None:
    rng = np.random.default_rng(400)
    mesh = industrial_part_mesh()
    T = make_transform(random_rotation(rng), [0.1, 0.0, 0.2])
    pts, nrm = sample_surface(mesh, 3000, rng=rng)
    model = _OracleModel("oracle", T, pts, nrm)
    assert isinstance(model, LocalizableModel)
    scene = apply(T, sample_surface(mesh, 2000, rng=rng)[0])
    loc = localize_cloud(model, scene, table="none")
    assert loc.found
    pos, rot = pose_error(loc.best.matrix, T)
    assert pos < 0.0005 and rot < 0.5


def test_nan_points_are_dropped_and_counted(cube_model: PolyhedralModel) -> None:
    rng = np.random.default_rng(500)
    T = make_transform(random_rotation(rng), [0.0, 0.0, 0.0])
    pts = apply(T, sample_surface(box_mesh(SIZE), 2000, rng=rng)[0])
    pts[::10] = np.nan
    loc = localize_cloud(cube_model, pts, table="none")
    assert loc.dropped_nan == 200 and loc.found


def test_scale_maps_a_millimetre_model_to_a_metre_scene() -> None:
    model_mm = PolyhedralModel.from_mesh(box_mesh(SIZE * 1000), "cube_mm")
    rng = np.random.default_rng(600)
    T = make_transform(random_rotation(rng), [0.1, 0.2, 0.3])
    pts = apply(T, sample_surface(box_mesh(SIZE), 2000, rng=rng)[0])
    loc = localize_cloud(model_mm, pts, scale=0.001, table="none")
    assert loc.found
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert pos < 0.001 and rot < 1.0


def test_cli_localize_cloud_json_against_known_pose(tmp_path, capsys) -> None:
    rng = np.random.default_rng(700)
    T = make_transform(_rot_z(0.4), [0.01, 0.02, SIZE / 2])
    eye = EYES[0]
    pts = _table_scan(box_mesh(SIZE), T, eye, rng)
    pts[::40] = np.nan  # a sensor's misses
    scene = tmp_path / "scan.ply"
    write_ply(scene, pts)
    model = tmp_path / "cube.stl"
    write_stl(model, box_mesh(SIZE))
    code = main(["localize-cloud", "--model", str(model), "--scene", str(scene), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["found"] is True
    assert out["dropped_nan"] == int(np.isnan(pts[:, 0]).sum())
    # a 200 x 150 scan: averaged; the object again only on cells >= 1.2 voxels, if at all
    assert out["voxel"] > 0
    assert out["object_voxel"] == 0.0 or out["object_voxel"] >= 1.2 * out["voxel"]
    best = out["hypotheses"][0]
    assert set(best) >= {"matrix", "votes", "score", "rmse"}
    M = np.array(best["matrix"])
    assert M.shape == (4, 4) and np.allclose(M[3], [0, 0, 0, 1])
    pos, rot = pose_error(M, T, cube_rotations())
    assert rot < 1.0 and pos < 0.001
    # text output
    assert main(["localize-cloud", "--model", str(model), "--scene", str(scene)]) == 0
    assert "FOUND" in capsys.readouterr().out


def test_cli_bad_inputs_exit_2_with_a_message(tmp_path, capsys) -> None:
    model = tmp_path / "cube.stl"
    write_stl(model, box_mesh(SIZE))
    bad = tmp_path / "bad.ply"
    bad.write_text("this is not a ply file\n")
    empty = tmp_path / "empty.npy"
    np.save(empty, np.zeros((0, 3)))
    cases = [
        (["--model", str(model), "--scene", str(tmp_path / "missing.ply")], "not found"),
        (["--model", str(model), "--scene", str(bad)], "bad.ply"),
        (["--model", str(model), "--scene", str(empty)], "points"),
        (["--model", str(tmp_path / "nope.stl"), "--scene", str(bad)], "not found"),
        (["--model", "no_such_model", "--scene", str(bad)], "no_such_model"),
        (["--model", str(model), "--scene", str(bad), "--scale", "-1"], "scale"),
    ]
    for args, message in cases:
        assert main(["localize-cloud", *args]) == 2
        err = capsys.readouterr().err
        assert "error" in err and message in err and "Traceback" not in err


def test_library_bad_inputs(cube_model: PolyhedralModel) -> None:
    with pytest.raises(DataError, match=r"expected \(N, 3\)"):
        localize_cloud(cube_model, np.zeros((10, 2)))
    with pytest.raises(DataError, match="at least 10 finite"):
        localize_cloud(cube_model, np.full((50, 3), np.nan))
    with pytest.raises(DataError, match="table must be"):
        localize_cloud(cube_model, np.zeros((20, 3)), table="sometimes")  # type: ignore[arg-type]
    for budget in ({"max_points": 0}, {"object_points": 0}, {"object_points": 2.5}):
        with pytest.raises(DataError, match="must be an integer >= 1"):
            localize_cloud(cube_model, np.zeros((20, 3)), **budget)  # type: ignore[arg-type]
    with pytest.raises(NotFound, match="not found"):
        load_model("/nonexistent/model.stl")
    with pytest.raises(DataError, match="LocalizableModel"):
        localize_cloud(object(), np.zeros((20, 3)))
    with pytest.raises(DataError, match="vertexes"):
        PolyhedralModel.from_vertexes(np.zeros((3, 3)))
    # nothing there: not found, no exception
    rng = np.random.default_rng(0)
    loc = localize_cloud(cube_model, rng.uniform(-1, 1, (300, 3)), table="none")
    assert not loc.found


def test_paper_cube_from_the_model_database() -> None:
    # Section 4.2: the detected cube is the model cube translated by 5 units along x.
    rng = np.random.default_rng(800)
    T = make_transform(np.eye(3), [5.0, 0.0, 0.0])
    pts = apply(T, sample_surface(box_mesh(2.0), 2500, rng=rng)[0])
    loc = localize_cloud("paper_cube", pts, table="none")
    assert loc.found
    pos, rot = pose_error(loc.best.matrix, T, cube_rotations())
    assert pos < 0.02 and rot < 1.0
    with pytest.raises(DataError, match="control points"):
        load_model("paper_renault")


def test_free_form_model_by_database_name_on_a_part_scan(tmp_path, capsys) -> None:
    from mks_sim.geometry.meshes import industrial_part_mesh

    rng = np.random.default_rng(810)
    T = make_transform(_rot_z(2.1), [0.01, -0.015, 0.0])  # resting on its bottom face
    pts = _table_scan(industrial_part_mesh(), T, EYES[1], rng, width=240, height=180)
    scene = tmp_path / "part_scan.ply"
    write_ply(scene, pts)
    code = main(["localize-cloud", "--model", "part_freeform", "--scene", str(scene), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["found"] is True and out["warnings"] == []
    pos, rot = pose_error(np.array(out["hypotheses"][0]["matrix"]), T)
    assert pos < 0.002 and rot < 2.0


def test_model_and_scene_in_different_units_warn_and_scale_fixes_it(
    tmp_path, capsys, caplog
) -> None:
    rng = np.random.default_rng(820)
    T = make_transform(_rot_z(0.7), [0.0, 0.01, SIZE / 2])
    scene = tmp_path / "scan_m.ply"
    write_ply(scene, _table_scan(box_mesh(SIZE), T, EYES[0], rng))
    model_mm = tmp_path / "cube_mm.stl"
    write_stl(model_mm, box_mesh(SIZE * 1000))  # CAD in millimetres, scan in metres
    main(["localize-cloud", "--model", str(model_mm), "--scene", str(scene), "--json"])
    captured = capsys.readouterr()
    (warning,) = json.loads(captured.out)["warnings"]
    assert "--scale 0.001" in warning
    assert any("--scale 0.001" in r.getMessage() for r in caplog.records)  # logged as well
    args = ["--model", str(model_mm), "--scene", str(scene), "--scale", "0.001", "--json"]
    assert main(["localize-cloud", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["found"] and out["warnings"] == []
    pos, rot = pose_error(np.array(out["hypotheses"][0]["matrix"]), T, cube_rotations())
    assert pos < 0.001 and rot < 1.0


def test_full_resolution_polish_leaves_the_table_out() -> None:
    """The polish's ICP on the raw points near a pose: with the table's points within the
    band left out, a pose 0.7 mm off comes back within 0.09 mm of the truth; with them, the
    table's points near the part's lowest faces pull it (checked against the truth: on
    average more than twice as far off)."""
    from mks_sim.localization.pipeline import _polish_full_resolution
    from mks_sim.lowlevel.regions import Plane

    part = industrial_part_mesh()
    model = PolyhedralModel.from_mesh(part, "part")
    table = Plane(np.array([0.0, 0.0, 1.0]), 0.0)
    errors: dict[bool, list[float]] = {True: [], False: []}
    for seed in range(4):
        rng = np.random.default_rng(seed)
        T = make_transform(_rot_z(rng.uniform(0, 2 * np.pi)), [0.01, -0.02, 0.0])
        az = rng.uniform(0, 2 * np.pi)
        eye = np.array([0.45 * np.cos(az), 0.45 * np.sin(az), 0.4])
        raw = synthetic_scan(
            part, T, eye, [0.0, 0.0, 0.0], width=240, height=180, fov_deg=22,
            noise_sigma=0.0003, rng=rng, extra=[TABLE],
        )  # fmt: skip
        T0 = T.copy()
        T0[:3, 3] += [0.0005, -0.0003, 0.0004]
        start = PoseHypothesis(T0, T0[:3, 3])
        for leave_out in (True, False):
            polished = _polish_full_resolution(
                start, model.surface, raw, 0.0012, np.random.default_rng(0),
                table if leave_out else None, 0.0015,
            )  # fmt: skip
            errors[leave_out].append(pose_error(polished.matrix, T)[0])
    assert max(errors[True]) < 0.09e-3, errors
    assert np.mean(errors[True]) < 0.5 * np.mean(errors[False]), errors


@pytest.mark.parametrize("brute", [True, False])
def test_one_spg_gives_the_components_and_the_segments_graphs(
    brute: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """localize_cloud builds one thresholded SPG of the object points and takes each
    component's SPG from it (the rows the threshold cut asked anew: by brute force in the
    compiled pass, or by the grid): checked against the graphs built directly, to the bit,
    on clusters with stray points, ties (a rounded grid) and components whose rows the
    threshold cut."""
    from scipy.sparse import csgraph

    import mks_sim.localization.pipeline as pipeline
    from mks_sim.localization.pipeline import _segment_graph
    from mks_sim.lowlevel.normals import build_graph

    if not brute:
        monkeypatch.setattr(pipeline, "_BRUTE_CUT_WORK", 0)
    rng = np.random.default_rng(11)
    n_cut = 0
    for trial in range(6):
        # patches of surface (as a scan samples one), tilted
        blobs = []
        for c in rng.uniform(-0.1, 0.1, size=(3, 3)):
            n = int(rng.integers(600, 1500))
            flat = np.column_stack([rng.uniform(0.0, 0.02, (n, 2)), rng.normal(0, 1e-4, n)])
            blobs.append(flat @ random_rotation(rng).T + c)
        if trial % 2:
            blobs = [np.round(b, 3) for b in blobs]  # ties on a millimetre grid
        blobs.append(rng.uniform(-0.15, 0.15, size=(5, 3)))  # stray points
        gap = 0.004 * (1 + trial % 3)
        # a sparse patch (about ten points within the gap of each): rows the threshold cuts
        flat = np.column_stack([rng.uniform(0.0, 5 * gap, (80, 2)), rng.normal(0, 1e-4, 80)])
        blobs.append(flat @ random_rotation(rng).T + 0.3)
        pts = np.unique(np.concatenate(blobs), axis=0)
        rng.shuffle(pts)
        adj = build_graph(pts, m=12, threshold=gap).adjacency
        _, comp = csgraph.connected_components(adj, directed=True, connection="weak")
        for c in range(comp.max() + 1):
            members = np.flatnonzero(comp == c)
            if len(members) <= 12:
                continue
            own = build_graph(pts[members], m=12).adjacency
            graph = _segment_graph(adj, members, pts[members], 12)
            if graph is None:  # a cut row the grid cannot prove: the caller builds the SPG
                continue
            sub = graph.adjacency
            n_cut += int(np.sum(np.diff(adj.indptr)[members] < 12))
            assert np.array_equal(sub.indptr, own.indptr)
            assert np.array_equal(sub.indices, own.indices)
            assert sub.data.tobytes() == own.data.tobytes()
    assert n_cut >= 100  # rows the threshold cut were among those answered


def test_cut_rows_by_brute_force_give_up_on_a_tie_at_the_mth_neighbour() -> None:
    """On a lattice the 12th neighbour of a point ties with others left out (the index would
    have to settle which): the brute-force rows give up (the grid's rule), and
    _segment_graph still returns the SPG built directly, by the grid or as None."""
    from mks_sim.localization.pipeline import _segment_graph
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.normals import build_graph

    if not _gridknn.available():
        pytest.skip("numba not importable")
    g = np.arange(7) * 0.001
    pts = np.stack(np.meshgrid(g, g, [0.0]), axis=-1).reshape(-1, 3)
    adj = build_graph(pts, m=12, threshold=1e-6).adjacency  # every row cut
    members = np.arange(len(pts))
    ok, *_ = _gridknn.induced_rows(adj, members, pts, 12)
    assert not ok
    graph = _segment_graph(adj, members, pts, 12)
    if graph is not None:
        own = build_graph(pts, m=12).adjacency
        assert np.array_equal(graph.adjacency.indices, own.indices)


def test_plane_pair_poses_compiled_as_by_numpy() -> None:
    """``plane_pair_hypotheses(compiled=True)``: the same poses, in the same order, as the
    numpy pass (within 1e-12), from pairs of the part's own faces seen under random poses
    (with and without their points, the table's case), and the true pose among them."""
    from mks_sim.localization.hypotheses import _plane_pair_poses, plane_pair_hypotheses
    from mks_sim.lowlevel import _gridknn
    from mks_sim.lowlevel.regions import Plane

    if not _gridknn.available():
        pytest.skip("needs numba")
    from mks_sim.models._refine_kernels import plane_pair_poses

    model = PolyhedralModel.from_mesh(industrial_part_mesh(), "part")
    model.surface.with_lookup()
    extremes, offsets = model.face_extremes
    pa, pb, pcos, pframes = model.face_pairs
    rng = np.random.default_rng(12)
    cos_tol, slack = float(np.sin(np.radians(8.0))), 0.002
    n_poses = 0
    for _ in range(8):
        T = make_transform(random_rotation(rng), rng.normal(0, 0.1, 3))
        faces = [model.faces[i] for i in rng.choice(len(model.faces), 4, replace=False)]
        planes = []
        for k, face in enumerate(faces):
            n = T[:3, :3] @ face.normal
            pts = face.points @ T[:3, :3].T + T[:3, 3] + rng.normal(0, 2e-4, face.points.shape)
            planes.append((Plane(n, float(n @ T[:3, 3] + face.offset)), None if k == 3 else pts))
        numpy_poses = _plane_pair_poses(planes, extremes, offsets, model.face_pairs, cos_tol, slack)
        sampled = np.array([p is not None for _, p in planes])
        chunks = [np.zeros((0, 3)) if p is None else p for _, p in planes]
        starts = np.concatenate([[0], np.cumsum([len(c) for c in chunks])]).astype(np.int64)
        compiled_poses = plane_pair_poses(
            np.array([P.normal for P, _ in planes]), np.array([P.offset for P, _ in planes]),
            starts, sampled, np.ascontiguousarray(np.concatenate(chunks)),
            np.ascontiguousarray(extremes), offsets, pa.astype(np.int64), pb.astype(np.int64),
            pcos, np.ascontiguousarray(pframes), cos_tol, slack,
        )  # fmt: skip
        assert len(compiled_poses) == len(numpy_poses)
        if numpy_poses:
            assert np.abs(compiled_poses - np.stack(numpy_poses)).max() < 1e-12
        n_poses += len(numpy_poses)
        scene = np.concatenate([p for _, p in planes if p is not None])
        for compiled in (False, True):
            hyps = plane_pair_hypotheses(
                model, planes, scene, inlier_distance=0.001, keep=1000, compiled=compiled
            )
            best = min(pose_error(h.matrix, T) for h in hyps)
            assert best[0] < 0.002 and best[1] < 1.0, best
    assert n_poses > 100


def test_vertex_hypotheses_compiled_as_by_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """``vertex_hypotheses(compiled=True)``: the same hypotheses in the same order (votes,
    corner correspondences, matrices within 1e-12) as the numpy pass, on the vertexes the
    grouping finds in one-sided scans of the part and the cube; and the compiled Kabsch
    step is ``rotation_from_covariance`` (reflections included) within 1e-10."""
    import mks_sim.localization.pipeline as pipe
    from mks_sim.geometry.transforms import rotation_from_covariance
    from mks_sim.localization.hypotheses import vertex_hypotheses
    from mks_sim.lowlevel import _gridknn

    if not _gridknn.available():
        pytest.skip("needs numba")
    from mks_sim.models._refine_kernels import _kabsch3

    rng = np.random.default_rng(13)
    R, X, Y = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for k in range(3000):
        H = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 3)
        if k % 2:  # near a rotation (or its mirror): the matcher's case
            Q = random_rotation(rng) * (1 if k % 4 == 1 else -1)
            H = Q @ np.diag(rng.uniform(0.2, 2.0, 3))
        _kabsch3(H, X, Y, R)
        assert np.abs(R - rotation_from_covariance(H)).max() < 1e-10, k
    seen: list[tuple] = []
    real = pipe.vertex_hypotheses

    def both(model, detected, pts, **kwargs):  # type: ignore[no-untyped-def]
        seen.append((model, detected, pts, kwargs))
        return real(model, detected, pts, **kwargs)

    monkeypatch.setattr(pipe, "vertex_hypotheses", both)
    model, _, eye, pts = _part_view()
    localize_cloud(model, pts, viewpoint=eye)
    cube = PolyhedralModel.from_mesh(box_mesh(0.05), "cube")
    T = make_transform(_rot_z(0.4), [0.01, -0.02, 0.025])
    localize_cloud(cube, _table_scan(box_mesh(0.05), T, EYES[0], rng), viewpoint=EYES[0])
    n_hyps = 0
    for model, detected, pts, kwargs in seen:
        if kwargs.get("corners") is False or len(detected) == 0:
            continue
        kwargs = {k: v for k, v in kwargs.items() if k not in ("compiled", "rotinv")}
        # (without the rotation-invariant Hough's maxima the compiled poses are ranked as
        # arrays, the workstation's way; with them, as a list with those maxima)
        for rotinv in (True, False):
            a = vertex_hypotheses(model, detected, pts, **kwargs, rotinv=rotinv, compiled=False)
            b = vertex_hypotheses(model, detected, pts, **kwargs, rotinv=rotinv, compiled=True)
            assert len(a) == len(b)
            for x, y in zip(a, b, strict=True):
                assert x.votes == y.votes
                assert np.array_equal(np.asarray(x.correspondences), np.asarray(y.correspondences))
                assert np.abs(x.matrix - y.matrix).max() < 1e-12
                assert np.abs(x.reference_point - y.reference_point).max() < 1e-12
            n_hyps += len(a) * (not rotinv)
    assert n_hyps > 20


def test_table_tests_compiled_as_by_numpy() -> None:
    """``find_table`` without ``near_z``: the compiled band and footprint tests
    (``_support``) give numpy's answer (``_support_numpy``) for the same plane -- the same
    plane, band and band mask, or the same refusal -- on table scans with objects, a scan
    seen from below (refused: the table faces away) and a plane with nothing on it
    (refused: no objects)."""
    import mks_sim.localization.verify as vf
    from mks_sim.localization.representation import spacing_and_noise
    from mks_sim.lowlevel.regions import fit_plane_ransac

    if not vf._gridknn.available():
        pytest.skip("needs numba")
    rng = np.random.default_rng(14)
    clouds = []
    for k in range(4):
        T = make_transform(_rot_z(0.3 * k), [0.01 * k, -0.01, 0.025])
        clouds.append((_table_scan(box_mesh(0.05), T, EYES[k % 2], rng), EYES[k % 2]))
    clouds.append((clouds[0][0], np.array([0.3, 0.2, -0.4])))  # the eye under the table
    flat = np.column_stack([rng.uniform(-0.2, 0.2, (3000, 2)), rng.normal(0, 2e-4, 3000)])
    clouds.append((flat, EYES[0]))
    found = []
    for pts, eye in clouds:
        spacing, noise = spacing_and_noise(pts, np.random.default_rng(0))
        threshold = max(spacing, 3.0 * noise)
        plane, _ = fit_plane_ransac(pts, threshold, np.random.default_rng(1), iterations=150)
        pa, ba, ma = vf._support(pts, plane, threshold, spacing, eye, 0.2)
        pb, bb, mb = vf._support_numpy(pts, plane, threshold, spacing, eye, 0.2)
        assert (pa is None) == (pb is None)
        found.append(pa is not None)
        if pa is not None and pb is not None:
            assert np.array_equal(pa.normal, pb.normal) and pa.offset == pb.offset
            assert abs(ba - bb) < 1e-15 and np.array_equal(ma, mb)
            assert pa.normal[2] > 0.99  # the table, facing the objects
    assert found == [True, True, True, True, False, False]
