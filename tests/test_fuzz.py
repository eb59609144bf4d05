"""Fuzz the real entry points with malformed inputs (issue 12).

Every example must end in a result or an ``MksError`` (exit 2 / 1 for the CLI): no other
exception, no traceback, no warning on stderr, no hang (each example is time-boxed), nothing
written outside the output folder. Fast by default (a few examples each, derandomized); run
``MKS_FUZZ=long pytest tests/test_fuzz.py`` for the long profile (many random examples).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import tempfile
import tomllib
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mks_sim.errors import MksError

ROOT = Path(__file__).resolve().parents[1]

settings.register_profile(
    "mks-fuzz-fast",
    parent=settings.get_profile("mks"),
    max_examples=12,
    derandomize=True,
    deadline=None,
    database=None,  # nothing written (no .hypothesis folder)
    suppress_health_check=list(HealthCheck),
)
settings.register_profile(
    "mks-fuzz-long",
    parent=settings.get_profile("mks-fuzz-fast"),
    max_examples=400,
    derandomize=False,
)
LONG = os.environ.get("MKS_FUZZ", "") == "long"
FUZZ = settings.get_profile("mks-fuzz-long" if LONG else "mks-fuzz-fast")
#: seconds one example may take before it counts as a hang
TIME_BOX_S = 20.0


@contextlib.contextmanager
def time_box(seconds: float = TIME_BOX_S) -> Iterator[None]:
    """Raise TimeoutError in the block after ``seconds`` (SIGALRM; the main thread)."""

    def hang(signum: int, frame: Any) -> None:
        raise TimeoutError(f"no answer within {seconds} s (a hang)")

    old = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def clean(call: Callable[[], Any]) -> Any:
    """Run ``call``: a value or an MksError (returned), never another exception or a warning."""
    with warnings.catch_warnings(record=True) as caught, time_box():
        warnings.simplefilter("always")
        try:
            out = call()
        except MksError as exc:
            out = exc
            text = str(exc)
            assert text.strip(), "an empty error message"
            assert "Traceback" not in text
    leaked = [f"{w.category.__name__}: {w.message}" for w in caught]
    assert not leaked, f"warnings leaked: {leaked}"
    return out


def listing(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


# --------------------------------------------------------------------------- byte mutations


@st.composite
def mutated(draw: st.DrawFn, raw: bytes) -> bytes:
    """``raw`` truncated, with bytes overwritten, or with a header number replaced."""
    how = draw(st.sampled_from(["truncate", "overwrite", "number", "insert"]))
    if how == "truncate":
        return raw[: draw(st.integers(0, len(raw)))]
    if how == "overwrite":
        data = bytearray(raw)
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(data) - 1))
            data[i] = draw(st.integers(0, 255))
        return bytes(data)
    if how == "insert":
        i = draw(st.integers(0, len(raw)))
        return raw[:i] + draw(st.binary(min_size=1, max_size=16)) + raw[i:]
    # a number of the (text) header replaced by a hostile one
    head_end = max(raw.find(b"end_header"), raw.find(b"DATA"), 0)
    tokens = [
        (m.start(), m.end())
        for m in __import__("re").finditer(rb"-?\d+", raw[: head_end + 1] or raw[:200])
    ]
    if not tokens:
        return raw
    a, b = draw(st.sampled_from(tokens))
    value = draw(
        st.sampled_from([b"-5", b"0", b"1", b"3", b"-1", b"999999999999", b"nan", b"1e400", b"x"])
    )
    return raw[:a] + value + raw[b:]


def _cloud_files(folder: Path) -> dict[str, bytes]:
    from mks_sim.io import write_pcd, write_ply

    pts = np.random.default_rng(0).random((12, 3))
    out: dict[str, bytes] = {}
    for name, write in (
        ("a.ply", lambda p: write_ply(p, pts, binary=False)),
        ("b.ply", lambda p: write_ply(p, pts, np.ones_like(pts), binary=True)),
        ("a.pcd", lambda p: write_pcd(p, pts, data="ascii")),
        ("b.pcd", lambda p: write_pcd(p, pts, data="binary")),
        ("c.pcd", lambda p: write_pcd(p, pts, data="binary_compressed")),
        ("a.npy", lambda p: np.save(p, pts)),
    ):
        write(folder / name)
        out[name] = (folder / name).read_bytes()
    return out


def _mesh_files(folder: Path) -> dict[str, bytes]:
    from mks_sim.geometry.meshes import box_mesh
    from mks_sim.io import write_obj, write_ply_mesh, write_stl

    mesh = box_mesh((0.05, 0.04, 0.03))
    out: dict[str, bytes] = {}
    for name, write in (
        ("m.ply", lambda p: write_ply_mesh(p, mesh, binary=False)),
        ("n.ply", lambda p: write_ply_mesh(p, mesh, binary=True)),
        ("m.stl", lambda p: write_stl(p, mesh)),
        ("m.obj", lambda p: write_obj(p, mesh)),
    ):
        write(folder / name)
        out[name] = (folder / name).read_bytes()
    return out


with tempfile.TemporaryDirectory() as _tmp:
    CLOUDS = _cloud_files(Path(_tmp))
    MESHES = _mesh_files(Path(_tmp))


@FUZZ
@given(data=st.data())
def test_point_cloud_reader(data: st.DataObject) -> None:
    from mks_sim.io import read_point_cloud

    name = data.draw(st.sampled_from(sorted(CLOUDS)))
    raw = data.draw(mutated(CLOUDS[name]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_bytes(raw)
        out = clean(lambda: read_point_cloud(path))
        assert listing(Path(tmp)) == {name}
    if not isinstance(out, MksError):
        pts = np.asarray(out.points)
        assert pts.ndim == 2 and pts.shape[1] == 3 and np.isfinite(pts).all()


@FUZZ
@given(data=st.data())
def test_mesh_reader(data: st.DataObject) -> None:
    from mks_sim.io import read_mesh

    name = data.draw(st.sampled_from(sorted(MESHES)))
    raw = data.draw(mutated(MESHES[name]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_bytes(raw)
        out = clean(lambda: read_mesh(path))
    if not isinstance(out, MksError):
        assert out.faces.min() >= 0 and out.faces.max() < len(out.vertices)


# --------------------------------------------------------------------------- spec documents

SCALARS = st.one_of(
    st.integers(-(10**12), 10**12),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
    st.booleans(),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=8,
)


def _paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated_doc(draw: st.DrawFn, doc: dict[str, Any]) -> dict[str, Any]:
    """``doc`` (a parsed TOML document) with 1-3 values replaced, keys dropped or added."""
    doc = json.loads(json.dumps(doc))  # a deep copy (TOML documents here are JSON-able)
    for _ in range(draw(st.integers(1, 3))):
        paths = _paths(doc)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent: Any = doc
        for key in path[:-1]:
            parent = parent[key]
        how = draw(st.sampled_from(["replace", "drop", "add"]))
        if how == "replace":
            parent[path[-1]] = draw(VALUES)
        elif how == "drop":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=6))] = draw(VALUES)
    return doc


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return (
            "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        )
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_text(doc: dict[str, Any]) -> str:
    """A TOML document (every top-level value inline) equal to ``doc`` when parsed."""
    return "".join(f"{json.dumps(k)} = {_toml_value(v)}\n" for k, v in doc.items())


def _load(path: Path) -> dict[str, Any]:
    return json.loads(json.dumps(tomllib.loads(path.read_text())))


@FUZZ
@given(data=st.data())
def test_sensor_loader_and_graph(data: st.DataObject) -> None:
    from mks_sim.sensing import SensorGraph
    from mks_sim.sensing.loader import load_file

    name = data.draw(st.sampled_from(["points.toml", "vision.toml", "touch.toml"]))
    doc = data.draw(mutated_doc(_load(ROOT / "sensors" / name)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_text(toml_text(doc))
        others = [p for p in sorted((ROOT / "sensors").glob("*.toml")) if p.name != name]
        clean(lambda: (load_file(path), SensorGraph.from_files([*others, path])))


@FUZZ
@given(data=st.data())
def test_model_loader(data: st.DataObject) -> None:
    from mks_sim.models.database import ModelDatabase

    name = data.draw(st.sampled_from(["C2.toml", "cube_5cm.toml", "sphere_3cm.toml", "part.toml"]))
    doc = data.draw(mutated_doc(_load(ROOT / "tasks" / "models" / name)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_text(toml_text(doc))
        clean(lambda: ModelDatabase.from_files([path]))


@FUZZ
@given(data=st.data())
def test_task_loader(data: st.DataObject) -> None:
    from mks_sim.tasks.spec import load_task_file

    name = data.draw(st.sampled_from(["grasp_cube.toml", "grasp_part.toml"]))
    doc = data.draw(mutated_doc(_load(ROOT / "tasks" / name)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_text(toml_text(doc))
        clean(lambda: load_task_file(path))


@FUZZ
@given(data=st.data())
def test_scene_loader(data: st.DataObject) -> None:
    from mks_sim.sim.scenes import load_scene_file

    name = data.draw(st.sampled_from(["scene2.toml", "part.toml"]))
    doc = data.draw(mutated_doc(_load(ROOT / "worlds" / name)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        path.write_text(toml_text(doc))
        clean(lambda: load_scene_file(path))


# --------------------------------------------------------------------------- the CLI


def _vocabulary() -> dict[str, list[str]]:
    """Each command's option strings (from the real parser)."""
    from mks_sim.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    vocab: dict[str, list[str]] = {}
    for name, cmd in sub.choices.items():  # type: ignore[union-attr]
        vocab[name] = [s for a in cmd._actions for s in a.option_strings if s.startswith("--")]
    return vocab


