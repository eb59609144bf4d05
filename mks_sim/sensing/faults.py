"""One format for "what was degraded" in every command's result (issue 12).

Every result that sensed through devices says which devices failed and which logical sensors
ran on an alternate, as two JSON fields::

    "faults":   ["touch_finger_1"],
    "warnings": ["Touch_Contacts ran on alternate Torque_For_Pad_1"]

``faults`` are device names, sorted (the injected ones and any that raised); ``warnings`` one
line per logical sensor not served by its primary way, sorted by sensor.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

PRIMARY = "primary"


def alternate_warnings(provenance: Mapping[str, str]) -> list[str]:
    """One line per logical sensor served by an alternate (``provenance``: sensor -> way)."""
    return [
        f"{sensor} ran on alternate {way}"
        for sensor, way in sorted(provenance.items())
        if way != PRIMARY
    ]


def fault_fields(failed: Iterable[str], provenance: Mapping[str, str]) -> dict[str, Any]:
    """``{"faults": sorted failed devices, "warnings": alternate_warnings(provenance)}``."""
    return {"faults": sorted(set(failed)), "warnings": alternate_warnings(provenance)}
