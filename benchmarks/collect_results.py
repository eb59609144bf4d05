"""Assemble benchmarks/RESULTS.md from the per-benchmark files in benchmarks/results/.

Each benchmark script writes its own ``results/<name>.md`` (machine, date, command, table);
this script only concatenates them in a fixed order, so RESULTS.md always shows the last run
of every benchmark.  Usage: ``python benchmarks/collect_results.py``.
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
ORDER = ("spg", "localize", "localize_sim", "grasp", "freeform")
HEADER = """# Benchmark results

Every number here came from a run of the named script on this project's machines (x86_64,
2 cores, 24 GiB, no GPU), usually while other jobs shared the cores: read ratios within one
run, not absolute times across runs. Peers (scikit-learn, Open3D, OpenCV's ppf_match_3d) come
from the optional `bench` extra and ran in the same run on identical inputs (OpenCV's contrib
build in a subprocess: it conflicts with opencv-python-headless, see its section).
Each section is `benchmarks/results/<name>.md`, rewritten by its script.
"""


def main() -> None:
    files = {p.stem: p for p in (HERE / "results").glob("*.md")}
    names = [n for n in ORDER if n in files] + sorted(set(files) - set(ORDER))
    parts = [HEADER]
    for name in names:
        text = files[name].read_text().strip()
        # Demote the section's own headings one level under this page's title.
        text = "\n".join("#" + line if line.startswith("#") else line for line in text.splitlines())
        parts.append(text)
    (HERE / "RESULTS.md").write_text("\n\n".join(parts) + "\n")


if __name__ == "__main__":
    main()
