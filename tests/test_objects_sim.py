"""Objects at random resting poses in the simulator: added meshes and database objects are
dropped from random orientations, settled by physics, localized through
``mks_sim.workstation.localize_object`` within 5 mm / 5 degrees modulo their symmetries and
grasped (issue 10 section 5: an L-bracket, a cylinder, a wedge and an asymmetric blob, each
added with ``objects add``). Ground truth is read after localization, for evaluation only.

Seeds are tuning seeds (0-19); what fails in another room is an ``xfail`` naming the room and
the reason, so it turns green there without an edit here (``strict=False``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mks_sim.errors import NotFound
from mks_sim.models.importer import add_object
from mks_sim.models.objects import load_object
from mks_sim.sim import names, truth
from mks_sim.sim.world import build_world

sys.path.insert(0, str(Path(__file__).parent))
import _gen_meshes as gen  # noqa: E402

pytestmark = pytest.mark.slow

GENERATED = ("l_bracket", "cylinder", "wedge", "blob")



@pytest.fixture(scope="module")
def models(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("generated")
    for name in GENERATED:
        tm = getattr(gen, name)()
        tm.apply_scale(1000.0)
        tm.export(folder / f"{name}.stl")
        add_object(folder / f"{name}.stl", name, folder / "models", units="mm")
    return folder / "models"


@pytest.mark.parametrize("name", GENERATED)
def test_added_object_rests_on_a_stable_face(models: Path, name: str) -> None:
    """Dropped at three seeds: on the table (lowest vertex at the top), at rest, in the region."""
    obj = load_object(name, models=[models])
    for seed in range(3):
        w = build_world(objects=[name], models=[models], seed=seed)
        T = truth.object_to_world(w, name)
        low = float((obj.mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min())
        assert low == pytest.approx(names.TABLE_TOP_Z, abs=1.5e-3)
        before = T[:3, 3].copy()
        w.step(250)
        assert np.linalg.norm(truth.object_to_world(w, name)[:3, 3] - before) < 1e-3


def _localize(name: str, scene: str | None, seed: int, models: list[Path]) -> dict:
    from mks_sim.cli.localize import run_trial

    return run_trial(name, seed, (), scene, models=[str(m) for m in models])


@pytest.mark.parametrize(
    ("name", "seed"),
    [("cube", 11), ("cube", 12), ("part", 11), ("part", 12)],  # part 12: upside down
)
def test_database_object_dropped_is_localized(tmp_path: Path, name: str, seed: int) -> None:
    scene = tmp_path / "drop.toml"
    scene.write_text(f'[[object]]\nname = "{name}"\npose = "drop"\n')
    rec = _localize(name, str(scene), seed, [])
    assert rec["success"], rec["error"]  # within 5 mm and 5 degrees modulo symmetry


@pytest.mark.parametrize(
    ("name", "seed"),
    [
        ("l_bracket", 21),
        ("l_bracket", 14),  # lying flat
        ("l_bracket", 11),  # on its two leg ends
        ("l_bracket", 15),  # on its leg ends: no vertex seen; a rest on the hull's plane
        ("l_bracket", 2),  # on its leg ends, seen in four pieces
        ("wedge", 21),
        ("wedge", 12),
        ("cylinder", 11),  # lying on its side: the free-form path
        ("blob", 11),
    ],
)
def test_added_object_dropped_is_localized(models: Path, name: str, seed: int) -> None:
    try:
        rec = _localize(name, None, seed, [models])
    except NotFound as exc:
        if "localize_object" in str(exc):
            pytest.xfail(f"the engine does not resolve added objects yet: {exc}")
        raise
    assert rec["success"], rec["error"]


@pytest.mark.parametrize(
    ("name", "seed"),
    [
        ("wedge", 12),
        ("wedge", 11),  # slipped out of both pinches before the 25 deg face-lean limit
        ("l_bracket", 12),  # across a 10 mm wall
        ("l_bracket", 11),  # on its leg ends: the faces that lean 31 deg are not pinched
    ],
)
def test_added_object_dropped_is_grasped(
    models: Path, monkeypatch: pytest.MonkeyPatch, name: str, seed: int
) -> None:
    """The whole episode on an added object (its default task: the object alone, dropped):
    sensed, localized, a grasp synthesised from its mesh, lifted and held (simulator verdict)."""
    from mks_sim.tasks.episode import run_episode

    monkeypatch.setenv("MKS_SIM_MODELS", str(models))
    res = run_episode(name, seed)
    assert res.success, res.failure
