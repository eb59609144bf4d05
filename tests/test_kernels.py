"""The kernel signature list and compiling ahead (``mks_sim.kernels``)."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mks_sim import kernels
from mks_sim.lowlevel import _gridknn

needs_numba = pytest.mark.skipif(not _gridknn.available(), reason="numba unavailable")


@needs_numba
def test_every_listed_signature_names_a_kernel_and_fits_its_parameters() -> None:
    """Each line of the package's list: a numba kernel of the listed modules, argument types
    numba reads back, as many as the kernel's parameters (a kernel changed since the list
    was written fails here, not silently at compile time)."""
    import importlib

    from numba.core import types
    from numba.core.registry import CPUDispatcher

    todo = kernels.listed()
    assert len(todo) >= 40  # the workstation's kernels, at least
    for name, sigs in todo.items():
        modname, _, fname = name.rpartition(".")
        assert modname in kernels.KERNEL_MODULES, name
        disp = getattr(importlib.import_module(modname), fname)
        assert isinstance(disp, CPUDispatcher), name
        n_params = len(inspect.signature(disp.py_func).parameters)
        for text in sigs:
            sig = eval(text, vars(types))  # noqa: S307 - numba's type reprs
            assert isinstance(sig, tuple) and all(isinstance(t, types.Type) for t in sig)
            assert len(sig) == n_params, (name, text)


def test_every_kernel_module_of_the_package_is_listed() -> None:
    """A kernel module added later (``_*kernels.py``) belongs in ``KERNEL_MODULES``: its
    signatures would otherwise never be recorded nor compiled ahead."""
    root = Path(kernels.__file__).parent
    found = {
        ".".join(("mks_sim", *p.relative_to(root).with_suffix("").parts))
        for p in root.rglob("_*kernels.py")
    }
    assert found == set(kernels.KERNEL_MODULES)


@needs_numba
def test_used_and_record_merge_the_signatures_of_several_processes(tmp_path: Path) -> None:
    """A kernel called here is in :func:`used`; two records into one file keep both
    processes' lines, once each, after the header."""
    from mks_sim.lowlevel import _gridknn_kernels

    _gridknn_kernels.counting_order(np.array([2, 0, 1], np.int64), 3)
    line = (
        "mks_sim.lowlevel._gridknn_kernels.counting_order\t"
        "(Array(int64, 1, 'C', False, aligned=True), int64)"
    )
    assert line in kernels.used()
    path = tmp_path / "sigs.txt"
    path.write_text("mks_sim.x.other\t(int64,)\n")  # another process's line
    kernels.record(path)
    kernels.record(path)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("#")
    assert lines.count(line) == 1 and lines.count("mks_sim.x.other\t(int64,)") == 1
    assert kernels.listed(path)["mks_sim.x.other"] == ["(int64,)"]


@needs_numba
@pytest.mark.slow
def test_compiled_ahead_a_new_process_loads_from_the_cache(tmp_path: Path) -> None:
    """With an empty numba cache: compile_ahead over two processes fills it (a stale line
    is skipped); a new process then calls the kernel and numba compiles nothing (a cache
    hit, no miss)."""
    sigs = tmp_path / "sigs.txt"
    sigs.write_text(
        "mks_sim.lowlevel._gridknn_kernels.counting_order\t"
        "(Array(int64, 1, 'C', False, aligned=True), int64)\n"
        "mks_sim.lowlevel._gridknn_kernels.counting_order\t(int64,)\n"  # stale: wrong arity
        "mks_sim.lowlevel._gridknn_kernels.no_such_kernel\t(int64,)\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    ahead = subprocess.run(
        [sys.executable, "-c",
         f"from mks_sim import kernels; print(kernels.compile_ahead(2, {str(sigs)!r}))"],
        env=env, capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "1 signatures of 2 kernels compiled or loaded" in ahead.stdout
    assert "2 stale skipped" in ahead.stdout and ahead.stdout.strip().endswith("1")
    probe = (
        "import numpy as np\n"
        "from mks_sim.lowlevel import _gridknn_kernels as k\n"
        "print(k.counting_order(np.array([2, 0, 1], np.int64), 3).tolist())\n"
        "s = k.counting_order.stats\n"
        "print(sum(s.cache_hits.values()), sum(s.cache_misses.values()))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True
    ).stdout.split("\n")
    assert out[0] == "[1, 2, 0]"  # the counting sort's order of keys 2, 0, 1
    assert out[1] == "1 0"  # loaded from the cache, nothing compiled


def test_bad_jobs_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert kernels.main(["--jobs", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m mks_sim.kernels: --jobs: expected >= 1, got 0"]
