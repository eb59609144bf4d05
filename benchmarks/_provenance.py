"""The provenance lines every benchmark writes at the top of its results file.

A table means something only beside the code and the machine state it came from: the commit
(``+dirty`` when the tree had uncommitted changes), the date, the machine, and the load average
before the run (numbers from a loaded machine mislead; a multithreaded peer suffers more).
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Above this 1-minute load average a run is flagged as taken on a busy machine.
IDLE_LOAD = 1.0


def commit() -> str:
    """Short commit hash of the checkout, ``+dirty`` when tracked files other than the
    benchmark results differ from it."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            # the results files themselves change with every run: not part of the code
            ["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
             ":!benchmarks/results", ":!benchmarks/RESULTS.md"], cwd=ROOT,
            capture_output=True, text=True, check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def header_lines(command: str | None = None) -> list[str]:
    """Markdown bullet lines: date, commit, machine, load average before the run, command."""
    load = os.getloadavg()
    busy = "" if load[0] < IDLE_LOAD else f" — BUSY (>= {IDLE_LOAD}): times are unreliable"
    cmd = command if command is not None else "python " + " ".join(sys.argv)
    return [
        f"- date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}",
        f"- commit: `{commit()}`",
        f"- machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        f"- load average before the run: {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} "
        f"(1 / 5 / 15 min){busy}",
        f"- command: `{cmd}`",
    ]
