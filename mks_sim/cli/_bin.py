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
            f"{100 * inst['visible_fraction']:.0f} %" + ("" if inst["correct"] else " (FALSE)")
        )
    for m in rec["missed"]:
        lines.append(f"  missed {m['instance']} ({100 * m['visible_fraction']:.0f} % visible)")
    served = ", ".join(f"{k} <- {v}" for k, v in sorted(rec["provenance"].items()))
    lines.append(f"logical sensors: {served}")
    lines.append(f"views: {rec['views']} ({', '.join(rec['view_names'])})")
    for dev, why in sorted(rec["faults"].items()):
        lines.append(f"fault: {dev}: {why}")
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
    ]
    for k, p in enumerate(rec["picks"]):
        what = "ok" if p["success"] else f"FAILED: {p['failure']}"
        lines.append(
            f"  pick {k + 1}: instance {p['instance']} (score {p['score']:.2f}) {what}; "
            f"{p['time_s']:.1f} s ({p['perception_s']:.1f} s perception, {p['views']} view(s))"
        )
    for dev, why in sorted(rec.get("faults", {}).items()):
        lines.append(f"fault: {dev}: {why}")
    return "\n".join(lines)
