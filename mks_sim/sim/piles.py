"""Settled piles, kept: a seeded drop's final physics state, saved by content.

Dropping a bin's parts and stepping them until at rest (:meth:`World.randomize`) takes 3-30 s
of simulation for the bins of six parts; the result depends only on the compiled model, the
seed, MuJoCo and the settling code. :func:`randomize_settled` saves MuJoCo's integration
state (:func:`mujoco.mj_getState`, ``mjSTATE_INTEGRATION``: time, positions, velocities,
activations, warm start, controls) after the first settle under a key hashing exactly those
four, and restores it the next time: the world is then bit for bit the one settling gives,
and every later step the same (MuJoCo is deterministic for a given build and state).

Where: the folders of ``MKS_SIM_PILE_CACHE`` (``os.pathsep``-separated; saved to the first,
looked up in all; ``off`` turns the cache off), else ``$XDG_CACHE_HOME/mks_sim/piles``
(``~/.cache/mks_sim/piles``). A state that cannot be read or does not fit the model is settled
anew; a folder that cannot be written is skipped with a log line.
"""

from __future__ import annotations

import hashlib
import inspect
import logging
import os
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np

if TYPE_CHECKING:
    from mks_sim.sim.world import World

log = logging.getLogger(__name__)

#: The environment variable naming the cache folders.
CACHE_ENV = "MKS_SIM_PILE_CACHE"
#: Bump when the saved file's layout changes.
FORMAT = 1
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


def cache_dirs() -> list[Path]:
    """The cache folders, the one written first (empty: the cache is off)."""
    raw = os.environ.get(CACHE_ENV)
    if raw is not None:
        if raw.strip().lower() == "off":
            return []
        return [Path(p).expanduser() for p in raw.split(os.pathsep) if p.strip()]
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return [Path(base) / "mks_sim" / "piles"]


def _code_digest() -> bytes:
    """What settling does: the source of the world module (its constants and methods)."""
    from mks_sim.sim import world as world_module

    return hashlib.sha256(inspect.getsource(world_module).encode()).digest()


def pile_key(world: World, seed: int) -> str:
    """The key of ``world`` settled from ``seed``: a hash of the compiled model (MuJoCo's
    binary model: bodies, meshes, contacts, solver options), the seed, MuJoCo's version, the
    settling code and :data:`FORMAT`."""
    h = hashlib.sha256()
    buf = np.empty(mujoco.mj_sizeModel(world.model), dtype=np.uint8)
    mujoco.mj_saveModel(world.model, None, buf)
    h.update(buf.tobytes())
    h.update(f"seed={int(seed)};mujoco={mujoco.__version__};format={FORMAT};".encode())
    h.update(_code_digest())
    return h.hexdigest()


def _restore(world: World, path: Path) -> bool:
    try:
        with np.load(path) as f:
            state = np.asarray(f["state"], dtype=np.float64)
            rest_steps = int(f["rest_steps"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        log.info("pile %s unreadable, settling anew: %s", path.name, exc)
        return False
    if state.shape != (mujoco.mj_stateSize(world.model, _STATE),):
        log.info("pile %s does not fit the model, settling anew", path.name)
        return False
    mujoco.mj_setState(world.model, world.data, state, _STATE)
    mujoco.mj_forward(world.model, world.data)
    world.rest_steps = rest_steps
    return True


def _save(world: World, key: str, folder: Path) -> None:
    state = np.empty(mujoco.mj_stateSize(world.model, _STATE))
    mujoco.mj_getState(world.model, world.data, state, _STATE)
    tmp = folder / f".{key}.{os.getpid()}.npz"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.savez(f, state=state, rest_steps=np.int64(world.rest_steps))
        tmp.replace(folder / f"{key}.npz")  # atomic: a reader never sees half a file
    except OSError as exc:
        log.info("pile cache %s not written: %s", folder, exc)
        try:
            tmp.unlink(missing_ok=True)  # (a half-written file, e.g. the disk full)
        except OSError:
            pass


def randomize_settled(world: World, seed: int) -> bool:
    """``world.randomize(np.random.default_rng(seed))``, restored from the cache when this
    world and seed were settled before (returns True then), else settled and saved."""
    dirs = cache_dirs()
    if not dirs:
        world.randomize(np.random.default_rng(seed))
        return False
    key = pile_key(world, seed)
    for folder in dirs:
        path = folder / f"{key}.npz"
        if path.is_file() and _restore(world, path):
            return True
    world.randomize(np.random.default_rng(seed))
    _save(world, key, dirs[0])
    return False
