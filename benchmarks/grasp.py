"""Grasp benchmark: success per object over seeded random poses, healthy and with the range
finder failed (localization then runs on the stereo pair); time per episode.

    .venv/bin/python benchmarks/grasp.py --episodes 100 --workers 2
    .venv/bin/python benchmarks/grasp.py --episodes 1000 --backend ray --address auto

Writes benchmarks/results/grasp.md (and grasp.json beside it).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from contextlib import nullcontext
from pathlib import Path

from mks_sim.cli.grasp import run_episodes
from mks_sim.tasks import backends
from mks_sim.tasks.backends import BACKENDS, check_backend, ray_session

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import header_lines  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=100, help="episodes per object, healthy")
    p.add_argument("--failed-episodes", type=int, default=None,
                   help="episodes per object with the range finder failed (default --episodes)")  # fmt: skip
    p.add_argument("--objects", nargs="+", default=["cube", "sphere", "part"])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=3000,
                   help="first seed; 3000.. are reporting seeds (thresholds were tuned on 0-19, 1000-1099)")  # fmt: skip
    p.add_argument("--env-episodes", type=int, default=0,
                   help="episodes per object of the scripted policy through the env (--env-id)")  # fmt: skip
    p.add_argument("--env-id", default="mks_sim/Grasp-v2",
                   help="gymnasium id for --env-episodes (v2: continuous grip, full hand rotation)")  # fmt: skip
    p.add_argument("--backend", choices=BACKENDS, default="local",
                   help="local process pool (--workers) or Ray tasks (one session for the sweep)")  # fmt: skip
    p.add_argument("--address", default=None,
                   help="--backend ray: auto or HOST:PORT of a running cluster (default: local Ray)")  # fmt: skip
    p.add_argument("--out", type=Path, default=RESULTS / "grasp.md")
    args = p.parse_args(argv)
    args.header = header_lines("python benchmarks/grasp.py " + " ".join(sys.argv[1:]))
    check_backend(args.backend, args.address)
    with ray_session(args.address, args.workers) if args.backend == "ray" else nullcontext():
        return _sweep(args)


def _sweep(args: argparse.Namespace) -> int:
    where = {"backend": args.backend, "address": args.address, "workers": args.workers}
    n_failed = args.episodes if args.failed_episodes is None else args.failed_episodes
    runs: list[dict] = []
    t0 = time.perf_counter()
    for condition, faults, n in (
        ("healthy", (), args.episodes),
        ("range_finder failed", ("range_finder",), n_failed),
    ):
        for obj in args.objects:
            if n <= 0:
                continue
            t = time.perf_counter()
            eps = run_episodes(obj, range(args.seed, args.seed + n), faults, args.workers,
                               backend=args.backend, address=args.address)  # fmt: skip
            wall = time.perf_counter() - t
            runs.append({"object": obj, "condition": condition, "episodes": eps, "wall_s": wall})
            ok = sum(e["success"] for e in eps)
            print(f"{obj:7s} {condition:20s} {ok}/{n} in {wall:.0f} s", file=sys.stderr, flush=True)
            _write(args, runs, time.perf_counter() - t0)
    if args.env_episodes > 0:
        for obj in args.objects:
            t = time.perf_counter()
            seeds = range(args.seed, args.seed + args.env_episodes)
            jobs = [(args.env_id, obj, s) for s in seeds]
            eps = backends.run_episodes(jobs, fn=_env_episode, **where,
                                        desc=f"env {obj}")  # fmt: skip
            wall = time.perf_counter() - t
            runs.append(
                {
                    "object": obj,
                    "condition": f"{args.env_id.split('/')[-1]}, scripted policy",
                    "episodes": eps,
                    "wall_s": wall,
                }
            )
            ok = sum(e["success"] for e in eps)
            print(
                f"{obj:7s} {args.env_id:20s} {ok}/{len(eps)} in {wall:.0f} s",
                file=sys.stderr,
                flush=True,
            )
            _write(args, runs, time.perf_counter() - t0)
    return 0


def _env_episode(job: tuple[str, str, int]) -> dict:
    """The scripted grasp through the env ``env_id`` (sensor-based localization at ``reset``)."""
    import gymnasium as gym

    import mks_sim  # noqa: F401
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env_id, obj, seed = job
    t = time.perf_counter()
    env = gym.make(env_id, object=obj, max_episode_steps=150)
    try:
        obs, info = env.reset(seed=seed)
        policy = ScriptedGraspPolicy(env.unwrapped)
        terminated = truncated = False
        while not (terminated or truncated):
            obs, _, terminated, truncated, info = env.step(policy(obs))
    finally:
        env.close()
    err = info["localization_error"]
    return {
        "seed": seed,
        "success": bool(info["success"]),
        "retries": 0,
        "error": {k: (None if v != v else v) for k, v in err.items()},
        "time_s": time.perf_counter() - t,
        "failure": "" if info["success"] else f"ended in phase {policy.phase}",
    }


def _write(args: argparse.Namespace, runs: list[dict], total_s: float) -> None:
    rows = []
    for r in runs:
        eps = r["episodes"]
        n = len(eps)
        ok = sum(e["success"] for e in eps)
        first = sum(e["success"] and e["retries"] == 0 for e in eps)
        pos = [e["error"]["position_mm"] for e in eps if e["error"]["position_mm"] is not None]
        rot = [e["error"]["rotation_deg"] for e in eps if e["error"]["rotation_deg"] is not None]
        times = [e["time_s"] for e in eps]
        fails: dict[str, int] = {}
        for e in eps:
            if not e["success"]:
                key = (e["failure"] or "judged failed").split(":")[0][:40]
                fails[key] = fails.get(key, 0) + 1
        rows.append(
            f"| {r['object']} | {r['condition']} | {n} | {ok / n:.0%} ({ok}) | {first / n:.0%} | "
            f"{statistics.median(pos) if pos else float('nan'):.2f} | "
            f"{statistics.median(rot) if rot else float('nan'):.2f} | "
            f"{statistics.mean(times):.1f} | {r['wall_s'] / n:.1f} | "
            + (", ".join(f"{k} ({v})" for k, v in sorted(fails.items())) or "-")
            + " |"
        )
    tuned = args.seed < 2000
    text = [
        "# Grasp benchmark",
        "",
        *args.header,
        f"- seeds {args.seed}.. (random object poses of each object's scene), "
        + ("TUNING seeds (thresholds were tuned on 0-19 and 1000-1099)" if tuned else
           "reporting seeds: no threshold was tuned on them")
        + f"; `--workers {args.workers}`, `--backend {args.backend}`",
        f"- total wall time {total_s / 60:.1f} min",
        "",
        "Success is judged with ground truth (object >= 8 cm above the table for the whole 1 s",
        "hold); localization is the real sensor pipeline (`mks_sim.workstation.localize`).",
        "Errors are of the estimate the last attempt used. `time/ep` is one episode's own wall",
        "time in its worker; `wall/ep` the batch wall time divided by the episodes.",
        "",
        "| object | condition | episodes | success | first try | pos err mm (median) | rot err deg (median) | time/ep s | wall/ep s | failures |",
        "|---|---|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(text))
    args.out.with_suffix(".json").write_text(json.dumps(runs, indent=1))


if __name__ == "__main__":
    sys.exit(main())
