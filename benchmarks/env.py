"""Env throughput: ``mks_sim/Grasp-v2`` against gymnasium-robotics ``FetchPickAndPlace-v4``
and dm_control's ``lift_brick_features`` / ``lift_brick_vision``, in one run.

Random actions; each env without a camera and with one 84x84 camera (ours: the overhead
camera as ``obs["image"]``; Fetch: ``render()`` at 84x84 every step; dm_control: the vision
task's own 84x84 front camera). Reported: steps per wall second, simulated seconds per step
and simulated seconds per wall second (the fair comparison: our step is 0.1 s of simulated
time, Fetch's and dm_control's 0.04 s); resets are timed apart (ours split into localization
and the rest). Then the per-core scaling of ``gym.make_vec(..., vectorization_mode="async")``
(spawn context) with 1 and 2 envs.

    .venv/bin/python benchmarks/env.py            # 600 steps per env (about 5 minutes)
    .venv/bin/python benchmarks/env.py --quick    # 100 steps, a smoke run

Writes benchmarks/results/env.md. Peers come from the ``bench`` extra.
Goals (issue 11): sim-s per wall-s >= Fetch's without a camera, >= 2x Fetch's with one.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import header_lines  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
OUR_ENV = "mks_sim/Grasp-v2"  # as made by default: resting bodies sleep (docs/env.md "Speed")
OUR_AWAKE = f"{OUR_ENV} sleep=False"  # every body simulated every step (the former default)
CAMERA = 84  # pixels, square, as dm_control's vision tasks


@dataclass(frozen=True)
class Row:
    """One env's measurement."""

    name: str
    camera: str
    steps: int
    step_wall_s: float
    sim_dt_s: float
    resets: int
    reset_wall_s: float
    note: str = ""

    @property
    def steps_per_s(self) -> float:
        return self.steps / self.step_wall_s

    @property
    def sim_per_wall(self) -> float:
        return self.steps_per_s * self.sim_dt_s


def _loop(
    reset: Callable[[], None], step: Callable[[], bool], n: int, max_resets: int
) -> tuple[float, int, float]:
    """(step wall s, resets, reset wall s): ``n`` timed steps; resets timed apart."""
    t = time.perf_counter()
    reset()
    reset_s, resets = time.perf_counter() - t, 1
    step_s = 0.0
    for _ in range(n):
        t = time.perf_counter()
        done = step()
        step_s += time.perf_counter() - t
        if done and resets < max_resets:
            t = time.perf_counter()
            reset()
            reset_s += time.perf_counter() - t
            resets += 1
    return step_s, resets, reset_s


def bench_ours(n: int, camera: bool, seed: int, sleep: bool = True) -> Row:
    import gymnasium as gym

    import mks_sim  # noqa: F401  (registers the envs)

    kw: dict = {"observe_image": True, "image_size": (CAMERA, CAMERA)} if camera else {}
    env = gym.make(OUR_ENV, object="cube", max_episode_steps=n + 1, sleep=sleep, **kw)
    env.action_space.seed(seed)
    loc: list[float] = []

    def reset() -> None:
        _, info = env.reset(seed=seed)
        loc.append(info["reset_timing_s"]["localization"])

    def step() -> bool:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        return bool(term or trunc)

    try:
        step_s, resets, reset_s = _loop(reset, step, n, max_resets=2)
        dt = float(env.unwrapped.dt)
    finally:
        env.close()
    note = f"reset: localization {np.mean(loc):.2f} s, rest {reset_s / resets - np.mean(loc):.2f} s"
    return Row(OUR_ENV if sleep else OUR_AWAKE, _cam(camera), n, step_s, dt, resets, reset_s, note)


def _fix_gymnasium_robotics() -> None:
    # gymnasium-robotics 1.4.2 asserts `jnt_type in (mjtJoint.mjJNT_HINGE, ...)`; under mujoco
    # 3.17 a numpy int equals the enum but `in` a tuple of enums is False, so Fetch cannot be
    # built. Its joint helpers get a mujoco whose joint enums are plain ints (no other change).
    import mujoco
    from gymnasium_robotics.utils import mujoco_utils

    if np.int32(int(mujoco.mjtJoint.mjJNT_HINGE)) in (mujoco.mjtJoint.mjJNT_HINGE,):
        return
    proxy = types.ModuleType("mujoco_int_enums")
    proxy.__getattr__ = lambda name: getattr(mujoco, name)  # type: ignore[method-assign]
    proxy.mjtJoint = types.SimpleNamespace(  # type: ignore[attr-defined]
        **{
            k: int(getattr(mujoco.mjtJoint, k))
            for k in dir(mujoco.mjtJoint)
            if k.startswith("mjJNT")
        }
    )
    mujoco_utils.mujoco = proxy


def bench_fetch(n: int, camera: bool, seed: int) -> Row:
    import gymnasium as gym
    import gymnasium_robotics

    _fix_gymnasium_robotics()
    gym.register_envs(gymnasium_robotics)
    kw = {"render_mode": "rgb_array", "width": CAMERA, "height": CAMERA} if camera else {}
    env = gym.make("FetchPickAndPlace-v4", **kw)
    env.action_space.seed(seed)

    def reset() -> None:
        env.reset(seed=seed)
        if camera:
            env.render()

    def step() -> bool:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if camera:
            env.render()
        return bool(term or trunc)

    try:
        step_s, resets, reset_s = _loop(reset, step, n, max_resets=1000)
        dt = float(env.unwrapped.dt)
    finally:
        env.close()
    return Row("FetchPickAndPlace-v4", _cam(camera), n, step_s, dt, resets, reset_s)