VOCAB = _vocabulary()
TOKENS = st.one_of(
    st.sampled_from(["-1", "0", "3", "nan", "inf", "-inf", "1e999", "abc", "", "cube", "sphere",
                     "part", "scene2", "range_finder", "laser", "out", "out.txt", "x.gif",
                     "/proc/x", "/dev/null", "/dev/zero", "no/such/dir/x.ply", "--", "-", "tables"]),
    st.text(max_size=6),
    st.integers(-(2**70), 2**70).map(str),
    st.floats().map(repr),
)  # fmt: skip


@st.composite
def argvs(draw: st.DrawFn) -> list[str]:
    command = draw(st.sampled_from(sorted(VOCAB)))
    argv = [command]
    for _ in range(draw(st.integers(0, 6))):
        if VOCAB[command] and draw(st.booleans()):
            argv.append(draw(st.sampled_from(VOCAB[command])))
        argv.append(draw(TOKENS))
    return argv


def _run_cli(argv: list[str], stub: Callable[..., int]) -> tuple[int, str]:
    import importlib

    from mks_sim.cli import COMMANDS, main

    err = io.StringIO()
    saved = {}
    for name in COMMANDS:
        module = importlib.import_module(f"mks_sim.cli.{name}")
        if name != "sensors":  # `sensors` is fast: it runs for real
            saved[module] = module.run
            module.run = stub
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse: usage errors (2) and --help (0)
                rc = exc.code if isinstance(exc.code, int) else 2
    finally:
        for module, run in saved.items():
            module.run = run
    return rc, err.getvalue()


