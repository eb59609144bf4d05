"""`mks-sim grasp`: closed-loop grasp episodes (sense, localize, grasp, lift, verify)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence

from mks_sim.cli import output_file
from mks_sim.cli._bin import add_task_argument, run_clear_bin_command
from mks_sim.errors import MksError, SpecError
from mks_sim.tasks.backends import BACKENDS, EpisodeJob, check_backend
from mks_sim.viz import add_rerun_argument, open_recorder

HELP = "grasp an object with the Jaco hand from sensor-based localization (episodes, JSON, video)"

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--object", default=None, metavar="NAME",
        help="a model-database object (cube, sphere, part, or one added with objects add); "
        "required unless --task",
    )  # fmt: skip
    add_task_argument(parser)  # bin picking (issue 13)
    parser.add_argument(
        "--models", action="append", default=[], metavar="DIR",
        help="extra model-database folder (repeatable; passed to workers as MKS_SIM_MODELS)",
    )  # fmt: skip
    parser.add_argument("--episodes", type=int, default=1, help="episodes (seeds S, S+1, ...)")
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--workers", type=int, default=1, help="parallel processes")
    parser.add_argument(
        "--fail", nargs="+", action="extend", default=[], metavar="DEVICE",
        help="fail these devices for every episode (e.g. range_finder)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print JSON to stdout")
    parser.add_argument("--video", metavar="FILE", help="write the first episode as MP4/GIF")
    add_rerun_argument(parser)  # recorded episodes run in this process, one after the other
    parser.add_argument(
        "--backend", choices=BACKENDS, default="local",
        help="where episodes run: local processes (--workers) or Ray tasks (the 'ray' extra)",
    )  # fmt: skip
    parser.add_argument(
        "--address", metavar="auto|HOST:PORT",
        help="--backend ray: join this Ray cluster (default: start a local Ray with --workers CPUs)",
    )  # fmt: skip
    parser.add_argument(
        "--record", metavar="DIR",
        help="step the env (mks_sim/Grasp-v*) with the scripted policy and write the episodes "
        "as the Minari dataset DIR (named NAME-vN; the 'record' extra)",
    )  # fmt: skip
    parser.add_argument(
        "--max-steps", type=int, default=150, metavar="N",
        help="--record: env steps per episode before truncation (default 150)",
    )  # fmt: skip


def run_episodes(
    obj: str,
    seeds: Sequence[int],
    faults: Sequence[str],
    workers: int,
    progress: bool = True,
    *,
    backend: str = "local",
    address: str | None = None,
) -> list[dict]:
    """Run episodes on ``backend`` (:func:`mks_sim.tasks.backends.run_episodes`), in seed
    order."""
    from mks_sim.tasks import backends

    jobs = [EpisodeJob(obj, int(s), tuple(faults)) for s in seeds]
    return backends.run_episodes(
        jobs, backend=backend, address=address, workers=workers, progress=progress,
        desc=f"grasp {obj}",
    )  # fmt: skip


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

    if args.task is not None:
        return run_clear_bin_command(args)
    if args.object is None:
        raise SpecError("grasp: --object NAME is required (or --task clear_bin)")
    if args.models:  # workers (processes) inherit the environment
        import os

        from mks_sim.models.objects import MODELS_ENV, models_dirs

        dirs = [str(d) for d in models_dirs(args.models)[1:]]
        os.environ[MODELS_ENV] = os.pathsep.join(dirs)
    from mks_sim.models.objects import load_object

    load_object(args.object)  # NotFound lists the database's objects
    if args.episodes < 1:
        raise MksError(f"--episodes: expected >= 1, got {args.episodes}")
    if args.workers < 1:
        raise MksError(f"--workers: expected >= 1, got {args.workers}")
    check_backend(args.backend, args.address)
    if args.record is not None:  # checked before any episode runs; Minari loaded only here
        from mks_sim.record import check_record_dir

        if args.video:
            raise MksError("--record and --video: expected one of them, got both")
        if args.max_steps < 1:
            raise MksError(f"--max-steps: expected >= 1, got {args.max_steps}")
        check_record_dir(args.record)
    if args.video:  # checked before any episode runs; no folder is created
        output_file(args.video, "--video", (".mp4", ".m4v", ".mov", ".gif"))
    seeds = list(range(args.seed, args.seed + args.episodes))
    faults = tuple(args.fail)
    if args.record is not None:
        from mks_sim.record import record_episodes

        episodes = record_episodes(
            args.record, args.object, seeds, faults, max_episode_steps=args.max_steps,
            backend=args.backend, address=args.address, workers=args.workers,
        )  # fmt: skip
        print(f"recorded {len(episodes)} episode(s) as the Minari dataset {args.record}",
              file=sys.stderr)  # fmt: skip
    elif args.rerun is not None:  # one recording: the episodes run here, in seed order
        shots: list = []
        with open_recorder(args.rerun, "mks_sim grasp") as recorder:
            results = [run_episode(args.object, s, faults, recorder=recorder,
                                   frame_sink=shots.append if args.video and s == seeds[0]
                                   else None) for s in seeds]  # fmt: skip
        if args.video:
            print(f"video of seed {seeds[0]}: {write_video(shots, args.video)}", file=sys.stderr)
        episodes = [r.to_json() for r in results]
    elif args.video:
        frames: list = []
        first = run_episode(args.object, seeds[0], faults, frame_sink=frames.append)
        written = write_video(frames, args.video)
        print(f"video of seed {seeds[0]} ({len(frames)} frames): {written}", file=sys.stderr)
        rest = (
            run_episodes(args.object, seeds[1:], faults, args.workers,
                         backend=args.backend, address=args.address)
            if len(seeds) > 1
            else []
        )  # fmt: skip
        episodes = [first.to_json(), *rest]
    else:
        episodes = run_episodes(
            args.object, seeds, faults, args.workers, backend=args.backend, address=args.address
        )
    doc = summary(episodes)
    if args.json:
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        rows = [
            (e["seed"], "yes" if e["success"] else "no", e["retries"],
             e["error"]["position_mm"] if e["error"]["position_mm"] is not None else float("nan"),
             e["error"]["rotation_deg"] if e["error"]["rotation_deg"] is not None else float("nan"),
             e["time_s"], e.get("relocalizations", "-"), e.get("corrections", "-"),
             e["failure"])
            for e in episodes
        ]  # fmt: skip
        headers = ("seed", "success", "retries", "pos err mm", "rot err deg", "time s",
                   "re-sensed", "corrections", "failure")  # fmt: skip
        print(format_table(headers, rows))
        failed = sorted({d for e in episodes for d in e.get("faults", ())})
        if failed:
            print(f"failed devices: {', '.join(failed)}")
        for line in sorted({w for e in episodes for w in e.get("warnings", ())}):
            print(f"warning: {line}")
        print(
            f"success rate: {doc['success_rate']:.2f} ({len(episodes)} episodes, object {args.object})"
        )
    # The exit-code contract: 0 every episode succeeded, 1 some failed (the JSON says which).
    return 0 if all(e["success"] for e in episodes) else 1
