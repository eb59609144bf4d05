"""The package's compiled kernels: which signatures are used, and compiling them ahead of use.

Every kernel is a numba function with ``cache=True``: its first use on a machine compiles it
(a workstation localization uses about 40 of them: ~100 s on one core), later processes load
the machine code from numba's cache. On a new machine -- a fresh clone in CI -- every process
that starts before the cache holds a kernel compiles it again: both test workers at once, the
episode pool's workers, Ray's workers. :func:`compile_ahead` compiles the signatures listed
in ``kernel_signatures.txt`` once, shared out over ``jobs`` processes; every later process
finds them in the cache. A signature that is not listed still compiles on first use, as
before: the list only moves work earlier.

The list is data, written by the suite itself: ``MKS_KERNEL_SIGNATURES=<file> pytest`` makes
every test process add the signatures it used to ``<file>`` (:func:`record`); copy it over
``mks_sim/kernel_signatures.txt``. Each line is ``module.function<TAB>(types)`` with the
argument types as numba prints them (``repr``), read back in ``numba.core.types``.

``python -m mks_sim.kernels [--jobs N]`` compiles ahead (``make test`` and ``make demo`` do).
"""

from __future__ import annotations

import argparse
import fcntl
import importlib
import importlib.util
import os
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path
from typing import Any

#: The modules holding the package's numba kernels.
KERNEL_MODULES = (
    "mks_sim.lowlevel._gridknn_kernels",
    "mks_sim.lowlevel._regions_kernels",
    "mks_sim.models._refine_kernels",
    "mks_sim.models._freeform_kernels",
    "mks_sim.localization._hypotheses_kernels",
    "mks_sim.localization._verify_kernels",
)
SIGNATURE_FILE = Path(__file__).with_name("kernel_signatures.txt")
_HEADER = (
    "# The kernel signatures the suite uses (mks_sim/kernels.py): written by\n"
    "# MKS_KERNEL_SIGNATURES=<file> pytest -n 2; compiled ahead by python -m mks_sim.kernels.\n"
)


def _dispatchers(module: Any) -> Iterator[tuple[str, Any]]:
    from numba.core.registry import CPUDispatcher

    for name, obj in vars(module).items():
        if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module.__name__:
            yield name, obj


def used() -> set[str]:
    """The signature lines (``module.function<TAB>(types)``) of every kernel compiled or
    loaded in this process so far."""
    out = set()
    for modname in KERNEL_MODULES:
        module = sys.modules.get(modname)
        if module is None:
            continue
        for name, disp in _dispatchers(module):
            for sig in disp.signatures:
                if "omitted" not in repr(sig):  # a default argument: compiled on use
                    out.add(f"{modname}.{name}\t{sig!r}")
    return out


def record(path: str | Path) -> None:
    """Add this process's :func:`used` signatures to the file ``path`` (created if missing;
    locked, so that several processes may record into one file)."""
    lines = used()
    with open(path, "a+") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        f.seek(0)
        lines |= {line for line in f.read().splitlines() if line.strip() and line[0] != "#"}
        f.seek(0)
        f.truncate()
        f.write(_HEADER + "".join(f"{line}\n" for line in sorted(lines)))


def listed(path: str | Path = SIGNATURE_FILE) -> dict[str, list[str]]:
    """``{module.function: [types, ...]}`` from a signature file (missing file: empty)."""
    out: dict[str, list[str]] = {}
    if not Path(path).is_file():
        return out
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, _, sig = line.partition("\t")
            out.setdefault(name, []).append(sig)
    return out


def _compile_one(name: str, sigs: list[str]) -> tuple[str, int, int]:
    """Compile (or load from the cache) kernel ``name``'s signatures: (name, compiled or
    loaded, skipped). A signature that no longer fits the kernel (it changed since
    the list was written) or names a type numba does not know is skipped."""
    from numba.core import types

    modname, _, fname = name.rpartition(".")
    try:
        disp = getattr(importlib.import_module(modname), fname)
    except (ImportError, AttributeError):
        return name, 0, len(sigs)
    done = skipped = 0
    for text in sigs:
        try:
            sig = eval(text, vars(types))  # noqa: S307 - numba's own type reprs, from our file
            disp.compile(tuple(sig))
            done += 1
        except Exception:  # noqa: BLE001 - a stale line: the kernel compiles on use instead
            skipped += 1
    return name, done, skipped


def _source_sizes(modnames: set[str]) -> dict[str, int]:
    """``{module.function: source lines}`` of the functions of these modules (a kernel's
    compile cost, roughly: for the order), each module's source parsed once."""
    import ast

    out = {}
    for modname in modnames:
        spec = importlib.util.find_spec(modname)
        if spec is None or spec.origin is None:
            continue
        for node in ast.parse(Path(spec.origin).read_text()).body:
            if isinstance(node, ast.FunctionDef):
                out[f"{modname}.{node.name}"] = (node.end_lineno or node.lineno) - node.lineno
    return out


def compile_ahead(jobs: int = 2, path: str | Path = SIGNATURE_FILE, quiet: bool = False) -> int:
    """Compile every listed signature, the kernels shared out over ``jobs`` processes
    (largest first; a process takes the next kernel when it is done). Returns the number of
    signatures compiled or loaded. Where numba is missing or cannot cache, nothing."""
    from mks_sim.lowlevel import _gridknn

    todo = listed(path)
    if not todo or not _gridknn.available():
        return 0
    from tqdm import tqdm

    size = _source_sizes({name.rpartition(".")[0] for name in todo})
    names = sorted(todo, key=lambda n: -size.get(n, 0))
    t0 = time.perf_counter()
    total = skipped = 0
    bar = tqdm(total=len(names), desc="kernels", unit="kernel", file=sys.stderr, disable=quiet)
    try:
        with ProcessPoolExecutor(max_workers=max(1, jobs), mp_context=get_context("spawn")) as pool:
            for _name, done, skip in pool.map(_compile_one, names, [todo[n] for n in names]):
                total += done
                skipped += skip
                bar.update()
    except (OSError, BrokenProcessPool) as exc:  # compiling ahead only moves work earlier
        print(f"kernels: compiling ahead stopped ({exc}); the rest compile on first use",
              file=sys.stderr)  # fmt: skip
    finally:
        bar.close()
    if not quiet:
        stale = f", {skipped} stale skipped" if skipped else ""
        print(
            f"kernels: {total} signatures of {len(names)} kernels compiled or loaded "
            f"in {time.perf_counter() - t0:.1f} s ({jobs} processes{stale})"
        )
    return total


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m mks_sim.kernels", description="Compile the package's kernels ahead of use."
    )
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="processes")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        print(f"python -m mks_sim.kernels: --jobs: expected >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    compile_ahead(args.jobs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
