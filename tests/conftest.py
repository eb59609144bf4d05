"""Suite-wide settings: deterministic property tests, headless GL."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from hypothesis import HealthCheck, settings  # noqa: E402

# Property tests must be deterministic in CI: the same examples every run.
settings.register_profile(
    "mks",
    derandomize=True,
    max_examples=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("mks")
