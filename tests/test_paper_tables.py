"""The paper's feature-model SPG tables (4-2, 4-4, 4-6) recomputed from its input tables.

Expected values are the paper's printed numbers, read from the data files that hold the print
(and checked against the paper's text when it is available), and the rows that differ are
derived here from the input data by brute force, independently of the library.
"""

from __future__ import annotations

import json
import re
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.cli.paper import assemble
from mks_sim.errors import MksError
from mks_sim.paper.tables import InputTable, PrintedSPG, report, reproduce

PAPER = Path("/work/shared/reference/mks-paper.md")
THRESHOLD = {"table_4_2": 0.1}


@pytest.fixture(scope="module")
def rep():
    return report()


def data_neighbours(source: InputTable, threshold: float) -> dict[int, list[int]]:
    """Brute force: k-vector = the model rows' non-"*" columns; every other row within threshold."""
    key = ~source.dont_care[0]
    pts = source.rows[:, key]
    out = {}
    for i in range(len(pts)):
        d = np.sqrt(((pts - pts[i]) ** 2).sum(axis=1))
        out[i] = [j for j in range(len(pts)) if j != i and d[j] <= threshold]
    return out


@pytest.mark.parametrize("name", ["table_4_2", "table_4_4", "table_4_6"])
def test_rows_agree_with_print_exactly_where_the_data_do(rep, name):
    printed = PrintedSPG.load(name)
    source = InputTable.load(printed.input)
    implied = data_neighbours(source, printed.threshold)
    contradicted = [i for i in implied if implied[i] != printed.printed[i]]
    got = rep[1][name]
    assert got["differs"] == contradicted
    for i, nb in printed.printed.items():
        if i not in contradicted:
            assert got["neighbors"][str(i)] == nb  # the paper's number, reproduced
        else:
            assert got["neighbors"][str(i)] == implied[i]  # the data's answer, not the print's
        assert got["paper"][str(i)] == nb


def test_table_4_2_differences_are_the_radius_misprints(rep):
    t = rep[1]["table_4_2"]
    assert t["differs"] == [1, 2, 3, 8, 9, 10, 11]
    assert t["neighbors"]["1"] == [2, 3, 10]  # object 10 has radius 0 like 1, 2, 3
    assert t["neighbors"]["8"] == [9, 11]  # 11 has radius 0.5, 10 has 0
    assert t["neighbors"]["0"] == [5] and t["neighbors"]["5"] == [0]
    assert "+10" in t["explanations"]["1"] and "radius 0" in t["explanations"]["1"]
    assert (
        "-10" in t["explanations"]["8"] and "distance 0.5 > threshold 0.1" in t["explanations"]["8"]
    )
    assert "row 8:" in rep[0] and "<- differs" in rep[0]


def test_nut_and_curvature_tables_reproduced_with_admissible_thresholds():
    nut = reproduce("table_4_4")
    assert nut.differs == () and nut.interval == (0.0, 1.0)
    curv = reproduce("table_4_6")
    assert curv.differs == () and curv.interval == (0.0, 2.0)
    assert curv.key_fields == ("curvature",)
    # Reading "don't care" as 0 and using every field reproduces neither table.
    for c in (nut, curv):
        assert c.interval_dont_care_zero[0] >= c.interval_dont_care_zero[1]
        lo, hi = c.interval
        assert lo <= c.printed.threshold < hi
    circles = reproduce("table_4_2")
    assert circles.interval[0] >= circles.interval[1]  # no threshold gives the printed 4-2


def test_feature_matchers_find_the_papers_matches(rep):
    assert rep[1]["table_4_2"]["matches"] == {"C2": [5]}
    assert rep[1]["table_4_4"]["matches"] == {"nut": [8]}
    assert rep[1]["table_4_6"]["matches"] == {
        "planar": [7, 8, 9, 10, 11],
        "curved": [2, 3, 4, 5, 6],
    }


def test_json_shape(rep):
    for key in ("table_4_2", "table_4_4", "table_4_6"):
        t = rep[1][key]
        assert list(t["neighbors"]) == [str(i) for i in range(12)]
        assert all(v == sorted(v) for v in t["neighbors"].values())
        assert all(isinstance(i, int) for i in t["differs"])
    json.dumps(rep[1])


def _paper_block(text: str, start: str, end: str) -> list[list[str]]:
    block = text[text.index(start) : text.index(end)]
    rows = []
    for line in block.splitlines():
        m = re.match(r"^\s*(\d+)\t(.*)$", line)
        if m:
            rows.append([m.group(1), m.group(2)])
    return rows


@pytest.mark.skipif(not PAPER.exists(), reason="paper text not available")
def test_data_files_hold_the_papers_print():
    text = PAPER.read_text()
    for table, start, end in [
        ("table_4_1", "Table 4-1 gives", "**Table 4-1:**"),
        ("table_4_3", "Table 4-3 gives", "**Table 4-3:**"),
        ("table_4_5", "<u>Point #</u>\t( <u>x-location</u>", "**Table 4-5:**"),
    ]:
        src = InputTable.load(table)
        rows = _paper_block(text, start, end)
        assert len(rows) == len(src.rows)
        for (num, rest), ours, dc in zip(rows, src.rows, src.dont_care, strict=True):
            vals = re.findall(r"\"don't care\"|[-+]?\d+(?:\.\d+)?", rest)
            got = ["*" if v.startswith('"') else float(v) for v in vals][: len(ours)]
            want = ["*" if d else float(v) for v, d in zip(ours, dc, strict=True)]
            assert got == want, (table, num)
    for table, start, end in [
        ("table_4_2", "<u>Object #</u>\t<u>Neighbors</u>", "**Table 4-2:**"),
        ("table_4_4", "Table 4-4 gives", "**Table 4-4:**"),
        ("table_4_6", "<u>Point #</u>\t<u>Neighbors</u>", "**Table 4-6:**"),
    ]:
        printed = PrintedSPG.load(table).printed
        rows = _paper_block(text, start, end)
        assert len(rows) == 12
        for num, rest in rows:
            nb = sorted(int(x) for x in re.findall(r"\d+", rest.split("\t")[0]))
            assert printed[int(num)] == nb, (table, num)


def test_cli_assembles_sections(monkeypatch, capsys):
    fake = types.ModuleType("fake_section")
    fake.report = lambda: ("FAKE", {"fake_key": 1})  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "fake_section", fake)
    text, data = assemble(("mks_sim.paper.tables", "fake_section"))
    assert text.endswith("FAKE") and data["fake_key"] == 1 and "table_4_2" in data
    with pytest.raises(MksError, match="repeats JSON key"):
        assemble(("fake_section", "fake_section"))
    # only our section: the others' sections are tested in their rooms
    assert main(["paper", "--json", "--section", "mks_sim.paper.tables"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"table_4_2", "table_4_4", "table_4_6"}
    assert main(["paper", "--section", "mks_sim.paper.tables"]) == 0
    assert "Table 4-6" in capsys.readouterr().out
