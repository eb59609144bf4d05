"""Benchmark: localization accuracy from simulated sensors (issue #4, section 5).

For each object (cube and sphere in scene2, the industrial part in the part scene) and each
sensing mode (all devices healthy; range finder failed, so ``Range_Points`` is served by
``Stereo_Points``), localize the object in ``--n`` seeded random layouts and report — not
assert — the median and 95th-percentile position and rotation errors, the success rate
(within 5 mm and 5 degrees of the ground truth) and the time per localization: the median
processing time (after the devices are read: representation, hypotheses, verification; goal
<= 50 ms) and the median total with sensing (goal <= 100 ms), from ``timing_s``.

Run (on an idle machine; one worker so that the two cores do not compete)::

    .venv/bin/python benchmarks/localize_sim.py --n 100 --out benchmarks/results/localize_sim.md
    .venv/bin/python benchmarks/localize_sim.py --quick        # 10 seeds, a smoke run

Seeds are ``--seed0 .. --seed0 + n - 1`` (default 2000..2099: reporting seeds; the engine was
tuned on seeds 0..19 and earlier on 1000..1099); the same seeds for every object and mode.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import header_lines  # noqa: E402

MODES: dict[str, tuple[str, ...]] = {"healthy": (), "stereo": ("range_finder",)}
GOALS = {
    "cube": (2.0, 1.0),
    "sphere": (2.0, 1.0),
    "part": (3.0, 2.0),
}


def _trial(job: tuple[str, int, tuple[str, ...]]) -> dict[str, Any]:
    os.environ.setdefault("MUJOCO_GL", "egl")
    import logging

    logging.disable(logging.WARNING)
    from mks_sim.cli.localize import run_trial

    obj, seed, fail = job
    t0 = time.perf_counter()
    try:
        rec = run_trial(obj, seed, fail)
    except Exception as exc:  # reported, not raised: one bad seed must not stop the sweep
        rec = {
            "object": obj,
            "seed": seed,
            "found": False,
            "error": {"position_mm": None, "rotation_deg": None},
            "success": False,
            "provenance": {},
            "time_s": float("nan"),
            "timing_s": {},
            "exception": f"{type(exc).__name__}: {exc}",
        }
    rec["wall_s"] = time.perf_counter() - t0
    rec["failed_devices"] = list(fail)
    return rec


def _stats(recs: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(recs)
    found = [r for r in recs if r["found"] and r["error"]["position_mm"] is not None]
    pos = np.array([r["error"]["position_mm"] for r in found], dtype=float)
    rot = np.array([r["error"]["rotation_deg"] for r in found], dtype=float)
    t = np.array([r["time_s"] for r in recs if np.isfinite(r.get("time_s", np.nan))], dtype=float)
    timed = [r["timing_s"] for r in recs if r.get("timing_s")]
    total = np.array([x["total"] for x in timed], dtype=float)
    processing = np.array([x["processing"] for x in timed], dtype=float)

    def q(a: np.ndarray, p: float) -> float:
        return float(np.percentile(a, p)) if len(a) else float("nan")

    served = sorted(
        {v for r in recs for k, v in r.get("provenance", {}).items() if k == "Range_Points"}
    )
    return {
        "n": n,
        "found": len(found),
        "success": sum(bool(r["success"]) for r in recs),
        "pos_median": q(pos, 50),
        "pos_p95": q(pos, 95),
        "rot_median": q(rot, 50),
        "rot_p95": q(rot, 95),
        "time_median": q(t, 50),
        "time_mean": float(np.mean(t)) if len(t) else float("nan"),
        "processing_median": q(processing, 50),
        "processing_p95": q(processing, 95),
        "total_median": q(total, 50),
        "range_points_served_by": served,
        "exceptions": [r["exception"] for r in recs if "exception" in r][:3],
        "failures": [
            (r["seed"], r["error"]["position_mm"], r["error"]["rotation_deg"])
            for r in recs
            if not r["success"]
        ][:10],
    }


def _table(stats: dict[tuple[str, str], dict[str, Any]]) -> str:
    head = (
        "| object | mode (Range_Points from) | n | success (<=5 mm, <=5 deg) | position median / p95 (mm)"
        " | rotation median / p95 (deg) | processing median / p95 (ms, goal <= 50)"
        " | total with sensing median (ms, goal <= 100) | goal (median) |\n"
        "|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = []
    for (obj, mode), s in stats.items():
        served = "/".join(s["range_points_served_by"]) or "-"
        g = GOALS[obj]
        rows.append(
            f"| {obj} | {mode} ({served}) | {s['n']} | {s['success']}/{s['n']} "
            f"({100.0 * s['success'] / max(s['n'], 1):.1f} %) | {s['pos_median']:.2f} / "
            f"{s['pos_p95']:.2f} | {s['rot_median']:.2f} / {s['rot_p95']:.2f} | "
            f"{1000 * s['processing_median']:.0f} / {1000 * s['processing_p95']:.0f} | "
            f"{1000 * s['total_median']:.0f} | <= {g[0]:g} mm, <= {g[1]:g} deg |"
        )
    return head + "\n".join(rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100, help="random layouts per object and mode")
    ap.add_argument("--seed0", type=int, default=2000, help="first seed (reporting: 2000)")
    ap.add_argument("--quick", action="store_true", help="10 seeds per object and mode")
    ap.add_argument("--workers", type=int, default=1, help="parallel processes (spawn)")
    ap.add_argument("--objects", nargs="+", default=list(GOALS), choices=list(GOALS))
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--out", type=Path, help="write the markdown results here")
    ap.add_argument("--json", type=Path, help="write every trial record here (JSON)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    if args.quick:
        args.n = min(args.n, 10)
    header = header_lines()  # the load average before anything runs
    from tqdm import tqdm

    jobs = [
        (obj, args.seed0 + i, MODES[mode], mode)
        for mode in args.modes
        for obj in args.objects
        for i in range(args.n)
    ]
    recs: dict[tuple[str, str], list[dict[str, Any]]] = {
        (o, m): [] for m in args.modes for o in args.objects
    }
    t0 = time.perf_counter()
    bar = tqdm(total=len(jobs), unit="loc", file=sys.stderr, disable=args.no_progress)
    if args.workers <= 1:
        for obj, seed, fail, mode in jobs:
            recs[(obj, mode)].append(_trial((obj, seed, fail)))
            bar.update()
    else:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=args.workers, mp_context=ctx) as pool:
            futs = {pool.submit(_trial, (o, s, f)): (o, m) for o, s, f, m in jobs}
            for fut in as_completed(futs):
                recs[futs[fut]].append(fut.result())
                bar.update()
    bar.close()
    wall = time.perf_counter() - t0
    stats = {k: _stats(sorted(v, key=lambda r: r["seed"])) for k, v in recs.items()}
    table = _table(stats)
    print(table)
    for k, s in stats.items():
        if s["failures"] or s["exceptions"]:
            print(f"{k}: failures (seed, mm, deg) {s['failures']} {s['exceptions']}")
    if args.json:
        args.json.write_text(json.dumps({f"{o}/{m}": v for (o, m), v in recs.items()}, indent=1))
    if args.out:
        lines = [
            "# Localization from simulated sensors (`benchmarks/localize_sim.py`)",
            "",
            *header,
            f"- {args.workers} worker process(es); wall {wall:.0f} s",
            f"- seeds {args.seed0}..{args.seed0 + args.n - 1} per object and mode; success = "
            "within 5 mm and 5 degrees of the ground truth (cube rotation modulo its 24 "
            "symmetries, sphere rotation not observable = 0)",
            "- processing: `localize_object` after the devices are read (`timing_s.processing`:"
            " representation, hypotheses, verification); total: the whole call with sensing "
            "(the first call of a process also loads the model database); the world build is "
            "not timed",
            "",
            table,
        ]
        for (o, m), s in stats.items():
            if s["failures"]:
                lines.append(f"- {o} / {m}: unsuccessful seeds (seed, mm, deg): {s['failures']}")
            if s["exceptions"]:
                lines.append(f"- {o} / {m}: exceptions: {s['exceptions']}")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
