"""`mks-sim localize`: localize an object in a randomised scene from simulated sensors.

Randomises the scene from ``--seed``, builds the devices (``--fail`` some of them), runs
:func:`mks_sim.workstation.localize_object` (logical sensors -> k-d tree/SPG -> grouping ->
matching -> refinement) and prints the estimate, the ground truth and the error. The ground
truth (``mks_sim.sim.truth``) is read here, after localization, for evaluation only.

Any object of the model database (``--models DIR`` adds folders) in any scene
(``--scene NAME|FILE``); without ``--scene`` the scene of the object's task file
(``tasks/grasp_<object>.toml``: scene2 for the cube and sphere, part for the part), else the
object alone on the table, dropped from a random orientation.

Example::

    mks-sim localize --scene scene2 --object cube --seed 3 --fail range_finder --json
    mks-sim localize --object bracket --models my_models/ --seed 4
"""

from __future__ import annotations

import argparse
import inspect
import json
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from mks_sim.cli._bin import add_all_arguments, run_all
from mks_sim.errors import DeviceFailure, SensorFailure, SpecError
from mks_sim.viz import NullRecorder, Recorder, add_rerun_argument, open_recorder

HELP = "localize a database object (cube, sphere, part, ...) from simulated sensors; estimate, truth and error"
#: success: within this many mm and degrees of the ground truth.
SUCCESS_MM = 5.0
SUCCESS_DEG = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scene", default=None, metavar="NAME|FILE",
        help="scene name (worlds/*.toml) or scene file (default: the scene of the object's "
        "task file, else the object alone on the table, dropped)",
    )  # fmt: skip
    parser.add_argument(
        "--object", required=True, metavar="NAME", help="database object to localize"
    )
    add_models_argument(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene layout and noise")
    parser.add_argument(
        "--fail", nargs="+", action="extend", default=[], metavar="DEVICE",
        help="devices to fail (e.g. range_finder): their logical sensors use alternates",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    add_rerun_argument(parser)
    add_all_arguments(parser)  # bin picking (issue 13)


def add_models_argument(parser: argparse.ArgumentParser) -> None:
    """``--models DIR`` (repeatable): extra model-database folders (also ``MKS_SIM_MODELS``)."""
    parser.add_argument(
        "--models", action="append", default=[], metavar="DIR",
        help="extra model-database folder (repeatable; also MKS_SIM_MODELS, path-separated)",
    )  # fmt: skip


def check_arguments(
    scene: str | None, obj: str, fail: Sequence[str], models: Sequence[str] = ()
) -> str | None:
    """Validate scene/object/devices; returns the scene (None: the default scene, the object
    alone on the table).

    Raises:
        NotFound: the object is not in the database, or the scene does not exist.
        SpecError: the object is not in that scene, or an unknown device name.
    """
    from mks_sim.devices import DEVICE_NAMES
    from mks_sim.models.objects import load_object
    from mks_sim.sim.scenes import scene_objects
    from mks_sim.tasks.spec import object_scene

    load_object(obj, models=models)  # NotFound lists the known objects
    if scene is None:
        scene = object_scene(obj)
    else:
        held = scene_objects(scene)
        if obj not in held:
            where = object_scene(obj)
            raise SpecError(
                f"--object {obj} is not in scene {scene!r} (it holds {held}); "
                + (f"use --scene {where}" if where else "leave out --scene for the default scene")
            )
    unknown = [d for d in fail if d not in DEVICE_NAMES]
    if unknown:
        raise SpecError(
            f"--fail: unknown device(s) {unknown}; valid device names: {list(DEVICE_NAMES)}"
        )
    return scene


def _round_matrix(T: np.ndarray | None) -> list[list[float]] | None:
    if T is None:
        return None
    return [[round(float(v), 6) for v in row] for row in np.asarray(T)]


def run_trial(
    obj: str,
    seed: int,
    fail: Sequence[str] = (),
    scene: str | None = None,
    recorder: Recorder | None = None,
    models: Sequence[str] = (),
) -> dict[str, Any]:
    """Randomise, sense, localize and evaluate one object; the CLI's JSON record.

    Args:
        obj: a database object name (``cube``, ``sphere``, ``part``, ...).
        seed: layout and device-noise seed.
        fail: devices failed for the trial.
        scene: scene name or file (default: the first shipped scene holding the object,
            else the object alone on the table, dropped).
        recorder: logs devices, logical sensors, hypotheses and the truth (default: off).
        models: extra model-database folders.

    Returns:
        ``{"object", "scene", "seed", "found", "matrix", "truth", "error": {"position_mm",
        "rotation_deg"}, "success", "provenance", "time_s", "timing_s", "failed_devices",
        "failure", "faults", "warnings"}``
        (matrices 4x4 column convention, world frame, metres; errors None when not found;
        ``failure`` names the fault when a needed logical sensor had no working way).
    """
    from mks_sim.devices import DeviceFaults, make_devices
    from mks_sim.models.objects import load_object
    from mks_sim.sensing.faults import fault_fields
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world
    from mks_sim.tasks.evaluate import object_pose_error
    from mks_sim.workstation import localize_object

    scene = check_arguments(scene, obj, fail, models)
    world = build_world(scene, seed=seed, objects=[obj], models=models)
    faults = {d: DeviceFaults(failed=True) for d in fail}
    devices = make_devices(world.model, world.data, np.random.default_rng(seed), faults)
    rec = recorder if recorder is not None else NullRecorder()
    rec.log_world(world)
    failure: str | None = None
    t0 = time.perf_counter()
    try:
        # extra model folders, once the engine's localize_object takes them
        takes_models = "models" in inspect.signature(localize_object).parameters
        extra: dict[str, Any] = {"models": tuple(models)} if models and takes_models else {}
        result = localize_object(
            world, obj, rec.tap_devices(devices), rng=np.random.default_rng(seed),
            graph=rec.tap_graph(None), **extra,
        )  # fmt: skip
        rec.log_localization(result, world=world)
        rec.log_camera_views()
    except (SensorFailure, DeviceFailure) as exc:
        # Every way of a needed logical sensor failed (e.g. all point sources): a clean
        # "not found" naming the fault, as `grasp` reports it, not a bad-input error.
        result, failure = None, str(exc)
    finally:
        devices.close()
    # Evaluation only: the ground truth is read after localization.
    T_true = truth.object_to_world(world, obj)
    rec.log_truth(obj, T_true, world=world)
    pos_mm: float | None = None
    rot_deg: float | None = None
    found = result is not None and bool(result.found)
    if result is not None and result.found and result.object_to_world is not None:
        # modulo the object's symmetries; 0 deg when its orientation is not observable
        p, rot_deg = object_pose_error(
            load_object(obj, models=models), result.object_to_world, T_true
        )
        pos_mm = 1000.0 * p
    success = (
        pos_mm is not None
        and rot_deg is not None
        and pos_mm <= SUCCESS_MM
        and rot_deg <= SUCCESS_DEG
    )
    return {
        "object": obj,
        "scene": scene if scene is not None else world.name,
        "seed": seed,
        "found": found,
        "matrix": None if result is None else _round_matrix(result.object_to_world),
        "truth": _round_matrix(T_true),
        "error": {
            "position_mm": None if pos_mm is None else round(pos_mm, 4),
            "rotation_deg": None if rot_deg is None else round(rot_deg, 4),
        },
        "success": bool(success),
        "provenance": {} if result is None else dict(result.provenance),
        "time_s": round(float(time.perf_counter() - t0 if result is None else result.time_s), 4),
        "timing_s": _timing(result),
        "failed_devices": list(fail),
        "failure": failure,
        # one format with `grasp --json` (mks_sim.sensing.faults): "faults", "warnings"
        **fault_fields(fail, {} if result is None else dict(result.provenance)),
    }


#: Stages reported in ``timing_s`` (seconds): resolving the model (cached after the first
#: call), reading the devices, the snapshot's low-level representation, hypothesis
#: generation, verification (ICP, consistency), everything after sensing, the whole flow.
TIMING_STAGES = (
    "model",
    "sensing",
    "representation",
    "hypotheses",
    "verification",
    "processing",
    "total",
)


def _timing(result: Any) -> dict[str, float]:
    """``timing_s`` of a localization: :data:`TIMING_STAGES` (0 when a stage did not run)."""
    if result is None:
        return {}
    timing = dict(getattr(result, "diagnostics", {}).get("timing", {}))
    timing.setdefault("total", float(result.time_s))
    return {k: round(float(timing.get(k, 0.0)), 4) for k in TIMING_STAGES}


def _fmt_matrix(M: list[list[float]] | None) -> str:
    if M is None:
        return "    (none)"
    return "\n".join("    " + " ".join(f"{v:+9.5f}" for v in row) for row in M)


def format_text(rec: dict[str, Any]) -> str:
    """Human-readable report of one trial."""
    err = rec["error"]
    lines = [
        f"object {rec['object']} in scene {rec['scene']} (seed {rec['seed']}): "
        + ("found" if rec["found"] else "NOT FOUND"),
        "estimate object_to_world (4x4, column convention, metres):",
        _fmt_matrix(rec["matrix"]),
        "ground truth:",
        _fmt_matrix(rec["truth"]),
    ]
    if rec["found"]:
        lines.append(
            f"error: position {err['position_mm']:.3f} mm, rotation {err['rotation_deg']:.3f} deg"
            + " (modulo the object's symmetries)"
        )
    served = ", ".join(f"{k} <- {v}" for k, v in sorted(rec["provenance"].items()))
    lines.append(f"logical sensors: {served}")
    if rec["failed_devices"]:
        lines.append(f"failed devices: {', '.join(rec['failed_devices'])}")
    if rec.get("failure"):
        lines.append(f"failure: {rec['failure']}")
    lines.append(f"time: {rec['time_s']:.2f} s")
    if rec.get("timing_s"):
        stages = ", ".join(f"{k} {1000 * v:.0f} ms" for k, v in rec["timing_s"].items())
        lines.append(f"timing: {stages}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.all:
        return run_all(args)
    scene = check_arguments(args.scene, args.object, args.fail, args.models)
    with open_recorder(args.rerun, "mks_sim localize") as recorder:
        rec = run_trial(
            args.object, int(args.seed), tuple(args.fail), scene, recorder, models=args.models
        )
    if args.json:
        out = {k: rec[k] for k in ("object", "found", "matrix", "truth", "error", "provenance")}
        out["time_s"] = rec["time_s"]
        out["timing_s"] = rec["timing_s"]
        out.update(scene=rec["scene"], seed=rec["seed"], success=rec["success"])
        out.update(failed_devices=rec["failed_devices"], failure=rec["failure"])
        out.update(faults=rec["faults"], warnings=rec["warnings"])
        print(json.dumps(out, allow_nan=False))
    else:
        print(format_text(rec))
    if not rec["found"]:
        return 1
    return 0
