"""Localization at the workstation, end to end from simulated sensors (paper section 4).

The flow lives in :mod:`mks_sim.localization.workstation` (the entry: snapshot -> points ->
pipeline) and :mod:`mks_sim.localization.pipeline` (the paths by model kind); this module
re-exports the entry so that old imports keep working.
"""

from __future__ import annotations

from mks_sim.localization.workstation import (
    POINTS_SENSOR,
    REPRESENTATION_SENSOR,
    WorkstationLocalization,
    _default_graph,
    find_table,
    localize,
    localize_object,
    table_z_m,
    workstation_representation,
)

__all__ = [
    "POINTS_SENSOR",
    "REPRESENTATION_SENSOR",
    "WorkstationLocalization",
    "_default_graph",
    "find_table",
    "localize",
    "localize_object",
    "table_z_m",
    "workstation_representation",
]
