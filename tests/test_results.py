"""benchmarks/RESULTS.md is what the benchmark scripts last wrote, with provenance (issue 15)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _collect() -> ModuleType:
    spec = importlib.util.spec_from_file_location("collect_results", BENCH / "collect_results.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("collect_results", mod)
    spec.loader.exec_module(mod)
    return mod


def _bench_bin() -> ModuleType:
    """``benchmarks/bin.py`` as a module (its own imports, ``_provenance``, from there)."""
    sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location("bench_bin", BENCH / "bin.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_results_md_matches_the_sections_and_every_section_has_provenance() -> None:
    cr = _collect()
    parts = cr.sections()
    assert {"spg", "localize", "localize_sim"} <= set(parts)
    assert cr.problems(parts, (BENCH / "RESULTS.md").read_text()) == []


def test_check_reports_a_stale_page_and_a_section_without_provenance() -> None:
    cr = _collect()
    parts = dict(cr.sections())
    page = cr.assemble(parts)
    parts["spg"] = parts["spg"] + "\n\n| an edited row |"
    found = cr.problems(parts, page)
    assert any("differs" in f for f in found)
    parts = {"x": "# x\n\n| a | b |"}
    found = cr.problems(parts, cr.assemble(parts))
    assert any("commit" in f for f in found) and any("load average" in f for f in found)


def test_bin_clearing_counts_a_bin_that_raised_as_nothing_picked() -> None:
    """A bin whose clear_bin run raised keeps its parts in the denominator (it was dropped,
    which lifted 11 picked of 24 present to '11 / 18')."""
    mod = _bench_bin()
    ok = {"seed": 1, "picked": 3, "present": 6, "stopped": "empty", "picks": []}
    raised = {"seed": 2, "present": 6, "error": "FatalError: out of memory", "trace": ""}
    rows = "\n".join(mod.clearing_rows([ok, raised]))
    assert "| **parts picked** | 3 / 12 | 25.0 % |" in rows
    assert "raised: FatalError: out of memory" in rows


def test_bin_clearing_counts_the_parts_picked_from_the_table() -> None:
    """Picks from the table around the bin count among the parts picked and on a row of
    their own; a bin whose table was searched says how that search ended."""
    mod = _bench_bin()
    pick = {"success": True, "time_s": 9.0, "perception_s": 1.0, "views": 1}
    recs = [
        {"seed": 1, "picked": 2, "present": 2, "stopped": "nothing found",
         "table_stopped": "nothing found",
         "picks": [{**pick, "region": "bin"}, {**pick, "region": "table"}]},
        {"seed": 2, "picked": 1, "present": 2, "stopped": "nothing found",
         "table_stopped": None, "picks": [{**pick, "region": "bin"}]},
    ]  # fmt: skip
    rows = "\n".join(mod.clearing_rows(recs))
    assert "| **parts picked** | 3 / 4 | 75.0 % |" in rows
    assert "| of which picked from the table around the bin | 1 |" in rows
    assert "| then the table searched, stopped: nothing found | 1 | |" in rows
    assert "| bins stopped: nothing found | 2 | |" in rows


def test_bin_records_are_kept_as_json_lines(tmp_path) -> None:
    """``--records``: every bin's record, with its mode and task, one JSON line each,
    appended across the sweep's sections; the rows are built from the same records."""
    import json

    mod = _bench_bin()
    path = tmp_path / "sub" / "records.jsonl"
    a = [{"seed": 1, "picked": 2}, {"seed": 2, "picked": 0}]
    assert mod._keep(path, "healthy", "clear", a) is a
    mod._keep(path, "range finder failed", "localize", [{"seed": 1, "found": 3}])
    assert mod._keep(None, "healthy", "clear", a) is a
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    assert lines == [
        {"mode": "healthy", "task": "clear", "seed": 1, "picked": 2},
        {"mode": "healthy", "task": "clear", "seed": 2, "picked": 0},
        {"mode": "range finder failed", "task": "localize", "seed": 1, "found": 3},
    ]
