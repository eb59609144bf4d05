"""Backends benchmark: grasp episodes per minute on the local process pool against a local Ray
with the same number of CPUs (issue 11, goal: Ray / pool >= 0.9), same seeds on both.

    .venv/bin/python benchmarks/backends.py                 # 24 episodes, 2 workers
    .venv/bin/python benchmarks/backends.py --quick         # 4 sphere episodes (smoke run)

Writes benchmarks/results/backends.md (and backends.json beside it). Ray's start-up
(``ray.init``) is timed apart: on a cluster it is paid once, not per sweep.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _provenance import header_lines  # noqa: E402

from mks_sim.tasks.backends import EpisodeJob, run_episodes  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
GOAL_RATIO = 0.9


def _jobs(objects: list[str], n: int, seed: int) -> list[EpisodeJob]:
    """``n`` episodes cycling through ``objects``, seeds ``seed``, ``seed + 1``, ..."""
    return [EpisodeJob(objects[i % len(objects)], seed + i) for i in range(n)]


def _same(a: dict, b: dict) -> bool:
    a, b = dict(a), dict(b)
    a.pop("time_s", None), b.pop("time_s", None)
    return a == b


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=24)
    p.add_argument("--objects", nargs="+", default=["cube", "sphere", "part"])
    p.add_argument("--workers", type=int, default=2, help="pool processes = Ray CPUs")
    p.add_argument("--seed", type=int, default=1000)
    p.add_argument("--quick", action="store_true",
                   help="4 sphere episodes, printed only (unless --out is given)")  # fmt: skip
    p.add_argument("--out", type=Path, default=None, help="default results/backends.md")
    args = p.parse_args(argv)
    if args.quick:
        args.episodes, args.objects = 4, ["sphere"]
    elif args.out is None:
        args.out = RESULTS / "backends.md"
    header = header_lines()
    jobs = _jobs(args.objects, args.episodes, args.seed)

    t = time.perf_counter()
    pool = run_episodes(jobs, backend="local", workers=args.workers, desc="pool")
    pool_s = time.perf_counter() - t
    print(f"process pool: {len(jobs)} episodes in {pool_s:.1f} s", file=sys.stderr, flush=True)

    import ray

    t = time.perf_counter()
    ray.init(num_cpus=args.workers, include_dashboard=False, logging_level=logging.WARNING)
    init_s = time.perf_counter() - t
    try:
        t = time.perf_counter()
        remote = run_episodes(jobs, backend="ray", desc="ray")
        ray_s = time.perf_counter() - t
    finally:
        ray.shutdown()
    print(f"ray: {len(jobs)} episodes in {ray_s:.1f} s (+ {init_s:.1f} s ray.init)",
          file=sys.stderr, flush=True)  # fmt: skip

    n = len(jobs)
    rows = {
        "process pool": pool_s,
        "Ray (running)": ray_s,
        "Ray (with ray.init)": ray_s + init_s,
    }
    epm = {k: 60.0 * n / v for k, v in rows.items()}
    ratio = epm["Ray (running)"] / epm["process pool"]
    ratio_init = epm["Ray (with ray.init)"] / epm["process pool"]
    mismatches = [j.seed for j, a, b in zip(jobs, pool, remote, strict=True) if not _same(a, b)]
    ok = sum(e["success"] for e in pool)
    lines = [
        "# Backends: process pool vs Ray",
        "",
        *header,
        f"- {n} grasp episodes ({', '.join(args.objects)} in turn), seeds {args.seed}.."
        f"{args.seed + n - 1}, `--workers {args.workers}` = Ray `num_cpus={args.workers}`; "
        + (
            "one BLAS/OpenMP thread per worker on both (the pool's default, as Ray sets)"
            if "OMP_NUM_THREADS" not in os.environ
            else f"OMP_NUM_THREADS={os.environ['OMP_NUM_THREADS']} exported"
        ),
        "",
        "| backend | wall s | episodes / min | ratio to the pool |",
        "|---|---|---|---|",
        *(
            f"| {k} | {v:.1f} | {epm[k]:.1f} | {epm[k] / epm['process pool']:.2f} |"
            for k, v in rows.items()
        ),
        "",
        f"Ray / pool = **{ratio:.2f}** with Ray running (goal >= {GOAL_RATIO}: "
        f"{'met' if ratio >= GOAL_RATIO else 'NOT met'}), {ratio_init:.2f} counting "
        f"`ray.init` ({init_s:.1f} s).",
        f"Same per-episode records on both backends (wall time aside): "
        f"{n - len(mismatches)}/{n}" + (f", differing seeds {mismatches}" if mismatches else "")
        + f"; grasp success {ok}/{n}.",
        "",
    ]
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines))
        args.out.with_suffix(".json").write_text(
            json.dumps({"wall_s": rows, "ray_init_s": init_s, "episodes_per_min": epm,
                        "ratio": ratio, "pool": pool, "ray": remote}, indent=1)  # fmt: skip
        )
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