def bench_dm_control(n: int, camera: bool, seed: int) -> Row:
    from dm_control import manipulation

    name = "lift_brick_vision" if camera else "lift_brick_features"
    env = manipulation.load(name, seed=seed)
    spec = env.action_spec()
    rng = np.random.default_rng(seed)

    def reset() -> None:
        env.reset()

    def step() -> bool:
        return bool(env.step(rng.uniform(spec.minimum, spec.maximum)).last())

    try:
        step_s, resets, reset_s = _loop(reset, step, n, max_resets=1000)
        dt = float(env.control_timestep())
    finally:
        env.close()
    return Row(f"dm_control {name}", _cam(camera), n, step_s, dt, resets, reset_s)


def bench_vector(n: int, num_envs: int, seed: int) -> tuple[float, float]:
    """(steps per wall second over all envs, reset wall s) of the async vector env."""
    import gymnasium as gym

    import mks_sim  # noqa: F401

    venv = gym.make_vec(
        OUR_ENV, num_envs=num_envs, vectorization_mode="async",
        vector_kwargs={"context": "spawn"}, max_episode_steps=n + 1,
    )  # fmt: skip
    try:
        venv.action_space.seed(seed)
        t = time.perf_counter()
        venv.reset(seed=seed)
        reset_s = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(n):  # fewer steps than max_episode_steps: no autoreset inside the timing
            venv.step(venv.action_space.sample())
        wall = time.perf_counter() - t
    finally:
        venv.close()
    return n * num_envs / wall, reset_s


def _cam(camera: bool) -> str:
    return f"{CAMERA}x{CAMERA}" if camera else "none"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=600, help="timed steps per env")
    p.add_argument("--vector-steps", type=int, default=150, help="timed steps of vector envs")
    p.add_argument("--quick", action="store_true", help="100 steps, 40 vector steps")
    p.add_argument("--no-vector", action="store_true", help="skip the vector-env scaling")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=RESULTS / "env.md")
    args = p.parse_args(argv)
    n, nv = (100, 40) if args.quick else (args.steps, args.vector_steps)
    header = header_lines()  # the load average before anything runs
    load_before = os.getloadavg()
    rows: list[Row] = []
    for camera in (False, True):
        benches: list[Callable[[int, bool, int], Row]] = [bench_ours]
        if not camera:  # awake for comparison; a camera step's time is rendering, not physics
            benches.append(lambda n, camera, seed: bench_ours(n, camera, seed, sleep=False))
        for bench in (*benches, bench_fetch, bench_dm_control):
            row = bench(n, camera, args.seed)
            rows.append(row)
            print(f"{row.name:32s} camera {row.camera:6s} {row.steps_per_s:8.1f} steps/s "
                  f"{row.sim_per_wall:6.2f} sim-s/wall-s", file=sys.stderr, flush=True)  # fmt: skip
    vector = {} if args.no_vector else {k: bench_vector(nv, k, args.seed) for k in (1, 2)}
    for k, (rate, _) in vector.items():
        print(f"async vector env x{k}: {rate:.1f} steps/s", file=sys.stderr, flush=True)
    _write(args.out, header, load_before, rows, vector, nv)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _write(
    out: Path,
    header: list[str],
    load_before: tuple[float, float, float],
    rows: list[Row],
    vector: dict[int, tuple[float, float]],  # empty: not measured
    nv: int,
) -> None:
    lines = ["# Env throughput (issue 11)", "", *header, ""]
    lines += [
        "Random actions, one process per env, resets timed apart. sim-s/wall-s = steps/s x "
        "simulated seconds per step.",
        "",
        "| env | camera | steps | steps/s | sim s/step | sim-s/wall-s | reset s (mean) | note |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.name} | {r.camera} | {r.steps} | {r.steps_per_s:.1f} | {r.sim_dt_s:.3f} | "
            f"{r.sim_per_wall:.2f} | {r.reset_wall_s / r.resets:.2f} | {r.note} |"
        )
    goals = []
    for camera, factor in (("none", 1.0), (_cam(True), 2.0)):
        ours = next(r for r in rows if r.camera == camera and r.name == OUR_ENV)
        fetch = next(r for r in rows if r.camera == camera and r.name.startswith("Fetch"))
        ratio = ours.sim_per_wall / fetch.sim_per_wall
        met = "met" if ratio >= factor else "NOT met"
        goals.append(
            f"- camera {camera}: ours / Fetch = {ratio:.2f} sim-s per wall-s "
            f"(goal >= {factor:g}: {met})"
        )
        awake = next((r for r in rows if r.camera == camera and r.name == OUR_AWAKE), None)
        if awake is not None:
            met = "met" if awake.sim_per_wall >= factor * fetch.sim_per_wall else "NOT met"
            goals.append(
                f"  - with `sleep=False`: {awake.sim_per_wall / fetch.sim_per_wall:.2f} "
                f"(goal >= {factor:g}: {met})"
            )
    lines += ["", "Goals:", "", *goals, ""]
    if not vector:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("\n".join([*lines, "Vector envs: not measured (`--no-vector`).", ""]))
        return
    r1, r2 = vector[1][0], vector[2][0]
    lines += [
        f'Async vector env (`gym.make_vec("{OUR_ENV}", vectorization_mode="async", '
        f'vector_kwargs={{"context": "spawn"}})`), {nv} steps after reset, no camera:',
        "",
        "| envs | steps/s (all envs) | reset s |",
        "|---:|---:|---:|",
        f"| 1 | {r1:.1f} | {vector[1][1]:.1f} |",
        f"| 2 | {r2:.1f} | {vector[2][1]:.1f} |",
        "",
        f"Scaling from 1 to 2 envs: {r2 / r1:.2f}x on {os.cpu_count()} cores "
        f"(load average before the run {load_before[0]:.2f}).",
        "",
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))


if __name__ == "__main__":
    raise SystemExit(main())
