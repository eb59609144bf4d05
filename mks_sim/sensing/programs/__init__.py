"""Registered logical-sensor programs (imported lazily by :mod:`mks_sim.sensing.registry`).

``kernel`` holds generic programs and acceptance tests usable with any devices; the
workstation's own programs live in ``vision`` and ``points``.
"""
