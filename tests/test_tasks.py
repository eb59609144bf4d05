"""Task files: the shipped ones load; bad files raise SpecError naming file, entry, field."""

from __future__ import annotations

from pathlib import Path

import pytest

from mks_sim.errors import NotFound, SpecError
from mks_sim.tasks.spec import GRASP_TYPES, get_task, load_task_file, load_tasks, task_for_object

GOOD = """
[[task]]
name = "t1"
scene = "scene2"
object = "cube"
model = "cube_5cm"
matcher = "rotinv"
[task.action]
kind = "grasp"
grasp_type = "antipodal"
lift_height_m = 0.1
retries = 1
"""


def _write(tmp_path: Path, text: str, name: str = "t.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_shipped_tasks_load() -> None:
    tasks = load_tasks()
    assert {"grasp_cube", "grasp_sphere", "grasp_part"} <= set(tasks)
    for obj, model in (("cube", "cube_5cm"), ("sphere", "sphere_3cm"), ("part", "part")):
        task = task_for_object(obj)
        assert task.object == obj
        assert task.model == model
        assert task.action.lift_height_m == pytest.approx(0.10)
        assert task.action.grasp_type in GRASP_TYPES
        assert task.action.retries >= 1
    assert get_task("grasp_cube").remove == ("sphere",)
    assert all(t.action.grasp_type == "antipodal" for t in tasks.values())


def test_good_file_defaults(tmp_path: Path) -> None:
    (task,) = load_task_file(_write(tmp_path, GOOD))
    assert task.name == "t1"
    assert task.action.approach_height_m == pytest.approx(0.12)
    assert task.action.retries == 1
    assert task.source.endswith("t.toml")


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('scene = "scene2"\n', "", "field 'scene': expected a non-empty string, got nothing"),
        ('matcher = "rotinv"', 'matcher = "magic"', "field 'matcher': expected one of object"),
        ('grasp_type = "antipodal"', 'grasp_type = "suction"',
         "field 'action.grasp_type': expected one of \\['antipodal'\\], got 'suction'"),
        ("lift_height_m = 0.1", 'lift_height_m = "high"',
         "field 'action.lift_height_m': expected a number, got 'high'"),
        ("lift_height_m = 0.1", "lift_height_m = 3.0",
         "field 'action.lift_height_m': expected a number <= 0.5, got 3.0"),
        ("retries = 1", "retries = -1", "field 'action.retries': expected a number >= 0, got -1"),
        ("retries = 1", "retries = 1\ncolour = 3",
         "field 'action': expected only the keys .*, got 'colour'"),
        ('object = "cube"', 'object = "cube"\nspeed = 2', "expected only the keys .*, got 'speed'"),
        # hand-written grasp geometry is gone (issue 10): its keys are unknown now
        ('grasp_type = "antipodal"', 'grasp_type = "antipodal"\nfeature = "step"',
         "field 'action': expected only the keys .*, got 'feature'"),
    ],
)  # fmt: skip
def test_bad_field_names_file_entry_and_field(
    tmp_path: Path, old: str, new: str, message: str
) -> None:
    """Task files use the one message format of every spec file (mks_sim.specs.spec_error):
    ``FILE: task 'NAME': field 'F': expected ..., got ...``."""
    assert old in GOOD
    path = _write(tmp_path, GOOD.replace(old, new, 1))
    with pytest.raises(SpecError, match=rf"t\.toml: task 't1': {message}"):
        load_task_file(path)


def test_task_errors_match_the_sensor_files_format(tmp_path: Path) -> None:
    """The same mistake gives the same message shape in a task file and a sensor file."""
    from mks_sim.specs import spec_error

    path = _write(tmp_path, GOOD.replace("lift_height_m = 0.1", "lift_height_m = 3.0"))
    with pytest.raises(SpecError) as exc:
        load_task_file(path)
    want = spec_error(path, "task 't1'", "action.lift_height_m", "a number <= 0.5", 3.0)
    assert str(exc.value) == str(want)


def test_bad_toml_and_empty(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match=r"bad\.toml: malformed TOML"):
        load_task_file(_write(tmp_path, "[[task]\nname=", "bad.toml"))
    with pytest.raises(SpecError, match=r"empty\.toml: field 'task': expected at least one \[\[task\]\]"):
        load_task_file(_write(tmp_path, "", "empty.toml"))
    with pytest.raises(SpecError, match=r"dup\.toml: task 't1': field 'name': expected distinct"):
        load_task_file(
            _write(tmp_path, GOOD + GOOD.replace("[task.action]", "[task.action]"), "dup.toml")
        )
    with pytest.raises(SpecError, match=r"x\.toml: task\[0\]: expected a table \[\[task\]\]"):
        load_task_file(_write(tmp_path, "task = [1]", "x.toml"))


