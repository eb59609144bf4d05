"""The simulated workstation: a compiled scene with its dm_control Physics.

Example:
    >>> from mks_sim.sim.world import build_world
    >>> world = build_world("scene2", seed=0)
    >>> world.step(100)
    >>> world.data.body("cube").xpos  # doctest: +SKIP
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import mujoco
import numpy as np
from dm_control import mjcf
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from mks_sim.errors import DataError, MksError, NotFound, SpecError
from mks_sim.sim import names
from mks_sim.sim.robot import Robot
from mks_sim.sim.scenes import SceneSpec, build_scene, default_scene

log = logging.getLogger(__name__)

# Arm home pose: pinch site at (0, 0.24, 1.12) m (37 cm above the table, behind the region),
# fingers down, out of the overhead view (found with dm_control IK on the pinch site).
HOME_ARM_QPOS = (-1.107, 2.788, 1.171, 3.725, -1.846, 4.189)
HOME_FINGER_QPOS = (0.2, 0.2, 0.2)
SETTLE_STEPS = 250  # 0.5 s at 2 ms: objects dropped from their resting height come to rest
# Objects dropped from a random orientation tumble onto a stable face: 1.5 s more.
DROP_SETTLE_STEPS = 750
DROP_CLEARANCE_M = 0.003  # lowest point of a dropped object above the support at release
DROP_DAMPING_TAU_S = 0.05  # rotational damping time constant while a dropped object settles
# After the fixed settle, dropped objects (a pile) are stepped on until at rest: every one
# slower than REST_SPEED_M_S and REST_SPIN_RAD_S for REST_CALM_STEPS steps in a row, at most
# REST_MAX_STEPS (a bin of six parts leaning on each other kept moving 4-78 mm over 4 s after
# the fixed 2 s; docs/bin.md "A pile at rest").
REST_SPEED_M_S = 5e-4
REST_SPIN_RAD_S = 5e-3
REST_CALM_STEPS = 100
REST_MAX_STEPS = 5000
_MIN_GAP_M = 0.012  # clearance between footprints of randomly placed objects
_MAX_TRIES = 100  # per object, before the whole layout restarts
_MAX_LAYOUTS = 200
# Sleeping (MuJoCo's mjENBL_SLEEP; opt-in, ``sleep=True``; docs/env.md "Speed"): a body tree
# whose velocities stay below SLEEP_TOLERANCE (m/s, rad/s) for 10 steps is no longer simulated
# nor collided until an awake body touches it or its pose is set; the actuated robot never
# sleeps. Sleeping bodies keep their poses: cameras and the range finder still see them.
SLEEP_TOLERANCE = 1e-3


class World:
    """A compiled scene: MuJoCo model/data, the dm_control Physics and the object specs.

    Attributes:
        scene: the scene spec (MJCF root, robot entities, object specs).
        physics: dm_control ``mjcf.Physics`` (for ``physics.bind`` and dm_control IK).
        model: the raw ``mujoco.MjModel`` (``physics.model.ptr``).
        data: the raw ``mujoco.MjData`` (``physics.data.ptr``).
        robot: the Jaco arm and hand entities.
        sleep: whether resting bodies may sleep (``SLEEP_TOLERANCE``).

    Args:
        scene: the scene to compile.
        sleep: let resting bodies sleep (MuJoCo's ``mjENBL_SLEEP``): resting clutter then
            costs nothing per step. Off by default: it changes the contact solution (the
            grasp success rates were measured without it; docs/env.md "Speed").
    """

    def __init__(self, scene: SceneSpec, *, sleep: bool = False) -> None:
        self.scene = scene
        self.sleep = bool(sleep)
        self.rest_steps = 0  # steps the last randomize ran until a dropped pile was at rest
        if self.sleep:
            # In the MJCF, before compiling: the flag set on the compiled model instead broke
            # the IK's scratch MjData (measured).
            scene.root.option.flag.sleep = "enable"
            scene.root.option.sleep_tolerance = SLEEP_TOLERANCE
        self.physics = mjcf.Physics.from_mjcf_model(scene.root)
        self.model: mujoco.MjModel = self.physics.model.ptr
        self.data: mujoco.MjData = self.physics.data.ptr
        self.robot: Robot = scene.robot
        self._set_home()
        mujoco.mj_forward(self.model, self.data)
        self._initial = self._snapshot()

    # --- state -----------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """The scene name."""
        return self.scene.name

    @property
    def object_names(self) -> tuple[str, ...]:
        """Bodies of the movable objects, in placement order."""
        return tuple(spec.name for spec in self.scene.objects)

    def _snapshot(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        d = self.data
        return d.qpos.copy(), d.qvel.copy(), d.ctrl.copy(), d.act.copy()

    def mark_initial(self) -> None:
        """Make the current state the one ``reset()`` restores."""
        self._initial = self._snapshot()

    def reset(self) -> None:
        """Restore the initial state (as built, after the seeded randomisation if any)."""
        mujoco.mj_resetData(self.model, self.data)
        qpos, qvel, ctrl, act = self._initial
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        self.data.ctrl[:] = ctrl
        self.data.act[:] = act
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance the simulation ``n`` steps of ``model.opt.timestep`` seconds."""
        if n < 0:
            raise MksError(f"step count must be >= 0, got {n}")
        if n:
            mujoco.mj_step(self.model, self.data, nstep=n)

    def forward(self) -> None:
        """Recompute derived quantities (positions, contacts, sensors) without stepping."""
        mujoco.mj_forward(self.model, self.data)

    def _set_home(self) -> None:
        for joint, q in zip(names.ARM_JOINTS, HOME_ARM_QPOS, strict=True):
            self.data.joint(joint).qpos[0] = q
        for joint, q in zip(names.FINGER_JOINTS, HOME_FINGER_QPOS, strict=True):
            self.data.joint(joint).qpos[0] = q
        self.data.qvel[:] = 0.0
        self.data.ctrl[:] = 0.0

    # --- objects ---------------------------------------------------------------------------
    def _joint_of(self, name: str) -> mujoco._structs._MjDataJointViews:
        try:
            return self.data.joint(names.free_joint(name))
        except KeyError:
            raise NotFound(
                f"no movable object {name!r} in scene {self.name!r}; expected one of "
                f"{list(self.object_names)}"
            ) from None

    def set_object_pose(self, name: str, object_to_world: ArrayLike) -> None:
        """Place object ``name`` (body frame) at the 4x4 pose ``object_to_world``, at rest.

        Raises:
            NotFound: no such movable object.
            DataError: the matrix is not a finite 4x4 rigid transform.
        """
        T = np.asarray(object_to_world, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise DataError(f"object_to_world for {name!r}: expected finite (4, 4), got {T.shape}")
        R = T[:3, :3]
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise DataError(f"object_to_world for {name!r}: rotation block is not a rotation")
        joint = self._joint_of(name)
        x, y, z, w = Rotation.from_matrix(R).as_quat()
        joint.qpos[:3] = T[:3, 3]
        joint.qpos[3:] = (w, x, y, z)
        joint.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def randomize(self, rng: np.random.Generator, settle_steps: int = SETTLE_STEPS) -> None:
        """Place the objects at random non-overlapping resting poses in the object region.

        Each free-standing object gets a uniform position (footprint inside the region, or
        the scene file's x, y ranges) and a uniform yaw; an object placed with ``pose =
        "drop"`` also gets a uniform random orientation and is released just above the
        support, then settles (``DROP_SETTLE_STEPS`` more) onto whichever stable face it
        falls on. Stacked objects (scene 2's sphere) sit on their support with a small random
        offset. The arm goes home, then the world settles ``settle_steps`` steps; dropped
        objects are then stepped on until at rest (:meth:`settle_until_rest`, steps in
        ``rest_steps``), and all velocities are zeroed.

        Raises:
            MksError: no non-overlapping placement found.
        """
        scene = self.scene
        self.rest_steps = 0
        self._set_home()
        specs = {s.name: s for s in scene.objects}
        placed = self._sample_layout(rng)
        dropped: list[str] = []
        for name, (xy, yaw) in placed.items():
            spec = specs[name]
            placement = scene.placements.get(name)
            if placement is not None and placement.pose == "drop":
                # Footprints that overlap (a pile, gap_m < 0): released above the objects
                # already dropped under it, so that nothing starts interpenetrating.
                floor = scene.support_z
                for other in dropped:
                    oxy, r = placed[other][0], specs[other].reach_m
                    if np.hypot(xy[0] - oxy[0], xy[1] - oxy[1]) < r + spec.reach_m:
                        floor = max(floor, self._top_z(other) + DROP_CLEARANCE_M)
                self._drop(name, xy, yaw, rng, floor)
                dropped.append(name)
                continue
            self._place(name, xy, yaw, scene.support_z + spec.rest_height_m, spec.rest_quat)
        for top, bottom in scene.stacked:
            b = specs[bottom]
            t = specs[top]
            offset = rng.uniform(-0.003, 0.003, size=2)
            bx, by = placed[bottom][0]
            z = scene.support_z + 2 * b.rest_height_m + t.rest_height_m
            self._place(
                top, (bx + offset[0], by + offset[1]), rng.uniform(-np.pi, np.pi), z, t.rest_quat
            )
        mujoco.mj_forward(self.model, self.data)
        if dropped:
            self._settle_damped(dropped)
        self.settle(settle_steps)
        if dropped:
            self.rest_steps = self.settle_until_rest(dropped)

    def settle_until_rest(self, bodies: Sequence[str], max_steps: int = REST_MAX_STEPS) -> int:
        """Step with zero controls until every body of ``bodies`` has stayed slower than
        ``REST_SPEED_M_S`` / ``REST_SPIN_RAD_S`` for ``REST_CALM_STEPS`` steps (or
        ``max_steps`` have run), then zero all velocities; returns the steps run."""
        m = self.model
        adr = [int(m.joint(names.free_joint(b)).dofadr[0]) for b in bodies]
        lin = np.concatenate([np.arange(a, a + 3) for a in adr])
        ang = np.concatenate([np.arange(a + 3, a + 6) for a in adr])
        self.data.ctrl[:] = 0.0
        calm = steps = 0
        chunk = 20
        while steps < max_steps and calm < REST_CALM_STEPS:
            self.step(chunk)
            steps += chunk
            v = self.data.qvel
            still = (
                np.max(np.linalg.norm(v[lin].reshape(-1, 3), axis=1)) < REST_SPEED_M_S
                and np.max(np.linalg.norm(v[ang].reshape(-1, 3), axis=1)) < REST_SPIN_RAD_S
            )
            calm = calm + chunk if still else 0
        if calm < REST_CALM_STEPS:
            log.info("scene %r: objects still moving after %d more settle steps", self.name, steps)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)
        return steps

    def _settle_damped(self, bodies: list[str]) -> None:
        """Let dropped objects topple onto a stable face with their rotation damped.

        A light object released on an edge topples fast and, with MuJoCo's soft contacts,
        can keep tumbling off the table; damping the rotational degrees of freedom (time
        constant ``DROP_DAMPING_TAU_S``) makes the fall quasi-static. The damping is removed
        afterwards.
        """
        m = self.model
        saved = m.dof_damping.copy()
        for name in bodies:
            j = m.joint(names.free_joint(name))
            b = m.body(name).id
            adr = int(j.dofadr[0])
            m.dof_damping[adr + 3 : adr + 6] = float(np.max(m.body_inertia[b])) / DROP_DAMPING_TAU_S
        try:
            self.settle(DROP_SETTLE_STEPS)
        finally:
            m.dof_damping[:] = saved

    def _top_z(self, name: str) -> float:
        """World z of the highest hull vertex of object ``name`` at its current pose."""
        spec = next(s for s in self.scene.objects if s.name == name)
        body = self.data.body(name)
        if spec.hull is None:
            return float(body.xpos[2] + spec.reach_m)
        return float(np.max(spec.hull @ body.xmat.reshape(3, 3)[2] + body.xpos[2]))

    def _drop(
        self,
        name: str,
        xy: tuple[float, float],
        yaw: float,
        rng: np.random.Generator,
        floor_z: float | None = None,
    ) -> None:
        """Release ``name`` at ``xy`` in a uniform random orientation, just above the support
        (or above ``floor_z``)."""
        from mks_sim.geometry.transforms import random_rotation

        spec = next(s for s in self.scene.objects if s.name == name)
        R = Rotation.from_euler("z", yaw).as_matrix() @ random_rotation(rng)
        hull = spec.hull if spec.hull is not None else np.zeros((1, 3))
        lowest = float(np.min((hull @ R.T)[:, 2]))
        T = np.eye(4)
        T[:3, :3] = R
        base = self.scene.support_z if floor_z is None else floor_z
        T[:3, 3] = (xy[0], xy[1], base - lowest + DROP_CLEARANCE_M)
        self.set_object_pose(name, T)

    def _sample_layout(
        self, rng: np.random.Generator
    ) -> dict[str, tuple[tuple[float, float], float]]:
        """Non-overlapping (xy, yaw) of the free-standing objects, by rejection sampling.

        A layout that paints itself into a corner is restarted as a whole (deterministic
        given ``rng``).
        """
        scene = self.scene
        tops = {top for top, _ in scene.stacked}
        cx, cy = scene.region_center_xy
        hx, hy = scene.region_half_xy
        specs = [s for s in scene.objects if s.name not in tops]
        for _ in range(_MAX_LAYOUTS):
            placed: dict[str, tuple[tuple[float, float], float]] = {}
            radius: dict[str, float] = {}
            for spec in specs:
                pl = scene.placements.get(spec.name)
                drop = pl is not None and pl.pose == "drop"
                r = spec.reach_m if drop else spec.footprint_radius_m
                (x0, x1) = pl.x if pl is not None and pl.x is not None else (cx - hx, cx + hx)
                (y0, y1) = pl.y if pl is not None and pl.y is not None else (cy - hy, cy + hy)
                yaw0, yaw1 = pl.yaw if pl is not None else (-np.pi, np.pi)
                gap = _MIN_GAP_M if pl is None or pl.gap_m is None else pl.gap_m
                for _ in range(_MAX_TRIES):
                    xy = (
                        float(rng.uniform(x0 + r, max(x0 + r, x1 - r))),
                        float(rng.uniform(y0 + r, max(y0 + r, y1 - r))),
                    )
                    if all(
                        np.hypot(xy[0] - p[0], xy[1] - p[1]) > r + radius[o] + gap
                        for o, (p, _) in placed.items()
                    ):
                        break
                else:
                    break  # restart the layout
                placed[spec.name] = (xy, float(rng.uniform(yaw0, yaw1)))
                radius[spec.name] = r
            if len(placed) == len(specs):
                return placed
        raise MksError(
            f"scene {self.name!r}: no non-overlapping layout in region "
            f"{scene.region_half_xy} m after {_MAX_LAYOUTS} attempts; enlarge the region"
        )

    def settle(self, steps: int = SETTLE_STEPS) -> None:
        """Step ``steps`` times with zero controls, then zero all velocities."""
        self.data.ctrl[:] = 0.0
        self.step(steps)
        self.data.qvel[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def _place(
        self,
        name: str,
        xy: tuple[float, float],
        yaw: float,
        z: float,
        rest_quat: tuple[float, float, float, float],
    ) -> None:
        w, x, y, zq = rest_quat
        rest = Rotation.from_quat([x, y, zq, w])
        R = (Rotation.from_euler("z", yaw) * rest).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = (xy[0], xy[1], z)
        self.set_object_pose(name, T)


def build_world(
    scene: str | Path | None = None,
    seed: int | None = None,
    *,
    objects: Sequence[str] = (),
    models: Sequence[str | Path] = (),
    sleep: bool = False,
) -> World:
    """Compile a scene; with a ``seed``, randomise the object poses from it.

    Args:
        scene: a scene name (``worlds/<name>.toml``) or a scene file; None with ``objects``:
            the default scene (those database objects alone on the table, dropped from
            random orientations).
        seed: randomise the layout from this seed; without one the objects keep the
            scene's default layout (settled).
        objects: database object names for the default scene.
        models: extra model folders (``--models DIR``).
        sleep: let resting bodies sleep (:class:`World`).

    Raises:
        NotFound: unknown scene or object name.
        SpecError: neither a scene nor objects, or a malformed scene file.
    """
    if scene is None:
        if not objects:
            raise SpecError("build_world: expected a scene name/file or objects=[...], got neither")
        spec = default_scene(list(objects), models=models)
    else:
        spec = build_scene(scene, models=models)
    world = World(spec, sleep=sleep)
    if seed is not None:
        world.randomize(np.random.default_rng(seed))
    else:
        world.settle(SETTLE_STEPS)
    world.mark_initial()
    return world
