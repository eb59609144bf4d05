"""`mks-sim demo`: the whole system on scene 2 (cube, sphere atop) and the industrial part.

Sense (camera views, stereo pair, range finder), the SPG, curvature separation, vertexes and
control points, Hough localization and refinement, then grasp the sphere, the cube and the
part in turn; last a bin of 3 parts: every instance localized, one picked into the output
box (``mks_sim.cli._bin.demo_bin``). Prints a summary table (estimate vs truth, errors, grasp result per object)
and writes a report folder: one image per stage, a video of the grasps and, when the ``viz``
extra is installed, ``demo.rrd``: a Rerun recording of every stage (``--rerun SPEC`` sends it
elsewhere, ``--no-rerun`` skips it; ``docs/visualization.md``). On its ``episode`` timeline
0 is scene 2, 1 the part.

Ground truth is read only to fill the "truth" and "error" columns and to judge the grasps.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from mks_sim.viz import NullRecorder, Recorder, RerunSpec, add_rerun_argument, open_recorder

HELP = "run the whole system on scene 2 and the part: sense, SPG, Hough, grasp; write a report"

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", metavar="DIR", help="report folder (default ./reports/demo-<timestamp>/)"
    )
    parser.add_argument("--seed", type=int, default=0, help="object placement and noise seed")
    parser.add_argument("--no-video", action="store_true", help="skip the grasp video")
    parser.add_argument("--no-grasp", action="store_true", help="sense and localize only")
    add_rerun_argument(parser)  # default: OUT/demo.rrd when rerun-sdk is installed
    parser.add_argument("--no-rerun", action="store_true", help="write no demo.rrd")


@dataclass
class ObjectRow:
    """One line of the summary table."""

    object: str
    estimate: np.ndarray | None = None
    truth: np.ndarray | None = None
    position_mm: float = float("nan")
    rotation_deg: float = float("nan")
    localize_s: float = float("nan")
    grasp: str = "-"
    retries: int = 0
    note: str = ""
    provenance: dict[str, str] = field(default_factory=dict)


class Demo:
    """The demo's state: output folder, progress, frames, rows."""

    def __init__(self, out: Path, seed: int, video: bool, grasp: bool) -> None:
        from tqdm import tqdm

        self.out = out
        self.seed = seed
        self.video = video
        self.do_grasp = grasp
        self.frames: list[np.ndarray] = []
        self.rows: dict[str, ObjectRow] = {}
        self.images: list[str] = []
        self.notes: list[str] = []
        self.recorder: Recorder = NullRecorder()
        self.bar = tqdm(total=15, desc="demo", unit="stage", file=sys.stderr)

    def stage(self, name: str, fn: Callable[[], Any]) -> Any:
        """Run one stage; a failing stage is reported and the demo goes on."""
        from mks_sim.errors import MksError

        self.bar.set_postfix_str(name)
        t0 = time.perf_counter()
        try:
            return fn()
        except (MksError, ImportError, ValueError, RuntimeError) as exc:
            msg = f"stage {name!r} failed: {type(exc).__name__}: {exc}"
            logger.warning(msg)
            self.notes.append(msg)
            return None
        finally:
            logger.info("stage %s: %.1f s", name, time.perf_counter() - t0)
            self.bar.update()

    def image(self, name: str) -> Path:
        path = self.out / name
        self.images.append(name)
        return path


# ----------------------------------------------------------------------------- stages


def _sense_images(demo: Demo, devices: Any, tag: str) -> None:
    from mks_sim.errors import DeviceFailure
    from mks_sim.report import save_image

    for name in ("overhead_camera", "stereo_left", "stereo_right"):
        dev = devices.get(name)
        if dev is None:
            continue
        try:
            frame = dev.read()
        except DeviceFailure as exc:
            demo.notes.append(f"{tag}: {exc}")
            continue
        save_image(frame.rgb, demo.image(f"{tag}_01_{name}.png"), f"{tag}: {name}")


def _scan(demo: Demo, devices: Any, tag: str) -> np.ndarray:
    from mks_sim.devices.range_finder import merge_scans
    from mks_sim.report import save_points

    scans = devices["range_finder"].read()
    pts, views = merge_scans(scans)
    save_points(pts, demo.image(f"{tag}_02_range_scan.png"),
                f"{tag}: range finder, {len(scans)} views, {len(pts)} points", labels=views)  # fmt: skip
    return pts


