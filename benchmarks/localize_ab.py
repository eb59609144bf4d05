"""Benchmark: localization time of two commits, alternated on the same machine state.

The machine's speed drifts by tens of percent from hour to hour (and within a run of
``localize_sim.py``), so a speed-up is measured here, not by comparing two results files:
the base commit (checked out into a temporary git worktree) and the new code (this checkout,
or ``--new REV``) localize the same seeded scenes in alternating subprocesses, ``--rounds``
times each. Per seed and stage the best of all its localizations counts (``--reps`` per
round); the table gives the medians over the seeds and the ratio base / new.

Run (alone, on an idle machine)::

    .venv/bin/python benchmarks/localize_ab.py --base e054b11
    .venv/bin/python benchmarks/localize_ab.py --base e054b11 --seeds 2000-2009 --rounds 1

Seeds default to 2000-2029 (reporting seeds: no threshold was tuned on them). Healthy
devices; ``timing_s`` of ``localize_object`` (processing = representation + hypotheses +
verification, after the devices are read).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import ROOT, header_lines  # noqa: E402

STAGES = ("representation", "hypotheses", "verification", "processing")


def worker(objects: list[str], seeds: list[int], reps: int) -> dict[str, dict[str, float]]:
    """Best-of-``reps`` stage times of every (object, seed), seconds (run inside a tree)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import logging

    logging.disable(logging.WARNING)
    from mks_sim.cli.localize import check_arguments
    from mks_sim.devices import make_devices
    from mks_sim.sim.world import build_world
    from mks_sim.workstation import localize_object

    out: dict[str, dict[str, float]] = {}
    for i, obj in enumerate(objects):
        scene = check_arguments(None, obj, (), ())
        for seed in ([99] if i == 0 else []) + seeds:  # seed 99 first: imports, kernels
            world = build_world(scene, seed=seed, objects=[obj])
            best = dict.fromkeys(STAGES, np.inf)
            for _ in range(reps):
                devices = make_devices(world.model, world.data, np.random.default_rng(seed), {})
                try:
                    res = localize_object(world, obj, devices, rng=np.random.default_rng(seed))
                finally:
                    devices.close()
                timing = res.diagnostics["timing"]
                best = {k: min(best[k], float(timing.get(k, 0.0))) for k in STAGES}
            if seed != 99 or i != 0:
                out[f"{obj}:{seed}"] = best
    return out


def _run_tree(tree: Path, objects: list[str], seeds: list[int], reps: int) -> dict[str, Any]:
    env = dict(os.environ, MUJOCO_GL="egl", PYTHONPATH=str(tree))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker",
           "--objects", ",".join(objects), "--seeds", ",".join(map(str, seeds)),
           "--reps", str(reps)]  # fmt: skip
    proc = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"localize_ab: the run in {tree} failed:\n{proc.stderr[-2000:]}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def _bad_input(message: str) -> SystemExit:
    """A one-line error for bad input (exit 2)."""
    print(f"localize_ab: {message}", file=sys.stderr)
    return SystemExit(2)


def _seeds(text: str) -> list[int]:
    try:
        if "-" in text and "," not in text:
            a, b = (int(x) for x in text.split("-"))
            return list(range(a, b + 1))
        return [int(x) for x in text.split(",")]
    except ValueError:
        raise _bad_input(f"--seeds: expected A-B or a,b,c, got {text!r}") from None


def _checkout(rev: str, where: Path) -> None:
    proc = subprocess.run(["git", "worktree", "add", "--detach", str(where), rev],
                          cwd=ROOT, capture_output=True, text=True)  # fmt: skip
    if proc.returncode != 0:
        why = (proc.stderr.strip().splitlines() or ["git worktree add failed"])[-1]
        raise _bad_input(f"cannot check out {rev!r}: {why}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", help="the commit to compare against (required)")
    ap.add_argument("--new", default=None, help="the new commit (default: this checkout)")
    ap.add_argument("--objects", default="cube,part,sphere")
    ap.add_argument("--seeds", default="2000-2029", help="A-B or a,b,c (default 2000-2029)")
    ap.add_argument("--rounds", type=int, default=2, help="alternations (default 2)")
    ap.add_argument("--reps", type=int, default=2, help="localizations per seed and round")
    ap.add_argument("--out", default=None, help="default benchmarks/results/localize_ab.md")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    objects = [o for o in args.objects.split(",") if o]
    seeds = _seeds(args.seeds)
    if args.worker:
        print(json.dumps(worker(objects, seeds, args.reps)))
        return 0
    if not args.base:
        ap.error("--base REV is required (the commit to compare against)")
    if args.rounds < 1 or args.reps < 1:
        ap.error("--rounds and --reps must be >= 1")
    header = header_lines(
        "python benchmarks/localize_ab.py " + " ".join(sys.argv[1:] if argv is None else argv)
    )
    tmp = Path(tempfile.mkdtemp(prefix="localize_ab_"))
    trees = {"base": tmp / "base", "new": ROOT if args.new is None else tmp / "new"}
    try:
        _checkout(args.base, trees["base"])
        if args.new is not None:
            _checkout(args.new, trees["new"])
        runs: dict[str, list[dict[str, Any]]] = {"base": [], "new": []}
        for r in range(args.rounds):
            for side in ("base", "new"):
                print(f"round {r + 1}/{args.rounds}: {side}", file=sys.stderr, flush=True)
                runs[side].append(_run_tree(trees[side], objects, seeds, args.reps))
    finally:
        for side in ("base", "new"):
            if trees[side] != ROOT and trees[side].exists():
                subprocess.run(["git", "worktree", "remove", "--force", str(trees[side])],
                               cwd=ROOT, capture_output=True)  # fmt: skip
    rows = []
    for obj in objects:
        med = {}
        for side in ("base", "new"):
            keys = [k for k in runs[side][0] if k.startswith(obj + ":")]
            med[side] = {s: 1000 * float(np.median([min(run[k][s] for run in runs[side])
                                                     for k in keys])) for s in STAGES}  # fmt: skip
        cells = [f"{med['base'][s]:.1f} -> {med['new'][s]:.1f}" for s in STAGES]
        ratio = med["base"]["processing"] / max(med["new"]["processing"], 1e-9)
        rows.append(f"| {obj} | " + " | ".join(cells) + f" | {ratio:.2f}x |")
    new_name = "this checkout" if args.new is None else f"`{args.new}`"
    lines = [
        "# Localization time, two commits alternated (`benchmarks/localize_ab.py`)",
        "",
        *header,
        f"- base `{args.base}` against {new_name}; seeds {seeds[0]}..{seeds[-1]} "
        f"({len(seeds)}), healthy; {args.rounds} round(s) of alternating subprocesses, "
        f"{args.reps} localization(s) per seed each; per seed and stage the best of all its "
        "localizations; medians over the seeds, ms (base -> new)",
        "",
        "| object | representation | hypotheses | verification | processing | base / new |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    text = "\n".join(lines)
    print(text)
    out = Path(args.out) if args.out else ROOT / "benchmarks" / "results" / "localize_ab.md"
    out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
