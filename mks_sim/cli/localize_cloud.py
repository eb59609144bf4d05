"""`mks-sim localize-cloud`: localize a model in a recorded point cloud (no simulator).

Examples::

    mks-sim localize-cloud --model part.stl --scene scan.ply
    mks-sim localize-cloud --model torus.stl --scene scan.ply --kind auto   # -> freeform
    mks-sim localize-cloud --model cube_model.npy --scene scan.pcd --json
    mks-sim localize-cloud --model part_mm.stl --scale 0.001 --scene scan.ply --viewpoint 0.3 0.2 0.45
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np

from mks_sim.errors import DataError, MksError
from mks_sim.viz import add_rerun_argument, open_recorder

HELP = "localize a model (database name, mesh or point file) in a point cloud file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        required=True,
        metavar="NAME_OR_FILE",
        help="model database name, or a mesh (.stl/.obj/.ply with faces) or point file "
        "(.ply/.pcd/.npy/.npz) of the whole model surface",
    )
    parser.add_argument(
        "--scene", required=True, metavar="FILE", help="point cloud: .ply, .pcd, .npy or .npz"
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--scale",
        type=float,
        default=1.0,
        metavar="S",
        help="multiply model coordinates by S to get scene units (default 1; 0.001 for a "
        "model in mm and a scene in m)",
    )
    parser.add_argument(
        "--viewpoint",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="sensor position in the scene frame (orients normals)",
    )
    parser.add_argument(
        "--table",
        choices=("auto", "none"),
        default="auto",
        help="detect and remove a supporting plane (auto, default) or keep all points",
    )
    parser.add_argument(
        "--kind",
        choices=("auto", "polyhedral", "freeform", "sphere"),
        default="auto",
        help="model kind for a mesh: auto (default: a mostly curved mesh -> freeform, a "
        "sphere -> sphere, else polyhedral), or force one",
    )
    parser.add_argument(
        "--min-score", type=float, default=0.5, help="score needed for found (default 0.5)"
    )
    parser.add_argument(
        "--max-hypotheses", type=int, default=5, help="hypotheses reported (default 5)"
    )
    add_rerun_argument(parser)


def _result_json(loc: Any, n_points: int, dropped: int, kind: str = "") -> dict[str, Any]:
    return {
        "found": bool(loc.found),
        "kind": kind,
        "hypotheses": [
            {
                "matrix": np.round(h.matrix, 9).tolist(),
                "votes": int(h.votes),
                "score": float(h.score),
                "rmse": float(h.rmse),
                "inlier_fraction": float(frac),
                "symmetric_equivalents": len(eq),
            }
            for h, frac, eq in zip(loc.hypotheses, loc.inlier_fractions, loc.equivalents)
        ],
        "points": n_points,
        "dropped_nan": dropped,
        "segments": [
            {"points": len(s.indices), "planes": len(s.planes), "vertexes": len(s.vertexes)}
            for s in loc.segments
        ],
        "table_removed": loc.table is not None,
        "voxel": float(loc.voxel),
        "object_voxel": float(loc.object_voxel),
        "timing_s": {k: round(v, 4) for k, v in loc.timing.items()},
        "warnings": list(loc.warnings),
    }


def _print_text(result: dict[str, Any], model_name: str) -> None:
    out = sys.stdout
    out.write(
        f"scene: {result['points']} points"
        + (f" ({result['dropped_nan']} NaN points dropped)" if result["dropped_nan"] else "")
        + f", table removed: {'yes' if result['table_removed'] else 'no'}, "
        f"{len(result['segments'])} object segment(s)\n"
    )
    for i, s in enumerate(result["segments"]):
        out.write(
            f"  segment {i}: {s['points']} points, {s['planes']} planes, {s['vertexes']} vertexes\n"
        )
    verdict = "FOUND" if result["found"] else "NOT FOUND"
    out.write(f"model {model_name!r} ({result['kind']}): {verdict}\n")
    for i, h in enumerate(result["hypotheses"]):
        out.write(
            f"hypothesis {i}: score {h['score']:.3f}, votes {h['votes']}, "
            f"rmse {h['rmse']:.3g}, inliers {h['inlier_fraction']:.3f}"
            + (
                f", {h['symmetric_equivalents']} symmetric equivalents"
                if h["symmetric_equivalents"]
                else ""
            )
            + "\n"
        )
        for row in h["matrix"]:
            out.write("   " + " ".join(f"{v:10.5f}" for v in row) + "\n")
    out.write("time: " + ", ".join(f"{k} {v:.3f} s" for k, v in result["timing_s"].items()) + "\n")


def run(args: argparse.Namespace) -> int:
    from mks_sim.io.pointcloud import read_point_cloud
    from mks_sim.localization.model import model_kind
    from mks_sim.localize import load_model, localize_cloud

    if not np.isfinite(args.scale) or args.scale <= 0:
        raise DataError(f"--scale: expected a positive number, got {args.scale}")
    if args.max_hypotheses < 1:
        raise DataError(f"--max-hypotheses: expected >= 1, got {args.max_hypotheses}")
    from mks_sim.io.units import require_spread

    model = load_model(args.model, kind=args.kind)
    cloud = read_point_cloud(args.scene)
    require_spread(cloud.points, str(args.scene))  # a degenerate scene: a clear message, fast
    try:
        loc = localize_cloud(
            model,
            cloud.points,
            scale=args.scale,
            viewpoint=args.viewpoint,
            table=args.table,
            min_score=args.min_score,
            max_hypotheses=args.max_hypotheses,
        )
    except MksError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:  # degenerate data deep in numpy
        raise DataError(f"{args.scene}: cannot localize in this cloud: {exc}") from exc
    with open_recorder(args.rerun, "mks_sim localize-cloud") as recorder:
        model_points = np.asarray(getattr(model, "points", np.empty((0, 3))), dtype=float)
        recorder.log_cloud(cloud.points, loc, model_points=model_points * args.scale,
                           name=str(getattr(model, "name", "model")))  # fmt: skip
    dropped = int(cloud.dropped_nan) + int(loc.dropped_nan)
    result = _result_json(
        loc, len(cloud.points) + int(cloud.dropped_nan), dropped, model_kind(model)
    )
    if args.json:
        json.dump(result, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print_text(result, getattr(model, "name", str(args.model)))
    return 0 if loc.found else 1
