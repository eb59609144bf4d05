"""Assemble benchmarks/RESULTS.md from the per-benchmark files in benchmarks/results/.

Each benchmark script writes its own ``results/<name>.md`` (provenance lines from
``benchmarks/_provenance.py``: date, commit, machine, load average, command; then its tables);
this script only concatenates them in a fixed order, so RESULTS.md always shows the last run
of every benchmark.

Usage:
    python benchmarks/collect_results.py           # rewrite RESULTS.md
    python benchmarks/collect_results.py --check   # exit 1 when RESULTS.md is stale or a
                                                   # section lacks its commit / load lines
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = (
    "spg", "localize", "localize_sim", "localize_ab", "freeform", "env", "grasp", "objects",
    "objects_localization", "bin", "bin_localization", "backends", "grasp_synthesis",
)
HEADER = """# Benchmark results

Every number here came from a run of the named script on this project's machines (x86_64,
2 cores, 24 GiB, no GPU). Each section states the commit it ran at and the load average before
the run; runs are meant to be taken alone on an idle machine (load < 1), and a section taken on
a busy machine says so. Peers (scikit-learn, Open3D, OpenCV's ppf_match_3d, Gymnasium-Robotics,
dm_control) come from the optional `bench` extra and ran in the same run on identical inputs.
Each section is `benchmarks/results/<name>.md`, rewritten by its script; this page is assembled
by `benchmarks/collect_results.py` (`--check` fails when it is stale).
"""
_COMMIT = re.compile(r"^- commit: `[0-9a-f]{7,}(\+dirty)?`", re.M)
_LOAD = re.compile(r"^- load average before the run: \d", re.M)


def sections() -> dict[str, str]:
    """Section name -> its results file's text, in page order."""
    files = {p.stem: p for p in (HERE / "results").glob("*.md")}
    names = [n for n in ORDER if n in files] + sorted(set(files) - set(ORDER))
    return {name: files[name].read_text().strip() for name in names}


def assemble(parts: dict[str, str]) -> str:
    """The RESULTS.md text for ``parts`` (each section's headings demoted one level)."""
    out = [HEADER]
    for text in parts.values():
        out.append("\n".join("#" + ln if ln.startswith("#") else ln for ln in text.splitlines()))
    return "\n\n".join(out) + "\n"


def problems(parts: dict[str, str], results_md: str | None) -> list[str]:
    """What --check reports: a stale RESULTS.md, sections with no commit or load line."""
    found = []
    if results_md != assemble(parts):
        found.append("RESULTS.md differs from benchmarks/results/*.md: run collect_results.py")
    for name, text in parts.items():
        if not _COMMIT.search(text):
            found.append(f"results/{name}.md: no '- commit: `<hash>`' line")
        if not _LOAD.search(text):
            found.append(f"results/{name}.md: no '- load average before the run: ...' line")
    return found


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="verify instead of writing")
    args = ap.parse_args(argv)
    parts = sections()
    target = HERE / "RESULTS.md"
    if args.check:
        found = problems(parts, target.read_text() if target.exists() else None)
        for line in found:
            print(f"collect_results --check: {line}", file=sys.stderr)
        return 1 if found else 0
    target.write_text(assemble(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
