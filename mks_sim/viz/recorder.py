"""The recorder seam: what the pipeline tells a recording, and the no-op used when off.

Code that can be recorded takes a ``recorder`` (default :class:`NullRecorder`) and calls it at a
few points; the Rerun implementation (:mod:`mks_sim.viz.rerun_recorder`) turns the calls into
entities (``docs/visualization.md``). Two taps see inside the sensing without touching it:

- :meth:`Recorder.tap_devices` wraps the devices so that every reading (camera frame, range
  scan, touch pads) is logged as it is read;
- :meth:`Recorder.tap_graph` wraps a :class:`~mks_sim.sensing.SensorGraph` so that the
  snapshots it makes are kept; :meth:`Recorder.log_localization` then logs their logical
  sensor streams (cached by the snapshot, so nothing is sensed twice) and the fallbacks.

Ground truth reaches a recorder only through :meth:`Recorder.log_truth`, called by evaluation
code, and is logged under ``eval/``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["DeviceTap", "GraphTap", "NullRecorder", "Recorder"]


@runtime_checkable
class Recorder(Protocol):
    """What recordable code calls. Every method is cheap to call on :class:`NullRecorder`."""

    enabled: bool

    def set_time(self, sim_time_s: float) -> None:
        """Put what follows at simulated time ``sim_time_s`` (seconds)."""

    def set_episode(self, episode: int | None, attempt: int | None = None) -> None:
        """Put what follows on episode ``episode`` (its seed) and attempt ``attempt``."""

    def tap_devices(self, devices: Mapping[str, Any]) -> Mapping[str, Any]:
        """The devices, wrapped so that each reading is logged (unchanged when off)."""

    def tap_graph(self, graph: Any) -> Any:
        """The sensor graph, wrapped so that its snapshots are kept (unchanged when off)."""

    def log_camera_views(self) -> None:
        """Read and log the tapped cameras not read yet (context views; call it after the
        last localization, as a camera reading draws on that camera's noise generator)."""

    def log_world(self, world: Any) -> None:
        """The world's static geometry (robot meshes) and its current robot state."""

    def log_robot(self, world: Any) -> None:
        """Joint state and posed robot meshes at the current time."""

    def log_localization(self, result: Any, *, world: Any = None) -> None:
        """A localization result: kept snapshots' streams, hypotheses, the chosen pose."""

    def log_snapshot(self, snap: Any, readings: Mapping[str, Any] | None = None) -> None:
        """A snapshot's device readings (and ``readings`` taken outside it), its logical
        sensor streams, fallbacks and grouping."""

    def log_cloud(
        self,
        points: Any,
        result: Any,
        *,
        model_points: Any = None,
        model_mesh: tuple[np.ndarray, np.ndarray] | None = None,
        name: str = "model",
    ) -> None:
        """A simulator-free localization: scene points, segments, hypotheses."""

    def log_truth(self, object_name: str, object_to_world: Any, *, world: Any = None) -> None:
        """Evaluation only: the true pose of ``object_name`` (logged under ``eval/``)."""

    def log_grasps(self, candidates: Sequence[Any], chosen: Any = None) -> None:
        """Grasp candidates (with their quality) and the one chosen."""

    def log_text(self, text: str, level: str = "INFO") -> None:
        """A line of the text log (``INFO`` | ``WARN`` | ``ERROR``)."""

    def close(self) -> None:
        """Flush and close the recording."""

    def __enter__(self) -> Recorder:
        """The recorder itself; closed on exit."""

    def __exit__(self, *exc: object) -> None:
        """Close the recording."""


class NullRecorder:
    """Logging off: every call does nothing and imports nothing."""

    enabled = False

    def set_time(self, sim_time_s: float) -> None:
        del sim_time_s

    def set_episode(self, episode: int | None, attempt: int | None = None) -> None:
        del episode, attempt

    def tap_devices(self, devices: Mapping[str, Any]) -> Mapping[str, Any]:
        return devices

    def tap_graph(self, graph: Any) -> Any:
        return graph

    def log_camera_views(self) -> None:
        pass

    def log_world(self, world: Any) -> None:
        del world

    def log_robot(self, world: Any) -> None:
        del world

    def log_localization(self, result: Any, *, world: Any = None) -> None:
        del result, world

    def log_snapshot(self, snap: Any, readings: Mapping[str, Any] | None = None) -> None:
        del snap, readings

    def log_cloud(
        self,
        points: Any,
        result: Any,
        *,
        model_points: Any = None,
        model_mesh: tuple[np.ndarray, np.ndarray] | None = None,
        name: str = "model",
    ) -> None:
        del points, result, model_points, model_mesh, name

    def log_truth(self, object_name: str, object_to_world: Any, *, world: Any = None) -> None:
        del object_name, object_to_world, world

    def log_grasps(self, candidates: Sequence[Any], chosen: Any = None) -> None:
        del candidates, chosen

    def log_text(self, text: str, level: str = "INFO") -> None:
        del text, level

    def close(self) -> None:
        pass

    def __enter__(self) -> NullRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class DeviceTap:
    """A device whose readings are handed to ``on_read(name, reading)`` (failures too).

    Everything but ``read`` is the wrapped device's own (``name``, ``faults``, ``close``).
    """

    def __init__(self, device: Any, name: str, on_read: Any) -> None:
        self.device = device
        self._device = device
        self._name = name
        self._on_read = on_read

    def read(self) -> Any:
        reading = self._device.read()
        self._on_read(self._name, reading)
        return reading

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._device, attr)


class GraphTap:
    """A sensor graph whose snapshots are appended to ``kept`` (everything else delegated)."""

    def __init__(self, graph: Any, kept: list[Any]) -> None:
        self._graph = graph
        self._kept = kept

    def snapshot(self, devices: Mapping[str, Any], **kwargs: Any) -> Any:
        snap = self._graph.snapshot(devices, **kwargs)
        self._kept.append(snap)
        return snap

    def __getattr__(self, attr: str) -> Any:
        return getattr(self._graph, attr)


def as_matrix(T: Any) -> np.ndarray | None:
    """(4, 4) float array of a pose (or None when ``T`` is None or not a finite 4x4)."""
    if T is None:
        return None
    M = np.asarray(T, dtype=float)
    if M.shape == (16,):
        M = M.reshape(4, 4)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        return None
    return M
