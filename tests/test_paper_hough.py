"""The paper's Hough examples (sections 2.2, 4.2) against the numbers printed in the paper.

The printed numbers are typed here again from the paper (not imported from the code under test).
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from mks_sim.geometry.transforms import cube_rotations, from_row_convention, pose_error
from mks_sim.models.database import ModelDatabase
from mks_sim.paper import hough_cases

# Figure 2-3 as printed (blank = 0), rows 1..6.
PAPER_FIG_2_3 = [
    [0, 0, 0, 0, 0, 0],
    [0, 0, 0, 0, 0, 0],
    [0, 0, 2, 3, 1, 0],
    [1, 4, 2, 0, 0, 0],
    [0, 2, 2, 0, 0, 0],
    [0, 0, 1, 0, 0, 0],
]
PAPER_CUBE_RADII = [4.09, 3.43, 3.38, 3.28, 2.54, 2.40, 2.33, 0.65]
PAPER_TABLE_4_7 = [
    [4, -1, 1],
    [4, 1, 1],
    [6, 1, 1],
    [6, -1, 1],
    [4, 1, -1],
    [4, 1, -1],
    [6, 1, -1],
    [6, -1, -1],
]
PAPER_RENAULT_RADII = [29.900755, 18.041958, 13.079391, 3.379884]
PAPER_RENAULT_DETECTED = [
    [-21.000000, -7.246000, 2.706000],
    [-17.600000, -3.183000, 16.096001],
    [-17.200001, 3.755000, 16.305000],
    [-18.000000, 10.844000, 25.872999],
]
PAPER_RENAULT_MATRIX = [
    [0.000000, 1.000000, -0.000000, 0.000000],
    [-1.000000, -0.000002, 0.000002, 0.000000],
    [-0.000000, -0.000000, 1.000001, 0.000000],
    [-2.000000, 1.000031, 0.999962, 1.000000],
]


@pytest.fixture(scope="module")
def rep() -> tuple[str, dict]:
    return hough_cases.report()


def test_printed_inputs_kept_as_printed() -> None:
    assert [list(r) for r in hough_cases.FIG_2_3_PRINTED] == PAPER_FIG_2_3
    assert [list(r) for r in hough_cases.TABLE_4_7] == PAPER_TABLE_4_7
    assert list(hough_cases.CUBE_PRINTED_RADII) == PAPER_CUBE_RADII
    assert [list(r) for r in hough_cases.RENAULT_MATRIX] == PAPER_RENAULT_MATRIX


def test_figure_2_3_against_print(rep) -> None:
    f = hough_cases.figure_2_3()
    data = rep[1]["figure_2_3"]
    assert data["paper"] == PAPER_FIG_2_3
    # The algorithm of section 2.2 on the printed inputs: 5 x 4 = 20 votes, one (from the edge
    # at row 4, column 1, displaced by (-1, 0)) falls off the array; the print sums to 18.
    assert f.votes_cast == 20 and f.votes_off == 1
    assert int(np.sum(data["accumulator"])) == 19
    assert int(np.sum(PAPER_FIG_2_3)) == 18
    assert data["matches"] is False
    # Cell (4, 2) is printed 4, but only 3 of its 4 neighbours are edges.
    assert (4, 2, 4, 3) in f.unreachable
    # Every axis convention gives our array: the displacement set is symmetric.
    acc = np.array(data["accumulator"])
    for flip in (lambda a: a, np.transpose):
        edges = {(r, c) for r, c in [(3, 3), (3, 5), (4, 1), (4, 3), (5, 2)]}
        brute = np.zeros((6, 6), int)
        for (r, c), (dr, dc) in itertools.product(edges, [(-1, 0), (0, -1), (1, 0), (0, 1)]):
            if 1 <= r + dr <= 6 and 1 <= c + dc <= 6:
                brute[r + dr - 1, c + dc - 1] += 1
        np.testing.assert_array_equal(flip(acc), flip(brute))


def test_cube_radii_against_print() -> None:
    c = hough_cases.cube_case()
    cube = np.array(list(itertools.product([-1, 1], repeat=3)), float)
    radii = np.sort(np.linalg.norm(cube - [1.5, 1.3, 1.25], axis=1))[::-1]
    np.testing.assert_allclose(c.radii, radii)
    # Not equal to the printed precision (0.005): the largest gap is 2.40 vs 2.367.
    assert np.abs(radii - PAPER_CUBE_RADII).max() == pytest.approx(c.radii_max_diff)
    assert 0.03 < c.radii_max_diff < 0.035
    # A reference point exists that reproduces the print to its precision.
    fitted = np.sort(np.linalg.norm(cube - c.best_reference, axis=1))[::-1]
    assert np.abs(fitted - PAPER_CUBE_RADII).max() < 0.005


def test_cube_detection_against_print(rep) -> None:
    c = hough_cases.cube_case()
    data = rep[1]["cube"]
    # Table 4-7 has 7 distinct vertexes: the repeated one counts once.
    assert len(c.result.unique_points) == 7
    assert c.result.top_votes == 7
    # The paper's pick: detected reference point (6.5, 1.3, 1.25), identity, +5 along x.
    want = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [5, 0, 0, 1]], float)
    hits = [
        h
        for h in data["hypotheses"]
        if np.allclose(h["reference_point"], [6.5, 1.3, 1.25], atol=1e-6)
    ]
    assert len(hits) == 1
    np.testing.assert_allclose(hits[0]["matrix_row_convention"], want, atol=1e-9)
    assert hits[0]["votes"] == 7
    # Every reported top hypothesis is the paper's pose up to a rotation of the cube.
    T_paper = from_row_convention(want)
    for h in data["hypotheses"]:
        T = from_row_convention(np.array(h["matrix_row_convention"]))
        pos, rot = pose_error(T, T_paper, cube_rotations())
        assert pos < 1e-9 and rot < 1e-4
    assert data["maxima"] == 48 and data["proper_maxima"] == 24
    assert data["paper_maxima"] == 18
    assert len(data["hypotheses"]) == 24


def test_renault_against_print(rep) -> None:
    r = hough_cases.renault_case()
    data = rep[1]["renault"]
    # The paper's own consistency: preimages under the printed matrix, radii from the printed
    # reference point.
    M = np.array(PAPER_RENAULT_MATRIX)
    det = np.array(PAPER_RENAULT_DETECTED)
    model = (det - M[3, :3]) @ np.linalg.inv(M[:3, :3])
    radii = np.linalg.norm(model - [10.344000, 19.333334, 25.122999], axis=1)
    np.testing.assert_allclose(radii, PAPER_RENAULT_RADII, atol=1e-5)
    np.testing.assert_allclose(r.radii, radii)
    # Detected reference point = the printed reference point mapped by the printed matrix.
    mapped = (np.array([10.344000, 19.333334, 25.122999, 1.0]) @ M)[:3]
    np.testing.assert_allclose(data["reference_point"], mapped, atol=1e-4)
    # Each detected control point paired with its printed radius, in order.
    assert [d for d, _ in data["correspondences"]] == [0, 1, 2, 3]
    np.testing.assert_allclose(
        [rad for _, rad in data["correspondences"]], PAPER_RENAULT_RADII, atol=1e-5
    )
    np.testing.assert_allclose(data["matrix_row_convention"], M, atol=1e-4)
    # Four non-coplanar centres: a unique maximum.
    assert len(r.result.top_maxima) == 1 and r.result.top_votes == 4
    assert len(r.triple_candidates) == 2
    misses = sorted(m for _, m in r.triple_candidates)
    assert misses[0] < 1e-4 and misses[1] > 1.0


def test_model_files_match_print() -> None:
    db = ModelDatabase.from_dir()
    cube = db.get("paper_cube")
    np.testing.assert_allclose(cube.reference, [1.5, 1.3, 1.25])
    assert cube.symmetries.shape == (24, 3, 3)
    ren = db.get("paper_renault")
    np.testing.assert_allclose(ren.reference, [10.344000, 19.333334, 25.122999])
    np.testing.assert_allclose(ren.radii, PAPER_RENAULT_RADII, atol=2e-5)
    hyps = ren.detect(PAPER_RENAULT_DETECTED)
    np.testing.assert_allclose(hyps[0].matrix_row_convention, PAPER_RENAULT_MATRIX, atol=1e-4)


def test_report_text_and_json(rep) -> None:
    text, data = rep
    assert set(data) == {"figure_2_3", "cube", "renault"}
    json.dumps(data)  # serialisable
    assert "matches: False" in text and "paper 18" in text
    assert "largest entry difference" in text