def test_unknown_task(tmp_path: Path) -> None:
    _write(tmp_path, GOOD)
    with pytest.raises(NotFound, match=r"task 'nope' not found; known tasks: \['t1'\]"):
        get_task("nope", tmp_path)


# ----------------------------------------------- touch stand-ins, faults named (issue 12)


class _Dev:
    def __init__(self, name: str, force: float, *, fail: bool = False) -> None:
        from types import SimpleNamespace

        import numpy as np

        self.name, self.fail = name, fail
        x = {"1": -0.02, "2": 0.02, "3": 0.03}[name[-1]]
        self.reading = SimpleNamespace(
            force=np.array([force]), pressure=np.array([force * 1e4]),
            positions_world=np.array([[x, 0.0, 1.0]]),
        )  # fmt: skip

    def read(self):
        from mks_sim.errors import DeviceFailure

        if self.fail:
            raise DeviceFailure(self.name, "failed (fault injected)")
        return self.reading


def _hand(failed: tuple[str, ...]) -> dict:
    pads = {f"touch_finger_{i}": 1.0 + i for i in (1, 2, 3)}
    torques = {f"finger_torque_{i}": 10.0 + i for i in (1, 2, 3)}
    return {n: _Dev(n, f, fail=n in failed) for n, f in {**pads, **torques}.items()}


@pytest.mark.parametrize(
    ("failed", "expected", "stand_ins"),
    [
        ((), [2.0, 3.0, 4.0], {}),
        (("touch_finger_1",), [11.0, 3.0, 4.0], {"touch_finger_1": "finger_torque_1"}),
        (("touch_finger_3",), [2.0, 3.0, 13.0], {"touch_finger_3": "finger_torque_3"}),
        (("touch_finger_1", "finger_torque_1"), [None, 3.0, 4.0], {}),
    ],
)
def test_touch_reader_stands_a_finger_torque_in_for_a_failed_pad(failed, expected, stand_ins):
    import numpy as np

    from mks_sim.tasks.episode import make_touch_reader

    reader = make_touch_reader(_hand(failed))
    got = reader()
    want = np.array([np.nan if e is None else e for e in expected])
    assert np.array_equal(got, want, equal_nan=True)
    assert reader.stand_ins == stand_ins and reader.failed == set(failed)


@pytest.mark.parametrize(
    ("failed", "way"),
    [
        (("touch_finger_1",), "Torque_For_Pad_1"),
        (("touch_finger_2",), "Torque_For_Pad_2"),
        (("touch_finger_1", "finger_torque_1"), "Without_Pad_1"),
        (("touch_finger_1", "touch_finger_2"), "none"),
    ],
)
def test_failed_pad_is_named_with_the_way_touch_contacts_ran(failed, way) -> None:
    """Through the installed sensor graph (sensors/touch.toml): the failure reason names the
    failed pad and the Touch_Contacts way; the warnings say which alternate served."""
    from mks_sim.tasks.episode import EpisodeAssembly

    ep = EpisodeAssembly(task_for_object("cube"), faults=failed)
    ep.devices = _hand(failed)
    pads = ", ".join(d for d in failed if d.startswith("touch"))
    assert ep.touch_fault() == f"{pads} failed (Touch_Contacts ran on {way})"
    assert ep.failed_devices() == tuple(sorted(failed))
    assert ep.warnings() == (f"Touch_Contacts ran on alternate {way}",)
    healthy = EpisodeAssembly(task_for_object("cube"))
    healthy.devices = _hand(())
    assert healthy.touch_fault() == "" and healthy.warnings() == ()


def test_fault_fields_one_format() -> None:
    from mks_sim.sensing.faults import fault_fields

    got = fault_fields(["stereo_left", "range_finder", "range_finder"],
                       {"Vertex_Detector": "primary", "Range_Points": "Stereo_Points"})  # fmt: skip
    assert got == {"faults": ["range_finder", "stereo_left"],
                   "warnings": ["Range_Points ran on alternate Stereo_Points"]}  # fmt: skip
