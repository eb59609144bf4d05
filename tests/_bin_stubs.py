"""A stub robot for tests of the ``clear_bin`` loop alone (no simulator): the methods every
such stub shares, and the evaluation hooks patched to read its state."""

from __future__ import annotations

from typing import Any

import pytest


def bin_box() -> Any:
    """The shipped bin scene's output box (worlds/bin.toml ``[output_box]``)."""
    from mks_sim.sim.scenes import build_scene

    box = build_scene("bin").output_box
    assert box is not None
    return box


class StubPicker:
    """What a stub :class:`~mks_sim.tasks.bin.BinPicker` answers alike in every loop test:
    neighbours never block, the one body is ``part``, and it counts as picked once
    ``in_box``. Subclasses set ``in_box`` and define ``grasps`` and ``pick`` (and ``sense``
    when the one part at the origin will not do)."""

    in_box = False

    def __init__(self, world: Any = None, devices: Any = None, **kw: Any) -> None:
        """The state ``clear_bin`` reads of a robot with one part and one view, healthy."""
        from types import SimpleNamespace

        self.world, self.bodies = world, ["part"]
        self.failed_grasps: list[Any] = []
        self.felt: list[Any] = []
        self.retry_failed = False
        self.in_box = False
        self.sensed = SimpleNamespace(provenance={})
        self.perception_s = self.last_tilt_deg = 0.0
        self.last_passengers = self.last_hung_on = 0
        self.views, self.faults_seen, self.obj = 1, {}, None
        self.faults: dict[str, str] = {}
        self.region = "bin"
        self.tried: list[float] = []  # what a subclass records of each pick it tries

    def sense(self) -> list[Any]:
        """The one part at the origin, score 1, until it is in the box."""
        from types import SimpleNamespace

        import numpy as np

        return [] if self.in_box else [SimpleNamespace(matrix=np.eye(4), score=1.0)]

    def to_table(self) -> None:
        """The table around the bin holds nothing (whatever a subclass senses in the bin)."""
        self.region = "table"
        self.sense = self.unsure_left = lambda *a: []  # type: ignore[method-assign]

    def unsure_left(self, avoid: Any = ()) -> list[Any]:
        """No instance is unsure."""
        return []

    def clear_of_neighbours(self, i: int, cands: list[Any]) -> list[Any]:
        return list(cands)

    def redraw(self) -> None:
        pass

    def body_of(self, T: Any) -> str:
        return "part"

    def picked(self) -> int:
        return int(self.in_box)


def patch_loop(
    monkeypatch: pytest.MonkeyPatch, binmod: Any, robot_class: type, robots: list
) -> None:
    """``clear_bin`` builds ``robot_class``; nothing is covered, the box holds the part when
    the last robot says so, and no fault fields are reported."""
    monkeypatch.setattr(binmod, "BinPicker", robot_class)
    monkeypatch.setattr(binmod, "covered_points", lambda *a: 0)
    monkeypatch.setattr(binmod, "in_output_box", lambda world, body: robots[-1].in_box)
    monkeypatch.setattr(binmod, "fault_fields", lambda *a: {}, raising=False)
