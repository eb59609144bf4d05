"""A model naming a logical sensor the sensor graph does not define fails at model load with
a one-line SpecError (it was swallowed, and the pipeline ran without the model's sensor)."""

from __future__ import annotations

from typing import Any

import pytest

from mks_sim.errors import SpecError
from mks_sim.localization import workstation


def test_unknown_model_sensor_fails_at_model_load(monkeypatch: pytest.MonkeyPatch) -> None:
    real = workstation._resolve_model

    def with_unknown_sensor(*args: Any, **kwargs: Any) -> tuple[str, Any, str, str, Any]:
        name, model, _sensor, source, entry = real(*args, **kwargs)
        return name, model, "No_Such_Detector", source, entry

    monkeypatch.setattr(workstation, "_resolve_model", with_unknown_sensor)
    read: list[str] = []

    class Untouchable(dict):  # type: ignore[type-arg]
        """Devices that record any read: the error must come before sensing."""

        def __getitem__(self, key: str) -> Any:
            read.append(key)
            raise AssertionError("a device was read")

    with pytest.raises(SpecError, match="No_Such_Detector") as info:
        workstation.localize_object(None, "cube", Untouchable())
    assert "\n" not in str(info.value)
    assert read == []


def test_known_model_sensor_is_listed() -> None:
    graph = workstation._default_graph()
    _, _, sensor, _, _ = workstation._resolve_model("cube", None, ())
    assert sensor in graph.required([sensor])
