"""Simulated RGB / depth camera over a named MuJoCo camera.

Frames and conventions (OpenCV pinhole):

- Image: row 0 at the top, ``u`` = column (right), ``v`` = row (down); integer pixel
  coordinates are pixel centres.
- Camera frame: x right, y down, z forward (the optical axis). MuJoCo's camera frame is
  x right, y up, looking along -z, so ``R_opencv = R_mujoco @ diag(1, -1, -1)``.
- ``K`` = [[f, 0, cx], [0, f, cy], [0, 0, 1]] with square pixels, ``f = (H / 2) / tan(fovy / 2)``
  from ``model.cam_fovy`` and ``cx = (W - 1) / 2``, ``cy = (H - 1) / 2`` (MuJoCo's frustum is
  symmetric about the image centre).
- ``camera_to_world`` (4x4, column convention) maps OpenCV camera coordinates to world.
- Depth: metres along the optical axis (z of the OpenCV camera frame), as MuJoCo 3.x's
  ``Renderer`` returns it once ``enable_depth_rendering()`` is on; pixels that see nothing
  (at or beyond the far clip plane) and dropped pixels are NaN.

Noise: RGB gets Gaussian noise of ``rgb_sigma`` (intensity units, clipped to 0..255), depth
gets Gaussian noise of ``depth_sigma_m + depth_sigma_rel * depth`` metres, and a fraction
``dropout`` of depth pixels is lost (NaN; the RGB pixel reads 0). All scaled / extended by the
device's :class:`~mks_sim.devices.faults.DeviceFaults`.
"""

from __future__ import annotations

import atexit
import logging
import weakref
from dataclasses import dataclass

import mujoco
import numpy as np

from mks_sim.devices.faults import DeviceFaults, SimDevice, combined_dropout
from mks_sim.errors import SpecError

logger = logging.getLogger(__name__)

# MuJoCo camera (y up, looking along -z) -> OpenCV camera (y down, z forward).
MUJOCO_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True, eq=False)
class CameraFrame:
    """One camera reading.

    Attributes:
        rgb: (H, W, 3) uint8 image, row 0 at the top.
        depth: (H, W) float64 metres along the optical axis, NaN where nothing was seen; None
            for an RGB-only camera.
        K: (3, 3) float64 intrinsic matrix (pixels).
        camera_to_world: (4, 4) float64 pose of the OpenCV camera frame in the world.
        name: the device name.
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    K: np.ndarray
    camera_to_world: np.ndarray
    name: str

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) in pixels."""
        return (int(self.rgb.shape[0]), int(self.rgb.shape[1]))