@FUZZ
@given(argv=argvs())
def test_cli_argument_parser(argv: list[str]) -> None:
    """Generated command lines: exit 0, 1 or 2; a one-line message, never a traceback; the
    commands (stubbed after parsing, except `sensors`) see only checked options."""

    def stub(args: Any) -> int:
        seed = getattr(args, "seed", None)
        assert seed is None or seed >= 0
        for value in vars(args).values():
            for f in value if isinstance(value, list) else [value]:
                assert not (isinstance(f, float) and not math.isfinite(f))
        return 0

    with tempfile.TemporaryDirectory() as tmp:
        before_repo = set(os.listdir(ROOT))
        cwd = os.getcwd()
        os.chdir(tmp)
        try:
            with time_box():
                rc, err = _run_cli(argv, stub)
        finally:
            os.chdir(cwd)
        assert rc in (0, 1, 2), (argv, rc, err)
        assert "Traceback" not in err, err
        if rc == 2:
            assert err.strip(), "exit 2 without a message"
        assert listing(Path(tmp)) == set(), "the command wrote files"
        assert set(os.listdir(ROOT)) == before_repo


@FUZZ
@given(parts=st.lists(st.sampled_from(["a", "b", "..", ".", "x.gif", "out.txt", "f"]), min_size=1,
                      max_size=4), kind=st.sampled_from(["dir", "file"]))  # fmt: skip
def test_output_paths_create_at_most_the_named_folder(parts: list[str], kind: str) -> None:
    from mks_sim.cli import output_dir, output_file

    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "work"
        base.mkdir()
        (base / "f").write_text("keep")
        target = base.joinpath(*parts)
        before = listing(Path(tmp))
        if kind == "dir":
            out = clean(lambda: output_dir(target))
        else:
            out = clean(lambda: output_file(target, "--video", (".gif", ".mp4")))
        created = listing(Path(tmp)) - before
        if kind == "file" or isinstance(out, MksError):
            assert created == set()
        else:
            assert len(created) <= 1 and Path(out).is_dir()
        assert (base / "f").read_text() == "keep"


# --------------------------------------------------------------------------- the env


@pytest.fixture(scope="module")
def env() -> Iterator[Any]:
    from mks_sim.envs.grasp_env import GraspEnv

    e = GraspEnv()
    e.reset(seed=0)
    yield e
    e.close()


ACTIONS = st.one_of(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=0, max_size=7),
    st.lists(st.integers(-(10**9), 10**9), min_size=5, max_size=5),
    st.lists(st.floats(-1e6, 1e6), min_size=5, max_size=5),
    st.just("abcde"),
    st.just(None),
)


@pytest.mark.slow
@FUZZ
@given(action=ACTIONS)
def test_env_step(env: Any, action: Any) -> None:
    """Generated actions: a step, or ValueError (gymnasium's convention) / MksError."""
    with warnings.catch_warnings(record=True) as caught, time_box():
        warnings.simplefilter("always")
        try:
            obs, reward, terminated, truncated, info = env.step(action)
        except (ValueError, MksError) as exc:
            assert str(exc).strip()
        else:
            assert math.isfinite(float(reward))
            if terminated or truncated:
                env.reset(seed=1)
    assert not [str(w.message) for w in caught]
