"""Datasets of scripted episodes in Minari's format (the ``record`` extra).

``mks-sim grasp ... --record DIR`` steps the env (``mks_sim/Grasp-v*``) with the scripted
policy and writes every episode through :class:`minari.DataCollector`: observations,
actions, rewards, terminations, truncations and per-step infos of one fixed structure
(:mod:`mks_sim.record.infos`). Minari is imported only here, so unrecorded runs never load it.
"""

from __future__ import annotations

from mks_sim.record.dataset import (
    RECORD_INSTALL_HINT,
    check_record_dir,
    load_recorded,
    record_episodes,
)
from mks_sim.record.infos import StepInfo

__all__ = [
    "RECORD_INSTALL_HINT",
    "StepInfo",
    "check_record_dir",
    "load_recorded",
    "record_episodes",
]
