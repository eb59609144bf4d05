"""Multi-instance localization (issue 13): every instance of a model, none twice."""

from __future__ import annotations

import numpy as np
import pytest

from mks_sim.geometry.meshes import box_mesh, industrial_part_mesh
from mks_sim.geometry.scan import synthetic_scan
from mks_sim.geometry.transforms import rotation_angle_deg
from mks_sim.localization.instances import instance_model, localize_all
from mks_sim.lowlevel.regions import Plane

TABLE_Z = 0.75
EYES = ((0.38, -0.28, 1.07), (-0.38, -0.28, 1.07))  # the workstation's range-finder mounts
TARGET = (0.0, 0.0, 0.78)


def _pose(x: float, y: float, yaw_deg: float, z: float = TABLE_Z, tilt_deg: float = 0.0):
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZX", [yaw_deg, tilt_deg], degrees=True).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


# Three parts on the table, two of them touching (their footprints 2 mm apart at the
# closest), the third on its side (rolled 90 deg about its x axis).
POSES = (
    _pose(-0.055, 0.01, 20.0),
    _pose(0.043, 0.035, -35.0),
    _pose(0.02, -0.06, 100.0, z=TABLE_Z + 0.03, tilt_deg=90.0),
)


def _scan(poses, eyes=EYES[:1], rng_seed=0):
    mesh = industrial_part_mesh()
    table = box_mesh((0.5, 0.5, 0.02))
    T_table = np.eye(4)
    T_table[:3, 3] = (0.0, 0.0, TABLE_Z - 0.01)
    clouds = []
    for k, eye in enumerate(eyes):
        others = [(mesh, T) for T in poses[1:]] + [(table, T_table)]
        clouds.append(
            synthetic_scan(
                mesh,
                poses[0],
                eye,
                TARGET,
                width=320,
                height=240,
                fov_deg=40.0,
                noise_sigma=0.0003,
                rng=np.random.default_rng(rng_seed + k),
                extra=others,
            )  # fmt: skip
        )
    return np.concatenate(clouds)


def _errors(found, truth):
    """Per true pose: (mm, deg) of the nearest found pose."""
    out = []
    for G in truth:
        best = min(found, key=lambda E: np.linalg.norm(E[:3, 3] - G[:3, 3]))
        out.append(
            (
                1000 * np.linalg.norm(best[:3, 3] - G[:3, 3]),
                rotation_angle_deg(best[:3, :3], G[:3, :3]),
            )
        )
    return out


TABLE = Plane(np.array([0.0, 0.0, 1.0]), TABLE_Z, 0.0003)


def test_three_touching_parts_all_found_once():
    # the third part rests on its side: check the pose is physically plausible (on the table)
    model = instance_model("part")
    pts = _scan(POSES)
    result = localize_all(model, pts, table=TABLE, rng=np.random.default_rng(0))
    found = [i.matrix for i in result.instances]
    assert len(found) == 3, [np.round(T[:3, 3], 3) for T in found]
    for mm, deg in _errors(found, POSES):
        assert mm < 5.0 and deg < 5.0, (mm, deg)
    # brute force: no two reported poses are one instance
    c = np.array([T[:3, 3] for T in found])
    assert min(np.linalg.norm(c[i] - c[j]) for i in range(3) for j in range(i)) > 0.03
    assert all(0.0 < i.score <= 1.0 for i in result.instances)
    scores = [i.score for i in result.instances]
    assert scores == sorted(scores, reverse=True)


def test_an_instance_seen_from_two_views_is_reported_once():
    # Two range-finder views of one part: twice the evidence on the same surfaces, and
    # the two views' points do not coincide -- still one instance.
    model = instance_model("part")
    pts = _scan(POSES[:1], eyes=EYES)
    result = localize_all(model, pts, table=TABLE, rng=np.random.default_rng(0))
    assert result.found == 1
    ((mm, deg),) = _errors([i.matrix for i in result.instances], POSES[:1])
    assert mm < 5.0 and deg < 5.0


def test_nothing_in_an_empty_scene_and_bad_input():
    from mks_sim.errors import DataError

    model = instance_model("part")
    rng = np.random.default_rng(0)
    table = rng.uniform(-0.1, 0.1, (2000, 3))
    table[:, 2] = TABLE_Z + rng.normal(0, 0.0003, 2000)
    assert localize_all(model, table, table=TABLE).found == 0
    with pytest.raises(DataError, match=r"expected \(N, 3\) points, got shape \(5, 2\)"):
        localize_all(model, np.zeros((5, 2)))


