"""`mks-sim localize`: JSON keys and values against the simulator's ground truth; bad arguments."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mks_sim.cli import main
from mks_sim.cli.localize import check_arguments
from mks_sim.errors import SpecError


@pytest.mark.slow
def test_json_has_the_documented_keys_and_values(capsys: pytest.CaptureFixture[str]) -> None:
    from mks_sim.sim import truth
    from mks_sim.sim.world import build_world

    rc = main(
        ["localize", "--scene", "scene2", "--object", "cube", "--seed", "6", "--fail",
         "range_finder", "--json"]
    )  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert rc == 0
    for key in ("object", "found", "matrix", "truth", "error", "provenance", "time_s"):
        assert key in out, key
    assert out["object"] == "cube" and out["found"] is True
    assert out["provenance"]["Range_Points"] == "Stereo_Points"
    M, T = np.array(out["matrix"]), np.array(out["truth"])
    assert M.shape == T.shape == (4, 4)
    np.testing.assert_allclose(M[3], [0, 0, 0, 1])
    # the truth is the simulator's body pose for that seed (independent rebuild)
    world = build_world("scene2", seed=6)
    np.testing.assert_allclose(T, truth.object_to_world(world, "cube"), atol=1e-5)
    # the reported error is the distance between the two matrices (modulo cube symmetry)
    assert out["error"]["position_mm"] == pytest.approx(
        1000 * np.linalg.norm(M[:3, 3] - T[:3, 3]), abs=0.01
    )
    assert 0 <= out["error"]["position_mm"] < 3.5
    # within the success criterion (5 mm / 5 deg): this seed's stereo estimate moved from 1.5
    # to 4.7 deg when the support-face starts grew (a near-equal pose 3 deg away now ranks
    # first by 65 points of net support; the only seed of 136 compared that got worse by
    # more than a degree); the accuracy is the benchmark's to report
    assert 0 <= out["error"]["rotation_deg"] < 5.0
    assert out["time_s"] > 0


@pytest.mark.slow
def test_text_output_names_estimate_truth_and_error(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["localize", "--object", "sphere", "--seed", "2"])
    text = capsys.readouterr().out
    assert rc == 0
    for word in ("estimate", "ground truth", "error: position", "Range_Points <- primary"):
        assert word in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--scene", "part", "--object", "cube"], r"not in scene 'part'.*--scene scene2"),
        (["--scene", "scene2", "--object", "part"], r"not in scene 'scene2'.*--scene part"),
        (["--object", "cube", "--fail", "laser"], r"unknown device.*'laser'.*range_finder"),
    ],
)
def test_bad_arguments_give_clear_errors(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["localize", *argv]) == 2
    err = capsys.readouterr().err
    assert "mks-sim localize: error:" in err
    import re

    assert re.search(message, err), err


def test_check_arguments_defaults_the_scene() -> None:
    assert check_arguments(None, "part", ()) == "part"
    assert check_arguments(None, "sphere", ["range_finder"]) == "scene2"
    with pytest.raises(SpecError, match="valid device names"):
        check_arguments("scene2", "cube", ["stereo_middle"])


def test_unknown_object_or_scene_is_rejected(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["localize", "--object", "pyramid"]) == 2
    assert "known objects: ['cube', 'part', 'sphere']" in capsys.readouterr().err
    assert main(["localize", "--object", "cube", "--scene", "nowhere"]) == 2
    assert "unknown scene 'nowhere'" in capsys.readouterr().err
