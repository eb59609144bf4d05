"""`mks-sim grasp`: closed-loop grasp episodes (sense, localize, grasp, lift, verify)."""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import sys
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

from mks_sim.errors import MksError

HELP = "grasp an object with the Jaco hand from sensor-based localization (episodes, JSON, video)"

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--object", required=True, choices=("cube", "sphere", "part"))
    parser.add_argument("--episodes", type=int, default=1, help="episodes (seeds S, S+1, ...)")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--workers", type=int, default=1, help="parallel processes")
    parser.add_argument(
        "--fail", nargs="+", action="extend", default=[], metavar="DEVICE",
        help="fail these devices for every episode (e.g. range_finder)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print JSON to stdout")
    parser.add_argument("--video", metavar="FILE", help="write the first episode as MP4/GIF")


def _episode(job: tuple[str, int, tuple[str, ...]]) -> dict:
    # Module-level so that spawn-started workers can import and run it.
    from mks_sim.tasks.episode import run_episode

    obj, seed, faults = job
    return run_episode(obj, seed, faults).to_json()


def run_episodes(
    obj: str, seeds: Sequence[int], faults: Sequence[str], workers: int, progress: bool = True
) -> list[dict]:
    """Run episodes (in ``workers`` spawn-started processes when > 1), in seed order."""
    from tqdm import tqdm

    jobs = [(obj, int(s), tuple(faults)) for s in seeds]
    results: dict[int, dict] = {}
    bar = tqdm(
        total=len(jobs), desc=f"grasp {obj}", unit="ep", file=sys.stderr, disable=not progress
    )
    try:
        if workers <= 1:
            for job in jobs:
                results[job[1]] = _episode(job)
                bar.update()
        else:
            ctx = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures = {pool.submit(_episode, job): job[1] for job in jobs}
                for fut in as_completed(futures):
                    results[futures[fut]] = fut.result()
                    bar.update()
    finally:
        bar.close()
    return [results[int(s)] for s in seeds]


def summary(episodes: list[dict]) -> dict:
    """The CLI's JSON document."""
    n = len(episodes)
    return {
        "episodes": episodes,
        "success_rate": (sum(e["success"] for e in episodes) / n) if n else 0.0,
    }


def run(args: argparse.Namespace) -> int:
    from mks_sim.report import format_table, write_video
    from mks_sim.tasks.episode import run_episode

    if args.episodes < 1:
        raise MksError(f"--episodes: expected >= 1, got {args.episodes}")
    if args.workers < 1:
        raise MksError(f"--workers: expected >= 1, got {args.workers}")
    seeds = list(range(args.seed, args.seed + args.episodes))
    faults = tuple(args.fail)
    if args.video:
        frames: list = []
        first = run_episode(args.object, seeds[0], faults, frame_sink=frames.append)
        written = write_video(frames, args.video)
        print(f"video of seed {seeds[0]} ({len(frames)} frames): {written}", file=sys.stderr)
        rest = run_episodes(args.object, seeds[1:], faults, args.workers) if len(seeds) > 1 else []
        episodes = [first.to_json(), *rest]
    else:
        episodes = run_episodes(args.object, seeds, faults, args.workers)
    doc = summary(episodes)
    if args.json:
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        rows = [
            (e["seed"], "yes" if e["success"] else "no", e["retries"],
             e["error"]["position_mm"] if e["error"]["position_mm"] is not None else float("nan"),
             e["error"]["rotation_deg"] if e["error"]["rotation_deg"] is not None else float("nan"),
             e["time_s"], e["failure"])
            for e in episodes
        ]  # fmt: skip
        print(
            format_table(
                ("seed", "success", "retries", "pos err mm", "rot err deg", "time s", "failure"),
                rows,
            )
        )
        print(
            f"success rate: {doc['success_rate']:.2f} ({len(episodes)} episodes, object {args.object})"
        )
    return 0