def _region(points: np.ndarray, half: float = 0.22) -> np.ndarray:
    from mks_sim.sim import names

    cx, cy = names.OBJECT_REGION_CENTER_XY
    keep = (np.abs(points[:, 0] - cx) < half) & (np.abs(points[:, 1] - cy) < half)
    keep &= points[:, 2] > names.TABLE_TOP_Z + 0.003
    return points[keep]


def _spg_and_features(demo: Demo, snapshot: Any, tag: str, detector: str) -> None:
    from mks_sim.lowlevel.spg import SpatialProximityGraph
    from mks_sim.report import save_points

    pts = np.asarray(snapshot.get("Range_Points").data, dtype=float)[:, :3]
    objects = _region(pts)
    spg = SpatialProximityGraph(objects, m=8)
    coo = spg.adjacency.tocoo()
    edges = np.stack([coo.row, coo.col], axis=1)
    n, labels = (
        spg.symmetric_components() if hasattr(spg, "symmetric_components") else spg.components()
    )
    save_points(objects, demo.image(f"{tag}_03_spg.png"),
                f"{tag}: SPG m=8 over {len(objects)} points above the table, {n} components",
                labels=labels, edges=edges)  # fmt: skip
    curv = np.asarray(snapshot.get("Surface_Curvature").data, dtype=float)
    sel = _region(curv[:, :3])
    mask = np.isin(curv[:, 0], sel[:, 0])
    save_points(curv[mask, :3], demo.image(f"{tag}_04_curvature.png"),
                f"{tag}: curvature separation (planar / curved)", labels=curv[mask, 3])  # fmt: skip
    markers = {}
    for sensor in detector.split(","):
        rows = np.asarray(snapshot.get(sensor).data, dtype=float)
        markers[f"{sensor} ({len(rows)})"] = rows[:, :3]
    save_points(objects, demo.image(f"{tag}_05_features.png"), f"{tag}: {detector.replace(',', ' + ')}",
                markers=markers)  # fmt: skip


def _localize(demo: Demo, world: Any, devices: Any, obj: str) -> Any:
    from mks_sim.report import save_votes
    from mks_sim.sim import truth
    from mks_sim.tasks.evaluate import localization_error
    from mks_sim.workstation import localize_object

    row = demo.rows.setdefault(obj, ObjectRow(obj))
    t0 = time.perf_counter()
    result = localize_object(world, obj, devices, rng=np.random.default_rng(demo.seed),
                             graph=demo.recorder.tap_graph(None))  # fmt: skip
    demo.recorder.log_localization(result, world=world)
    row.localize_s = time.perf_counter() - t0
    row.provenance = dict(result.provenance)
    row.estimate = result.object_to_world
    row.truth = truth.object_to_world(world, obj)  # evaluation only: the summary's truth column
    demo.recorder.log_truth(obj, row.truth, world=world)
    err = localization_error(world, obj, result.object_to_world)
    row.position_mm, row.rotation_deg = err.position_mm, err.rotation_deg
    if not result.found:
        row.note = "not localized"
    save_votes(result.hypotheses, demo.image(f"{obj}_06_hough_maxima.png"),
               f"{obj}: accumulator maxima after refinement")  # fmt: skip
    return result


def _grasp(demo: Demo, world: Any, devices: Any, obj: str, renderer_hook: Any) -> Any:
    from mks_sim.report import save_grasp
    from mks_sim.tasks.episode import EpisodeAssembly
    from mks_sim.tasks.spec import task_for_object

    episode = EpisodeAssembly(task_for_object(obj), recorder=demo.recorder)
    episode.initialize_episode(world, np.random.default_rng([demo.seed, 3]), devices=devices,
                               on_frame=renderer_hook, frame_every=4)  # fmt: skip
    ok, retries, reason = episode.run()
    row = demo.rows.setdefault(obj, ObjectRow(obj))
    n = len(episode.relocalizations)
    moved = sum(r.corrected for r in episode.relocalizations)
    row.grasp = ("success" if episode.success() else f"failed ({reason})") + (
        f"; re-sensed {n}x, {moved} corrections"
    )
    row.retries = retries
    if episode.plan is not None and episode.estimate is not None:
        save_grasp(
            episode.estimate,
            episode.plan,
            demo.image(f"{obj}_07_grasp.png"),
            f"{obj}: chosen grasp",
        )
    return episode.controller, ok


