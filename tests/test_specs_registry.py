"""mks_sim.registry (lazy "module:callable" table) and mks_sim.specs (one message format)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Literal

import pytest

from mks_sim.errors import NotFound, SpecError
from mks_sim.registry import Registry, resolve_entry_point
from mks_sim.specs import (
    Where,
    located,
    param,
    parse_dataclass,
    require_keys,
    require_number,
    require_str,
    spec_error,
)

# ------------------------------------------------------------------ registry


def test_registry_resolves_lazily_and_caches(tmp_path, monkeypatch):
    mod = tmp_path / "mks_lazy_probe.py"
    mod.write_text("IMPORTS = []\nIMPORTS.append(1)\ndef f():\n    return 42\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    reg: Registry[object] = Registry("widget", {"f": "mks_lazy_probe:f"})
    assert "mks_lazy_probe" not in sys.modules  # nothing imported by building the table
    assert reg.names() == ["f"] and "f" in reg
    f = reg.get("f")
    assert f() == 42 and reg.get("f") is f
    assert sys.modules["mks_lazy_probe"].IMPORTS == [1]  # imported exactly once
    assert reg.entry_point("f") == "mks_lazy_probe:f"


def test_registry_unknown_name_lists_known():
    reg: Registry[object] = Registry("widget", {"b": "os:getcwd", "a": "os:getpid"})
    with pytest.raises(NotFound, match=r"unknown widget 'c'; known widgets: \['a', 'b'\]"):
        reg.get("c")
    with pytest.raises(NotFound, match=r"unknown widget \['a'\]"):
        reg.get(["a"])  # type: ignore[arg-type]  (an unhashable name from a bad file)
    assert ["a"] not in reg


def test_registry_bad_targets():
    with pytest.raises(SpecError, match="expected 'package.module:callable'"):
        Registry("widget", {"x": "no colon"})
    reg: Registry[object] = Registry("widget", {"x": "mks_no_such_module_zz:f", "y": "os:nope"})
    with pytest.raises(SpecError, match="widget 'x'.*importable module.*not found"):
        reg.get("x")
    with pytest.raises(SpecError, match="widget 'y'.*define 'nope'"):
        reg.get("y")
    with pytest.raises(SpecError, match="registered twice"):
        reg.add("x", "os:getcwd")
    reg.add("x", "os:getcwd", replace=True)
    import os

    assert reg.get("x") is os.getcwd


def test_registry_objects_and_same_target_twice():
    def g() -> int:
        return 1

    reg: Registry[object] = Registry("widget")
    reg.add("g", g)
    reg.add("g", g)  # same object again: fine
    assert reg.get("g") is g
    assert resolve_entry_point("os.path:join") is __import__("os").path.join


# ------------------------------------------------------------------ specs


def test_spec_error_format():
    exc = spec_error("s.toml", "sensor 'X'", "params.m", "a number >= 1", 0)
    assert str(exc) == "s.toml: sensor 'X': field 'params.m': expected a number >= 1, got 0"
    w = Where("m.toml", "model", "cube")
    assert str(w.error("kind", "a string", None)) == (
        "m.toml: model 'cube': field 'kind': expected a string, got None"
    )
    assert "got nothing (missing)" in str(w.error("kind", "a string", require_missing()))


def require_missing():
    from mks_sim.specs import MISSING

    return MISSING


def test_validators_return_values_and_reject():
    w = Where("f.toml", "task", "t")
    t = {"a": "x", "n": 3, "bad": float("nan"), "b": True}
    assert require_str(t, "a", w) == "x"
    assert require_number(t, "n", w, 1, 5) == 3
    assert require_number(t, "missing", w, default=7) == 7
    with pytest.raises(SpecError, match=r"field 'bad': expected a finite number, got nan"):
        require_number(t, "bad", w)
    with pytest.raises(SpecError, match=r"field 'b': expected a number, got True"):
        require_number(t, "b", w)  # bool is not a number
    with pytest.raises(SpecError, match=r"field 'n': expected a number <= 2, got 3"):
        require_number(t, "n", w, high=2)
    with pytest.raises(SpecError, match=r"field 'a': expected one of \['y'\], got 'x'"):
        require_str(t, "a", w, choices=["y"])
    with pytest.raises(SpecError, match=r"expected only the keys \['a', 'n'\], got 'bad'"):
        require_keys({"a": 1, "bad": 2}, ["a", "n"], w)


def test_located_never_doubles_the_prefix():
    w = Where("m.toml", "model", "x")
    with pytest.raises(SpecError) as info, located(w):
        with located(w):
            raise w.error("kind", "a string", 1)
    assert str(info.value).count("m.toml") == 1
    with pytest.raises(SpecError) as info, located(w):
        raise SpecError("something inside")
    assert str(info.value) == "m.toml: model 'x': something inside"


@dataclass(frozen=True)
class _P:
    m: int = param(8, low=1)
    gap_m: float = param(0.01, low=0.0, low_open=True)
    crop_min: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    polarity: Literal["auto", "dark"] = "auto"
    key: str | None = None
    fields: tuple[str, ...] = ()


def test_parse_dataclass():
    w = Where("s.toml", "sensor", "S")
    p = parse_dataclass(_P, {"m": 3, "crop_min": [0, 1, 2.5], "fields": ["x"]}, w)
    assert p == _P(m=3, crop_min=(0.0, 1.0, 2.5), fields=("x",))
    assert isinstance(p.crop_min[0], float)
    cases = {
        "crop_min": ("abc", "field 'params.crop_min': expected a list of 3 numbers, got 'abc'"),
        "crop_mn": ([0, 0, 0], "field 'params': expected only the keys"),
        "m": (0, "field 'params.m': expected a number >= 1, got 0"),
        "gap_m": (0.0, "field 'params.gap_m': expected a number > 0, got 0.0"),
        "polarity": ("x", "expected one of ['auto', 'dark'], got 'x'"),
        "key": (3, "field 'params.key': expected a string, got 3"),
    }
    for key, (value, message) in cases.items():
        with pytest.raises(SpecError) as info:
            parse_dataclass(_P, {key: value}, w)
        assert str(info.value).startswith("s.toml: sensor 'S': ")
        assert message in str(info.value), str(info.value)
    with pytest.raises(SpecError, match=r"params.m': expected an integer, got 2.5"):
        parse_dataclass(_P, {"m": 2.5}, w)


def test_model_file_errors_name_the_entry_once(tmp_path):
    from mks_sim.models.database import ModelDatabase

    path = tmp_path / "r.toml"
    path.write_text('[[model]]\nname = "y"\nkind = "rotinv"\nvertexes = "abc"\n')
    with pytest.raises(SpecError) as info:
        ModelDatabase.from_files([path])
    message = str(info.value)
    assert message.startswith(f"{path}: model 'y': ") and message.count(str(path)) == 1
    assert "vertexes" in message
