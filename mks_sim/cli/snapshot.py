"""`mks-sim snapshot`: what the workstation's sensors see, written to a folder.

Files (all from device readings and logical sensors; nothing from the ground truth):

- ``overhead.png``, ``stereo_left.png``, ``stereo_right.png``: camera images;
  ``depth.png``: the depth camera, colour-mapped (near = bright);
- ``disparity.png``: StereoSGBM disparity of the rectified stereo pair (colour-mapped);
- ``range_points.ply``: the ``Range_Points`` logical sensor (range scan merged over its views,
  world frame, metres; served by an alternate if the range finder fails);
- ``spg.png``: the spatial proximity graph of the object points (top view, edges);
- ``curvature.png``: Surface_Curvature codes (planar blue / curved red, Table 4-5);
- ``planes.png``: planar regions of the grouping and the recovered vertexes (``Vertex_Detector``)
  and control points (``Control_Point_Detector``);
- scene 1: ``detections.png``: Circle_Detector circles and Corner_Holes_Detector labels
  (corners/holes) drawn on the overhead image, the ``disc_2cm`` and ``square_nut`` matches
  highlighted.

Example::

    mks-sim snapshot --scene scene2 --out snap/ --seed 3
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.cli import output_dir
from mks_sim.errors import MksError, SpecError
from mks_sim.sim import names
from mks_sim.viz import add_rerun_argument, open_recorder

HELP = "write camera images, disparity, range scan (PLY) and SPG/region/vertex pictures"

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scene", default=None, metavar="NAME|FILE",
        help="scene name (worlds/*.toml: scene1, scene2, part, ...) or scene file",
    )  # fmt: skip
    parser.add_argument(
        "--object", action="append", default=[], metavar="NAME",
        help="without --scene: the default scene of these database objects, dropped",
    )  # fmt: skip
    parser.add_argument(
        "--models", action="append", default=[], metavar="DIR",
        help="extra model-database folder (repeatable; also MKS_SIM_MODELS)",
    )  # fmt: skip
    parser.add_argument(
        "--out", required=True, type=Path, help="output folder (created; its parent must exist)"
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="randomise the layout (default: none)"
    )
    parser.add_argument(
        "--fail", nargs="+", action="extend", default=[], metavar="DEVICE",
        help="devices to fail (their logical sensors use alternates)",
    )  # fmt: skip
    add_rerun_argument(parser)


def _save_rgb(path: Path, rgb: np.ndarray) -> None:
    import imageio.v3 as iio

    iio.imwrite(path, np.ascontiguousarray(rgb))


def _colormap(values: np.ndarray, cmap: str = "viridis", invert: bool = False) -> np.ndarray:
    from matplotlib import colormaps

    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    out = np.zeros((*v.shape, 3), dtype=np.uint8)
    if ok.any():
        lo, hi = np.percentile(v[ok], [1, 99])
        s = np.clip((v - lo) / max(hi - lo, 1e-12), 0, 1)
        if invert:
            s = 1 - s
        rgba = colormaps[cmap](s)
        out[ok] = (255 * rgba[ok, :3]).astype(np.uint8)
    return out


def disparity(left: Any, right: Any, num_disparities: int = 128, block: int = 5) -> np.ndarray:
    """(H, W) float disparity (pixels, NaN invalid) of two camera frames, rectified left view."""
    import cv2

    h, w = left.rgb.shape[:2]
    K = np.asarray(left.K, dtype=float)
    left_to_right = np.linalg.inv(right.camera_to_world) @ left.camera_to_world
    R1, R2, P1, P2, *_ = cv2.stereoRectify(
        K, np.zeros(5), K, np.zeros(5), (w, h), left_to_right[:3, :3], left_to_right[:3, 3],
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=0,
    )  # fmt: skip
    ml = cv2.initUndistortRectifyMap(K, np.zeros(5), R1, P1, (w, h), cv2.CV_32FC1)
    mr = cv2.initUndistortRectifyMap(K, np.zeros(5), R2, P2, (w, h), cv2.CV_32FC1)
    gl = cv2.remap(cv2.cvtColor(left.rgb, cv2.COLOR_RGB2GRAY), *ml, cv2.INTER_LINEAR)
    gr = cv2.remap(cv2.cvtColor(right.rgb, cv2.COLOR_RGB2GRAY), *mr, cv2.INTER_LINEAR)
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0, numDisparities=num_disparities, blockSize=block,
        P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1, uniquenessRatio=10,
        speckleWindowSize=100, speckleRange=2,
    )  # fmt: skip
    d = sgbm.compute(gl, gr).astype(np.float32) / 16.0
    d[d <= 0.5] = np.nan
    d[:, :num_disparities] = np.nan
    return d


def _project(frame: Any, xyz: np.ndarray) -> np.ndarray:
    """(N, 2) pixel coordinates of world points in a camera frame (OpenCV convention)."""
    T = np.linalg.inv(np.asarray(frame.camera_to_world, dtype=float))
    p = xyz @ T[:3, :3].T + T[:3, 3]
    uv = p @ np.asarray(frame.K, dtype=float).T
    return uv[:, :2] / uv[:, 2:3]


def _figure(size: tuple[float, float] = (6.4, 5.2)) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size, dpi=110)
    return plt, fig, ax


def _save_top_view(plt: Any, fig: Any, ax: Any, path: Path) -> None:
    """Label a top view in millimetres at equal aspect, save it and close the figure."""
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _objects(
    points: np.ndarray, table_z: float = names.TABLE_TOP_Z, margin: float = 0.004
) -> np.ndarray:
    return points[points[:, 2] > table_z + margin]


def draw_spg(path: Path, points: np.ndarray, title: str) -> None:
    """Top view of the SPG (m = 6 neighbours, edges <= 6 mm) of the object points."""
    from matplotlib.collections import LineCollection

    from mks_sim.lowlevel.spg import SpatialProximityGraph

    obj = _objects(points)
    if len(obj) > 6000:
        obj = obj[np.random.default_rng(0).choice(len(obj), 6000, replace=False)]
    plt, fig, ax = _figure()
    if len(obj) >= 10:
        spg = SpatialProximityGraph(obj, m=6, threshold=0.006)
        n, labels = spg.components()
        A = spg.adjacency.tocoo()
        segs = np.stack([obj[A.row, :2], obj[A.col, :2]], axis=1) * 1000
        ax.add_collection(LineCollection(list(segs), linewidths=0.3, colors="0.5"))
        ax.scatter(obj[:, 0] * 1000, obj[:, 1] * 1000, c=labels, s=1.5, cmap="tab20")
        title += f" ({len(obj)} points, {n} components)"
    ax.set_title(title, fontsize=9)
    _save_top_view(plt, fig, ax, path)


def draw_curvature(path: Path, rows: np.ndarray) -> None:
    """Surface_Curvature rows (x, y, z, code): planar blue, curved red (top view)."""
    plt, fig, ax = _figure()
    planar = rows[:, 3] < 0
    ax.scatter(
        rows[planar, 0] * 1000, rows[planar, 1] * 1000, s=1.5, c="tab:blue", label="planar (-1)"
    )
    ax.scatter(
        rows[~planar, 0] * 1000, rows[~planar, 1] * 1000, s=1.5, c="tab:red", label="curved (+1)"
    )
    ax.set_title("Surface_Curvature (Table 4-5 codes), top view", fontsize=9)
    ax.legend(loc="upper right", fontsize=8, markerscale=5)
    _save_top_view(plt, fig, ax, path)


def draw_planes(
    path: Path, points: np.ndarray, vertexes: np.ndarray | None, control: np.ndarray | None
) -> None:
    """Planar regions of each object (colours) with recovered vertexes / control points."""
    from mks_sim.lowlevel.grouping import segment_surfaces
    from mks_sim.sensing.programs.points import _object_clouds

    plt, fig, ax = _figure()
    k = 0
    for cloud in _object_clouds(
        points, {"table_z_m": names.TABLE_TOP_Z, "table_margin_m": 0.004, "gap_m": 0.012, "m": 12}
    ):
        try:
            seg = segment_surfaces(cloud, m=12)
        except MksError:
            continue
        ax.scatter(cloud[:, 0] * 1000, cloud[:, 1] * 1000, s=1, c="0.85")
        for region in seg.planes:
            p = cloud[region.indices]
            ax.scatter(p[:, 0] * 1000, p[:, 1] * 1000, s=1.5, color=plt.cm.tab20(k % 20))
            k += 1
    if vertexes is not None and len(vertexes):
        ax.scatter(
            vertexes[:, 0] * 1000,
            vertexes[:, 1] * 1000,
            marker="x",
            c="k",
            s=40,
            label="Vertex_Detector",
        )
    if control is not None and len(control):
        ax.scatter(
            control[:, 0] * 1000,
            control[:, 1] * 1000,
            marker="o",
            facecolors="none",
            edgecolors="m",
            s=80,
            label="Control_Point_Detector",
        )
    if (vertexes is not None and len(vertexes)) or (control is not None and len(control)):
        ax.legend(loc="upper right", fontsize=8)
    ax.set_title(f"planar regions ({k}) and recovered vertexes, top view", fontsize=9)
    _save_top_view(plt, fig, ax, path)


def draw_detections(path: Path, frame: Any, circles: np.ndarray, shapes: np.ndarray) -> None:
    """Scene 1: circles and (corners, holes) labels on the overhead image; model matches."""
    from mks_sim.models.database import ModelDatabase
    from mks_sim.models.feature import match_spg

    db = ModelDatabase.from_dir()
    discs = {m.description for m in match_spg([db.get("disc_2cm")], circles)}
    nuts = {m.description for m in match_spg([db.get("square_nut")], shapes)}
    plt, fig, ax = _figure((7.2, 5.6))
    ax.imshow(frame.rgb)
    z = names.TABLE_TOP_Z
    for i, (x, y, r) in enumerate(circles):
        if r <= 0:
            continue
        c = _project(frame, np.array([[x, y, z]]))[0]
        edge = _project(frame, np.array([[x + r, y, z]]))[0]
        rad = float(np.linalg.norm(edge - c))
        color = "lime" if i in discs else "yellow"
        ax.add_patch(plt.Circle(tuple(c), rad, fill=False, color=color, lw=2 if i in discs else 1))
    for i, (x, y, corners, holes) in enumerate(shapes):
        c = _project(frame, np.array([[x, y, z]]))[0]
        label = f"{int(corners)}c/{int(holes)}h"
        if i in nuts:
            label = "square nut " + label
        ax.text(c[0], c[1], label, color="red" if i in nuts else "white", fontsize=7,
                ha="center", va="center", bbox={"facecolor": "black", "alpha": 0.4, "pad": 1})  # fmt: skip
    ax.set_title("scene 1: Circle_Detector (green: disc_2cm) and Corner_Holes_Detector", fontsize=9)
    ax.axis("off")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    from mks_sim.devices import DEVICE_NAMES, DeviceFaults, make_devices
    from mks_sim.io.pointcloud import write_ply
    from mks_sim.sensing import SensorGraph
    from mks_sim.sim.world import build_world

    unknown = [d for d in args.fail if d not in DEVICE_NAMES]
    if unknown:
        raise SpecError(
            f"--fail: unknown device(s) {unknown}; valid device names: {list(DEVICE_NAMES)}"
        )
    if args.scene is None and not args.object:
        raise SpecError("expected --scene NAME|FILE or --object NAME, got neither")
    out: Path = output_dir(args.out, "--out")  # checked (and created) before any work
    world = build_world(args.scene, seed=args.seed, objects=args.object, models=args.models)
    # what to draw follows the scene's content: flat parts on a tray (scene 1) or objects
    # whose default sensor is the control-point detector (the part)
    tray = world.scene.support_z > names.TABLE_TOP_Z
    from mks_sim.models.objects import load_object

    wants_control = any(
        load_object(m, models=args.models).sensor == "Control_Point_Detector"
        for m in set(world.scene.models.values())
    )
    faults = {d: DeviceFaults(failed=True) for d in args.fail}
    seed = 0 if args.seed is None else int(args.seed)
    written: list[str] = []
    graph = SensorGraph.from_dir()
    with make_devices(world.model, world.data, np.random.default_rng(seed), faults) as devs:
        frames: dict[str, Any] = {}
        for name in ("overhead_camera", "stereo_left", "stereo_right", "depth_camera"):
            try:
                frames[name] = devs[name].read()
            except MksError as exc:
                log.warning("%s: %s", name, exc)
        for name, file in (("overhead_camera", "overhead.png"), ("stereo_left", "stereo_left.png"),
                           ("stereo_right", "stereo_right.png")):  # fmt: skip
            if name in frames:
                _save_rgb(out / file, frames[name].rgb)
                written.append(file)
        if "depth_camera" in frames and frames["depth_camera"].depth is not None:
            _save_rgb(
                out / "depth.png", _colormap(frames["depth_camera"].depth, "magma", invert=True)
            )
            written.append("depth.png")
        if "stereo_left" in frames and "stereo_right" in frames:
            disp = disparity(frames["stereo_left"], frames["stereo_right"])
            _save_rgb(out / "disparity.png", _colormap(disp, "turbo"))
            written.append("disparity.png")
        snap = graph.snapshot(devs)
        if tray:
            circles = snap.get("Circle_Detector").data
            shapes = snap.get("Corner_Holes_Detector").data
            if "overhead_camera" in frames:
                draw_detections(out / "detections.png", frames["overhead_camera"], circles, shapes)
                written.append("detections.png")
        try:
            pts = np.asarray(snap.get("Range_Points").data)[:, :3]
        except MksError as exc:
            log.warning("Range_Points: %s", exc)
            pts = None
        if pts is not None:
            write_ply(out / "range_points.ply", pts)
            written.append("range_points.ply")
            served = snap.provenance.get("Range_Points", "primary")
            draw_spg(out / "spg.png", pts, f"SPG of Range_Points ({served})")
            written.append("spg.png")
            if not tray:
                try:
                    draw_curvature(out / "curvature.png", snap.get("Surface_Curvature").data)
                    written.append("curvature.png")
                except MksError as exc:
                    log.warning("Surface_Curvature: %s", exc)
                verts = ctrl = None
                try:
                    verts = snap.get("Vertex_Detector").data
                    if wants_control:
                        ctrl = snap.get("Control_Point_Detector").data
                except MksError as exc:
                    log.warning("vertexes: %s", exc)
                draw_planes(out / "planes.png", pts, verts, ctrl)
                written.append("planes.png")
        provenance = dict(snap.provenance)
        with open_recorder(args.rerun, "mks_sim snapshot") as recorder:
            recorder.log_world(world)
            recorder.log_snapshot(snap, frames)
    print(f"wrote {len(written)} files to {out}: {', '.join(written)}")
    print("logical sensors: " + ", ".join(f"{k} <- {v}" for k, v in sorted(provenance.items())))
    return 0
