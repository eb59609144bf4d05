"""A free-form match that lands on the half-turned copy of a rounded shape is turned back:
``principal_half_turns`` and the restarts of ``_segment_verified`` (tuning seed 1042 of the
generated blob was localized 178 deg off about its long axis)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from mks_sim.geometry.meshes import Mesh
from mks_sim.geometry.scan import scan_scene
from mks_sim.geometry.transforms import pose_error
from mks_sim.localization.pipeline import _segment_verified
from mks_sim.models.freeform import FreeformModel
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import ModelSurface, principal_half_turns, verify_hypotheses

sys.path.insert(0, str(Path(__file__).parent))
import _gen_meshes as gen  # noqa: E402


def test_principal_half_turns_are_half_turns_about_the_axes() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(4000, 3)) * [3.0, 2.0, 1.0] + [1.0, -2.0, 0.5]
    c = pts.mean(axis=0)
    H = principal_half_turns(pts)
    assert H.shape == (3, 4, 4)
    for k in range(3):
        R = H[k, :3, :3]
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert np.isclose(np.trace(R), -1.0)  # a rotation by 180 deg
        assert np.allclose(H[k] @ np.append(c, 1.0), np.append(c, 1.0))  # centroid fixed
    # the axes are the principal ones: x, y, z here (variances 9, 4, 1)
    axes = sorted(np.argmax(np.abs(np.linalg.eigh(H[k, :3, :3])[1][:, -1])) for k in range(3))
    assert axes == [0, 1, 2]


def test_a_half_turned_start_is_turned_back() -> None:
    tm = gen.blob()
    mesh = Mesh(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64))
    model = FreeformModel.from_mesh(mesh, "blob")
    surface = ModelSurface.from_arrays(model.surface_points(), model.surface_normals())
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.0, 0.05]
    eye = np.array([0.25, 0.1, 0.3])
    pts = scan_scene(mesh, T, eye, T[:3, 3], width=160, height=120, fov_deg=30).points
    inlier = 1.0 * model.config.spacing
    rng = np.random.default_rng(0)
    # the start each half turn makes of the truth; keep the one ICP alone does not undo
    # (the check that this test can fail: with no restarts the answer stays turned)
    stuck = None
    for H in principal_half_turns(surface.points):
        start = PoseHypothesis(T @ H, T[:3, 3], votes=1)
        alone = verify_hypotheses([start], surface, pts, inlier_distance=inlier, rng=rng)
        if pose_error(alone[0].hypothesis.matrix, T)[1] > 90.0:
            stuck = start
            break
    assert stuck is not None, "every half turn converged back by ICP alone: nothing to test"
    out, _, _ = _segment_verified(
        None,
        [stuck],
        pts,
        lambda: [],
        inlier=inlier,
        cover_distance=1.5 * model.config.spacing,
        min_score=0.5,
        max_icp=4,
        verify_options={},
        rng=rng,
        surface=surface,
        symmetries=None,
    )
    pos, rot = pose_error(out[0][0].matrix, T)
    assert pos < 0.002 and rot < 3.0, (pos, rot)