def _put_aside(ctl: Any) -> None:
    """Set the held object down beside the work region and go back up."""
    from mks_sim.sim import names

    yaw = ctl.pinch_yaw()
    spot = np.array([0.24, 0.22, names.TABLE_TOP_Z])
    ctl.move_to(spot + [0, 0, 0.14], yaw, spacing_m=0.03)
    ctl.move_to(spot + [0, 0, 0.045], yaw, spacing_m=0.01)
    ctl.open(25)
    ctl.move_to(spot + [0, 0, 0.20], yaw, spacing_m=0.03)


def _frame_hook(demo: Demo, world: Any) -> tuple[Any, Any]:
    if not demo.video:
        return None, None
    import mujoco

    from mks_sim.sim import names

    renderer = mujoco.Renderer(world.model, height=240, width=320)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (0.0, 0.05, names.TABLE_TOP_Z + 0.08)
    cam.distance, cam.azimuth, cam.elevation = 0.85, 140.0, -22.0

    def hook() -> None:
        renderer.update_scene(world.data, camera=cam)
        demo.frames.append(renderer.render().copy())

    return renderer, hook


def run_demo(
    out: Path,
    seed: int = 0,
    video: bool = True,
    grasp: bool = True,
    rerun: RerunSpec | None = None,
) -> dict[str, Any]:
    """Run the demo, write the report into ``out`` (and the recording ``rerun`` asks for);
    returns the summary document."""
    from mks_sim.devices.factory import make_devices
    from mks_sim.sensing import SensorGraph
    from mks_sim.sim.world import build_world

    out.mkdir(parents=True, exist_ok=True)
    demo = Demo(out, seed, video, grasp)
    demo.recorder = open_recorder(rerun, "mks_sim demo")
    t_start = time.perf_counter()
    graph = SensorGraph.from_dir()
    try:
        # --- scene 2: the cube with the sphere atop it ------------------------------------
        world = build_world("scene2", seed=seed)
        demo.recorder.set_episode(0)
        demo.recorder.log_world(world)
        with make_devices(world.model, world.data, np.random.default_rng([seed, 1])) as devs:
            devices = demo.recorder.tap_devices(devs)  # each reading recorded (when on)
            demo.stage("scene2: cameras", lambda: _sense_images(demo, devices, "scene2"))
            demo.stage("scene2: range scan", lambda: _scan(demo, devices, "scene2"))
            snap = graph.snapshot(devices)
            demo.stage("scene2: SPG, curvature, vertexes",
                       lambda: _spg_and_features(demo, snap, "scene2", "Vertex_Detector,Sphere_Detector"))  # fmt: skip
            demo.stage("sphere: localize", lambda: _localize(demo, world, devices, "sphere"))
            demo.stage("cube: localize", lambda: _localize(demo, world, devices, "cube"))
            renderer, hook = _frame_hook(demo, world)
            try:
                if grasp:
                    res = demo.stage(
                        "sphere: grasp", lambda: _grasp(demo, world, devices, "sphere", hook)
                    )
                    if res is not None and res[1]:
                        demo.stage("sphere: put aside", lambda: _put_aside(res[0]))
                    else:
                        demo.bar.update()
                    demo.stage("cube: grasp", lambda: _grasp(demo, world, devices, "cube", hook))
                else:
                    demo.bar.update(3)
            finally:
                if renderer is not None:
                    renderer.close()
        # --- the industrial part ----------------------------------------------------------
        world = build_world("part", seed=seed)
        demo.recorder.set_episode(1)
        demo.recorder.log_world(world)
        with make_devices(world.model, world.data, np.random.default_rng([seed, 2])) as devs:
            devices = demo.recorder.tap_devices(devs)
            demo.stage("part: cameras", lambda: _sense_images(demo, devices, "part"))
            demo.stage("part: range scan", lambda: _scan(demo, devices, "part"))
            snap = graph.snapshot(devices)
            demo.stage("part: SPG, curvature, control points",
                       lambda: _spg_and_features(demo, snap, "part", "Control_Point_Detector"))  # fmt: skip
            demo.stage("part: localize", lambda: _localize(demo, world, devices, "part"))
            renderer, hook = _frame_hook(demo, world)
            try:
                if grasp:
                    demo.stage("part: grasp", lambda: _grasp(demo, world, devices, "part", hook))
                else:
                    demo.bar.update()
            finally:
                if renderer is not None:
                    renderer.close()
        # --- bin picking (issue 13; cli/_bin.py): 3 parts localized, one pick ---------------
        from mks_sim.cli._bin import demo_bin

        demo.stage("bin: localize all, pick one", lambda: demo_bin(demo, seed, grasp, _frame_hook))
        video_path = None
        if video and demo.frames:
            from mks_sim.report import write_video

            video_path = demo.stage(
                "video", lambda: write_video(demo.frames, out / "grasps.mp4", fps=12)
            )
        else:
            demo.bar.update()
    finally:
        demo.bar.close()
        demo.recorder.close()
    return _summary(demo, time.perf_counter() - t_start, video_path)


