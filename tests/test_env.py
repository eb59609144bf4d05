"""The gymnasium environments ``mks_sim/Grasp-v0`` / ``-v1`` (Gymnasium-Robotics-style API tests).

These tests check the env API, not localization: they pass a ground-truth ``localize_fn``
(the env's default is the sensor-based pipeline) so that they stay cheap.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mks_sim  # noqa: F401  (registers the envs)
from mks_sim.envs.grasp_env import GraspEnv, GraspEnvV1, GraspEnvV2


def _truth_localize(world, name):  # env API alone: ground truth stands in for sensing
    from mks_sim.sim import truth

    return truth.object_to_world(world, name)


def _make(env_id: str = "mks_sim/Grasp-v0", **kw):
    kw.setdefault("localize_fn", _truth_localize)
    return gym.make(env_id, **kw)


def _same(a, b) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


@pytest.mark.parametrize(
    ("version", "cls"), [("v0", GraspEnv), ("v1", GraspEnvV1), ("v2", GraspEnvV2)]
)
def test_registered_both_ways(version: str, cls: type) -> None:
    assert f"mks_sim/Grasp-{version}" in gym.registry
    env = gym.make(f"mks_sim:mks_sim/Grasp-{version}", object="sphere",
                   localize_fn=_truth_localize)  # fmt: skip
    try:
        assert type(env.unwrapped) is cls
        assert env.unwrapped.object == "sphere"
        assert env.unwrapped.continuous_grip is (version != "v0")
        assert env.unwrapped.rotation_action is (version == "v2")
        assert env.action_space.shape == ((7,) if version == "v2" else (5,))
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("cls", [GraspEnvV1, GraspEnvV2])
def test_check_env_passes(cls: type) -> None:
    env = cls(object="cube", localize_fn=_truth_localize, render_mode="rgb_array",
              observe_image=True, observe_depth=True, observe_points=True, n_points=64,
              image_size=(32, 24), render_size=(64, 48))  # fmt: skip
    try:
        with pytest.warns(UserWarning):  # infinite Box bounds of proprioception: intended
            check_env(env, skip_render_check=False)
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize("sleep", [False, True])
def test_same_seed_same_rollout_and_reset_restores_state(sleep: bool) -> None:
    env = _make(object="cube", sleep=sleep)  # sleeping: the reset must wake everything
    try:
        actions = np.random.default_rng(0).uniform(-1, 1, (6, 5)).astype(np.float32)

        def rollout():
            obs, _ = env.reset(seed=11)
            out = [obs]
            for a in actions:
                out.append(env.step(a)[0])
            return out

        first = rollout()
        state_after_reset = None
        env.reset(seed=11)
        d = env.unwrapped.world.data
        state_after_reset = (d.qpos.copy(), d.qvel.copy(), d.act.copy(), d.ctrl.copy(), d.time)
        for a in actions:
            env.step(a)
        env.reset(seed=11)
        again = (d.qpos.copy(), d.qvel.copy(), d.act.copy(), d.ctrl.copy(), d.time)
        for x, y in zip(state_after_reset, again):
            assert np.array_equal(x, y)
        second = rollout()
        assert all(_same(a, b) for a, b in zip(first, second))
        other, _ = env.reset(seed=12)
        assert not _same(first[0]["pose_estimate"], other["pose_estimate"])
    finally:
        env.close()


@pytest.mark.slow
def test_render_pickle_and_faults() -> None:
    env = _make(object="sphere", render_mode="rgb_array", render_size=(64, 48),
                faults=("touch_finger_1", "finger_torque_1"))  # pad and its stand-in  # fmt: skip
    try:
        obs, info = env.reset(seed=3)
        frame = env.render()
        assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0
        assert obs["touch"][0] == -1.0  # failed pad reported as -1
        assert set(info) >= {"success", "localization_error", "clearance_m"}
        clone = pickle.loads(pickle.dumps(env))
        try:
            a, _ = env.reset(seed=5)
            b, _ = clone.reset(seed=5)
            assert _same(a, b)
            act = np.array([0.5, -0.2, 0.1, 0.0, -1.0], np.float32)
            assert _same(env.step(act)[0], clone.step(act)[0])
        finally:
            clone.close()
    finally:
        env.close()
    none_env = _make(object="sphere")
    try:
        none_env.reset(seed=0)
        assert none_env.render() is None
    finally:
        none_env.close()


@pytest.mark.slow
@pytest.mark.parametrize("vector", ["sync", "async"])
def test_vector_envs(vector: str) -> None:
    kw = {"object": "cube", "localize_fn": _truth_localize}
    if vector == "sync":
        venv = gym.vector.SyncVectorEnv([lambda: gym.make("mks_sim/Grasp-v0", **kw)] * 2)
    else:  # spawn: forking a process that holds EGL contexts is unsafe
        venv = gym.make_vec("mks_sim/Grasp-v1", num_envs=2, vectorization_mode="async",
                            vector_kwargs={"context": "spawn"}, **kw)  # fmt: skip
    try:
        obs, _ = venv.reset(seed=[1, 2])
        assert obs["pinch_pos"].shape == (2, 3)
        obs, rew, term, trunc, _ = venv.step(venv.action_space.sample())
        assert rew.shape == (2,) and term.shape == (2,)
    finally:
        venv.close()


@pytest.mark.slow
def test_scripted_policy_through_the_env_lifts() -> None:
    """The scripted grasp run through the env API (action deltas + grip) succeeds."""
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env = _make(object="sphere", max_episode_steps=150)
    try:
        obs, _ = env.reset(seed=4)
        policy = ScriptedGraspPolicy(env.unwrapped)
        for _ in range(150):
            obs, _, terminated, truncated, info = env.step(policy(obs))
            if terminated or truncated:
                break
        assert info["success"], policy.phase
    finally:
        env.close()


@pytest.mark.slow
@pytest.mark.parametrize(("obj", "seed"), [("cube", 1001), ("cube", 1009), ("part", 1002)])
def test_scripted_policy_continuous_grip_lifts(obj: str, seed: int) -> None:
    """v1: pre-shaped, gentle close then squeeze. The cube seeds failed on v0 (the open hand
    landed a fingertip on the cube and the binary grip closed at full speed)."""
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env = _make("mks_sim/Grasp-v1", object=obj, max_episode_steps=150)
    try:
        obs, _ = env.reset(seed=seed)
        policy = ScriptedGraspPolicy(env.unwrapped)
        grips = []
        for _ in range(150):
            action = policy(obs)
            grips.append(float(action[4]))
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        assert info["success"], policy.phase
        assert any(-1.0 < g < 1.0 and g != 0.0 for g in grips)  # the grip was continuous
    finally:
        env.close()


def test_v1_points_are_the_scan_of_the_last_sensing() -> None:
    env = _make("mks_sim/Grasp-v1", object="cube", n_points=64)
    try:
        assert "points" in env.observation_space.spaces  # v1 observes them by default
        obs, _ = env.reset(seed=2)
        assert obs["n_points"][0] > 0
        finder = env.unwrapped._devices["range_finder"]
        reads = []
        read = finder.read
        finder.read = lambda *a, **k: reads.append(1) or read(*a, **k)
        after = env.step(np.zeros(5, np.float32))[0]
        assert not reads  # no scan per step (v0 scans every step)
        assert np.array_equal(after["points"], obs["points"])
    finally:
        env.close()


def test_nan_action_rejected_and_env_stays_usable() -> None:
    env = _make("mks_sim/Grasp-v1", object="cube")
    try:
        env.reset(seed=0)
        d = env.unwrapped.world.data
        before = (d.qpos.copy(), d.time)
        for bad in ([np.nan, 0, 0, 0, 0], [0, 0, np.inf, 0, 0], [0, 0, 0, 0, -np.inf]):
            with pytest.raises(ValueError, match=r"action: expected finite numbers"):
                env.step(np.array(bad, np.float32))
        assert np.array_equal(d.qpos, before[0]) and d.time == before[1]  # nothing happened
        with pytest.raises(ValueError, match=r"action: expected 5 numbers"):
            env.step(np.zeros(4, np.float32))
        obs, reward, *_ = env.step(np.array([0.5, 0, -0.5, 0, 0.3], np.float32))
        assert np.isfinite(reward) and np.all(np.isfinite(obs["arm_qpos"]))
        assert d.time > before[1]
    finally:
        env.close()


def test_reset_reports_timing() -> None:
    env = _make("mks_sim/Grasp-v1", object="sphere")
    try:
        _, info = env.reset(seed=1)
        t = info["reset_timing_s"]
        assert set(t) == {"localization", "other", "total"}
        assert t["localization"] >= 0 and t["other"] >= 0
        assert t["localization"] + t["other"] == pytest.approx(t["total"])
        assert env.unwrapped.dt == pytest.approx(0.1)
    finally:
        env.close()


@pytest.mark.slow
def test_no_egl_tracebacks_at_exit_when_not_closed() -> None:
    code = textwrap.dedent(
        """
        import gymnasium as gym, numpy as np, mks_sim
        from mks_sim.sim import truth
        env = gym.make("mks_sim/Grasp-v1", object="cube", render_mode="rgb_array",
                       observe_image=True, observe_depth=True, image_size=(32, 24),
                       localize_fn=lambda w, n: truth.object_to_world(w, n))
        env.reset(seed=0)
        env.step(np.zeros(5, np.float32))
        assert env.render().shape == (120, 160, 3)
        print("ok")
        """  # and no env.close()
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
    assert "Traceback" not in out.stderr and "EGLError" not in out.stderr, out.stderr


def test_bad_arguments() -> None:
    from mks_sim.errors import MksError, NotFound

    with pytest.raises(NotFound, match="unknown object 'pyramid'; expected a model-database"):
        GraspEnv(object="pyramid")
    with pytest.raises(MksError, match="render_mode: expected None or 'rgb_array'"):
        GraspEnv(object="cube", render_mode="human")
    for size in ((0, 0), (-5, 84)):
        with pytest.raises(MksError, match=r"image_size: expected \(width, height\) > 0"):
            GraspEnvV1(object="cube", observe_image=True, image_size=size)
    with pytest.raises(MksError, match=r"image_size: expected \(width, height\) of two ints"):
        GraspEnvV1(object="cube", image_size=(84,))
    with pytest.raises(MksError, match=r"render_size: expected \(width, height\) > 0"):
        GraspEnvV1(object="cube", render_size=(0, 10))


@pytest.fixture(scope="module")
def generated_models(tmp_path_factory: pytest.TempPathFactory):
    """A wedge made by ``tests/_gen_meshes.py`` added to a fresh model folder, as
    ``mks-sim objects add`` does (no task file, not in the built-in database)."""
    from pathlib import Path

    from mks_sim.models.importer import add_object

    sys.path.insert(0, str(Path(__file__).parent))
    import _gen_meshes as gen

    folder = tmp_path_factory.mktemp("env_models")
    tm = gen.wedge()
    tm.apply_scale(1000.0)
    tm.export(folder / "wedge.stl")
    add_object(folder / "wedge.stl", "wedge", folder / "models", units="mm")
    return folder / "models"


def test_unknown_object_lists_the_database(monkeypatch: pytest.MonkeyPatch) -> None:
    from mks_sim.errors import NotFound

    monkeypatch.setenv("MKS_SIM_MODELS", "")  # restored (unset) after the test
    with pytest.raises(NotFound, match=r"unknown object 'wedge'.*cube.*part.*sphere"):
        GraspEnvV1(object="wedge")
    with pytest.raises(NotFound, match="expected a model folder"):
        GraspEnvV1(object="cube", models=("/nonexistent/models",))


@pytest.mark.slow
def test_any_database_object_with_models_folder(
    generated_models, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 10: an object added to a model folder is a task of the env (its default task:
    alone on the table, dropped); the sensor-based estimate at reset is near the truth."""
    from mks_sim.sim import truth

    monkeypatch.setenv("MKS_SIM_MODELS", "")  # the env sets it; restored (unset) after the test
    env = gym.make("mks_sim/Grasp-v1", object="wedge", models=(str(generated_models),))
    try:
        u = env.unwrapped
        assert u.object == "wedge" and u.task.object == "wedge"
        obs, info = env.reset(seed=5)
        assert obs["pose_valid"][0] == 1
        err = info["localization_error"]
        assert err["position_mm"] < 5.0 and err["rotation_deg"] < 5.0, err
        # Independently of the env's own error bookkeeping: the estimate's position against
        # the simulator's pose of the body (evaluation only).
        T = truth.object_to_world(u.world, "wedge")
        assert np.linalg.norm(obs["pose_estimate"][:3, 3] - T[:3, 3]) < 0.005
        obs, *_ = env.step(np.zeros(5, np.float32))
        assert np.isfinite(obs["arm_qpos"]).all()
        assert pickle.loads(pickle.dumps(u)).object == "wedge"  # rebuilt with its models
    finally:
        env.close()


