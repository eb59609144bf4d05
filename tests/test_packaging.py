"""The data folders reach an installed wheel (package data), not only a checkout."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("hatchling")
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(out),
        ],
        check=True,
    )
    (path,) = out.glob("mks_sim-*.whl")
    return path


def test_wheel_holds_every_data_file(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    for folder in ("sensors", "tasks"):
        for file in (ROOT / folder).rglob("*.toml"):
            rel = file.relative_to(ROOT).as_posix()
            assert f"mks_sim/_data/{rel}" in names, rel
    assert "mks_sim/py.typed" in names
    assert any(n.endswith("entry_points.txt") for n in names)


def test_installed_package_finds_its_data_outside_a_checkout(wheel: Path, tmp_path: Path) -> None:
    zipfile.ZipFile(wheel).extractall(tmp_path / "site")
    code = (
        "from mks_sim.resources import data_dir; "
        "from mks_sim.sensing import SensorGraph; "
        "print(data_dir('sensors')); print(len(SensorGraph.from_dir().sensor_names))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env={"PYTHONPATH": str(tmp_path / "site"), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    )
    where, count = run.stdout.split()
    assert Path(where) == tmp_path / "site" / "mks_sim" / "_data" / "sensors"
    assert int(count) >= 8