def intrinsics_from_fovy(fovy_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole ``K`` (3, 3) of a MuJoCo camera with vertical field of view ``fovy_deg``."""
    f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def camera_to_world(data: mujoco.MjData, camera_id: int) -> np.ndarray:
    """(4, 4) pose of camera ``camera_id``'s OpenCV frame in the world (needs mj_kinematics)."""
    T = np.eye(4)
    T[:3, :3] = data.cam_xmat[camera_id].reshape(3, 3) @ MUJOCO_TO_OPENCV
    T[:3, 3] = data.cam_xpos[camera_id]
    return T


_OPEN_RENDERERS: weakref.WeakSet[Camera] = weakref.WeakSet()


@atexit.register
def _close_all_renderers() -> None:
    # EGL complains at interpreter exit about contexts that were never released.
    for cam in list(_OPEN_RENDERERS):
        cam.close()


@dataclass(frozen=True)
class CameraNoise:
    """Nominal noise of a camera (before the fault's ``noise_scale``)."""

    rgb_sigma: float = 2.0
    depth_sigma_m: float = 0.001
    depth_sigma_rel: float = 0.002
    dropout: float = 0.0


@dataclass
class _RenderState:
    renderer: mujoco.Renderer | None = None
    depth_renderer: mujoco.Renderer | None = None


class Camera(SimDevice):
    """A camera device: RGB (and optionally depth) of the MuJoCo camera ``camera``.

    Args:
        model, data: the compiled MuJoCo model and its data (read at ``read()`` time).
        camera: MuJoCo camera name.
        rng: generator for the noise.
        name: device name (defaults to the camera name).
        width, height: image size in pixels (must fit ``model.vis.global_.offwidth/offheight``).
        depth: also render depth.
        noise: nominal noise.
        faults: initial fault state.

    The renderers are created once, at the first read (building a device set whose cameras
    are never read costs nothing: ~0.25 s per renderer in software EGL), and released by
    :meth:`close` (also at exit).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        camera: str,
        rng: np.random.Generator,
        *,
        name: str | None = None,
        width: int = 320,
        height: int = 240,
        depth: bool = True,
        noise: CameraNoise | None = None,
        faults: DeviceFaults | None = None,
    ) -> None:
        super().__init__(name or camera, rng, faults)
        cam_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if cam_id < 0:
            names = [model.camera(i).name for i in range(model.ncam)]
            raise SpecError(
                f"device {self.name!r}: no MuJoCo camera named {camera!r}; cameras: {names}"
            )
        offw, offh = int(model.vis.global_.offwidth), int(model.vis.global_.offheight)
        if width > offw or height > offh:
            raise SpecError(
                f"device {self.name!r}: image {width}x{height} exceeds the offscreen buffer "
                f"{offw}x{offh}; set <visual><global offwidth=.. offheight=../> in the MJCF"
            )
        self.model, self.data = model, data
        self.camera, self.camera_id = camera, cam_id
        self.width, self.height, self.has_depth = int(width), int(height), bool(depth)
        self.noise = noise or CameraNoise()
        self.K = intrinsics_from_fovy(float(model.cam_fovy[cam_id]), self.width, self.height)
        self._state = _RenderState()
        self._closed = False
        # Depth at the far clip plane means "nothing there".
        self._far_m = float(model.vis.map.zfar * model.stat.extent)

    def _renderers(self) -> tuple[mujoco.Renderer, mujoco.Renderer | None]:
        if self._closed:
            raise SpecError(f"device {self.name!r}: read after close()")
        if self._state.renderer is None:
            self._state.renderer = self._make_renderer()
            if self.has_depth:
                self._state.depth_renderer = self._make_renderer()
                self._state.depth_renderer.enable_depth_rendering()
            _OPEN_RENDERERS.add(self)
            # mujoco.egl registers eglTerminate at exit when it makes its first context;
            # exit hooks run last-registered first, so ours must follow it (issue 11 §4).
            atexit.unregister(_close_all_renderers)
            atexit.register(_close_all_renderers)
        return self._state.renderer, self._state.depth_renderer

    def _make_renderer(self) -> mujoco.Renderer:
        r = mujoco.Renderer(self.model, self.height, self.width)
        # Software rendering: shadows and reflections cost most of the frame time and a
        # sensor camera does not need them (DESIGN.md, "Headless rendering").
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False
        return r

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has released the renderers."""
        return self._closed

    def close(self) -> None:
        """Release the renderers (idempotent)."""
        self._closed = True
        for attr in ("renderer", "depth_renderer"):
            r = getattr(self._state, attr)
            if r is not None:
                r.close()
                setattr(self._state, attr, None)
        _OPEN_RENDERERS.discard(self)

    def pose(self) -> np.ndarray:
        """(4, 4) camera_to_world of the OpenCV camera frame at the current state."""
        return camera_to_world(self.data, self.camera_id)

    def render_clean(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Noise-free (rgb (H, W, 3) uint8, depth (H, W) metres with NaN background | None)."""
        renderer, depth_renderer = self._renderers()
        renderer.update_scene(self.data, camera=self.camera_id)
        rgb = renderer.render().copy()
        depth = None
        if depth_renderer is not None:
            depth_renderer.update_scene(self.data, camera=self.camera_id)
            depth = depth_renderer.render().astype(np.float64)
            depth[depth >= 0.999 * self._far_m] = np.nan
        return rgb, depth

    def _measure(self) -> CameraFrame:
        rgb, depth = self.render_clean()
        s = self.faults.noise_scale
        if s > 0 and self.noise.rgb_sigma > 0:
            noisy = rgb + self.rng.normal(0.0, s * self.noise.rgb_sigma, rgb.shape)
            rgb = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        p_drop = combined_dropout(self.noise.dropout, self.faults)
        if depth is not None:
            if s > 0:
                sigma = s * (self.noise.depth_sigma_m + self.noise.depth_sigma_rel * depth)
                depth = depth + self.rng.normal(0.0, 1.0, depth.shape) * np.nan_to_num(sigma)
        if p_drop > 0:
            lost = self.rng.random((self.height, self.width)) < p_drop
            rgb[lost] = 0
            if depth is not None:
                depth[lost] = np.nan
        rgb.setflags(write=False)
        if depth is not None:
            depth.setflags(write=False)
        return CameraFrame(rgb, depth, self.K.copy(), self.pose(), self.name)
