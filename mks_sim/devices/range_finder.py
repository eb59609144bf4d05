"""Simulated scanning laser range finder (one or more mounts = views), by MuJoCo ray casting.

Each mount is a MuJoCo site; rays leave the site origin on a pan/tilt grid around the site's
+z axis (the boresight). Ray ``(i, j)`` has pan ``a_j`` (about the site's y axis) and tilt
``b_i`` (about its x axis) and direction, in the site frame,
``(tan a_j, tan b_i, 1) / norm`` — a regular grid on a plane perpendicular to the boresight,
like a galvanometer scanner's raster. Rays are cast with one ``mujoco.mj_multiRay`` call per
mount over all geoms in the enabled ``geomgroup`` s (visible geoms; ``rgba`` alpha 0 geoms are
never hit), excluding the body that carries the mount (unless that is the world body).

What the robot's own links do: they are real occluders (a ray that hits the arm stops there),
but the scanner knows its robot's shape and joint angles, so those returns are *self-filtered*:
``self_hit`` marks them and they do not count as ``hit`` (a standard robot self-filter; it uses
the robot's own model, not object ground truth). Which bodies are "self" is given by
``self_bodies`` (each with its whole subtree).

Noise: Gaussian range noise ``sigma_m`` (times the fault's ``noise_scale``), per-ray dropout,
and ``max_range_m`` (returns beyond it are misses). Missed rays have range ``inf`` and point NaN.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from mks_sim.devices.faults import DeviceFaults, SimDevice, combined_dropout
from mks_sim.errors import SpecError


@dataclass(frozen=True, eq=False)
class RangeScan:
    """One scan from one mount.

    Attributes:
        points_world: (N, 3) float64 hit points in the world frame, metres; NaN where not hit.
        ranges: (N,) float64 measured range along each ray, metres; ``inf`` where not hit.
        hit: (N,) bool, the ray returned from the scene (not dropped, within range, not self).
        self_hit: (N,) bool, the ray stopped on the robot itself (self-filtered).
        directions_sensor: (N, 3) unit ray directions in the mount frame.
        sensor_to_world: (4, 4) pose of the mount frame (+z = boresight).
        view: index of the mount (view) this scan came from.
        grid_shape: (n_tilt, n_pan), so ``ranges.reshape(grid_shape)`` is the range image.
    """

    points_world: np.ndarray
    ranges: np.ndarray
    hit: np.ndarray
    self_hit: np.ndarray
    directions_sensor: np.ndarray
    sensor_to_world: np.ndarray
    view: int
    grid_shape: tuple[int, int]

    @property
    def hit_points(self) -> np.ndarray:
        """(M, 3) the hit points only."""
        return self.points_world[self.hit]


@dataclass(frozen=True)
class ScanPattern:
    """The scan grid: ``n_pan`` x ``n_tilt`` rays over ``±pan_deg`` x ``±tilt_deg``."""

    n_pan: int = 64
    n_tilt: int = 48
    pan_deg: float = 30.0
    tilt_deg: float = 25.0

    def __post_init__(self) -> None:
        if self.n_pan < 1 or self.n_tilt < 1:
            raise SpecError(
                f"ScanPattern: expected n_pan, n_tilt >= 1, got {self.n_pan}, {self.n_tilt}"
            )
        if not (0 <= self.pan_deg < 89 and 0 <= self.tilt_deg < 89):
            raise SpecError(
                f"ScanPattern: expected 0 <= pan_deg, tilt_deg < 89, got {self.pan_deg}, {self.tilt_deg}"
            )

    def directions(self) -> np.ndarray:
        """(n_tilt * n_pan, 3) unit directions in the mount frame, row-major (tilt, pan)."""
        pan = np.deg2rad(np.linspace(-self.pan_deg, self.pan_deg, self.n_pan))
        tilt = np.deg2rad(np.linspace(-self.tilt_deg, self.tilt_deg, self.n_tilt))
        tt, pp = np.meshgrid(tilt, pan, indexing="ij")
        d = np.stack([np.tan(pp), np.tan(tt), np.ones_like(pp)], axis=-1).reshape(-1, 3)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


def _subtree_bodies(model: mujoco.MjModel, roots: Sequence[str]) -> np.ndarray:
    """(nbody,) bool mask of the bodies in the subtrees of ``roots``."""
    mask = np.zeros(model.nbody, dtype=bool)
    for root in roots:
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, root)
        if bid < 0:
            raise SpecError(f"range finder: self body {root!r} is not a body of the model")
        mask[bid] = True
    # Bodies are ordered parents first, so one pass propagates down the tree.
    for b in range(1, model.nbody):
        if mask[model.body_parentid[b]]:
            mask[b] = True
    return mask


class RangeFinder(SimDevice):
    """Scanning range finder over one or more mount sites; ``read()`` -> ``list[RangeScan]``.

    Args:
        model, data: the MuJoCo model and data.
        mounts: site names, one per view; each site's +z is its boresight.
        rng: generator for noise and dropout.
        name: device name.
        pattern: the scan grid.
        max_range_m: returns beyond this range are misses.
        sigma_m: nominal Gaussian range noise, metres.
        dropout: nominal fraction of rays that return nothing.
        geomgroup: six 0/1 flags, the geom groups the rays can hit (default: all).
        self_bodies: bodies (with their subtrees) of the robot, whose hits are self-filtered.
        faults: initial fault state.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        mounts: Sequence[str],
        rng: np.random.Generator,
        *,
        name: str = "range_finder",
        pattern: ScanPattern | None = None,
        max_range_m: float = 2.0,
        sigma_m: float = 0.0005,
        dropout: float = 0.0,
        geomgroup: Sequence[int] = (1, 1, 1, 1, 1, 1),
        self_bodies: Sequence[str] = (),
        faults: DeviceFaults | None = None,
    ) -> None:
        super().__init__(name, rng, faults)
        if not mounts:
            raise SpecError(f"device {name!r}: expected at least one mount site, got none")
        self.model, self.data = model, data
        self.site_ids: list[int] = []
        for site in mounts:
            sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
            if sid < 0:
                raise SpecError(f"device {name!r}: mount site {site!r} is not a site of the model")
            self.site_ids.append(sid)
        self.mounts = tuple(mounts)
        if not (max_range_m > 0 and sigma_m >= 0 and 0 <= dropout <= 1):
            raise SpecError(
                f"device {name!r}: expected max_range_m > 0, sigma_m >= 0, 0 <= dropout <= 1, "
                f"got {max_range_m}, {sigma_m}, {dropout}"
            )
        if len(geomgroup) != 6:
            raise SpecError(f"device {name!r}: expected 6 geomgroup flags, got {len(geomgroup)}")
        self.pattern = pattern or ScanPattern()
        self.max_range_m, self.sigma_m, self.dropout = (
            float(max_range_m),
            float(sigma_m),
            float(dropout),
        )
        self.geomgroup = np.asarray(geomgroup, dtype=np.uint8)
        self._self_body = _subtree_bodies(model, self_bodies)
        self._dirs_sensor = self.pattern.directions()

    @property
    def n_rays(self) -> int:
        """Rays per view."""
        return len(self._dirs_sensor)

    def sensor_to_world(self, view: int) -> np.ndarray:
        """(4, 4) pose of mount ``view`` (needs mj_kinematics / mj_forward on the data)."""
        sid = self.site_ids[view]
        T = np.eye(4)
        T[:3, :3] = self.data.site_xmat[sid].reshape(3, 3)
        T[:3, 3] = self.data.site_xpos[sid]
        return T

    def _scan(self, view: int) -> RangeScan:
        T = self.sensor_to_world(view)
        n = self.n_rays
        dirs_world = self._dirs_sensor @ T[:3, :3].T  # (n, 3)
        geomid = np.full(n, -1, dtype=np.int32)
        dist = np.full(n, -1.0)
        # Skip the scanner's own housing (its mount body) unless that is the world body,
        # which carries the table and floor.
        body = int(self.model.site_bodyid[self.site_ids[view]]) or -1
        mujoco.mj_multiRay(
            self.model, self.data, T[:3, 3].copy(), dirs_world.ravel().copy(),
            self.geomgroup, 1, body, geomid, dist, None, n, self.max_range_m,
        )  # fmt: skip
        returned = (geomid >= 0) & (dist >= 0)
        self_hit = np.zeros(n, dtype=bool)
        self_hit[returned] = self._self_body[self.model.geom_bodyid[geomid[returned]]]
        ranges = dist.copy()
        s = self.faults.noise_scale * self.sigma_m
        if s > 0:
            ranges = ranges + self.rng.normal(0.0, s, n)
        p_drop = combined_dropout(self.dropout, self.faults)
        dropped = self.rng.random(n) < p_drop if p_drop > 0 else np.zeros(n, dtype=bool)
        hit = returned & ~self_hit & ~dropped & (ranges > 0) & (ranges <= self.max_range_m)
        ranges = np.where(hit, ranges, np.inf)
        points = np.where(hit[:, None], T[:3, 3] + ranges[:, None] * dirs_world, np.nan)
        return RangeScan(
            points_world=points,
            ranges=ranges,
            hit=hit,
            self_hit=self_hit,
            directions_sensor=self._dirs_sensor.copy(),
            sensor_to_world=T,
            view=view,
            grid_shape=(self.pattern.n_tilt, self.pattern.n_pan),
        )

    def _measure(self) -> list[RangeScan]:
        return [self._scan(v) for v in range(len(self.site_ids))]


def merge_scans(scans: Sequence[RangeScan]) -> tuple[np.ndarray, np.ndarray]:
    """Hit points of several views: ((M, 3) points_world, (M,) int view index)."""
    if not scans:
        return np.empty((0, 3)), np.empty(0, dtype=np.int64)
    pts = [s.hit_points for s in scans]
    views = [np.full(len(p), s.view, dtype=np.int64) for p, s in zip(pts, scans)]
    return np.concatenate(pts), np.concatenate(views)
