"""Grasp synthesis benchmark: time per call of ``synthesize_grasps`` (goal < 50 ms) and the
number of candidates, per database object, over random resting yaws and positions.

    .venv/bin/python benchmarks/grasp_synthesis.py            # 200 poses per object
    .venv/bin/python benchmarks/grasp_synthesis.py --quick    # 20 poses, no results file

Writes benchmarks/results/grasp_synthesis.md (not with ``--quick``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mks_sim.models.objects import load_object, object_names
from mks_sim.tasks.grasp import synthesize_grasps

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import header_lines  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
TABLE_Z = 0.75


def _pose(mesh_vertices: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Resting on the face it was modelled on, random yaw and position on the table."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", rng.uniform(0, 360), degrees=True).as_matrix()
    z = -(mesh_vertices @ T[:3, :3].T)[:, 2].min()
    T[:3, 3] = (rng.uniform(-0.2, 0.2), rng.uniform(-0.1, 0.2), TABLE_Z + z)
    return T


def run(objects: list[str], poses: int, seed: int) -> list[dict]:
    rows = []
    for name in objects:
        obj = load_object(name)
        rng = np.random.default_rng(seed)
        synthesize_grasps(obj, _pose(obj.mesh.vertices, rng), table_z=TABLE_Z)  # warm the cache
        times, counts = [], []
        for k in range(poses):
            T = _pose(obj.mesh.vertices, rng)
            t0 = time.perf_counter()
            cands = synthesize_grasps(obj, T, table_z=TABLE_Z, rng=np.random.default_rng(k))
            times.append(time.perf_counter() - t0)
            counts.append(len(cands))
        times.sort()
        rows.append(
            {
                "object": name,
                "poses": poses,
                "median_ms": 1000 * statistics.median(times),
                "p90_ms": 1000 * times[int(0.9 * (len(times) - 1))],
                "with_grasp": sum(c > 0 for c in counts),
                "median_candidates": statistics.median(counts),
            }
        )
        r = rows[-1]
        print(f"{name:10s} {r['median_ms']:6.1f} ms median, {r['p90_ms']:6.1f} ms p90, "
              f"{r['with_grasp']}/{poses} with a grasp", file=sys.stderr, flush=True)  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=200, help="random poses per object")
    p.add_argument("--objects", nargs="+", default=None, help="default: every database object")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="20 poses, print only")
    p.add_argument("--out", type=Path, default=RESULTS / "grasp_synthesis.md")
    args = p.parse_args(argv)
    poses = 20 if args.quick else args.poses
    header = header_lines()  # the load before the run
    rows = run(args.objects or object_names(), poses, args.seed)
    if args.quick:
        return 0
    lines = ["# Grasp synthesis", "", *header, "",
             "| object | poses | median ms | p90 ms | poses with a grasp | median candidates |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    lines += [
        f"| {r['object']} | {r['poses']} | {r['median_ms']:.1f} | {r['p90_ms']:.1f} | "
        f"{r['with_grasp']} | {r['median_candidates']:.0f} |"
        for r in rows
    ]
    args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
