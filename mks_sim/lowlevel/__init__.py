"""Low-level processing of MKS (paper sections 1.2 and 3): k-d tree, dynamic k-d tree, SPG.

Public names: :class:`Metric`, :func:`abs_diff`, :class:`KDTree`, :class:`DynamicKDTree`,
:class:`SpatialProximityGraph`.
"""

from __future__ import annotations

from mks_sim.lowlevel.dynamic import DynamicKDTree
from mks_sim.lowlevel.kdtree import KDTree
from mks_sim.lowlevel.metric import Metric, abs_diff
from mks_sim.lowlevel.spg import SpatialProximityGraph

__all__ = ["DynamicKDTree", "KDTree", "Metric", "SpatialProximityGraph", "abs_diff"]
