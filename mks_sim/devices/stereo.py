"""A calibrated stereo pair built from two camera devices.

The pair's calibration comes from the two cameras' poses and intrinsics (as a calibration
routine would measure them): ``baseline_m`` is the distance between the optical centres, ``K``
the shared intrinsic matrix, ``right_to_left`` the relative pose. The workstation's devices
``stereo_left`` and ``stereo_right`` are plain :class:`~mks_sim.devices.camera.Camera`
devices; the ``stereo_points`` program forms a :class:`StereoFrame` from their two readings
with :func:`stereo_frame`. :class:`StereoPair` is the same thing as one device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mks_sim.devices.camera import Camera, CameraFrame
from mks_sim.devices.faults import DeviceFaults, SimDevice
from mks_sim.errors import DataError


@dataclass(frozen=True, eq=False)
class StereoFrame:
    """One stereo reading.

    Attributes:
        left, right: (H, W, 3) uint8 images.
        K: (3, 3) intrinsics shared by both cameras (pixels).
        baseline: distance between the optical centres, metres.
        left_to_world: (4, 4) pose of the left OpenCV camera frame.
        right_to_left: (4, 4) pose of the right camera frame in the left camera frame
            (for a rectified pair: identity rotation, translation (baseline, 0, 0)).
    """

    left: np.ndarray
    right: np.ndarray
    K: np.ndarray
    baseline: float
    left_to_world: np.ndarray
    right_to_left: np.ndarray


def stereo_frame(left: CameraFrame, right: CameraFrame) -> StereoFrame:
    """Pair two camera readings into a calibrated :class:`StereoFrame`.

    Raises:
        DataError: the images differ in size, the intrinsics differ, or the centres coincide.
    """
    if left.rgb.shape != right.rgb.shape:
        raise DataError(
            f"stereo pair {left.name!r}/{right.name!r}: expected equal image sizes, "
            f"got {left.rgb.shape} and {right.rgb.shape}"
        )
    if not np.allclose(left.K, right.K, rtol=1e-6, atol=1e-6):
        raise DataError(
            f"stereo pair {left.name!r}/{right.name!r}: expected equal intrinsics, "
            f"got {left.K.tolist()} and {right.K.tolist()}"
        )
    right_to_left = np.linalg.inv(left.camera_to_world) @ right.camera_to_world
    baseline = float(np.linalg.norm(right_to_left[:3, 3]))
    if baseline <= 1e-9:
        raise DataError(
            f"stereo pair {left.name!r}/{right.name!r}: expected distinct optical centres, "
            "got a zero baseline"
        )
    return StereoFrame(left.rgb, right.rgb, left.K, baseline, left.camera_to_world, right_to_left)


class StereoPair(SimDevice):
    """Two cameras read together; ``read()`` returns a :class:`StereoFrame`.

    The two cameras' own faults still apply (a failed camera fails the pair).
    """

    def __init__(
        self,
        left: Camera,
        right: Camera,
        rng: np.random.Generator,
        *,
        name: str = "stereo",
        faults: DeviceFaults | None = None,
    ) -> None:
        super().__init__(name, rng, faults)
        self.left, self.right = left, right

    @property
    def baseline_m(self) -> float:
        """Distance between the two optical centres at the current state, metres."""
        return float(np.linalg.norm(self.right.pose()[:3, 3] - self.left.pose()[:3, 3]))

    def _measure(self) -> StereoFrame:
        return stereo_frame(self.left.read(), self.right.read())

    def close(self) -> None:
        """Close both cameras."""
        self.left.close()
        self.right.close()
