"""Logical sensors with fake devices: file format, load-time checks, alternates, caching."""

from __future__ import annotations

import logging
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mks_sim.errors import DataError, DeviceFailure, NotFound, SensorFailure, SpecError
from mks_sim.fields import Field, OutputVector
from mks_sim.sensing import (
    PROGRAMS,
    AlternateSpec,
    SensorGraph,
    SensorSpec,
    get_program,
    load_file,
    program_names,
    register_acceptance,
    register_program,
)

ASSETS = Path(__file__).parent / "assets" / "sensors"
GOOD = ASSETS / "good"
BAD = ASSETS / "bad"
DEVICES = GOOD / "devices.toml"
STABLE_DEVICES = {
    "overhead_camera",
    "stereo_left",
    "stereo_right",
    "depth_camera",
    "range_finder",
    "touch_finger_1",
    "touch_finger_2",
    "touch_finger_3",
}


class FakeDevice:
    """A device returning a fixed reading (or failing), counting its reads."""

    def __init__(self, name: str, reading: Any = None, *, fail: bool = False) -> None:
        self.name = name
        self.reading = reading
        self.fail = fail
        self.reads = 0

    def read(self) -> Any:
        self.reads += 1
        if self.fail:
            raise DeviceFailure(self.name, "lens cap on")
        return self.reading


