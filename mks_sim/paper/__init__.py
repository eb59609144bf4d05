"""The paper's case studies recomputed (``mks-sim paper``).

Each section module exposes ``report() -> (text, json_dict)``; :mod:`mks_sim.cli.paper` lists
them in ``SECTIONS``. :mod:`mks_sim.paper.tables`: the feature-model SPG tables 4-2, 4-4, 4-6.
"""