def test_models_folder_does_not_leak_from_the_wedge_test() -> None:
    import os

    # Runs after test_any_database_object_with_models_folder (file order): its models folder
    # went into MKS_SIM_MODELS through the env and must be gone again.
    assert (
        not os.environ.get("MKS_SIM_MODELS", "").strip()
        or "env_models" not in os.environ["MKS_SIM_MODELS"]
    )


def _rotation_about(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` about unit ``axis`` (Rodrigues; independent of MuJoCo)."""
    k = np.asarray(axis, dtype=float)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _angle(R1: np.ndarray, R2: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(R1.T @ R2) - 1) / 2, -1, 1)))


@pytest.mark.slow
def test_v2_rotation_action_turns_the_hand_about_a_world_axis() -> None:
    """v2's ``(drx, dry, drz)`` turns the hand about a world axis, ``MAX_ROT_RAD`` per step at
    1: four steps of ``drx = 1`` tilt the hand 0.6 rad about world x (the arm's forward
    kinematics, read back through the simulator after it settles), the position held."""
    from mks_sim.envs.grasp_env import MAX_ROT_RAD
    from mks_sim.sim import names

    env = _make("mks_sim/Grasp-v2", object="cube")
    try:
        obs, _ = env.reset(seed=0)
        assert obs["pinch_rotation"].shape == (3, 3)
        site = env.unwrapped.world.data.site(names.PINCH_SITE)
        R0, p0 = site.xmat.reshape(3, 3).copy(), site.xpos.copy()
        assert np.allclose(obs["pinch_rotation"], R0)
        for _ in range(4):
            obs, *_ = env.step(np.array([0, 0, 0, 1, 0, 0, 0], np.float32))
        for _ in range(15):  # hold: the velocity-limited arm catches up with the target
            obs, *_ = env.step(np.zeros(7, np.float32))
        R = site.xmat.reshape(3, 3)
        expected = _rotation_about((1, 0, 0), 4 * MAX_ROT_RAD) @ R0
        assert _angle(R, expected) < 0.03, _angle(R, expected)
        assert _angle(R, R0) > 0.5  # it did turn (not the start pose within tolerance)
        assert np.linalg.norm(site.xpos - p0) < 0.01
        assert np.allclose(obs["pinch_rotation"], R)
    finally:
        env.close()


@pytest.mark.slow
def test_v2_scripted_policy_flies_a_tilted_plan() -> None:
    """Given a tilted plan (25 degrees off vertical), the v2 policy brings the hand to the
    plan's whole rotation at the pre-grasp point (simulator forward kinematics), where v1
    could only match its yaw."""
    from mks_sim.envs.scripted import ROT_TOL_RAD, ScriptedGraspPolicy
    from mks_sim.sim import names, truth
    from mks_sim.tasks.grasp import GraspPlan, down_rotation

    env = _make("mks_sim/Grasp-v2", object="cube", max_episode_steps=150)
    try:
        obs, _ = env.reset(seed=1)
        u = env.unwrapped
        cube = truth.object_to_world(u.world, "cube")[:3, 3]
        yaw = float(obs["pinch_yaw"][0]) + 0.4
        tilt = _rotation_about((np.cos(yaw), np.sin(yaw), 0.0), np.radians(25.0))
        rotation = tilt @ down_rotation(yaw)
        plan = GraspPlan(grasp_point_world=tuple(cube), yaw_rad=yaw, width_m=0.05,
                         approach_height_m=0.08, lift_height_m=0.1,
                         rotation_world=tuple(map(tuple, rotation)))  # fmt: skip
        assert plan.tilted
        policy = ScriptedGraspPolicy(u)
        policy.plan = plan
        for _ in range(60):
            obs, *_ = env.step(policy(obs))
            if policy.phase != "approach":
                break
        assert policy.phase == "descend"
        site = u.world.data.site(names.PINCH_SITE)
        assert _angle(site.xmat.reshape(3, 3), rotation) < ROT_TOL_RAD + 0.02
        assert np.linalg.norm(site.xpos - plan.pregrasp_world) < 0.01
    finally:
        env.close()


def test_v1_policy_plans_top_down_only() -> None:
    """v0/v1 cannot tilt the hand: the policy asks the synthesis for top-down grasps only."""
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env = _make("mks_sim/Grasp-v1", object="cube")
    try:
        obs, _ = env.reset(seed=0)
        policy = ScriptedGraspPolicy(env.unwrapped)
        policy(obs)
        assert policy.plan is not None and not policy.plan.tilted
        assert not policy.rotates
    finally:
        env.close()


@pytest.mark.parametrize(("env_id", "n"), [("mks_sim/Grasp-v1", 5), ("mks_sim/Grasp-v2", 7)])
def test_policy_waits_with_an_action_of_the_envs_length(env_id: str, n: int) -> None:
    """No valid estimate yet: the policy holds still, hand open, in the env's action shape."""
    from mks_sim.envs.scripted import ScriptedGraspPolicy

    env = _make(env_id, object="cube")
    try:
        obs, _ = env.reset(seed=0)
        obs["pose_valid"] = np.zeros(1, np.int8)
        action = ScriptedGraspPolicy(env.unwrapped)(obs)
        assert action.shape == env.action_space.shape == (n,)
        assert action[-1] == -1.0 and not action[:-1].any()
        env.step(action)
    finally:
        env.close()


def test_clearance_is_the_lowest_point_every_step() -> None:
    """The env recomputes the object's lowest point only when the body moved: on every
    step the reported clearance equals a fresh computation (simulator ground truth)."""
    from mks_sim.sim import names
    from mks_sim.tasks.evaluate import lowest_point_z

    env = _make("mks_sim/Grasp-v2", object="part")
    try:
        env.reset(seed=0)
        u = env.unwrapped
        rng = np.random.default_rng(0)
        for _ in range(25):
            *_, info = env.step(rng.uniform(-1, 1, 7).astype(np.float32))
            fresh = lowest_point_z(u.world.model, u.world.data, "part") - names.TABLE_TOP_Z
            assert info["clearance_m"] == fresh
    finally:
        env.close()