RANGE_ROWS = np.array([[0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [-0.1, -0.2, 1.9]])
STEREO_L = np.array([[1.0, 1.0, 1.0]])
STEREO_R = np.array([[1.5, 1.5, 1.5]])
TOUCH = np.array([[0.0, 0.0, 0.01]])


def devices(**overrides: Any) -> dict[str, FakeDevice]:
    devs = {
        "cam": FakeDevice("cam", np.array([[0, 0, 10], [1023, 512, 300]])),
        "cam_lo": FakeDevice("cam_lo", np.array([[7, 8, 9]])),
        "ranger": FakeDevice("ranger", RANGE_ROWS),
        "stereo_l": FakeDevice("stereo_l", STEREO_L),
        "stereo_r": FakeDevice("stereo_r", STEREO_R),
        "touch": FakeDevice("touch", TOUCH),
    }
    for name, value in overrides.items():
        if value is None:
            del devs[name]
        elif isinstance(value, FakeDevice):
            devs[name] = value
        else:
            devs[name] = FakeDevice(name, value)
    return devs


@pytest.fixture(scope="module")
def graph() -> SensorGraph:
    return SensorGraph.from_dir(GOOD)


# --------------------------------------------------------------------------- loading


def test_good_files_load_into_specs(graph: SensorGraph) -> None:
    assert graph.sensor_names == (
        "Camera_Points",
        "Camera_Lo_Points",
        "Cameras",
        "Range_Points",
        "Range_XY",
        "Heights",
    )
    assert graph.device_names == {"cam", "cam_lo", "ranger", "stereo_l", "stereo_r", "touch"}
    rp = graph.sensor("Range_Points")
    assert rp.inputs == ("ranger",) and rp.program == "passthrough"
    assert rp.output.names == ("x", "y", "z")
    assert [f.policy for f in rp.output] == ["reject", "reject", "flag"]
    assert rp.output.field("x").unit == "m" and rp.output.field("z").low == -0.5
    assert [a.name for a in rp.alternates] == ["Stereo_Points", "Touch_Points"]
    assert rp.alternates[0].inputs == ("stereo_l", "stereo_r")
    assert rp.acceptance is not None and rp.acceptance.params["min"] == 2
    # Alternates without their own acceptance test inherit the sensor's.
    ways = rp.ways
    assert [w.name for w in ways] == ["primary", "Stereo_Points", "Touch_Points"]
    assert ways[1].acceptance == rp.acceptance
    assert ways[2].acceptance is not None and ways[2].acceptance.params["min"] == 1
    assert graph.sensor("Range_XY").params["fields"] == ("x", "y")
    assert rp.file == GOOD / "sensors.toml"
    with pytest.raises(TypeError):
        rp.params["new"] = 1  # type: ignore[index]


def test_installed_devices_declare_the_stable_names() -> None:
    graph = SensorGraph.from_dir()  # the installed sensors/, whatever sensor files it holds
    assert STABLE_DEVICES <= set(graph.device_names)
    for dev in graph.devices.values():
        assert dev.kind and dev.description


def test_unknown_sensor_and_missing_folder(graph: SensorGraph) -> None:
    snap = graph.snapshot(devices())
    with pytest.raises(NotFound, match=r"'ranger' is a device, not a logical sensor"):
        snap.get("ranger")
    with pytest.raises(NotFound, match="unknown device 'lidar'"):
        snap.read("lidar")
    with pytest.raises(NotFound, match=r"unknown logical sensor 'Nope'; sensors: \["):
        graph.sensor("Nope")
    with pytest.raises(NotFound, match="sensors folder not found"):
        SensorGraph.from_dir(ASSETS / "missing")
    with pytest.raises(NotFound, match="sensor file not found"):
        load_file(ASSETS / "missing.toml")


BAD_CASES = [
    ("bad_toml.toml", r"bad_toml\.toml: line 4, column 1: malformed TOML"),
    (
        "bad_low.toml",
        r"bad_low\.toml: sensor 'Range_Points': field 'output\[2\]\.low': expected a number, "
        r"got 'abc'",
    ),
    (
        "bad_policy.toml",
        r"bad_policy\.toml: sensor 'Range_Points': field 'output\[0\]\.policy': expected one of "
        r"\['reject', 'clip', 'flag'\], got 'drop'",
    ),
    (
        "missing_output.toml",
        r"missing_output\.toml: sensor 'No_Output': field 'output': expected a non-empty list.*"
        r"got nothing \(missing\)",
    ),
    (
        "unknown_key.toml",
        r"unknown_key\.toml: sensor 'Typo': expected only the keys \[.*'program'.*\], "
        r"got 'programme'",
    ),
    (
        "unknown_field_key.toml",
        r"unknown_field_key\.toml: sensor 'Typo_Field': field 'output\[0\]': expected only the "
        r"keys \[.*'high'.*\], got 'hihg'",
    ),
    (
        "unknown_input.toml",
        r"unknown_input\.toml: sensor 'Lidar_Points': field 'inputs\[0\]': expected a logical "
        r"sensor or a declared device \(devices: \['cam'.*got 'lidar'",
    ),
    (
        "unknown_program.toml",
        r"unknown_program\.toml: sensor 'Magic': field 'program': expected one of the programs "
        r"\[.*'passthrough'.*\], got 'no_such_program'",
    ),
    (
        "unknown_alternate_program.toml",
        r"sensor 'Range_Points': alternate 'Stereo_Points': field 'program': expected one of "
        r"the programs \[.*\], got 'no_such_stereo'",
    ),
    (
        "unknown_acceptance.toml",
        r"sensor 'Picky': field 'acceptance\.test': expected one of the acceptance tests "
        r"\[.*'min_rows'\], got 'looks_good'",
    ),
    ("cycle.toml", r"cycle\.toml: sensor '[AB]': inputs: cycle of logical sensors (A -> B -> A)"),
    ("alternate_cycle.toml", r"Self_Fallback -> Self_Fallback"),
    (
        "duplicate.toml",
        r"duplicate\.toml: expected distinct sensor names, got duplicate\(s\) \['Twice'\]",
    ),
    (
        "low_above_high.toml",
        r"sensor 'Upside_Down': field 'output\[0\]': expected low < high \(x\), got low=5, high=1",
    ),
    (
        "single_table.toml",
        r"single_table\.toml: field 'sensor': expected an array of tables.*\[\[sensor\]\]",
    ),
    (
        "inputs_not_list.toml",
        r"sensor 'Scalar_Inputs': field 'inputs': expected a list of device or sensor names, "
        r"got 'ranger'",
    ),
    (
        "reserved_alternate.toml",
        r"sensor 'Range_Points': field 'alternate\[0\]\.name': expected a name other than "
        r"'primary'",
    ),
    ("sensor_named_like_device.toml", r"sensor 'ranger': name: 'ranger' is already a device"),
    (
        "duplicate_field.toml",
        r"sensor 'Two_X': field 'output': expected distinct field names, got duplicate\(s\) "
        r"\['x'\]",
    ),
    (
        "missing_name.toml",
        r"missing_name\.toml: sensor\[0\]: field 'name': expected a non-empty string",
    ),
    (
        "unknown_top_level.toml",
        r"unknown_top_level\.toml: expected only the keys \['device', 'sensor'\], got 'sensors'",
    ),
]


def test_every_bad_file_has_a_case() -> None:
    assert {p.name for p in BAD.glob("*.toml")} == {name for name, _ in BAD_CASES}


@pytest.mark.parametrize(("name", "match"), BAD_CASES, ids=[c[0] for c in BAD_CASES])
def test_malformed_files_name_file_sensor_and_field(name: str, match: str) -> None:
    with pytest.raises(SpecError, match=match):
        SensorGraph.from_files([DEVICES, BAD / name])


def test_duplicate_sensor_across_files_names_both_files(tmp_path: Path) -> None:
    copy = tmp_path / "copy.toml"
    copy.write_text((GOOD / "sensors.toml").read_text())
    with pytest.raises(
        SpecError, match=r"'Camera_Points' is defined twice \(.*sensors\.toml and .*copy\.toml\)"
    ):
        SensorGraph.from_files([DEVICES, GOOD / "sensors.toml", copy])


def test_graph_from_code_specs_and_device_names() -> None:
    vec = OutputVector.of(Field("x", 0.0, 1.0))
    spec = SensorSpec("S", ("d",), "passthrough", vec)
    graph = SensorGraph([spec], devices=["d"])
    assert graph.device_names == {"d"} and "S" in graph and len(graph) == 1
    with pytest.raises(SpecError, match=r"sensor 'S': field 'inputs\[0\]': expected .* got 'd'"):
        SensorGraph([spec], devices=["e"])


# --------------------------------------------------------------------------- required()


def test_required_is_minimal(graph: SensorGraph) -> None:
    assert graph.required(["Camera_Points"]) == {"Camera_Points", "cam"}
    assert graph.required(["Range_XY"], alternates=False) == {"Range_XY", "Range_Points", "ranger"}
    assert graph.required(["Range_XY"]) == {
        "Range_XY",
        "Range_Points",
        "ranger",
        "stereo_l",
        "stereo_r",
        "touch",
    }
    assert graph.required(["Cameras"]) == {
        "Cameras",
        "Camera_Points",
        "Camera_Lo_Points",
        "cam",
        "cam_lo",
    }
    with pytest.raises(NotFound, match="unknown sensor or device 'Nope'"):
        graph.required(["Nope"])
    order = graph.order(["Range_XY", "Heights"])
    assert order.index("Range_Points") < order.index("Range_XY")
    assert set(order) == {"Range_Points", "Range_XY", "Heights"}


# --------------------------------------------------------------------------- snapshots


def test_primary_serves(graph: SensorGraph) -> None:
    snap = graph.snapshot(devices())
    stream = snap.get("Range_Points")
    assert stream.served_by == "primary" and stream.sensor == "Range_Points"
    np.testing.assert_array_equal(stream.data, RANGE_ROWS)
    assert snap.provenance == {"Range_Points": "primary"}
    assert stream.report is not None and stream.report.clean


def test_failed_device_makes_the_alternate_serve(
    graph: SensorGraph, caplog: pytest.LogCaptureFixture
) -> None:
    ranger = FakeDevice("ranger", RANGE_ROWS, fail=True)
    snap = graph.snapshot(devices(ranger=ranger))
    with caplog.at_level(logging.WARNING, logger="mks_sim.sensing"):
        stream = snap.get("Range_Points")
    assert stream.served_by == "Stereo_Points"
    np.testing.assert_array_equal(stream.data, np.vstack([STEREO_L, STEREO_R]))
    assert snap.provenance == {"Range_Points": "Stereo_Points"}
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(
        "'Range_Points': primary failed (device 'ranger' failed: lens cap on); "
        "falling back to alternate 'Stereo_Points'" in m
        for m in warnings
    )
    attempts = snap.attempts["Range_Points"]
    assert [(a.way, a.ok) for a in attempts] == [("primary", False), ("Stereo_Points", True)]


def test_missing_device_counts_as_failed(graph: SensorGraph) -> None:
    snap = graph.snapshot(devices(ranger=None, stereo_r=None))
    stream = snap.get("Range_Points")
    assert stream.served_by == "Touch_Points"
    reasons = [a.reason for a in snap.attempts["Range_Points"] if not a.ok]
    assert "device 'ranger' failed: not connected" in reasons[0]
    assert "device 'stereo_r' failed: not connected" in reasons[1]


def test_acceptance_rejection_falls_through(graph: SensorGraph) -> None:
    snap = graph.snapshot(devices(ranger=RANGE_ROWS[:1]))  # 1 row < min_rows 2
    assert snap.get("Range_Points").served_by == "Stereo_Points"
    primary = snap.attempts["Range_Points"][0]
    assert "acceptance test 'min_rows' rejected it: 1 rows, expected at least 2" in primary.reason


def test_all_ways_fail_lists_every_reason(graph: SensorGraph) -> None:
    snap = graph.snapshot(
        devices(
            ranger=FakeDevice("ranger", fail=True),
            stereo_l=FakeDevice("stereo_l", fail=True),
            touch=np.zeros((0, 3)),
        )
    )
    with pytest.raises(SensorFailure) as info:
        snap.get("Range_XY")
    msg = str(info.value)
    assert "'Range_XY'" in msg
    assert "primary: device 'ranger' failed: lens cap on" in msg
    assert "Stereo_Points: device 'stereo_l' failed: lens cap on" in msg
    assert "Touch_Points: acceptance test 'min_rows' rejected it: 0 rows" in msg
    assert snap.failures.keys() == {"Range_Points", "Range_XY"}
    assert snap.provenance == {}
    with pytest.raises(SensorFailure):  # the failure is cached, not re-run
        snap.get("Range_Points")


def test_devices_and_sensors_run_at_most_once_per_snapshot(graph: SensorGraph) -> None:
    devs = devices()
    snap = graph.snapshot(devs)
    got = snap.evaluate(["Range_XY", "Heights"])
    assert devs["ranger"].reads == 1
    assert snap.get("Range_Points") is snap.get("Range_Points")
    np.testing.assert_array_equal(got["Range_XY"].data, RANGE_ROWS[:, :2])
    np.testing.assert_array_equal(got["Heights"].data, RANGE_ROWS[:, 2:])
    assert snap.provenance == {
        "Range_Points": "primary",
        "Range_XY": "primary",
        "Heights": "primary",
    }
    # Unused devices are not read at all (paper section 4: only what the model needs).
    assert devs["cam"].reads == 0 and devs["stereo_l"].reads == 0
    assert snap.devices_read == {"ranger"}
    # A new snapshot reads again.
    graph.snapshot(devs).get("Heights")
    assert devs["ranger"].reads == 2


def test_failed_device_is_read_once(graph: SensorGraph) -> None:
    ranger = FakeDevice("ranger", fail=True)
    snap = graph.snapshot(devices(ranger=ranger))
    snap.evaluate(["Range_XY", "Heights"])
    with pytest.raises(DeviceFailure):
        snap.read("ranger")
    assert ranger.reads == 1


def test_validation_policies_inside_a_snapshot(
    graph: SensorGraph, caplog: pytest.LogCaptureFixture
) -> None:
    rows = np.array(
        [
            [0.1, 0.2, 0.3],
            [5.0, 0.2, 0.3],  # x out of range: reject -> dropped
            [0.1, np.nan, 0.3],  # y NaN: reject -> dropped
            [0.1, 0.2, 3.0],  # z out of range: flag -> kept, flagged
            [0.2, 0.2, 0.2],
        ]
    )
    snap = graph.snapshot(devices(ranger=rows))
    with caplog.at_level(logging.WARNING, logger="mks_sim.sensing"):
        stream = snap.get("Range_Points")
    np.testing.assert_array_equal(stream.data, rows[[0, 3, 4]])
    assert stream.flags is not None
    np.testing.assert_array_equal(stream.flags[:, 2], [False, True, False])
    assert stream.report is not None
    assert stream.report.dropped == 2 and stream.report.field("z").flagged == 1
    assert any("5 rows in, 3 kept, 2 dropped" in r.getMessage() for r in caplog.records)
    # The camera's intensity field clips (300 -> 255).
    cam = snap.get("Camera_Points")
    np.testing.assert_array_equal(cam.data[:, 2], [10, 255])
    assert cam.report is not None and cam.report.field("intensity").clipped == 1


def test_strict_snapshot_falls_back_on_rejected_rows(graph: SensorGraph) -> None:
    rows = np.vstack([RANGE_ROWS, [[9.0, 0.0, 0.0]]])
    snap = graph.snapshot(devices(ranger=rows), strict=True)
    assert snap.get("Range_Points").served_by == "Stereo_Points"
    assert "strict validation failed" in snap.attempts["Range_Points"][0].reason


def test_wrong_shaped_reading_falls_back(graph: SensorGraph) -> None:
    snap = graph.snapshot(devices(ranger=np.zeros((4, 2))))
    assert snap.get("Range_Points").served_by == "Stereo_Points"
    assert "got shape (4, 2)" in snap.attempts["Range_Points"][0].reason


def test_merge_program_coerces_and_keeps_row_provenance(graph: SensorGraph) -> None:
    stream = graph.snapshot(devices()).get("Cameras")
    # Camera_Points (0:1023) coerced onto 0:511: x 1023 -> 511, y 512 -> 255.75 -> 256.
    np.testing.assert_array_equal(stream.data, [[0, 0, 10], [511, 256, 255], [7, 8, 9]])
    assert stream.source is not None
    assert list(stream.source) == ["Camera_Points", "Camera_Points", "Camera_Lo_Points"]
    assert stream.served_by == "primary"


# --------------------------------------------------------------------------- programs


CALLS: dict[str, int] = {}


@register_program("_test_counting")
def _counting(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    CALLS["count"] = CALLS.get("count", 0) + 1
    return np.asarray(next(iter(inputs.values())), dtype=float)


@register_program("_test_failing")
def _failing(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
    raise SensorFailure("Fragile", "no circles found")


@register_acceptance("_test_never")
def _never(stream: Any, params: Mapping[str, Any]) -> str | None:
    return "never good enough"


VEC1 = OutputVector.of(Field("v", 0.0, 10.0))


def test_program_failure_falls_through_and_sensor_runs_once() -> None:
    fragile = SensorSpec(
        "Fragile",
        ("d",),
        "_test_failing",
        VEC1,
        alternates=(AlternateSpec("Counting", ("d",), "_test_counting"),),
    )
    user_a = SensorSpec("User_A", ("Fragile",), "passthrough", VEC1)
    user_b = SensorSpec("User_B", ("Fragile",), "passthrough", VEC1)
    graph = SensorGraph([fragile, user_a, user_b], devices=["d"])
    CALLS.clear()
    snap = graph.snapshot({"d": FakeDevice("d", [[1.0], [2.0]])})
    snap.evaluate(["User_A", "User_B"])
    assert CALLS["count"] == 1
    assert snap.provenance["Fragile"] == "Counting"
    assert snap.attempts["Fragile"][0].reason == "no circles found"


def test_failed_input_sensor_makes_the_dependent_alternate_serve() -> None:
    broken = SensorSpec("Broken", ("d",), "_test_failing", VEC1)
    user = SensorSpec(
        "User",
        ("Broken",),
        "passthrough",
        VEC1,
        alternates=(AlternateSpec("Direct", ("d",), "passthrough"),),
    )
    graph = SensorGraph([broken, user], devices=["d"])
    snap = graph.snapshot({"d": FakeDevice("d", [[3.0]])})
    assert snap.get("User").served_by == "Direct"
    assert "logical sensor 'Broken' failed" in snap.attempts["User"][0].reason


def test_program_returning_a_stream_with_other_fields_fails_clearly() -> None:
    inner = SensorSpec("Inner", ("d",), "passthrough", VEC1)
    outer = SensorSpec("Outer", ("Inner",), "merge", OutputVector.of(Field("w", 0.0, 1.0)))
    graph = SensorGraph([inner, outer], devices=["d"])
    with pytest.raises(SensorFailure, match=r"program returned fields \['v'\], expected \['w'\]"):
        graph.snapshot({"d": FakeDevice("d", [[3.0]])}).get("Outer")


def test_sensor_level_acceptance_applies_to_alternates() -> None:
    from mks_sim.sensing import AcceptanceSpec

    spec = SensorSpec(
        "Picky",
        ("d",),
        "passthrough",
        VEC1,
        acceptance=AcceptanceSpec("_test_never"),
        alternates=(AlternateSpec("Other", ("d",), "passthrough"),),
    )
    snap = SensorGraph([spec], devices=["d"]).snapshot({"d": FakeDevice("d", [[1.0]])})
    with pytest.raises(SensorFailure, match="primary: .*never good enough; Other: .*never good"):
        snap.get("Picky")


def test_kernel_program_parameter_errors() -> None:
    spec = SensorSpec("Sel", ("In",), "select_fields", VEC1)
    inner = SensorSpec("In", ("d",), "passthrough", VEC1)
    # params are checked against the program's dataclass when the graph is built ...
    with pytest.raises(SpecError, match=r"sensor 'Sel': field 'params.fields': expected a value"):
        SensorGraph([inner, spec], devices=["d"])
    bad_type = SensorSpec("In", ("d",), "passthrough", VEC1, params={"key": 3})
    with pytest.raises(SpecError, match=r"field 'params.key': expected a string, got 3"):
        SensorGraph([bad_type], devices=["d"])
    # ... and a program called directly (no graph) still names what is missing.
    snap = SensorGraph([inner, spec], devices=["d"], check_programs=False).snapshot(
        {"d": FakeDevice("d", [[1.0]])}
    )
    with pytest.raises(SpecError, match=r"program 'select_fields': params\.fields: expected"):
        snap.get("Sel")


def test_constant_and_passthrough_key() -> None:
    const = get_program("constant")
    np.testing.assert_array_equal(const({}, {"rows": [[1, 2], [3, 4]]}), [[1, 2], [3, 4]])
    passthrough = get_program("passthrough")
    reading = {"points": np.ones((2, 3)), "image": np.zeros((4, 4, 3))}
    np.testing.assert_array_equal(passthrough({"d": reading}, {"key": "points"}), np.ones((2, 3)))
    with pytest.raises(SensorFailure, match="expected an \\(N, n\\) numeric table, got shape"):
        passthrough({"d": reading}, {"key": "image"})


# --------------------------------------------------------------------------- registry


def test_registry_is_one_table_of_entry_points() -> None:
    assert PROGRAMS.entry_point("passthrough") == "mks_sim.sensing.programs.kernel:passthrough"
    assert PROGRAMS.entry_point("range_points") == "mks_sim.sensing.programs.points:range_points"
    assert {"passthrough", "select_fields", "concat", "merge", "constant"} <= set(program_names())
    with pytest.raises(NotFound, match=r"unknown program 'nope'; known programs: \["):
        get_program("nope")


def test_program_names_import_nothing() -> None:
    code = (
        "import sys; from mks_sim.sensing import program_names; program_names(); "
        "print('mks_sim.sensing.programs.points' in sys.modules, 'cv2' in sys.modules)"
    )
    import subprocess

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_registering_a_name_twice_is_an_error() -> None:
    with pytest.raises(SpecError, match="program 'passthrough' is registered twice"):

        @register_program("passthrough")
        def other(inputs: Mapping[str, Any], params: Mapping[str, Any]) -> np.ndarray:
            return np.zeros((0, 1))


def test_missing_program_module_is_a_spec_error_but_broken_import_propagates(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "mks_test_broken_programs.py").write_text("import mks_no_such_dependency_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    PROGRAMS.add("t_missing", "mks_test_does_not_exist_xyz:f")
    PROGRAMS.add("t_broken", "mks_test_broken_programs:f")
    try:
        with pytest.raises(SpecError, match="program 't_missing'.*not found"):
            get_program("t_missing")
        with pytest.raises(ModuleNotFoundError, match="mks_no_such_dependency_xyz"):
            get_program("t_broken")
    finally:
        PROGRAMS.remove("t_missing")
        PROGRAMS.remove("t_broken")
        sys.modules.pop("mks_test_broken_programs", None)


def test_data_error_from_bad_stream_inputs() -> None:
    with pytest.raises(DataError):
        VEC1.validate(np.zeros((2, 2)))


# --------------------------------------------------------------------------- touch alternates


def _pad(name: str, x: float, *, fail: bool = False) -> FakeDevice:
    from types import SimpleNamespace

    reading = SimpleNamespace(
        pressure=np.array([0.0, 2000.0, 800.0]),
        positions_world=np.array([[x, 0.0, 1.0], [x, 0.01, 1.0], [x, 0.02, 1.0]]),
    )
    return FakeDevice(name, reading, fail=fail)


@pytest.mark.parametrize("failed", [None, 1, 2, 3])
def test_touch_contacts_survive_one_failed_pad(failed: int | None) -> None:
    """Through the installed sensor graph: a failed pad is named by the alternate that served,
    and the remaining pads still report their contacts (2 taxels above 500 Pa per pad)."""
    graph = SensorGraph.from_dir()
    x = {1: -0.02, 2: 0.02, 3: 0.03}  # finger 1 opposes fingers 2 and 3
    pads = {f"touch_finger_{i}": _pad(f"touch_finger_{i}", x[i], fail=i == failed) for i in x}
    snap = graph.snapshot(pads)
    data = snap.get("Touch_Contacts").data
    alive = [i for i in x if i != failed]
    assert len(data) == 2 * len(alive)
    assert sorted(set(np.round(data[:, 0], 3))) == sorted(x[i] for i in alive)
    served = snap.provenance["Touch_Contacts"]
    assert served == ("primary" if failed is None else f"Without_Pad_{failed}")
    if failed in (2, 3):  # both sides of the grasp still touched
        assert (data[:, 0] < 0).any() and (data[:, 0] > 0).any()


@pytest.mark.parametrize("failed", [1, 2, 3])
def test_finger_torque_stands_in_for_a_failed_pad(failed: int) -> None:
    """Torque_For_Pad_<i> serves before Without_Pad_<i>: the failed pad's finger comes back as
    one (x, y, z, pressure) row at its pad centre, so both sides of the grasp are sensed; a
    finger that is not pressing (0 Pa) adds no row."""
    from types import SimpleNamespace

    graph = SensorGraph.from_dir()
    x = {1: -0.02, 2: 0.02, 3: 0.03}
    devices: dict[str, Any] = {
        f"touch_finger_{i}": _pad(f"touch_finger_{i}", x[i], fail=i == failed) for i in x
    }
    for i in x:
        pressing = SimpleNamespace(pressure=np.array([9.0e4]),
                                   positions_world=np.array([[x[i], 0.005, 1.0]]))  # fmt: skip
        devices[f"finger_torque_{i}"] = FakeDevice(f"finger_torque_{i}", pressing)
    snap = graph.snapshot(devices)
    data = snap.get("Touch_Contacts").data
    assert snap.provenance["Touch_Contacts"] == f"Torque_For_Pad_{failed}"
    assert len(data) == 2 * 2 + 1
    (row,) = data[data[:, 3] == 9.0e4]
    assert np.allclose(row[:3], [x[failed], 0.005, 1.0])
    assert (data[:, 0] < 0).any() and (data[:, 0] > 0).any()  # both sides
    idle = SimpleNamespace(pressure=np.array([0.0]), positions_world=np.array([[0.0, 0, 1]]))
    devices[f"finger_torque_{failed}"] = FakeDevice(f"finger_torque_{failed}", idle)
    assert len(graph.snapshot(devices).get("Touch_Contacts").data) == 4