def _fmt_pos(T: np.ndarray | None) -> str:
    if T is None:
        return "-"
    x, y, z = 1000.0 * np.asarray(T)[:3, 3]
    yaw = np.degrees(np.arctan2(T[1, 0], T[0, 0]))
    return f"({x:.1f}, {y:.1f}, {z:.1f}) mm yaw {yaw:.1f}"


def _summary(demo: Demo, seconds: float, video: Any) -> dict[str, Any]:
    from mks_sim.report import format_table

    rows = [
        (r.object, _fmt_pos(r.estimate), _fmt_pos(r.truth), r.position_mm, r.rotation_deg,
         r.localize_s, r.grasp, r.retries)
        for r in demo.rows.values()
    ]  # fmt: skip
    headers = (
        "object",
        "estimate",
        "truth",
        "pos err mm",
        "rot err deg",
        "localize s",
        "grasp",
        "retries",
    )
    table = format_table(headers, rows) + (
        "\nrotation errors are modulo the object's symmetries (cube: its 24 rotations; the "
        "sphere's orientation is not observable)"
    )
    doc = {
        "seed": demo.seed,
        "seconds": round(seconds, 1),
        "objects": [
            {
                "object": r.object,
                "estimate": None if r.estimate is None else np.asarray(r.estimate).tolist(),
                "truth": None if r.truth is None else np.asarray(r.truth).tolist(),
                "position_error_mm": r.position_mm,
                "rotation_error_deg": r.rotation_deg,
                "localize_s": r.localize_s,
                "grasp": r.grasp,
                "retries": r.retries,
                "provenance": r.provenance,
            }
            for r in demo.rows.values()
        ],
        "images": demo.images,
        "video": None if video is None else str(Path(video).name),
        "notes": demo.notes,
        "table": table,
    }
    (demo.out / "summary.json").write_text(json.dumps(doc, indent=2, default=str))
    md = ["# mks-sim demo", "", f"seed {demo.seed}, {seconds:.0f} s", "", "```", table, "```", ""]
    md += [f"![{name}]({name})" for name in demo.images]
    if video is not None:
        md += ["", f"Video of the grasps: [{Path(video).name}]({Path(video).name})"]
    if (demo.out / "demo.rrd").is_file():
        md += ["", "Every stage as a Rerun recording: [demo.rrd](demo.rrd) (`rerun demo.rrd`; "
               "entity paths in the project's docs/visualization.md)"]  # fmt: skip
    if demo.notes:
        md += ["", "## Notes", "", *[f"- {n}" for n in demo.notes]]
    (demo.out / "README.md").write_text("\n".join(md) + "\n")
    return doc


def run(args: argparse.Namespace) -> int:
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    out = Path(args.out) if args.out else Path("reports") / f"demo-{stamp}"
    rerun = args.rerun
    if rerun is None and not args.no_rerun and importlib.util.find_spec("rerun") is not None:
        rerun = RerunSpec("save", str(out / "demo.rrd"))
    doc = run_demo(out, seed=args.seed, video=not args.no_video, grasp=not args.no_grasp,
                   rerun=rerun)  # fmt: skip
    print(doc["table"])
    for note in doc["notes"]:
        print(f"note: {note}")
    print(f"report written to {out.resolve()} ({len(doc['images'])} images"
          + (f", video {doc['video']}" if doc["video"] else "") + f", {doc['seconds']:.0f} s)")  # fmt: skip
    return 0
