"""Free-form rotation-invariant Hough model (project issue #6; paper sections 2.2.1, 4.2, 5).

The paper's rotation-invariant 3-D Hough transform accumulates votes for the model reference
point ``P0`` at the intersections of spheres centred on detected points, with radii the model
points' distances to ``P0``; section 4.2 keeps the accumulator small by using a few
*recoverable* points (vertexes, or four control points). For a free-form object we choose those
points automatically:

1. **Recoverable points.** Configuration time samples the model surface and renders it from
   ``n_views`` viewpoints (``mks_sim.geometry.scan``). Candidate model points are surface
   samples whose surface variation is high (corners, rims, bumps); each gets one rotation-
   invariant signature *per view in which it is visible* (``mks_sim.geometry.keypoints``:
   variation, anisotropy, convexity at two scales), so that a partial scan's signature finds its
   model counterpart despite self-occlusion.
2. **Pairing.** At execution time the scene keypoints (local maxima of surface variation) are
   each paired with the ``matches_per_keypoint`` model points of nearest signature.
3. **Sphere intersections.** Three pairings whose scene distances equal their model distances
   (within ``distance_tolerance``) form congruent triangles; the intersection of the three
   spheres centred on the detected points, with radii the model points' distances to ``P0``, is
   the reference point's location - computed, together with the rotation, by a rigid fit of the
   triangle (the sphere intersection on the model's side of the triangle, the mirror one
   rejected). Every consistent triangle votes there.
4. **Accumulator maxima.** Votes are binned in a 3-D accumulator (bin ``bin_size``); at each of
   the ``max_peaks`` fullest cells the voting triangles are clustered by rotation (the paper's
   "any of the maxima may be chosen" for symmetric models: each cluster is a hypothesis).
5. **Verification.** Every hypothesis is refined by point-to-plane ICP and scored
   (``mks_sim.models.refine``); symmetric equivalents are reported once.

``P0`` is the centroid of the model surface: it lies on every symmetry axis, so that symmetric
equivalents vote for the same location (the paper's distinct-radii condition serves its
labelling step, which the triangle fit replaces).

This is not point-pair-feature voting: no feature of a pair of oriented points is hashed and
no (model point, angle) space is voted in; pairs are only checked for rigid distance
consistency, and votes go to the reference point's location as in the paper.

Hot paths are vectorised (signatures, pairing, triangle enumeration, batched fits, voting).
Tables (model points, signatures, surface) save to and load from ``.npz``.
"""

from __future__ import annotations

import functools
import json
import logging
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from mks_sim.errors import DataError
from mks_sim.geometry.keypoints import (
    add_convexity,
    ball_signatures,
    estimate_normals_pca,
    local_signatures,
    nms_keypoints,
    pca_normals_signed,
    voxel_downsample,
)
from mks_sim.geometry.meshes import Mesh, sample_surface
from mks_sim.geometry.points import fibonacci_sphere
from mks_sim.geometry.scan import scan_scene
from mks_sim.models.pose import PoseHypothesis
from mks_sim.models.refine import (
    ModelSurface,
    VerifiedHypothesis,
    _compiled_available,
    group_equivalent,
    merge_verified,
    verify_hypotheses,
)