@pytest.mark.slow
def test_sim_bin_of_three_parts_localized(capsys):
    import json

    from mks_sim.cli import main

    argv = ["localize", "--scene", "bin", "--object", "part", "--all", "--count", "3"]
    assert main([*argv, "--seed", "1", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["present"] == 3
    assert rec["found"] == 3 and rec["correct"] == 3 and rec["false_positives"] == 0, rec
    for inst in rec["instances"]:
        assert inst["error"]["position_mm"] < 5.0 and inst["error"]["rotation_deg"] < 5.0
        assert 0.0 < inst["visible_fraction"] <= 1.0
    # the views' fused sensor, served by the range finder alone (one view: its scan)
    assert rec["provenance"]["Fused_Points"] == "primary"
    assert rec["view_names"][0] == "range_finder#0" and rec["views"] == len(rec["view_names"])


@pytest.mark.slow
@pytest.mark.parametrize("seed", [22, 26, 32, 42, 55])
def test_six_part_bins_without_the_turned_parts_reported(seed):
    """Tuning bins where a part was reported turned (simulator truth, evaluation only):
    bin 32, the vote's candidate 5.6 mm off failed and its near-twin passed, polished to
    0.1 mm and 180 deg off (571 points; the twin of the polished pose explains 589 and sees
    nothing through itself); bin 26, a part reported turned over about its y axis (0.8 mm,
    179.5 deg, 8 points seen through it; the truth explains 1492 points to its 1135); bin 55,
    a part 41 % visible reported turned 180 deg about its height axis and slid 19.8 mm along
    its length (5 points seen through it); bin 22, a part 36 % visible reported 4.1 mm and
    18.7 deg off (1181 points, 6 seen through it; the truth 1254 and none: a nudge); bin 42,
    a part 30 % visible reported as its near-twin (697 points, 5 seen through it; the truth
    694 and none: the points seen through weigh). Every reported instance is correct and
    every instance >= 30 % visible but one is found."""
    from mks_sim.tasks.bin import run_localize_all

    rec = run_localize_all(seed)
    assert rec["present"] == 6
    assert rec["false_positives"] == 0, [i["error"] for i in rec["instances"]]
    visible_missed = [m for m in rec["missed"] if m["visible_fraction"] >= 0.3]
    assert len(visible_missed) <= 1, visible_missed


@pytest.mark.slow
def test_a_pose_its_points_do_not_pin_down_is_not_reported():
    """Tuning bin 18 (simulator truth, evaluation only): a part 21 % visible was reported
    4.1 mm and 5.1 deg off, nothing seen through it, 503 points against the truth's 506 --
    its points leave one motion nearly free (stability 0.0022, the true instances of bins
    0-59 0.0052 and up). It is found but not reported; the others are, each correct."""
    from mks_sim.tasks.bin import run_localize_all

    rec = run_localize_all(18)
    assert rec["false_positives"] == 0, [i["error"] for i in rec["instances"]]
    assert rec["unsure"] == 1
    assert rec["found"] == 5 and rec["present"] == 6
    assert all(i["stability"] >= 0.0035 for i in rec["instances"])


@pytest.mark.slow
def test_a_prior_seen_through_gives_way_to_its_near_twin():
    """Tuning bin 58 with the range finder failed (simulator truth, evaluation only): the
    wrist camera's first view reported two parts turned 180 deg about their height axes;
    kept as priors, the fused views saw 1 and 4 points through them, and their near-twins --
    the truth -- explain more (1479 against 1429, 1943 against 1903) and see none. The twin
    of a prior seen through now competes: no false positive, every part >= 30 % visible
    found."""
    from mks_sim.tasks.bin import run_localize_all

    rec = run_localize_all(58, fail=("range_finder",))
    assert rec["present"] == 6 and rec["views"] >= 2
    assert rec["false_positives"] == 0, [i["error"] for i in rec["instances"]]
    assert not [m for m in rec["missed"] if m["visible_fraction"] >= 0.3], rec["missed"]


@pytest.mark.slow
def test_tight_pile_found_with_the_alternate_model():
    """Tuning bin 40, a tight pile: the polyhedral votes found 1 of its 6 parts (three 34-52 %
    visible missed, every candidate near one of them 17-22 mm off); the segments that no
    candidate fits vote again with the part's free-form model (its ``freeform`` kind in the
    database). Simulator truth, evaluation only: every instance >= 30 % visible found, no
    false positive."""
    from mks_sim.tasks.bin import run_localize_all

    rec = run_localize_all(40)
    assert rec["present"] == 6
    assert rec["false_positives"] == 0, [i["error"] for i in rec["instances"]]
    assert rec["correct"] >= 5
    assert not [m for m in rec["missed"] if m["visible_fraction"] >= 0.3], rec["missed"]


def test_alternate_model_comes_from_the_object_kinds():
    from mks_sim.localization.instances import instance_alternate
    from mks_sim.models.freeform import FreeformModel
    from mks_sim.models.objects import load_object

    alt = instance_alternate("part")
    assert "freeform" in load_object("part").kinds and isinstance(alt, FreeformModel)
    assert instance_alternate("part") is alt  # built once
    assert "freeform" not in load_object("cube").kinds and instance_alternate("cube") is None


def test_cli_all_bad_input():
    from mks_sim.cli import main

    argv = ["localize", "--object", "part", "--all", "--seed", "1"]
    assert main([*argv, "--count", "13"]) == 2
    assert main([*argv, "--fail", "laser"]) == 2


def test_bin_text_reports_name_failed_devices_and_alternates():
    from mks_sim.cli._bin import _fault_lines

    rec = {
        "faults": ["range_finder", "wrist_camera"],
        "fault_reasons": {"wrist_camera": "x"},
        "warnings": ["Fused_Points ran on alternate Stereo_View"],
    }
    assert _fault_lines(rec) == [
        "fault: range_finder: failed",
        "fault: wrist_camera: x",
        "warning: Fused_Points ran on alternate Stereo_View",
    ]


def test_prior_poses_are_checked_kept_once_and_wrong_ones_dropped():
    # An earlier view's estimates (active sensing): the true poses off by 2 mm / 2 deg are
    # polished and kept without any voting (max_passes=0), a repeat of one is not reported
    # twice, and poses the points contradict -- floating over empty table, sunk through the
    # table -- are dropped.
    model = instance_model("part")
    pts = _scan(POSES)
    near = []
    for G in POSES:
        T = G.copy()
        T[:3, :3] = _pose(0.0, 0.0, 2.0)[:3, :3] @ G[:3, :3]
        T[:3, 3] += [0.002, 0.0, 0.0]
        near.append(T)
    floating = _pose(0.15, 0.15, 0.0)
    sunk = _pose(0.0, -0.06, 0.0, z=TABLE_Z - 0.01)
    prior = [near[0], POSES[0], floating, near[1], sunk, near[2]]
    result = localize_all(
        model, pts, table=TABLE, rng=np.random.default_rng(0), prior=prior, max_passes=0
    )
    found = [i.matrix for i in result.instances]
    assert len(found) == 3, [np.round(T[:3, 3], 3) for T in found]
    for mm, deg in _errors(found, POSES):
        assert mm < 1.0 and deg < 1.0, (mm, deg)
    # and with voting, the priors do not come back twice
    again = localize_all(model, pts, table=TABLE, rng=np.random.default_rng(0), prior=prior)
    assert again.found == 3


def test_the_part_has_one_near_twin_and_the_cube_none():
    """The industrial part turned half round about its height axis (z, through the centre
    of its bounding box) lands mostly on itself; no other half turn does. The cube's half
    turns are exact symmetries (its 24 rotations given): none is a near-twin. Checked by
    brute force: the turned samples' median distance to the nearest sample."""
    from mks_sim.geometry.meshes import sample_surface
    from mks_sim.geometry.transforms import cube_rotations
    from mks_sim.models.refine import near_symmetries

    pts = sample_surface(industrial_part_mesh(), 4000, rng=np.random.default_rng(0))[0]
    twins = near_symmetries(pts)
    assert len(twins) == 1
    R = twins[0][:3, :3]
    assert rotation_angle_deg(R, np.diag([-1.0, -1.0, 1.0])) < 1.0
    c = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    assert np.allclose(twins[0][:3, 3], c - R @ c)
    moved = pts @ R.T + twins[0][:3, 3]
    brute = np.sqrt(((moved[::20, None] - pts[None]) ** 2).sum(-1)).min(axis=1)
    assert np.median(brute) < 0.003
    cube = sample_surface(box_mesh(0.05), 3000, rng=np.random.default_rng(1))[0]
    assert len(near_symmetries(cube, cube_rotations())) == 0


def _found_from_one_vote(monkeypatch, truth, vote):
    """``localize_all`` on a scan of one part at ``truth`` when every vote proposes only the
    pose ``vote``: (found, (mm, deg) of the nearest found pose from the truth)."""
    import mks_sim.localize as loc_mod
    from mks_sim.models.pose import PoseHypothesis

    real = loc_mod.localize_cloud

    def vote_only(model_, points, **kwargs):  # noqa: ANN001, ANN202, ANN003
        out = real(model_, points, **kwargs)
        h = PoseHypothesis(vote, vote[:3, 3].copy(), votes=10)
        return type(out)(**{**out.__dict__, "hypotheses": (h,), "segment_of": (0,)})

    monkeypatch.setattr(loc_mod, "localize_cloud", vote_only)
    pts = _scan((truth,))
    result = localize_all(instance_model("part"), pts, table=TABLE, rng=np.random.default_rng(0))
    if not result.found:
        return 0, None
    return result.found, _errors([i.matrix for i in result.instances], [truth])[0]


def test_a_near_twin_pose_from_the_vote_is_turned_back(monkeypatch):
    """The vote proposes only the part turned half round about its height axis (what tuning
    bin 9 reported, score 0.99): the near-twin check turns it back to the pose the points
    were scanned at."""
    truth = POSES[0]
    flipped = truth @ np.diag([-1.0, -1.0, 1.0, 1.0])  # the box is centred on x, y = 0
    found, err = _found_from_one_vote(monkeypatch, truth, flipped)
    assert found == 1
    mm, deg = err
    assert mm < 2.0 and deg < 2.0, (mm, deg)


def test_a_part_upside_down_is_found_from_its_upright_vote(monkeypatch):
    """The vote proposes only the part upright with its bottom face where the real part,
    lying upside down, shows its bottom (tuning bin 15: such candidates explained 270 of
    1150 points and the part was not found): turned over about a face of its bounding box,
    it is found at the pose the points were scanned at."""
    # upside down on the table: half round about its x axis, its 30 mm height below the
    # origin (the bottom face, z = 0 in the model frame) then facing up at 30 mm
    truth = _pose(-0.01, 0.02, 25.0, z=TABLE_Z + 0.03) @ np.diag([1.0, -1.0, -1.0, 1.0])
    upright = truth @ np.diag([1.0, -1.0, -1.0, 1.0])  # the same bottom face, body up
    assert _errors([upright], [truth])[0][1] > 170.0
    found, err = _found_from_one_vote(monkeypatch, truth, upright)
    assert found == 1
    mm, deg = err
    assert mm < 2.0 and deg < 2.0, (mm, deg)


def test_turned_over_poses_keep_a_face_in_place():
    """Each of the 15 half turns maps the model's bounding box onto itself or onto the box
    turned over about one of its faces' centre lines: brute force, the turned box's corners
    stay within the box grown by its extent along one axis only."""
    from mks_sim.geometry.meshes import sample_surface
    from mks_sim.localization.instances import _turned_over

    pts = sample_surface(industrial_part_mesh(), 3000, rng=np.random.default_rng(0))[0]
    flips = _turned_over(pts)
    assert flips.shape == (15, 4, 4)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    same_box = 0
    for S in flips:
        assert np.allclose(S[:3, :3] @ S[:3, :3], np.eye(3)) and np.isclose(
            np.linalg.det(S[:3, :3]), 1.0
        )
        moved = corners @ S[:3, :3].T + S[:3, 3]
        m_lo, m_hi = moved.min(axis=0), moved.max(axis=0)
        shift = np.round((m_lo - lo) / (hi - lo), 6)
        assert np.allclose(m_hi - m_lo, hi - lo)  # a half turn about a box axis keeps the box
        assert np.count_nonzero(shift) <= 1 and set(np.abs(shift)) <= {0.0, 1.0}, shift
        same_box += not np.any(shift)
    assert same_box == 3  # the turns through the box's centre


def test_two_parts_stacked_bottom_to_bottom_are_two_instances():
    """One part lies upside down on the table, another stands upright on it, bottom faces
    together, 20 mm apart along their length: their centres are 26 mm apart (under 0.25 x
    the part's 120 mm size, the
    distance that made two poses one instance), yet they share only the bottom face. The
    overlap of the two posed models is the shared bottom's share of the surface (brute force
    over the samples: those within 2 d of the model's z = 0 plane, over the other part),
    a pose and its 2 mm shifted copy overlap almost wholly; and both parts are found."""
    from mks_sim.localization.instances import SAME_OVERLAP, _overlap
    from mks_sim.models.refine import ModelSurface

    model = instance_model("part")
    sp = np.asarray(model.surface_points())
    surface = ModelSurface.from_arrays(sp, np.asarray(model.surface_normals()))
    d = 0.003
    lower = _pose(-0.02, 0.0, 0.0, z=TABLE_Z + 0.03) @ np.diag([1.0, -1.0, -1.0, 1.0])
    upper = _pose(0.0, 0.0, 0.0, z=TABLE_Z + 0.03)  # 20 mm along the parts' long axis
    centre = sp.mean(axis=0)
    gap = np.linalg.norm(
        (upper[:3, :3] @ centre + upper[:3, 3]) - (lower[:3, :3] @ centre + lower[:3, 3])
    )
    assert gap < 0.25 * surface.size
    samples = sp[:: max(1, len(sp) // 400)]
    # the upper part's samples on its bottom face over the lower part's (which reaches to
    # x = 30 mm in the upper part's frame)
    bottom = float(np.mean((np.abs(samples[:, 2]) <= 2 * d) & (samples[:, 0] <= 0.03 + 2 * d)))
    assert abs(_overlap(upper, lower, surface, d) - bottom) < 0.05, bottom
    assert _overlap(upper, lower, surface, d) < SAME_OVERLAP
    shifted = upper.copy()
    shifted[:3, 3] += [0.002, 0.0, 0.0]
    assert _overlap(shifted, upper, surface, d) > 0.95
    pts = _scan((upper, lower), eyes=EYES)  # both mounts: one sees little of the lower part
    result = localize_all(model, pts, table=TABLE, rng=np.random.default_rng(0))
    assert result.found == 2
    errors = _errors([i.matrix for i in result.instances], [upper, lower])
    assert all(mm < 2.0 and deg < 2.0 for mm, deg in errors), errors


def test_nudges_turn_about_the_box_centre_and_shift_along_its_axes():
    """The 12 nudges of a seen-through pose: 6 turns by 20 deg about the bounding box's
    axes that keep the box's centre in place, 6 shifts by the step along the axes (checked
    on the transforms applied to the box's corners, brute force)."""
    from mks_sim.geometry.meshes import sample_surface
    from mks_sim.localization.instances import _nudged

    pts = sample_surface(industrial_part_mesh(), 3000, rng=np.random.default_rng(0))[0]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid = 0.5 * (lo + hi)
    moves = _nudged(pts, 20.0, 0.005)
    assert moves.shape == (12, 4, 4)
    axes_turned, shifts = set(), []
    for S in moves[:6]:
        R = S[:3, :3]
        assert np.isclose(rotation_angle_deg(R, np.eye(3)), 20.0, atol=1e-6)
        assert np.allclose(R @ mid + S[:3, 3], mid)
        fixed = [k for k in range(3) if np.allclose(R[:, k], np.eye(3)[k])]
        assert len(fixed) == 1  # a turn about one box axis
        axes_turned.add(fixed[0])
    assert axes_turned == {0, 1, 2}
    for S in moves[6:]:
        assert np.allclose(S[:3, :3], np.eye(3))
        assert np.isclose(np.linalg.norm(S[:3, 3]), 0.005)
        shifts.append(tuple(np.round(S[:3, 3] / 0.005).astype(int)))
    assert sorted(shifts) == sorted(
        [tuple(s * np.eye(3, dtype=int)[k]) for k in range(3) for s in (1, -1)]
    )


class _Surface:
    """A model surface for pose_stability: points, normals and their tree (model frame)."""

    def __init__(self, points, normals):
        from scipy.spatial import cKDTree

        self.points, self.normals, self.tree = points, normals, cKDTree(points)


def _cube_surface(n=20, half=0.05):
    """Samples and outward normals of a cube's six faces (model frame, centred at 0)."""
    u = (np.arange(n) + 0.5) * (2 * half / n) - half  # cell centres: no sample on an edge
    a, b = (g.ravel() for g in np.meshgrid(u, u))
    pts, nrm = [], []
    for k in range(3):
        for sign in (1.0, -1.0):
            p = np.zeros((len(a), 3))
            p[:, k] = sign * half
            p[:, (k + 1) % 3], p[:, (k + 2) % 3] = a, b
            pts.append(p)
            nrm.append(np.tile(sign * np.eye(3)[k], (len(a), 1)))
    return np.vstack(pts), np.vstack(nrm)


def test_pose_stability_is_the_point_to_plane_cost_of_the_least_constrained_motion():
    """Brute force: the mean squared point-to-plane distance after a small motion (turn w
    about the centre, scaled by the radius, and shift t) is (w r, t)^T H (w r, t); the
    stability is H's smallest eigenvalue, so no random motion of unit size costs less, and
    the cheapest one found by sampling comes close to it."""
    from scipy.spatial.transform import Rotation

    from mks_sim.localization.instances import pose_stability

    pts, nrm = _cube_surface()
    surface = _Surface(pts, nrm)
    T = _pose(0.1, -0.05, 30.0, z=0.8, tilt_deg=20.0)
    radius = float(np.max(np.linalg.norm(pts, axis=1)))
    rng = np.random.default_rng(1)
    for faces in ([0], [0, 2], [0, 2, 4], [0, 1, 2, 3, 4, 5]):  # +x; +x +y; corner; all
        keep = np.isin(np.arange(len(pts)) // 400, faces)
        seen = pts[keep] @ T[:3, :3].T + T[:3, 3]
        s = pose_stability(T, surface, seen, np.zeros(3), radius)
        costs = []
        for _ in range(3000):
            m = rng.normal(size=6)
            m /= np.linalg.norm(m)
            eps = 1e-4
            R = Rotation.from_rotvec(eps * m[:3] / radius).as_matrix()
            q = pts[keep] @ R.T + eps * m[3:]  # the model moved by eps, in its own frame
            costs.append(np.mean(np.einsum("ij,ij->i", q - pts[keep], nrm[keep]) ** 2) / eps**2)
        assert min(costs) >= s - 1e-6
        assert min(costs) <= s + 0.02
        if len(faces) < 3:  # a face or two leave a shift along them free
            assert s < 1e-9
    assert s > 0.05  # the whole cube pins every motion (translation 1/3, turns about half)


def test_instances_whose_pose_is_not_pinned_are_not_reported():
    """The same scene with min_stability above what any pose can reach (1/3: normals evenly
    spread) reports nothing and keeps every instance as unsure; with 0 all are reported."""
    model = instance_model("part")
    pts = _scan(POSES[:2])
    rng = np.random.default_rng
    every = localize_all(model, pts, table=TABLE, rng=rng(0), min_stability=0.0)
    none = localize_all(model, pts, table=TABLE, rng=rng(0), min_stability=0.34)
    assert every.found == 2 and not every.unsure
    assert none.found == 0 and len(none.unsure) == 2
    assert all(0.0 < i.stability <= 1 / 3 + 1e-9 for i in every.instances)


def test_an_instance_seen_through_is_not_reported():
    """Points inside a part's solid (sensed through where the pose puts material) make its
    pose doubtful: 12 points deep inside the first of two parts (more than 0.3 % of the
    ~2,500 it explains, under the 1 % that lets it be accepted and claim its points) leave it
    found but unsure; the other part, and both with the limit at 1 %, are reported."""
    from scipy.spatial import cKDTree

    from mks_sim.localization.instances import MAX_INSIDE

    model = instance_model("part")
    sp, sn = np.asarray(model.surface_points()), np.asarray(model.surface_normals())
    q = np.random.default_rng(0).uniform(sp.min(axis=0), sp.max(axis=0), size=(20000, 3))
    dist, j = cKDTree(sp).query(q)
    deep = q[(dist > 0.006) & (np.einsum("ij,ij->i", q - sp[j], sn[j]) < 0)][:12]
    assert len(deep) == 12
    T = POSES[0]
    pts = np.concatenate([_scan(POSES[:2]), deep @ T[:3, :3].T + T[:3, 3]])
    rng = np.random.default_rng
    doubt = localize_all(model, pts, table=TABLE, rng=rng(0))
    lenient = localize_all(model, pts, table=TABLE, rng=rng(0), max_inside_reported=MAX_INSIDE)
    assert lenient.found == 2 and not lenient.unsure
    assert doubt.found == 1 and len(doubt.unsure) == 1
    (err_unsure,) = _errors([doubt.unsure[0].matrix], [T])
    (err_reported,) = _errors([doubt.instances[0].matrix], [POSES[1]])
    assert err_unsure[0] < 5.0 and err_unsure[1] < 5.0
    assert err_reported[0] < 5.0 and err_reported[1] < 5.0
    assert doubt.unsure[0].check.inside >= 10
