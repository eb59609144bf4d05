"""Reports: stage images (matplotlib, Agg backend), videos (imageio) and summary tables.

Videos are MP4 through ``imageio-ffmpeg`` (a runtime dependency); GIF (Pillow) only when the
path ends in ``.gif``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.errors import DataError, MksError

logger = logging.getLogger(__name__)


def has_ffmpeg() -> bool:
    """True when imageio can write MP4 (``imageio-ffmpeg`` installed)."""
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def write_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 15.0) -> Path:
    """Write (H, W, 3) uint8 frames to ``path``: GIF when it ends in ``.gif``, else MP4
    (H.264 through ``imageio-ffmpeg``; ``.mp4``, ``.m4v``, ``.mov``).

    Returns:
        The path written.

    Raises:
        DataError: no frames, or frames of different shapes.
        MksError: a video suffix and ``imageio-ffmpeg`` is not installed.
    """
    import imageio.v3 as iio

    if not frames:
        raise DataError(f"video {path}: expected at least one frame, got none")
    shape = frames[0].shape
    if any(f.shape != shape for f in frames) or len(shape) != 3:
        raise DataError(f"video {path}: frames must all be (H, W, 3); first is {shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() != ".gif" and not has_ffmpeg():
        raise MksError(
            f"video {path}: MP4 needs imageio-ffmpeg, which is not installed; run "
            "`pip install imageio-ffmpeg==0.8.1` or ask for a .gif"
        )
    stack = np.stack([np.asarray(f, dtype=np.uint8) for f in frames])
    if path.suffix.lower() == ".gif":
        iio.imwrite(path, stack, duration=1000.0 / fps, loop=0)
    else:
        iio.imwrite(path, stack, fps=fps)
    return path


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """A plain-text table (columns padded, floats to 2 decimals, nan as '-')."""

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "-" if not math.isfinite(v) else f"{v:.2f}"
        return str(v)

    text = [[cell(v) for v in row] for row in rows]
    widths = [
        max(len(h), *(len(r[i]) for r in text)) if text else len(h) for i, h in enumerate(headers)
    ]
    lines = ["  ".join(h.ljust(w) for h, w in zip(headers, widths))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in text]
    return "\n".join(lines)


def _figure(title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6.4, 4.8), dpi=100)
    fig.suptitle(title)
    return fig, plt


def save_image(image: np.ndarray, path: str | Path, title: str = "") -> Path:
    """Save an (H, W[, 3]) image with a title (depth images get a colour bar)."""
    fig, plt = _figure(title)
    ax = fig.add_subplot(111)
    img = np.asarray(image)
    if img.ndim == 2:
        im = ax.imshow(img, cmap="viridis")
        fig.colorbar(im, ax=ax, shrink=0.8)
    else:
        ax.imshow(img)
    ax.set_axis_off()
    path = Path(path)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def save_points(
    points: np.ndarray,
    path: str | Path,
    title: str = "",
    labels: np.ndarray | None = None,
    edges: np.ndarray | None = None,
    markers: dict[str, np.ndarray] | None = None,
    max_points: int = 6000,
) -> Path:
    """3-D scatter of ``points`` (N, 3), coloured by ``labels`` (N,), with optional SPG
    ``edges`` (E, 2) index pairs and named marker sets (M, 3)."""
    fig, plt = _figure(title)
    ax = fig.add_subplot(111, projection="3d")
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    idx = np.arange(len(pts))
    if len(pts) > max_points:
        idx = np.random.default_rng(0).choice(len(pts), max_points, replace=False)
    c = None if labels is None else np.asarray(labels)[idx]
    if len(idx):
        if c is None:
            ax.scatter(pts[idx, 0], pts[idx, 1], pts[idx, 2], s=1, color="tab:blue")
        else:
            ax.scatter(pts[idx, 0], pts[idx, 1], pts[idx, 2], s=1, c=c, cmap="tab20")
    if edges is not None and len(edges):
        e = np.asarray(edges)[:: max(1, len(edges) // 3000)]
        for i, j in e:
            ax.plot(*pts[[i, j]].T, lw=0.2, color="0.4")
    for k, (name, m) in enumerate((markers or {}).items()):
        m = np.asarray(m, dtype=float).reshape(-1, 3)
        ax.scatter(m[:, 0], m[:, 1], m[:, 2], s=40, marker="x^os*"[k % 5], label=name)
    if markers:
        ax.legend(loc="upper left", fontsize=7)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    path = Path(path)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def save_votes(hypotheses: Sequence[Any], path: str | Path, title: str = "", top: int = 12) -> Path:
    """Bar chart of the votes (and scores) of pose hypotheses: the accumulator maxima."""
    fig, plt = _figure(title)
    ax = fig.add_subplot(111)
    hyps = list(hypotheses)[:top]
    votes = [int(getattr(h, "votes", 0)) for h in hyps]
    scores = [float(getattr(h, "score", float("nan"))) for h in hyps]
    if hyps:
        ax.bar(range(len(hyps)), votes, color="tab:blue")
        for i, s in enumerate(scores):
            if math.isfinite(s):
                ax.text(i, votes[i], f"{s:.2f}", ha="center", va="bottom", fontsize=7)
    else:
        ax.text(0.5, 0.5, "no maxima", ha="center", transform=ax.transAxes)
    ax.set_xlabel("hypothesis (best first; label = verification score)")
    ax.set_ylabel("votes")
    path = Path(path)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def save_grasp(object_to_world: np.ndarray, plan: Any, path: str | Path, title: str = "") -> Path:
    """Top view of a chosen grasp: the estimated object frame, the pinch point, the closing
    axis and the open fingertips."""
    from mks_sim.tasks.grasp import FINGERTIPS_XY

    fig, plt = _figure(title)
    ax = fig.add_subplot(111)
    T = np.asarray(object_to_world, dtype=float)
    o = T[:3, 3]
    for k, colour in enumerate(("r", "g", "b")):
        ax.annotate(
            "", o[:2] + 0.03 * T[:2, k], o[:2], arrowprops={"arrowstyle": "->", "color": colour}
        )
    p = np.asarray(plan.grasp_point_world)
    c, s = math.cos(plan.yaw_rad), math.sin(plan.yaw_rad)
    tips = FINGERTIPS_XY @ np.array([[c, s], [-s, c]]) + p[:2]
    ax.plot(*p[:2], "k+", ms=12, label="pinch point")
    ax.plot(tips[:, 0], tips[:, 1], "o", ms=10, mfc="none", label="open fingertips")
    half = plan.width_m / 2
    ax.plot([p[0] - half * c, p[0] + half * c], [p[1] - half * s, p[1] + half * s], "m-", lw=3,
            label=f"closing axis, width {1000 * plan.width_m:.0f} mm")  # fmt: skip
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=7)
    path = Path(path)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path
