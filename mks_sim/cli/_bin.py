"""Bin picking from the CLI (issue 13): ``mks-sim localize --all`` and its report.

``mks-sim localize --scene bin --object part --all [--count N] --seed S --json`` builds the
bin from the seed, senses (a second view with the wrist camera when the first is not good
enough: ``BinPicker.sense``; ``--one-view`` never), localizes every instance
(:func:`mks_sim.localization.instances.localize_instances`) and evaluates them against the
ground truth afterwards (``mks_sim.tasks.bin.evaluate_instances``). ``--models DIR`` adds
model folders (an object of its own in the bin).
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from mks_sim.errors import SpecError


def add_all_arguments(parser: argparse.ArgumentParser) -> None:
    """``--all`` and ``--count`` for ``mks-sim localize``."""
    parser.add_argument(
        "--all", action="store_true",
        help="localize every instance (bin picking: --scene bin); JSON instances, found, "
        "present, false_positives",
    )  # fmt: skip
    parser.add_argument(
        "--count", type=int, default=None, metavar="N",
        help="with --all: instances dropped into the bin scene (1..12; default the file's)",
    )  # fmt: skip
    _add_one_view(parser)


def _add_one_view(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--one-view", action="store_true",
        help="bin: never take a second view with the wrist camera (active sensing off)",
    )  # fmt: skip


def format_all_text(rec: dict[str, Any]) -> str:
    """Human-readable report of one ``--all`` trial."""
    lines = [
        f"{rec['object']} in scene {rec['scene']} (seed {rec['seed']}): found {rec['found']} of "
        f"{rec['present']} present, {rec['false_positives']} false positive(s)"
    ]
    for i, inst in enumerate(rec["instances"]):
        e = inst["error"]
        t = [row[3] for row in inst["matrix"][:3]]
        lines.append(
            f"  {i}: score {inst['score']:.3f} at ({t[0]:+.4f}, {t[1]:+.4f}, {t[2]:+.4f}) m; "
            f"error {e['position_mm']:.2f} mm {e['rotation_deg']:.2f} deg; visible "
            f"{100 * inst['visible_fraction']:.0f} %; stability {inst['stability']:.3f}"
            + ("" if inst["correct"] else " (FALSE)")
        )
    for m in rec["missed"]:
        lines.append(f"  missed {m['instance']} ({100 * m['visible_fraction']:.0f} % visible)")
    if rec.get("unsure"):
        lines.append(
            f"  not reported: {rec['unsure']} instance(s) whose pose their points do not pin down"
            " or see through"
        )
    served = ", ".join(f"{k} <- {v}" for k, v in sorted(rec["provenance"].items()))
    lines.append(f"logical sensors: {served}")
    lines.append(f"views: {rec['views']} ({', '.join(rec['view_names'])})")
    lines += _fault_lines(rec)
    lines.append(f"time: {rec['time_s']:.2f} s")
    return "\n".join(lines)


def run_all(args: argparse.Namespace) -> int:
    """``mks-sim localize --all``: exit 0 when an instance was found, 1 otherwise."""
    from mks_sim.devices import DEVICE_NAMES
    from mks_sim.tasks.bin import BIN_SCENE, run_localize_all

    unknown = [d for d in args.fail if d not in DEVICE_NAMES]
    if unknown:
        raise SpecError(
            f"--fail: unknown device(s) {unknown}; valid device names: {list(DEVICE_NAMES)}"
        )
    rec = run_localize_all(
        int(args.seed),
        object_name=args.object,
        count=args.count,
        fail=tuple(args.fail),
        scene=args.scene or BIN_SCENE,
        active=not args.one_view,
        models=tuple(args.models),
    )
    if args.json:
        print(json.dumps(rec, allow_nan=False))
    else:
        print(format_all_text(rec))
    return 0 if rec["found"] else 1


TASKS = ("clear_bin",)


def add_task_argument(parser: argparse.ArgumentParser) -> None:
    """``--task clear_bin`` (and ``--count``) for ``mks-sim grasp``."""
    parser.add_argument(
        "--task", choices=TASKS, default=None,
        help="clear_bin: localize every part in the bin scene, pick them one by one into the "
        "output box (--seed, --count, --fail, --json); no --object needed",
    )  # fmt: skip
    parser.add_argument(
        "--count", type=int, default=None, metavar="N",
        help="--task clear_bin: parts dropped into the bin (1..12; default 6)",
    )  # fmt: skip
    parser.add_argument(
        "--budget", type=int, default=None, metavar="N",
        help="--task clear_bin: picks at most (default 2 x parts + 2)",
    )  # fmt: skip
    parser.add_argument(
        "--bin-only", action="store_true",
        help="--task clear_bin: when the bin is done, do not pick the parts found on the "
        "table around it (lifted out with another or dropped on the way)",
    )  # fmt: skip
    _add_one_view(parser)


def run_clear_bin_command(args: argparse.Namespace) -> int:
    """``mks-sim grasp --task clear_bin``: exit 0 when the bin was cleared, 1 otherwise."""
    from mks_sim.devices import DEVICE_NAMES
    from mks_sim.tasks.bin import run_clear_bin

    unknown = [d for d in args.fail if d not in DEVICE_NAMES]
    if unknown:
        raise SpecError(
            f"--fail: unknown device(s) {unknown}; valid device names: {list(DEVICE_NAMES)}"
        )
    if args.budget is not None and args.budget < 1:
        raise SpecError(f"--budget: expected >= 1, got {args.budget}")
    rec = run_clear_bin(
        int(args.seed),
        object_name=args.object,
        count=args.count,
        fail=tuple(args.fail),
        budget=args.budget,
        active=not args.one_view,
        models=tuple(args.models),
        table=not args.bin_only,
    )
    if args.json:
        print(json.dumps(rec, allow_nan=False))
    else:
        print(format_clear_text(rec))
    return 0 if rec["picked"] == rec["present"] else 1


def format_clear_text(rec: dict[str, Any]) -> str:
    """Human-readable report of one clear_bin run."""
    lines = [
        f"clear_bin (seed {rec['seed']}): picked {rec['picked']} of {rec['present']} "
        f"({100 * rec['cleared_fraction']:.0f} %) in {rec['time_s']:.1f} s; stopped: "
        f"{rec['stopped']}"
        + (f"; the table then: {rec['table_stopped']}" if rec.get("table_stopped") else "")
    ]
    for k, p in enumerate(rec["picks"]):
        what = "ok" if p["success"] else f"FAILED: {p['failure']}"
        where = " on the table" if p.get("region") == "table" else ""
        lines.append(
            f"  pick {k + 1}{where}: instance {p['instance']} (score {p['score']:.2f}"
            f"{', unsure pose' if p.get('unsure') else ''}) {what}; "
            f"{p['time_s']:.1f} s ({p['perception_s']:.1f} s perception, {p['views']} view(s))"
        )
    lines += _fault_lines(rec)
    return "\n".join(lines)


# --------------------------------------------------------------------------- the demo's stage

DEMO_PARTS = 3


def demo_bin(demo: Any, seed: int, grasp: bool, frame_hook: Any) -> None:
    """``mks-sim demo``'s bin-picking stage: a bin of 3 parts, every instance localized (a
    second wrist view when the first is not good enough), then ONE pick into the output box
    (the fewest steps that show a pick). Pictures: the wrist camera's view, the fused points
    coloured by the instance that explains them; the pick goes into the demo's video.

    Args:
        demo: the running ``mks_sim.cli.demo.Demo`` (images, rows, frames, notes).
        seed: the bin's seed.
        grasp: also pick (``--no-grasp``: localize only).
        frame_hook: ``(demo, world) -> (renderer | None, hook | None)``, the demo's video.
    """
    import numpy as np

    from mks_sim.cli.demo import ObjectRow
    from mks_sim.devices import make_devices
    from mks_sim.report import save_image, save_points
    from mks_sim.sim import truth
    from mks_sim.tasks.bin import BinPicker, bin_world, evaluate_instances, in_output_box

    world = bin_world(seed, count=DEMO_PARTS)
    with make_devices(world.model, world.data, np.random.default_rng([seed, 4])) as devices:
        wrist = devices.get("wrist_camera")
        if wrist is not None:
            save_image(wrist.read().rgb, demo.image("bin_01_wrist_camera.png"),
                       "bin: the wrist camera from the arm's home pose")  # fmt: skip
        robot = BinPicker(world, devices, rng=np.random.default_rng(seed))
        found = robot.sense()
        sensed = robot.sensed
        labels = np.full(len(sensed.points), -1)
        for k, inst in enumerate(found):
            labels[inst.points] = k
        save_points(sensed.points, demo.image("bin_02_instances.png"),
                    f"bin: {len(found)} instances found in {robot.views} view(s) "
                    f"({', '.join(sensed.views)})", labels=labels)  # fmt: skip
        ev = evaluate_instances(world, robot.name, [i.matrix for i in found], sensed.points)
        row = demo.rows.setdefault("bin", ObjectRow(f"bin: {DEMO_PARTS} {robot.name}s"))
        row.localize_s = robot.perception_s
        row.provenance = dict(sensed.provenance)
        row.grasp = f"found {ev['correct']} of {ev['present']} ({ev['false_positives']} false)"
        if not found:
            return
        row.estimate = found[0].matrix
        body = robot.body_of(found[0].matrix)  # evaluation only
        if body is not None:
            row.truth = truth.object_to_world(world, body)
            err = ev["errors"][0]
            row.position_mm, row.rotation_deg = err["position_mm"], err["rotation_deg"]
        if not grasp:
            return
        chosen = None
        for obstacles in ("all", "fixed"):
            chosen = next(
                ((i, c) for i in range(len(found)) if (c := robot.grasps(i, obstacles=obstacles))),
                None,
            )
            if chosen is not None:
                break
        if chosen is None:
            row.grasp += "; no grasp"
            return
        i, cands = chosen
        body = robot.body_of(found[i].matrix)
        renderer, hook = frame_hook(demo, world)
        robot.ctl.on_frame, robot.ctl.frame_every = hook, 4
        try:
            ok, failure = robot.pick(cands)
        finally:
            robot.ctl.on_frame = None
            if renderer is not None:
                renderer.close()
        success = body is not None and in_output_box(world, body)
        row.grasp += "; one pick: " + ("in the box" if success else f"failed ({failure or 'not in the box'})")


def _fault_lines(rec: dict[str, Any]) -> list[str]:
    """The failed devices with their reasons, and the alternates used (``faults``/``warnings``)."""
    reasons = rec.get("fault_reasons", {})
    lines = [f"fault: {dev}: {reasons.get(dev, 'failed')}" for dev in rec.get("faults", [])]
    return lines + [f"warning: {w}" for w in rec.get("warnings", [])]