__all__ = ["FreeformConfig", "FreeformModel", "FreeformResult"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


#: At most this many (keypoint, model point) pairings per detection: their pairwise rigid
#: consistency is a dense (C, C) float32 matrix (8000: 256 MB, a few temporaries of it), so
#: beyond it only the most salient keypoints are paired (``matches`` per keypoint).
MAX_PAIRINGS = 8000


@dataclass(frozen=True)
class FreeformConfig:
    """Parameters of the free-form model; ``None`` means "derived from the model size".

    Lengths are in the model's units. ``size`` is the diagonal of the model's bounding box;
    ``s = spacing`` (default ``size / 60``).

    Attributes:
        spacing: surface sampling spacing ``s``.
        radii: the two signature ball radii (default ``(4 s, 8 s)``).
        keypoint_radius: non-maximum-suppression radius of scene keypoints (default ``1.5 s``).
        model_point_spacing: spacing of candidate model points (default ``1.5 s``).
        saliency_floor: minimum saliency (surface variation summed over both scales) of a
            keypoint / model point; default: the 20th percentile over the model's candidate
            points, at least 0.01 (a plane with noise sigma = s / 4 stays below).
        n_views: virtual views of the model for view-dependent signatures.
        max_keypoints: at most this many scene keypoints, the most salient (None: all).
        matches_per_keypoint: model points paired with each scene keypoint.
        distance_tolerance: rigid distance consistency (default ``3 s``).
        min_side: minimum triangle side (default ``0.1 size``).
        max_triangles: cap on voting triangles (random subset beyond, seeded).
        bin_size: accumulator bin (default ``0.05 size``).
        max_peaks: accumulator maxima examined.
        modes_per_peak: rotation clusters taken per maximum.
        mode_angle_deg: rotation cluster radius.
        normal_tolerance_deg: a triangle's fit must map the model normals at its corners to
            within this angle of the scene normals (a check of the transform, not a feature).
        retry_votes: below this many votes at the best maximum, pairing is widened (see
            :meth:`FreeformModel.hypotheses`).
        retry_matches: model points paired per keypoint in the widened pass (default
            ``3 x matches_per_keypoint``).
        first_starts: :meth:`FreeformModel.localize` first verifies only this many of the
            first pass's most voted hypotheses...
        accept_score: ...and stops there when the best verified score reaches this and no
            other distinct placement comes within ``accept_margin`` of it (None: always run
            the full verification).
        accept_margin: see ``accept_score``.
        seed: seed of every random choice.
    """

    spacing: float | None = None
    radii: tuple[float, float] | None = None
    keypoint_radius: float | None = None
    model_point_spacing: float | None = None
    saliency_floor: float | None = None
    n_views: int = 20
    max_keypoints: int | None = None
    matches_per_keypoint: int = 8
    distance_tolerance: float | None = None
    min_side: float | None = None
    max_triangles: int = 60000
    bin_size: float | None = None
    max_peaks: int = 10
    modes_per_peak: int = 2
    mode_angle_deg: float = 12.0
    normal_tolerance_deg: float = 40.0
    retry_votes: int = 150
    retry_matches: int | None = None
    first_starts: int = 4
    accept_score: float | None = 0.95
    accept_margin: float = 0.05
    accept_gap: float | None = None
    accept_gap_floor: float = 0.6
    seed: int = 0

    def resolved(self, size: float) -> FreeformConfig:
        """A copy with every ``None`` replaced by its default for a model of this size."""
        s = self.spacing or size / 60.0
        return replace(
            self,
            spacing=s,
            radii=self.radii or (4.0 * s, 8.0 * s),
            keypoint_radius=self.keypoint_radius or 1.5 * s,
            model_point_spacing=self.model_point_spacing or 1.5 * s,
            distance_tolerance=self.distance_tolerance or 3.0 * s,
            min_side=self.min_side or 0.1 * size,
            bin_size=self.bin_size or 0.05 * size,
        )


@dataclass(frozen=True, eq=False)
class FreeformResult:
    """Hypotheses for one scene, best first, with timing and counts (for reports)."""

    hypotheses: list[PoseHypothesis]
    n_keypoints: int
    n_pairings: int
    n_triangles: int
    #: the scene keypoints (indices, signatures, normals), reusable by another detect call
    keypoints: tuple[NDArray[np.int64], FloatArray, FloatArray] | None = field(
        default=None, repr=False, compare=False
    )


def _triangle_rigid(
    src: FloatArray, dst: FloatArray, *, compiled: bool = False
) -> tuple[FloatArray, FloatArray]:
    """Rigid fits of (T, 3, 3) triangles -> triangles, in closed form (no SVD).

    Three points span a plane, so the proper rotation that best fits them maps the source
    triangle's plane onto the destination's (normals from the same vertex order, the mirror
    solution excluded as in :func:`_batched_rigid`) composed with the best in-plane rotation,
    a 2-D Procrustes angle. Equals :func:`_batched_rigid` for triangles whose orientation
    agrees (every congruent pair; the tests compare both); degenerate (collinear) triangles
    fall back to it. ``compiled``: triangle by triangle in the numba kernel
    (:func:`mks_sim.models._freeform_kernels.triangle_rigid`, the same arithmetic).
    """
    if compiled:
        from mks_sim.models._freeform_kernels import triangle_rigid

        r, t, bad = triangle_rigid(np.ascontiguousarray(src), np.ascontiguousarray(dst))
        if bad.any():
            r[bad], t[bad] = _batched_rigid(src[bad], dst[bad])
        return r, t
    # Sums over axes of length 3 written out: numpy's reductions cost more than the
    # arithmetic at this size, and the sums are the same (left to right).
    cs = (src[:, 0] + src[:, 1] + src[:, 2]) / 3.0
    cd = (dst[:, 0] + dst[:, 1] + dst[:, 2]) / 3.0
    a, b = src - cs[:, None], dst - cd[:, None]

    def frame(x: FloatArray) -> tuple[FloatArray, FloatArray]:
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        nn = np.linalg.norm(n, axis=1)
        e1 = x[:, 0] - x[:, 1]  # any in-plane direction
        e1 = e1 / np.maximum(np.linalg.norm(e1, axis=1), 1e-300)[:, None]
        n = n / np.maximum(nn, 1e-300)[:, None]
        return np.stack([e1, np.cross(n, e1), n], axis=1), nn  # rows: e1, e2, n

    fs, ns = frame(a)
    fd, nd = frame(b)
    # in-plane coordinates (T, 3) of each triangle in its own frame
    ax, ay = _dot3(a, fs[:, None, 0]), _dot3(a, fs[:, None, 1])
    bx, by = _dot3(b, fd[:, None, 0]), _dot3(b, fd[:, None, 1])
    cross, dot = ax * by - ay * bx, ax * bx + ay * by
    phi = np.arctan2(cross[:, 0] + cross[:, 1] + cross[:, 2], dot[:, 0] + dot[:, 1] + dot[:, 2])
    co, si = np.cos(phi)[:, None], np.sin(phi)[:, None]
    # R = Fd^T Rz(phi) Fs as a sum of outer products (elementwise: no batched einsum)
    m0 = co * fs[:, 0] - si * fs[:, 1]
    m1 = si * fs[:, 0] + co * fs[:, 1]
    r = (
        fd[:, 0, :, None] * m0[:, None, :]
        + fd[:, 1, :, None] * m1[:, None, :]
        + fd[:, 2, :, None] * fs[:, 2, None, :]
    )
    scale = np.maximum(np.abs(a).max(axis=(1, 2)), np.abs(b).max(axis=(1, 2)))
    bad = (ns <= 1e-9 * scale**2) | (nd <= 1e-9 * scale**2)
    if bad.any():
        r[bad] = _batched_rigid(src[bad], dst[bad])[0]
    t = cd - _dot3(r, cs[:, None, :])
    return r, t


def _dot3(x: FloatArray, y: FloatArray) -> FloatArray:
    """``(x * y).sum(axis=-1)`` for a last axis of length 3 (same sum order, no reduction)."""
    return x[..., 0] * y[..., 0] + x[..., 1] * y[..., 1] + x[..., 2] * y[..., 2]


def _batched_rigid(src: FloatArray, dst: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Kabsch fits of (T, k, 3) -> (T, k, 3): rotations (T, 3, 3), translations (T, 3)."""
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    h = np.einsum("tki,tkj->tij", src - cs[:, None], dst - cd[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("tij,tjk->tik", u, vt)))
    vt = vt.copy()
    vt[:, 2, :] *= d[:, None]  # reflection guard: the sphere intersection on the model's side
    r = np.einsum("tji,tkj->tik", vt, u)  # R = V U^T
    t = cd - np.einsum("tij,tj->ti", r, cs)
    return r, t


class FreeformModel:
    """A free-form object for the rotation-invariant Hough matcher (implements the
    ``LocalizableModel`` protocol of ``mks_sim.localize``).

    Build with :meth:`from_mesh` (or :meth:`from_points`), save with :meth:`save`, reload with
    :meth:`load`.
    """

    def __init__(
        self,
        name: str,
        config: FreeformConfig,
        surface_points: FloatArray,
        surface_normals: FloatArray,
        model_points: FloatArray,
        model_normals: FloatArray,
        signatures: FloatArray,
        reference_point: FloatArray,
        symmetries: FloatArray | None = None,
    ) -> None:
        self.name = name
        self.config = config
        self._surface_points = surface_points
        self._surface_normals = surface_normals
        self.model_points = model_points  # (M, 3)
        self.model_normals = model_normals  # (M, 3)
        self.signatures = signatures  # (M, V, 6), NaN where invisible
        self.reference_point = reference_point  # (3,)
        self._symmetries = symmetries
        flat = signatures.reshape(-1, signatures.shape[-1])
        good = np.all(np.isfinite(flat), axis=1)
        if not good.any():
            raise DataError(f"freeform model {name!r}: no model point has a signature")
        self._sig_scale = np.maximum(np.nanstd(flat[good], axis=0), 1e-6)
        self._sig_flat = flat[good] / self._sig_scale
        self._sig_owner = np.repeat(np.arange(len(model_points)), signatures.shape[1])[good]
        self._sig_tree = cKDTree(self._sig_flat)
        self._model_dist = np.linalg.norm(model_points[:, None] - model_points[None], axis=-1)
        # float32 for the (C x C) consistency test: half the memory traffic, and lengths
        # compared at ~1e-7 relative against a tolerance of 3 spacings
        self._model_dist32 = self._model_dist.astype(np.float32)

    # --- construction -------------------------------------------------------------------

    @property
    def size(self) -> float:
        """Diagonal of the model's bounding box (model units)."""
        return float(np.linalg.norm(np.ptp(self._surface_points, axis=0)))

    @classmethod
    def from_mesh(
        cls,
        mesh: Mesh,
        name: str = "freeform",
        config: FreeformConfig | None = None,
        symmetries: ArrayLike | None = None,
    ) -> FreeformModel:
        """Build the model's tables from a closed triangle mesh (model frame, model units)."""
        size = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
        if not size > 0:
            raise DataError(f"freeform model {name!r}: mesh has zero size")
        cfg = (config or FreeformConfig()).resolved(size)
        assert cfg.spacing is not None and cfg.radii is not None
        rng = np.random.default_rng(cfg.seed)
        pts, nrm = sample_surface(mesh, spacing=cfg.spacing / 2.0, rng=rng)
        keep = voxel_downsample(pts, cfg.spacing)
        surf, surf_n = pts[keep], nrm[keep]
        # Views: a ring of cameras at 3 size around the centroid.
        centre = mesh.centroid
        views = []
        for d in fibonacci_sphere(cfg.n_views):
            up = (0.0, 0.0, 1.0) if abs(d[2]) < 0.95 else (1.0, 0.0, 0.0)
            res = scan_scene(
                mesh,
                np.eye(4),
                centre + 3.0 * size * d,
                centre,
                width=128,
                height=128,
                fov_deg=30.0,
                up=up,
            )
            views.append(res.points)
        return cls._from_views(name, cfg, surf, surf_n, views, symmetries)

    @classmethod
    def from_points(
        cls,
        points: ArrayLike,
        normals: ArrayLike,
        name: str = "freeform",
        config: FreeformConfig | None = None,
        symmetries: ArrayLike | None = None,
    ) -> FreeformModel:
        """Build from a dense model point set with outward normals (no views: every model
        point gets one signature from the whole surface)."""
        p = np.asarray(points, dtype=np.float64)
        n = np.asarray(normals, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape != n.shape or len(p) < 10:
            raise DataError(
                f"from_points: expected (M >= 10, 3) points and normals, got {p.shape}, {n.shape}"
            )
        size = float(np.linalg.norm(np.ptp(p, axis=0)))
        cfg = (config or FreeformConfig()).resolved(size)
        assert cfg.spacing is not None
        keep = voxel_downsample(p, cfg.spacing)
        return cls._from_views(name, cfg, p[keep], n[keep], [p], symmetries)

    @classmethod
    def _from_views(
        cls,
        name: str,
        cfg: FreeformConfig,
        surf: FloatArray,
        surf_n: FloatArray,
        views: list[FloatArray],
        symmetries: ArrayLike | None,
    ) -> FreeformModel:
        assert cfg.radii is not None and cfg.model_point_spacing is not None
        assert cfg.spacing is not None
        cand = voxel_downsample(surf, cfg.model_point_spacing)
        mp = surf[cand]
        mn = pca_normals_signed(surf, surf_n, mp, cfg.radii[0])
        sig = np.full((len(mp), len(views), 6), np.nan)
        for v, cloud in enumerate(views):
            if len(cloud) < 10:
                continue
            d, _ = cKDTree(cloud).query(mp)
            vis = d < cfg.spacing
            if vis.any():
                sig[vis, v] = local_signatures(cloud, mp[vis], mn[vis], cfg.radii)
        sal = _saliency(sig)  # (M, V)
        salient = np.max(np.where(np.isfinite(sal), sal, -1.0), axis=1)
        if cfg.saliency_floor is None:
            # The most salient 80 % of the model's candidate points, never flat regions.
            seen = salient[salient >= 0]
            floor = max(0.01, float(np.quantile(seen, 0.2))) if seen.size else 0.01
            cfg = replace(cfg, saliency_floor=floor)
        assert cfg.saliency_floor is not None
        keep = salient > cfg.saliency_floor
        if keep.sum() < 3:
            raise DataError(
                f"freeform model {name!r}: only {keep.sum()} salient model points "
                f"(surface variation > {cfg.saliency_floor}); lower saliency_floor or spacing"
            )
        ref = surf.mean(axis=0)
        syms = None if symmetries is None else np.asarray(symmetries, dtype=np.float64)
        log.info(
            "freeform %s: %d model points of %d candidates, %d views",
            name,
            keep.sum(),
            len(mp),
            len(views),
        )
        return cls(name, cfg, surf, surf_n, mp[keep], mn[keep], sig[keep], ref, syms)

    # --- persistence --------------------------------------------------------------------

    def save(self, path: str | Path) -> None:
        """Save the configuration-time tables to ``.npz``."""
        np.savez_compressed(
            path,
            name=np.array(self.name),
            config=np.array(json.dumps(asdict(self.config))),
            surface_points=self._surface_points,
            surface_normals=self._surface_normals,
            model_points=self.model_points,
            model_normals=self.model_normals,
            signatures=self.signatures,
            reference_point=self.reference_point,
            symmetries=np.zeros((0, 3, 3)) if self._symmetries is None else self._symmetries,
        )

    @classmethod
    def load(cls, path: str | Path) -> FreeformModel:
        """Load tables saved by :meth:`save`."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                cfg_d: dict[str, Any] = json.loads(str(z["config"]))
                if cfg_d.get("radii") is not None:
                    cfg_d["radii"] = tuple(cfg_d["radii"])
                syms = z["symmetries"]
                return cls(
                    str(z["name"]),
                    FreeformConfig(**cfg_d),
                    z["surface_points"],
                    z["surface_normals"],
                    z["model_points"],
                    z["model_normals"],
                    z["signatures"],
                    z["reference_point"],
                    syms if len(syms) else None,
                )
        except (KeyError, ValueError, OSError, TypeError) as exc:
            raise DataError(f"{path.name}: not a freeform model table ({exc})") from exc

    # --- LocalizableModel protocol ------------------------------------------------------

    def surface_points(self) -> FloatArray:
        """(M, 3) model surface samples, model frame."""
        return self._surface_points

    @functools.cached_property
    def surface(self) -> ModelSurface:
        """The surface samples as a :class:`~mks_sim.models.refine.ModelSurface` (k-d tree;
        built once: the verification of every :meth:`localize` uses it).
        ``model.surface.with_lookup()`` adds the nearest-sample grid for a long-lived model."""
        return ModelSurface.from_arrays(self._surface_points, self._surface_normals)

    def surface_normals(self) -> FloatArray:
        """(M, 3) outward unit normals of :meth:`surface_points`."""
        return self._surface_normals

    def symmetries(self) -> FloatArray | None:
        """(S, 3, 3) model symmetries given at construction, or None."""
        return self._symmetries

    def hypotheses(
        self, scene_points: ArrayLike, scene_normals: ArrayLike | None = None
    ) -> list[PoseHypothesis]:
        """Pose hypotheses (model -> scene), most voted first; see the module docstring.

        When the fullest accumulator cell holds fewer than ``retry_votes`` votes (few
        keypoints paired correctly), pairing is widened to ``3 x matches_per_keypoint`` and the
        hypotheses of both runs are returned.
        """
        res = self.detect(scene_points, scene_normals)
        hyps = res.hypotheses
        top = hyps[0].votes if hyps else 0
        if top < self.config.retry_votes:
            wide = self.detect(
                scene_points,
                scene_normals,
                matches=self.config.retry_matches or 3 * self.config.matches_per_keypoint,
                keypoints=res.keypoints,  # the same scene: its keypoints are not recomputed
            )
            hyps = sorted(hyps + wide.hypotheses, key=lambda h: -h.votes)
        return hyps

    def localize(
        self,
        scene_points: ArrayLike,
        scene_normals: ArrayLike | None = None,
        *,
        inlier_distance: float | None = None,
        max_icp: int = 20,
        prescreen: int | None = None,
        full_refine: int = 2,
    ) -> list[VerifiedHypothesis]:
        """Hypotheses refined by ICP and scored (``mks_sim.models.refine``), best first.

        A convenience for one segment (``mks_sim.localize.localize_cloud`` does table removal
        and segmentation first). ``inlier_distance`` defaults to the spacing. ``prescreen``:
        when set, all distinct hypotheses are first scored together in one batch and only this
        many of the best are refined by ICP (faster; on the benchmark's scenes 8 lost one
        success in 21, so the default keeps ICP on up to ``max_icp`` of them).

        Verification stops early when it can: the ``first_starts`` most voted hypotheses of the
        first pass are verified first, and if the best scores at least ``accept_score`` with
        no other distinct placement within ``accept_margin`` of it, that is the answer (the
        widened pass and the other starts are skipped). Otherwise the remaining hypotheses
        (and the widened pass's, as in :meth:`hypotheses`) are verified too, up to
        ``max_icp`` starts in all, and both rankings are merged.
        """
        cfg = self.config
        scene = np.asarray(scene_points, dtype=np.float64)
        surface = self.surface
        d_in = inlier_distance or float(cfg.spacing or 0.0)

        def verify(hyps: list[PoseHypothesis], n_icp: int) -> list[VerifiedHypothesis]:
            return verify_hypotheses(
                hyps,
                surface,
                scene,
                inlier_distance=d_in,
                symmetries=self._symmetries,
                max_icp=n_icp,
                prescreen=prescreen,
                full_refine=full_refine,
            )

        if cfg.accept_score is None or cfg.first_starts <= 0:
            return verify(self.hypotheses(scene, scene_normals), max_icp)
        res = self.detect(scene, scene_normals)
        hyps = res.hypotheses
        n1 = min(cfg.first_starts, max_icp)
        first = verify(hyps[:n1], n1)
        if first:
            best = first[0].hypothesis.score
            second = first[1].hypothesis.score if len(first) > 1 else None
            gap = best - (0.0 if second is None else second)
            if best >= cfg.accept_score and gap >= cfg.accept_margin:
                return first
            if cfg.accept_gap is not None and second is not None:
                if best >= cfg.accept_gap_floor and gap >= cfg.accept_gap:
                    return first
        every = hyps
        if (hyps[0].votes if hyps else 0) < cfg.retry_votes:
            wide = self.detect(
                scene,
                scene_normals,
                matches=cfg.retry_matches or 3 * cfg.matches_per_keypoint,
                keypoints=res.keypoints,
            )
            every = sorted(hyps + wide.hypotheses, key=lambda h: -h.votes)
        # The starts the full verification would take (the max_icp most voted distinct
        # placements of both passes, as verify_hypotheses chooses them), less those already
        # refined above (up to a symmetry).
        size = surface.size
        k1 = len(hyps[:n1])
        labels = group_equivalent(
            [h.matrix for h in hyps[:n1] + every],
            self._symmetries,
            rotation_tol_deg=8.0,
            translation_tol=0.05 * size,
        )
        rest = [h for i, h in enumerate(every) if labels[k1 + i] >= k1]
        starts = group_equivalent(
            [h.matrix for h in every],
            self._symmetries,
            rotation_tol_deg=8.0,
            translation_tol=0.05 * size,
        )
        chosen = {id(h) for h in [h for i, h in enumerate(every) if starts[i] == i][:max_icp]}
        rest = [h for h in rest if id(h) in chosen]
        if not rest:
            return first
        return merge_verified(
            first + verify(rest, len(rest)), self._symmetries, max(d_in, 0.01 * size)
        )

    def scaled(self, factor: float) -> FreeformModel:
        """The same model with every length multiplied by ``factor`` (e.g. 0.001: mm -> m).

        Signatures are dimensionless, so the tables are reused.
        """
        if not factor > 0:
            raise DataError(f"freeform {self.name}: scale must be > 0, got {factor}")
        c = self.config

        def sc(v: float | None) -> float | None:
            return None if v is None else v * factor

        cfg = replace(
            c,
            spacing=sc(c.spacing),
            radii=None if c.radii is None else (c.radii[0] * factor, c.radii[1] * factor),
            keypoint_radius=sc(c.keypoint_radius),
            model_point_spacing=sc(c.model_point_spacing),
            distance_tolerance=sc(c.distance_tolerance),
            min_side=sc(c.min_side),
            bin_size=sc(c.bin_size),
        )
        return FreeformModel(
            self.name,
            cfg,
            self._surface_points * factor,
            self._surface_normals,
            self.model_points * factor,
            self.model_normals,
            self.signatures,
            self.reference_point * factor,
            self._symmetries,
        )

    # --- detection ----------------------------------------------------------------------

    def scene_keypoints(
        self, scene_points: FloatArray, scene_normals: FloatArray | None
    ) -> tuple[NDArray[np.int64], FloatArray, FloatArray]:
        """Scene keypoint indices (into ``scene_points``), (K, 6) signatures, (K, 3) normals."""
        cfg = self.config
        assert cfg.spacing is not None and cfg.radii is not None and cfg.keypoint_radius is not None
        sub = voxel_downsample(scene_points, cfg.spacing)
        p = scene_points[sub]
        # Saliency needs no normals: keypoints first, normals (and convexity) at keypoints only
        # (the same values as computing them everywhere; a tenth of the PCA work).
        sig, centroids = ball_signatures(scene_points, p, cfg.radii)
        assert cfg.saliency_floor is not None
        sal = _saliency(sig)
        kp = nms_keypoints(p, sal, cfg.keypoint_radius, cfg.saliency_floor)
        kp = kp[np.all(np.isfinite(sig[kp]), axis=1)]
        if cfg.max_keypoints is not None and len(kp) > cfg.max_keypoints:
            # the most salient (noise raises every point's variation; the pairing consistency
            # matrix grows with the square of the keypoints)
            kp = np.sort(kp[np.argsort(-sal[kp], kind="stable")[: cfg.max_keypoints]])
        if scene_normals is None:
            # oriented away from the centroid of the whole subsample: estimated on all of it
            n = estimate_normals_pca(p, cfg.radii[0])[kp]
        else:
            n = pca_normals_signed(scene_points, scene_normals, p[kp], cfg.radii[0])
        sig = add_convexity(sig[kp], centroids[:, kp], p[kp], n, cfg.radii)
        return sub[kp], sig, n

    def detect(
        self,
        scene_points: ArrayLike,
        scene_normals: ArrayLike | None = None,
        *,
        matches: int | None = None,
        keypoints: tuple[NDArray[np.int64], FloatArray, FloatArray] | None = None,
    ) -> FreeformResult:
        """Run steps 1-4 of the module docstring on one scene segment.

        Args:
            scene_points: (N, 3) one scene segment, model units, finite.
            scene_normals: (N, 3) normals oriented towards the sensor, or None (estimated;
                then the normal check is sign-free).
            matches: model points paired per keypoint (default ``matches_per_keypoint``).
            keypoints: :meth:`scene_keypoints` of this very scene, when already computed
                (``FreeformResult.keypoints`` of an earlier call); None computes them.
        """
        cfg = self.config
        assert cfg.distance_tolerance is not None and cfg.min_side is not None
        assert cfg.bin_size is not None
        scene = np.asarray(scene_points, dtype=np.float64)
        if scene.ndim != 2 or scene.shape[1] != 3:
            raise DataError(
                f"freeform {self.name}: expected (N, 3) scene points, got {scene.shape}"
            )
        finite = np.all(np.isfinite(scene), axis=1)
        if not finite.all():
            raise DataError(
                f"freeform {self.name}: {int((~finite).sum())} scene points are NaN/inf "
                "(drop them first: read_point_cloud does)"
            )
        normals = None if scene_normals is None else np.asarray(scene_normals, dtype=np.float64)
        if len(scene) < 20:
            return FreeformResult([], 0, 0, 0)
        if keypoints is None:
            keypoints = self.scene_keypoints(scene, normals)
        kp_idx, kp_sig, kp_n = keypoints
        if len(kp_idx) < 3:
            return FreeformResult([], len(kp_idx), 0, 0, keypoints)
        # Pairing: each keypoint with the model points of nearest signature (any view).
        n_match = matches or cfg.matches_per_keypoint
        cap = max(3, MAX_PAIRINGS // n_match)
        if len(kp_idx) > cap:
            # the consistency matrix is (pairings x pairings): a noisy or wide scene with
            # thousands of keypoints took 13 GB (stereo points of a cylinder, paired 24 per
            # keypoint); keep the most salient keypoints (saliency: variation at both scales)
            keep = np.sort(np.argsort(-_saliency(kp_sig), kind="stable")[:cap])
            kp_idx, kp_sig, kp_n = kp_idx[keep], kp_sig[keep], kp_n[keep]
        k = min(len(self._sig_flat), n_match * 4)
        _, j = self._sig_tree.query(kp_sig / self._sig_scale, k=k)
        j = j.reshape(len(kp_idx), -1)
        owners = self._sig_owner[j]  # (K, k) model point per signature, repeats across views
        pair_s, pair_m = _first_distinct(owners, n_match)
        s_pos = scene[kp_idx[pair_s]]  # (C, 3)
        m_pos = self.model_points[pair_m]
        n_pair = len(pair_s)
        # Rigid consistency of every two pairings (C x C), from the (K x K) keypoint distances
        # and the model's table.
        kp_pos = scene[kp_idx].astype(np.float32)
        dk = np.sqrt(((kp_pos[:, None] - kp_pos[None]) ** 2).sum(axis=-1))  # (K, K)
        compiled = n_pair >= _COMPILED_MIN_PAIRS and _compiled_available()
        cons, edges = _consistent(
            dk, pair_s, self._model_dist32, pair_m, cfg.min_side, cfg.distance_tolerance,
            compiled=compiled,
        )  # fmt: skip
        tri = _triangles(
            cons, edges, cfg.max_triangles, np.random.default_rng(cfg.seed), compiled=compiled
        )
        if len(tri) == 0:
            return FreeformResult([], len(kp_idx), n_pair, 0, keypoints)
        rot, trans = _triangle_rigid(m_pos[tri], s_pos[tri], compiled=compiled)
        # Verify each triangle's rotation on its normals: the rotated model normals must agree
        # with the scene normals at all three corners (sign-free when normals were estimated).
        # rotated model normals (T, 3 corners, 3), elementwise (batched einsum is slower)
        rn = _dot3(self.model_normals[pair_m][tri][:, :, None, :], rot[:, None, :, :])
        dots = _dot3(rn, kp_n[pair_s][tri])
        if normals is None:
            dots = np.abs(dots)
        good = np.all(dots >= np.cos(np.radians(cfg.normal_tolerance_deg)), axis=1)
        tri, rot, trans = tri[good], rot[good], trans[good]
        if len(tri) == 0:
            return FreeformResult([], len(kp_idx), n_pair, 0, keypoints)
        ref = _dot3(rot, self.reference_point) + trans  # (T, 3) votes for P0
        hyps = self._peaks(ref, rot, trans, tri, kp_idx[pair_s], pair_m, compiled=compiled)
        return FreeformResult(hyps, len(kp_idx), n_pair, len(tri), keypoints)

    def _peaks(
        self,
        ref: FloatArray,
        rot: FloatArray,
        trans: FloatArray,
        tri: NDArray[np.int64],
        scene_index: NDArray[np.int64],
        model_index: NDArray[np.int64],
        *,
        compiled: bool = False,
    ) -> list[PoseHypothesis]:
        cfg = self.config
        assert cfg.bin_size is not None
        b = cfg.bin_size
        cell = np.floor(ref / b).astype(np.int64)
        # Cells as one integer key each (mixed radix: sorted keys = lexicographic cells, the
        # order of np.unique(axis=0), without its slow row sort).
        lo = cell.min(axis=0) - 1
        span = cell.max(axis=0) - lo + 2
        stride = np.array([span[1] * span[2], span[2], 1], dtype=np.int64)
        keys, first, inv, counts = np.unique(
            (cell - lo) @ stride, return_index=True, return_inverse=True, return_counts=True
        )
        inv = inv.reshape(-1)
        uniq = cell[first]
        # Sum each cell's votes with its 26 neighbours (a bin edge must not split a peak),
        # neighbours found by binary search.
        offs = np.array([[a, b_, c] for a in (-1, 0, 1) for b_ in (-1, 0, 1) for c in (-1, 0, 1)])
        nb_keys = (uniq[:, None, :] + offs[None] - lo) @ stride
        pos = np.minimum(np.searchsorted(keys, nb_keys), len(keys) - 1)
        hit = keys[pos] == nb_keys  # (U, 27)
        smooth = np.where(hit, counts[pos], 0).sum(axis=1)
        order = np.argsort(-smooth, kind="stable")
        out: list[PoseHypothesis] = []
        used: list[FloatArray] = []
        tree = cKDTree(ref)
        n_model = np.int64(len(self.model_points))
        cos_thr = np.cos(np.radians(cfg.mode_angle_deg))
        # each cell's votes as one slice of a stable sort (the same points, in the same order,
        # as ref[inv == u], without a pass over all votes per cell)
        by_cell = np.argsort(inv, kind="stable")
        cell_start = np.concatenate([[0], np.cumsum(counts)])
        if compiled:
            from mks_sim.models._freeform_kernels import rotations_close
        for u in order:
            if len(used) >= cfg.max_peaks:
                break
            centre = ref[by_cell[cell_start[u] : cell_start[u + 1]]].mean(axis=0)
            if used and np.linalg.norm(np.asarray(used) - centre, axis=1).min() < 1.5 * b:
                continue
            used.append(centre)
            members = np.asarray(tree.query_ball_point(centre, 1.5 * b), dtype=np.int64)
            if len(members) > 400:
                members = np.sort(
                    np.random.default_rng(cfg.seed).choice(members, 400, replace=False)
                )
            r = rot[members]
            # Pairwise rotation similarity: cos(angle) = (trace(Ri^T Rj) - 1) / 2. (einsum over
            # the flattened 3x3, not a BLAS matmul: multithreaded BLAS on a busy machine was
            # 5-20x slower here; the flattened form is ~1.5x faster than "aij,bij->ab")
            r9 = r.reshape(len(r), 9)
            if compiled:
                close = rotations_close(np.ascontiguousarray(r9), float(cos_thr))
            else:
                cos = (np.einsum("ak,bk->ab", r9, r9) - 1.0) / 2.0
                close = cos >= cos_thr
            free = np.ones(len(members), bool)
            for _ in range(cfg.modes_per_peak):
                support = (close & free[None, :]).sum(axis=1) * free
                best = int(np.argmax(support))
                if support[best] < 3:
                    break
                mode = close[best] & free
                free &= ~mode
                mm = members[mode]
                rm = _mean_rotation(rot[mm])
                p0 = ref[mm].mean(axis=0)
                matrix = np.eye(4)
                matrix[:3, :3] = rm
                matrix[:3, 3] = p0 - rm @ self.reference_point
                # distinct (scene, model) pairs, sorted, through one integer key each
                pk = np.unique(
                    scene_index[tri[mm]].ravel() * n_model + model_index[tri[mm]].ravel()
                )
                pairs = np.stack([pk // n_model, pk % n_model], 1)
                out.append(
                    PoseHypothesis(
                        matrix=matrix,
                        reference_point=p0,
                        votes=int(mode.sum()),
                        correspondences=pairs,
                    )
                )
        out.sort(key=lambda h: -h.votes)
        return out


def _saliency(sig: FloatArray) -> FloatArray:
    """Keypoint saliency: surface variation summed over the two scales (the small scale
    localises corners and rims, the large one finds the gentle bumps of smooth shapes)."""
    return sig[..., 0] + sig[..., 3]


def _mean_rotation(r: FloatArray) -> FloatArray:
    """The rotation nearest the arithmetic mean of rotations (chordal L2 mean)."""
    u, _, vt = np.linalg.svd(r.mean(axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _first_distinct(
    owners: NDArray[np.int64], m: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per row, the first ``m`` distinct values: returns (row, value) pairs."""
    k = owners.shape[1]
    eq = owners[:, :, None] == owners[:, None, :]  # (K, k, k)
    earlier = np.tril(np.ones((k, k), bool), -1)
    first = ~np.any(eq & earlier[None], axis=2)
    rank = np.cumsum(first, axis=1)
    take = first & (rank <= m)
    rows, cols = np.nonzero(take)
    return rows.astype(np.int64), owners[rows, cols].astype(np.int64)


#: Pairings from which the consistency and the triangles use the compiled kernels
#: (:mod:`mks_sim.models._freeform_kernels`) when numba imports.
_COMPILED_MIN_PAIRS = 256


def _consistent(
    dk: NDArray[np.float32],
    pair_s: NDArray[np.int64],
    model_dist: NDArray[np.float32],
    pair_m: NDArray[np.int64],
    min_side: float,
    tolerance: float,
    *,
    compiled: bool,
) -> tuple[NDArray[np.bool_], tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """The (C, C) rigid consistency of the pairings (scene keypoint ``pair_s``, model point
    ``pair_m``): keypoints at least ``min_side`` apart, at a distance (float32) within
    ``tolerance`` of their model points'. Returns it and its upper-triangle pairs ``(a, b)``,
    ``a < b``, in row-major order. ``compiled``: the numba kernel (the same values, no
    (C, C) temporaries) instead of the numpy gathers."""
    lo, tol = np.float32(min_side), np.float32(tolerance)
    if compiled:
        from mks_sim.models._freeform_kernels import consistent_pairs

        cons, a, b = consistent_pairs(
            dk,
            np.ascontiguousarray(pair_s, dtype=np.int64),
            model_dist,
            np.ascontiguousarray(pair_m, dtype=np.int64),
            lo,
            tol,
        )
        return cons, (a, b)
    if np.all(pair_s[1:] >= pair_s[:-1]):  # grouped by keypoint (np.nonzero order)
        per = np.bincount(pair_s, minlength=len(dk))
        ds = np.repeat(np.repeat(dk, per, axis=0), per, axis=1)  # 4x faster than take
    else:
        ds = np.take(np.take(dk, pair_s, axis=0), pair_s, axis=1)
    cons = ds >= lo
    ds -= np.take(np.take(model_dist, pair_m, axis=0), pair_m, axis=1)
    np.abs(ds, out=ds)
    cons &= ds <= tol
    # (np.triu would build a C x C mask and a copy first; the filter keeps row-major order)
    a, b = np.nonzero(cons)
    upper = a < b
    return cons, (a[upper].astype(np.int64), b[upper].astype(np.int64))


def _triangles(
    cons: NDArray[np.bool_],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    cap: int,
    rng: np.random.Generator,
    *,
    compiled: bool = False,
) -> NDArray[np.int64]:
    """(T, 3) index triples a < b < c with all three pairs consistent (at most ``cap``), from
    the consistency matrix and its upper-triangle ``edges`` (:func:`_consistent`)."""
    a, b = edges
    if len(a) == 0:
        return np.zeros((0, 3), np.int64)
    # Expected triangle count ~ edges * mean degree; thin the edge list to stay near the cap.
    deg = 2.0 * len(a) / cons.shape[0]  # (cons is symmetric with an empty diagonal)
    est = len(a) * max(deg, 1.0) / 3.0
    if est > cap:
        keep = rng.random(len(a)) < cap / est
        a, b = a[keep], b[keep]
    if compiled:
        from mks_sim.models._freeform_kernels import edge_triangles

        tri = edge_triangles(cons, np.ascontiguousarray(a), np.ascontiguousarray(b))
    else:
        out = []
        chunk = max(1, 2_000_000 // cons.shape[0])
        for s in range(0, len(a), chunk):
            aa, bb = a[s : s + chunk], b[s : s + chunk]
            common = cons[aa] & cons[bb]  # (E, C)
            e, c = np.nonzero(common)
            ok = c > bb[e]
            out.append(np.stack([aa[e[ok]], bb[e[ok]], c[ok]], 1))
        tri = np.concatenate(out) if out else np.zeros((0, 3), np.int64)
    if len(tri) > cap:
        tri = tri[np.sort(rng.choice(len(tri), cap, replace=False))]
    return tri.astype(np.int64)


# --- model database kind "freeform" ---------------------------------------------------------

#: Built-in meshes a database entry can name with ``mesh = "builtin:<name>"``.
BUILTIN_MESHES = ("industrial_part", "torus", "blob")


def axial_symmetries(step_deg: float = 1.0, flip: bool = True) -> FloatArray:
    """(S, 3, 3) rotations about z in ``step_deg`` steps (and the 180-degree flips about
    horizontal axes when ``flip``): the symmetries of a torus or cylinder, discretised."""
    from scipy.spatial.transform import Rotation

    ang = np.arange(step_deg, 360.0, step_deg)
    rz = Rotation.from_euler("z", ang[:, None], degrees=True).as_matrix()
    if not flip:
        return rz
    fx = Rotation.from_euler("x", 180.0, degrees=True).as_matrix()
    return np.concatenate([rz, rz @ fx, fx[None]])


def _builtin_mesh(name: str) -> Mesh:
    from mks_sim.geometry import meshes

    if name == "industrial_part":
        return meshes.industrial_part_mesh()
    if name == "torus":
        return meshes.torus_mesh()
    if name == "blob":
        return meshes.blob_mesh()
    raise DataError(f"unknown builtin mesh {name!r}; known: {list(BUILTIN_MESHES)}")


def load_freeform_entry(entry: Any, where: str) -> FreeformModel:
    """Database loader of ``kind = "freeform"`` entries.

    Entry fields: ``name``; ``mesh`` (a mesh file, relative paths from the TOML file's folder,
    or ``"builtin:industrial_part" | "builtin:torus" |
    "builtin:blob"``); optional ``tables`` (an ``.npz`` saved by :meth:`FreeformModel.save`,
    used instead of rebuilding when it exists); ``scale`` (model units -> metres, default 1);
    ``symmetry`` (``"none"`` | ``"axial"``); ``config`` (a table of :class:`FreeformConfig`
    fields).
    """
    from mks_sim.errors import SpecError

    name = str(entry.get("name", "freeform"))
    # Relative paths are relative to the TOML file (``where`` starts with its path).
    toml_file = Path(where.split(": model ")[0])
    base = toml_file.parent if toml_file.is_file() else Path.cwd()

    def resolve(v: Any) -> Path:
        q = Path(str(v))
        return q if q.is_absolute() else base / q

    tables = None if entry.get("tables") is None else resolve(entry["tables"])
    if tables is not None and tables.is_file():
        model = FreeformModel.load(tables)
    else:
        mesh_spec = entry.get("mesh")
        if not isinstance(mesh_spec, str):
            raise SpecError(f"{where}: field 'mesh': expected a mesh file or 'builtin:<name>'")
        if mesh_spec.startswith("builtin:"):
            mesh = _builtin_mesh(mesh_spec.split(":", 1)[1])
        else:
            from mks_sim.io.mesh import read_mesh

            mesh = read_mesh(resolve(mesh_spec))
        cfg_fields = dict(entry.get("config", {}))
        if "radii" in cfg_fields:
            cfg_fields["radii"] = tuple(cfg_fields["radii"])
        try:
            cfg = FreeformConfig(**cfg_fields)
        except TypeError as exc:
            raise SpecError(f"{where}: field 'config': {exc}") from exc
        sym = entry.get("symmetry", "none")
        if sym not in ("none", "axial"):
            raise SpecError(f"{where}: field 'symmetry': expected 'none' or 'axial', got {sym!r}")
        syms = axial_symmetries() if sym == "axial" else None
        model = FreeformModel.from_mesh(mesh, name, cfg, syms)
        if tables is not None:
            model.save(tables)
    scale = float(entry.get("scale", 1.0))
    return model if scale == 1.0 else model.scaled(scale)
