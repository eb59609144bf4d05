"""Model database: loading, kinds, and clear errors for bad files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mks_sim.errors import NotFound, SpecError
from mks_sim.fields import DONT_CARE
from mks_sim.models.database import ModelDatabase, register_model_kind
from mks_sim.models.feature import FeatureModel
from mks_sim.resources import data_dir

SHIPPED = ["C2.toml", "nut.toml", "planar.toml", "curved.toml"]


def shipped_db() -> ModelDatabase:
    folder = data_dir("tasks") / "models"
    return ModelDatabase.from_files([folder / f for f in SHIPPED])


def test_shipped_feature_models_are_the_papers():
    db = shipped_db()
    assert {"C2", "nut", "planar", "curved"} <= set(db.names())
    c2 = db.get("C2")
    assert isinstance(c2, FeatureModel) and c2.sensor == "Circle_Detector"
    assert c2.reference == (DONT_CARE, DONT_CARE, 2.0) and c2.key_fields == ("radius",)
    assert db.get("nut").reference[2:] == (4.0, 1.0)
    assert db.get("planar").reference == (DONT_CARE,) * 3 + (-1.0,)
    assert db.get("curved").reference == (DONT_CARE,) * 3 + (1.0,)
    assert db.kind("nut") == "feature" and db.path("nut").name == "nut.toml"
    assert db.get("C2").matches([[256, 86, 0], [320, 224, 2]]).tolist() == [False, True]


def test_default_folder_is_tasks_models():
    try:
        db = ModelDatabase.from_dir()
    except SpecError as exc:  # another room's file may be mid-edit; ours must still be there
        pytest.skip(f"a model file of another room does not load: {exc}")
    assert {"C2", "nut", "planar", "curved"} <= set(db.names())


def test_unknown_name_lists_known():
    with pytest.raises(NotFound, match=r"'C3' not in the model database; known models: \['C2'"):
        shipped_db().get("C3")


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("body", "pattern"),
    [
        (
            'reference = ["*", "two"]\nthreshold = 1',
            r"m\.toml: model 'bad': field 'reference'\[1\]",
        ),
        ('reference = ["*", 2]', r"model 'bad': field 'threshold' is missing"),
        (
            'reference = ["*", 2]\nthreshold = -1',
            r"model 'bad': field 'threshold': expected a number >= 0",
        ),
        ('reference = ["*", "*"]\nthreshold = 1', r"model 'bad'.*every field is don't care"),
        (
            'reference = [1, 2]\nthreshold = 1\nmetric = "cosine"',
            r"model 'bad': field 'metric'.*cosine",
        ),
        (
            'reference = [1, 2]\nthreshold = 1\nmetric = { kind = "euclidean", weights = [1, 2, 3] }',
            r"model 'bad': field 'metric'.*k=3",
        ),
        (
            'reference = [1, 2]\nthreshold = 1\nfields = ["x"]',
            r"model 'bad': field 'fields': expected 2",
        ),
        (
            'reference = [1, 2]\nthreshold = 1\ncolour = "red"',
            r"model 'bad': unknown field\(s\) \['colour'\]",
        ),
    ],
)
def test_bad_feature_entries_name_file_model_field(tmp_path, body, pattern):
    p = _write(tmp_path, f'[[model]]\nname = "bad"\nkind = "feature"\nsensor = "S"\n{body}\n')
    with pytest.raises(SpecError, match=pattern):
        ModelDatabase.from_files([p])


def test_bad_files(tmp_path):
    with pytest.raises(SpecError, match="not valid TOML"):
        ModelDatabase.from_files([_write(tmp_path, "[[model]\n")])
    with pytest.raises(SpecError, match="field 'kind': unknown model kind 'teapot'"):
        ModelDatabase.from_files([_write(tmp_path, '[[model]]\nname = "t"\nkind = "teapot"\n')])
    with pytest.raises(SpecError, match="one or more \\[\\[model\\]\\] entries"):
        ModelDatabase.from_files([_write(tmp_path, "")])
    with pytest.raises(NotFound, match="model file not found"):
        ModelDatabase.from_files([tmp_path / "none.toml"])
    with pytest.raises(NotFound, match="folder not found"):
        ModelDatabase.from_dir(tmp_path / "nowhere")
    one = '[[model]]\nname = "a"\nkind = "feature"\nsensor = "S"\nreference = [1]\nthreshold = 0\n'
    with pytest.raises(SpecError, match="duplicate model name"):
        ModelDatabase.from_files([_write(tmp_path, one + one)])


def test_other_kinds_register_loaders(tmp_path):
    register_model_kind("test_blob", lambda entry, where: ("blob", entry["size"]))
    p = _write(tmp_path, '[[model]]\nname = "b"\nkind = "test_blob"\nsize = 3\n')
    db = ModelDatabase.from_files([p])
    assert db.get("b") == ("blob", 3) and db.of_kind("test_blob") == ["b"]


def test_metric_tables(tmp_path):
    p = _write(
        tmp_path,
        '[[model]]\nname = "w"\nkind = "feature"\nsensor = "S"\nreference = ["*", 0, 0]\nthreshold = 1\n'
        'metric = { kind = "manhattan", weights = [1, 2], ranges = [10, 1] }\n'
        '[[model]]\nname = "s"\nkind = "feature"\nsensor = "S"\nreference = ["*", 0, 0]\nthreshold = 1\n'
        'metric = { kind = "sum_of", terms = [{ f = "abs", scale = 2.0 }, { f = "square" }] }\n',
    )
    db = ModelDatabase.from_files([p])
    row = np.array([[99.0, 4.0, 0.5]])
    np.testing.assert_allclose(db.get("w").distance(row), [4 / 10 + 2 * 0.5])
    np.testing.assert_allclose(db.get("s").distance(row), [4 / 2 + 0.25])
