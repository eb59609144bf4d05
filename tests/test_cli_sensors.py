"""`mks-sim sensors`: listing, JSON, and --check of good and malformed files."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mks_sim.cli import main

ASSETS = Path(__file__).parent / "assets" / "sensors"
GOOD = ASSETS / "good"
BAD = ASSETS / "bad"
SENSORS = Path(__file__).parents[1] / "sensors"


def test_lists_sensors_with_inputs_program_output_and_alternates(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["sensors", "--dir", str(GOOD)]) == 0
    out = capsys.readouterr().out
    block = out[out.index("Range_Points  (") :].split("\n\n")[0]
    assert "inputs:     ranger" in block
    assert "program:    passthrough" in block
    assert "[0]  x  -2:2    m  reject" in block
    assert "[2]  z  -0.5:2  m  flag" in block
    assert "acceptance: min_rows {min = 2}" in block
    assert block.index("1. Stereo_Points: stereo_l, stereo_r -> concat") < block.index(
        "2. Touch_Points: touch -> passthrough"
    )
    assert "devices: cam (camera), cam_lo (camera), ranger (range_finder)" in out
    for name in ("Camera_Points", "Cameras", "Range_XY", "Heights"):
        assert f"\n{name}  (" in f"\n{out}"


def test_lists_selected_sensors_only(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors", "--dir", str(GOOD), "Heights"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("Heights  (") and "Range_XY" not in out


def test_unknown_sensor_name_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors", "--dir", str(GOOD), "Nope"]) == 2
    assert "unknown logical sensor 'Nope'" in capsys.readouterr().err


def test_json_listing(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors", "--dir", str(GOOD), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    sensors = {s["name"]: s for s in doc["sensors"]}
    rp = sensors["Range_Points"]
    assert rp["inputs"] == ["ranger"] and rp["program"] == "passthrough"
    assert [f["name"] for f in rp["output"]] == ["x", "y", "z"]
    assert rp["output"][2] == {
        "name": "z",
        "low": -0.5,
        "high": 2.0,
        "unit": "m",
        "policy": "flag",
        "resolution": None,
        "coercion": "rescale",
    }
    assert [a["name"] for a in rp["alternates"]] == ["Stereo_Points", "Touch_Points"]
    assert rp["acceptance"] == {"test": "min_rows", "params": {"min": 2}}
    assert sensors["Range_XY"]["params"] == {"fields": ["x", "y"]}
    assert {d["name"] for d in doc["devices"]} >= {"cam", "ranger"}
    assert "passthrough" in doc["programs"]


def test_installed_listing_shows_the_stable_devices(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors"]) == 0
    out = capsys.readouterr().out
    assert "range_finder (range_finder)" in out and "touch_finger_3 (touch)" in out


def test_check_good_file_against_installed_devices(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "my_sensor.toml"
    path.write_text(
        "[[sensor]]\n"
        'name = "My_Range_Copy"\n'
        'inputs = ["range_finder"]\n'
        'program = "passthrough"\n'
        'output = [{ name = "x", low = -2.0, high = 2.0, unit = "m" }]\n'
    )
    assert main(["sensors", "--check", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"ok: {path}: 1 sensor(s) (My_Range_Copy)")


def test_check_good_file_in_its_own_folder(capsys: pytest.CaptureFixture[str]) -> None:
    # The file is part of the folder: it replaces itself, it is not a duplicate.
    assert main(["sensors", "--dir", str(GOOD), "--check", str(GOOD / "sensors.toml")]) == 0
    assert capsys.readouterr().out.startswith("ok: ")


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("bad_low.toml", "sensor 'Range_Points': field 'output[2].low': expected a number, got 'abc'"),
        ("unknown_program.toml", "field 'program': expected one of the programs"),
        ("bad_toml.toml", "line 4, column 1: malformed TOML"),
    ],
)
def test_check_bad_file_exits_2_with_the_error(
    name: str, match: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["sensors", "--dir", str(GOOD), "--check", str(BAD / name)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mks-sim sensors: error: ")
    assert f"{BAD / name}: " in err and match in err


def test_check_unknown_input_against_installed_devices(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 'cam' is a test device, not an installed one: the installed set must reject it.
    path = tmp_path / "cam_sensor.toml"
    path.write_text(
        "[[sensor]]\n"
        'name = "Test_Cam_Points"\n'
        'inputs = ["cam"]\n'
        'program = "passthrough"\n'
        'output = [{ name = "x", low = 0, high = 1023, unit = "px" }]\n'
    )
    assert main(["sensors", "--check", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"{path}: sensor 'Test_Cam_Points': field 'inputs[0]': expected a logical" in err
    assert "got 'cam'" in err
    assert "'range_finder'" in err  # the valid options are listed


def test_check_json_reports_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors", "--dir", str(GOOD), "--json", "--check", str(BAD / "cycle.toml")]) == 2
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is False and "cycle of logical sensors" in doc["error"]
    assert (
        main(["sensors", "--dir", str(GOOD), "--json", "--check", str(GOOD / "sensors.toml")]) == 0
    )
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is True and "Range_Points" in doc["sensors"]


def test_check_missing_file(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sensors", "--check", str(ASSETS / "nope.toml")]) == 2
    assert "sensor file not found" in capsys.readouterr().err


def test_model_naming_an_unknown_sensor_is_an_error(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.delenv("MKS_SIM_MODELS", raising=False)
    (tmp_path / "bad.toml").write_text(
        '[[model]]\nname = "bad_c"\nkind = "feature"\nsensor = "No_Such_Sensor"\n'
        "reference = [1, 2, 3]\nthreshold = 0.1\n"
    )
    rc = main(["sensors", "--check", str(SENSORS / "touch.toml"), "--models", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"{tmp_path / 'bad.toml'}: model 'bad_c': field 'sensor': expected one of the " in err
    assert "got 'No_Such_Sensor'" in err and "'Circle_Detector'" in err
    # the installed models all name existing sensors (10 references today, at least 8)
    assert main(["sensors", "--check", str(SENSORS / "touch.toml")]) == 0
    out = capsys.readouterr().out
    n = int(out.split("; ")[-1].split()[0])
    assert n >= 8


@pytest.mark.parametrize("path", ["/dev/zero", "FOLDER"])
def test_check_a_device_or_folder_is_bad_input_not_a_hang(path, tmp_path, capsys) -> None:
    target = str(tmp_path) if path == "FOLDER" else path
    assert main(["sensors", "--check", target]) == 2
    err = capsys.readouterr().err
    assert f"{target}: expected a sensor file (TOML), got a" in err


def test_programs_lists_the_params_each_program_accepts(capsys) -> None:
    assert main(["sensors", "--programs", "--json"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema["program vertex_detector"]["m"] == {"type": "int", "default": 12, "low": 1}
    assert schema["acceptance min_rows"]["min"]["required"] is True
    assert schema["program concat"] == {}  # takes no params: any key is an error
    from mks_sim.sensing import ACCEPTANCE, PROGRAMS

    for kind, table in (("program", PROGRAMS), ("acceptance", ACCEPTANCE)):
        for name in table.names():  # every built-in declares its params (tests add others)
            if table.entry_point(name).startswith("mks_sim.sensing.programs."):
                assert schema[f"{kind} {name}"] is not None, name
    assert main(["sensors", "--programs"]) == 0
    text = capsys.readouterr().out
    assert "program range_points:" in text and "voxel_m: float, default 0.0, >= 0" in text
