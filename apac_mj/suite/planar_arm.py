"""The ``planar_arm`` domain: the paper's two-link arm as a dm_control domain.

``Physics`` offers the arm's geometry in the paper's units (cm, degrees);
``Reach`` is the target-reaching task, parameterized by a
:class:`~apac_mj.suite.task_spec.TaskSpec` read from ``tasks/``.
"""
from __future__ import annotations

import collections
import math

import mujoco
import numpy as np
from dm_control.mujoco import engine
from dm_control.rl import control
from dm_control.suite import base
from dm_env import specs

from apac_mj.config import ACTUATIONS  # noqa: F401 (re-exported: declared once, in config)
from apac_mj.util import paths
from apac_mj.kinematics import motion_function
from apac_mj.suite.plant import (_SITE, FORCE_UNIT, INERTIA_UNIT, LENGTH_UNIT, TORQUE_UNIT,  # noqa: F401 (re-exported)
                                  Plant, PlantSpec, check_field, curl_force)
from apac_mj.suite import deliberation
from apac_mj.suite.task_spec import START_ANGLES, TaskSpec  # noqa: F401  (START_ANGLES: re-exported)
from apac_mj.suite.signals import Senses, check_actuation, motor_command
from apac_mj.suite.trials import TrialRunner, trial_key

#: Physics sub-steps per environment step under servo actuation. With the
#: servo gains in the MJCF (kp = 1e4, kv = 200, rotor armature 1, 10 ms
#: sub-steps) a 180 deg move on both joints is within ~0.01 deg after 20
#: sub-steps, ~1e-4 deg after 30 and ~1e-6 deg after 40 (tests/test_suite.py
#: checks < 0.01 deg at several link lengths).
N_SUB_STEPS = 40
#: Physics sub-steps per step under kinematic actuation: the angles are
#: written exactly and the servos hold them, so one sub-step is enough.
KINEMATIC_SUB_STEPS = 1
#: Joint range of both hinges in the MJCF, degrees (the default of ``TaskSpec.joint_range``).
JOINT_RANGE = (0.0, 180.0)
#: Bound of each action component (change of a joint angle), degrees.
ACTION_BOUND = 180.0


class _Ids:
    """Indices of the named model elements, resolved once per model.

    The hot paths (observation, reward, servo setpoints) index MuJoCo's arrays
    with these integers instead of dm_control's named indexing, which costs a
    dictionary lookup and a fancy-index copy per access.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        def idx(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                raise KeyError(f"the arm model has no {kind.name} named {name!r}")
            return i

        site, body, geom, joint, act = (mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtObj.mjOBJ_BODY, mujoco.mjtObj.mjOBJ_GEOM,
                                        mujoco.mjtObj.mjOBJ_JOINT, mujoco.mjtObj.mjOBJ_ACTUATOR)
        self.end_site = idx(site, "end_effector")
        self.elbow_site = idx(site, "elbow")
        self.target_site = idx(site, "target")
        self.zone_site = idx(site, "target_zone")
        self.upper_body = idx(body, "upper_arm")
        self.fore_body = idx(body, "forearm")
        self.upper_geom = idx(geom, "upper_arm")
        self.fore_geom = idx(geom, "forearm")
        joints = [idx(joint, "shoulder"), idx(joint, "elbow")]
        self.joints = np.array(joints)
        self.qpos = np.array([model.jnt_qposadr[j] for j in joints])
        self.qvel = np.array([model.jnt_dofadr[j] for j in joints])
        self.ctrl = np.array([idx(act, "shoulder_servo"), idx(act, "elbow_servo")])


class Physics(engine.Physics):
    """The arm's MuJoCo physics with the paper's named geometric queries (cm, degrees).

    The queries read MuJoCo's raw ``MjModel``/``MjData`` arrays through element
    indices resolved once per (re)load (:class:`_Ids`): dm_control's named
    indexing costs more than the physics itself at this model's size. A task
    with a ``[plant]`` table gives it a :class:`~apac_mj.suite.plant.Plant`
    (:meth:`set_plant`), which holds the dynamics.
    """

    # Plane bounds and the joints' range (degrees), set by the task that owns this physics.
    plane_size: tuple[float, float] = (30.0, 30.0)
    joint_range: tuple[float, float] = JOINT_RANGE
    #: The arm's dynamics (:meth:`set_plant`: masses, gravity, hand load, force field; :mod:`apac_mj.suite.plant`);
    #: None: the paper's ideal arm as the MJCF has it.
    dynamics: Plant | None = None
    #: Called with this physics after every sub-step (a task's feedback delays record what is observed:
    #: :class:`~apac_mj.suite.signals.Senses`); None: :meth:`step` runs its sub-steps in one call.
    sub_step_hook = None

    def _reload_from_data(self, data) -> None:
        # Set before the base class runs after_reset(), and again on every copy/reload.
        self._m, self._d = data.model.ptr, data.ptr
        self.ids = _Ids(self._m)
        if self.dynamics is not None:
            self.dynamics.bind(self._m, self._d, self.ids)
        super()._reload_from_data(data)

    @property
    def plant(self) -> PlantSpec | None:
        """The arm's dynamics as data (the task's ``[plant]`` table); None: the paper's ideal arm."""
        return None if self.dynamics is None else self.dynamics.spec

    @property
    def load(self) -> float:
        """The point load in the hand now (kg; 0 for the ideal arm)."""
        return 0.0 if self.dynamics is None else self.dynamics.load

    @property
    def field_b(self) -> float:
        """The curl field's b now (N·s/m; 0: off, and always for the ideal arm)."""
        return 0.0 if self.dynamics is None else self.dynamics.field_b

    def end_effector(self) -> np.ndarray:
        return self._d.site_xpos[self.ids.end_site, :2].copy()

    def elbow(self) -> np.ndarray:
        return self._d.site_xpos[self.ids.elbow_site, :2].copy()

    def target(self) -> np.ndarray:
        return self._m.site_pos[self.ids.target_site, :2].copy()

    def origin(self) -> np.ndarray:
        return self._m.body_pos[self.ids.upper_body, :2].copy()

    def set_origin(self, xy) -> None:
        """Move the shoulder to ``xy`` (cm) on the plane."""
        self._m.body_pos[self.ids.upper_body, :2] = check_target(xy, self.plane_size)
        self.forward()

    def distance_to_target(self) -> float:
        end = self._d.site_xpos[self.ids.end_site]
        target = self._m.site_pos[self.ids.target_site]
        return math.hypot(end[0] - target[0], end[1] - target[1])

    def joint_angles(self) -> np.ndarray:
        """(shoulder, elbow) in degrees."""
        return self._d.qpos[self.ids.qpos] * (180.0 / np.pi)

    def link_lengths(self) -> np.ndarray:
        """(l1, l2) in cm: shoulder->elbow and elbow->end-effector."""
        ids = self.ids
        return np.array([self._m.body_pos[ids.fore_body, 0], self._m.site_pos[ids.end_site, 0]])

    def set_joint_angles(self, alpha_deg: float, beta_deg: float) -> None:
        """Place the arm at these angles, at rest, with the servos holding them."""
        lo, hi = self.joint_range
        for name, value in (("shoulder", alpha_deg), ("elbow", beta_deg)):
            if not math.isfinite(value) or not lo <= value <= hi:
                raise ValueError(f"{name} angle must be finite and within the joint range [{lo}, {hi}] degrees, "
                                 f"got {value!r}")
        self.write_joint_angles(np.array([alpha_deg, beta_deg], dtype=np.float64))

    def write_joint_angles(self, angles_deg: np.ndarray) -> None:
        """:meth:`set_joint_angles` without the checks, for angles already clipped to the range."""
        q = angles_deg * (np.pi / 180.0)
        ids = self.ids
        self._d.qpos[ids.qpos] = q
        self._d.qvel[ids.qvel] = 0.0
        self._d.ctrl[ids.ctrl] = 0.0 if self.plant is not None and self.plant.actuation == "torque" else q
        mujoco.mj_forward(self._m, self._d)  # positions only: no step, so no instability to check

    def set_joint_limits(self, limited: bool, joint_range: tuple[float, float] = JOINT_RANGE) -> None:
        """Turn MuJoCo's joint-limit constraint of both hinges on or off, at ``joint_range`` (degrees;
        the MJCF's compiled [0, 180] is kept as it is for the default)."""
        self.joint_range = tuple(joint_range)
        self._m.jnt_limited[self.ids.joints] = 1 if limited else 0
        if self.joint_range != JOINT_RANGE:
            self._m.jnt_range[self.ids.joints] = np.deg2rad(np.asarray(self.joint_range, dtype=np.float64))

    def set_torques(self, torques_nm) -> None:
        """Command these (shoulder, elbow) joint torques in N·m (torque actuation)."""
        self._d.ctrl[self.ids.ctrl] = np.asarray(torques_nm, dtype=np.float64)

    def set_servo_setpoint(self, angles_deg) -> None:
        """Command the position servos to these (shoulder, elbow) angles in degrees."""
        self._d.ctrl[self.ids.ctrl] = np.asarray(angles_deg, dtype=np.float64) * (np.pi / 180.0)

    def set_link_lengths(self, l1: float, l2: float) -> None:
        """Change both link lengths in place (no recompilation).

        Moves the elbow body and the end-effector site and stretches both
        capsules (position, half-length and bounding volumes) and moves each
        link's centre of mass to its middle: MuJoCo places a geom that shares
        its body's inertial frame (``geom_sameframe``) at the body's centre of
        mass, so the rendered capsules follow ``body_ipos``. Afterwards the
        sites, the rendered arm and :func:`motion_function` agree. Masses and
        rotational inertias are left alone: the servos' rotor armature (1)
        dominates them (< 0.01).
        """
        check_link_lengths(l1, l2)
        m, ids = self._m, self.ids
        m.body_pos[ids.fore_body] = [l1, 0.0, 0.0]
        m.site_pos[ids.end_site] = [l2, 0.0, 0.0]
        for body, geom, length in ((ids.upper_body, ids.upper_geom, l1), (ids.fore_body, ids.fore_geom, l2)):
            radius = m.geom_size[geom, 0]
            m.body_ipos[body] = [length / 2.0, 0.0, 0.0]
            m.geom_pos[geom] = [length / 2.0, 0.0, 0.0]
            m.geom_size[geom, 1] = length / 2.0
            m.geom_rbound[geom] = length / 2.0 + radius
            m.geom_aabb[geom, 5] = length / 2.0 + radius
        if self.dynamics is not None:
            self.dynamics.apply_masses()
        self.forward()

    # -- dynamics (apac_mj.suite.plant.Plant): none of this runs for the paper's ideal arm ------------------------
    def set_plant(self, plant: PlantSpec) -> None:
        """Give the arm ``plant``'s dynamics (compliant or torque actuation, masses, damping, gravity): a
        :class:`~apac_mj.suite.plant.Plant` that edits the compiled model in place (:meth:`Plant.apply`) and
        acts every step. The ideal plant needs none of it (the MJCF is that plant)."""
        self.dynamics = Plant(plant, self._m, self._d, self.ids)
        self.dynamics.apply()

    def set_load(self, kg: float) -> None:
        """Hold a point load of ``kg`` in the hand (dynamic plants); call between episodes."""
        if self.dynamics is None:
            raise ValueError("a hand load needs a plant with dynamics (set_plant)")
        self.dynamics.set_load(kg)

    def set_field(self, b: float) -> None:
        """Curl field F = B v, B = [[0, b], [-b, 0]] (N·s/m) at the hand from the next sub-step; 0: off."""
        if self.dynamics is not None:
            self.dynamics.set_field(b)
            return
        check_field(b)
        if b != 0.0:
            raise ValueError("a force field needs a plant with dynamics (set_plant)")
        self._d.xfrc_applied[self.ids.fore_body] = 0.0

    def step(self, nstep: int = 1) -> None:
        """dm_control's step; with a force field on, the plant's (:meth:`Plant.step`): the field's force set
        before every sub-step from the hand's velocity then. With a :attr:`sub_step_hook`, one sub-step at a
        time (the same MuJoCo calls in the same order), the hook after each."""
        if self.sub_step_hook is not None:
            for _ in range(nstep):
                self._step(1)
                self.sub_step_hook(self)
            return
        self._step(nstep)

    def _step(self, nstep: int) -> None:
        if self.field_b == 0.0 and (self.dynamics is None or self.dynamics.trial is None):
            return super().step(nstep)
        with self.check_invalid_state():
            self.dynamics.step(nstep)

    def _apply_field(self) -> None:
        """The field's force on the arm now (:meth:`Plant.apply_field`; it runs every sub-step)."""
        self.dynamics.apply_field()

    def hand_velocity(self) -> np.ndarray:
        """The hand's (x, y) velocity in cm/s."""
        res = np.zeros(6)
        mujoco.mj_objectVelocity(self._m, self._d, _SITE, self.ids.end_site, res, 0)
        return res[3:5]

    def field_force_model(self) -> np.ndarray:
        """The field's force at the hand now, (x, y) in MuJoCo's units (kg·cm/s^2): F = B v."""
        v = self.hand_velocity()
        return curl_force(0.0, v) if self.dynamics is None else self.dynamics.field_force(v)

    def field_force(self) -> np.ndarray:
        """The curl field's force at the hand now, (x, y) in N (zeros when off)."""
        if self.field_b == 0.0:
            return np.zeros(2)
        return self.field_force_model() / FORCE_UNIT

    def joint_velocities(self) -> np.ndarray:
        """(shoulder, elbow) angular velocities in deg/s."""
        return self._d.qvel[self.ids.qvel] * (180.0 / np.pi)

    def servo_setpoint(self) -> np.ndarray:
        """The servos' commanded (shoulder, elbow) angles in degrees (torque actuation: the torques, N·m)."""
        ctrl = self._d.ctrl[self.ids.ctrl]
        if self.plant is not None and self.plant.actuation == "torque":
            return ctrl.copy()
        return ctrl * (180.0 / np.pi)

    def energy(self) -> tuple[float, float]:
        """(potential, kinetic) energy in J, as MuJoCo computes it (dynamic plants: mjENBL_ENERGY is on)."""
        mujoco.mj_energyPos(self._m, self._d)
        mujoco.mj_energyVel(self._m, self._d)
        return float(self._d.energy[0] / TORQUE_UNIT), float(self._d.energy[1] / TORQUE_UNIT)

    def set_target(self, xy) -> None:
        """Move the target (and its zone) to ``xy``, which must lie on the plane."""
        xy = check_target(xy, self.plane_size)
        ids = self.ids
        self._m.site_pos[ids.target_site, :2] = xy
        self._m.site_pos[ids.zone_site, :2] = xy

    def set_zone_radius(self, radius: float) -> None:
        self._m.site_size[self.ids.zone_site, 0] = radius


def check_link_lengths(l1: float, l2: float) -> None:
    """Raise ValueError unless both lengths are positive finite real numbers."""
    for name, value in (("l1", l1), ("l2", l2)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                or not math.isfinite(value) or value <= 0:
            raise ValueError(f"link length {name} must be a positive finite number (cm), got {value!r}")


def check_target(xy, plane_size: tuple[float, float]) -> np.ndarray:
    """``xy`` as a float (2,) array; raises ValueError unless it is a finite point on the plane."""
    xy = np.asarray(xy, dtype=np.float64)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise ValueError(f"target must be a finite (x, y) pair, got {xy!r}")
    w, h = plane_size
    if not (0.0 <= xy[0] <= w and 0.0 <= xy[1] <= h):
        raise ValueError(f"target {xy.tolist()} lies outside the {w} x {h} plane")
    return xy


class ScaledArray(specs.Array):
    """An unbounded dm_env array spec that also carries ``scale``: the magnitude the agent's networks read as 1
    (``layout.Sizes.from_specs``). A bound would be wrong: dm_env checks observations against it, and the arm
    may move faster than its velocity scale."""

    __slots__ = ("_scale",)

    def __init__(self, shape, dtype, scale: float, name: str | None = None) -> None:
        super().__init__(shape, dtype, name)
        self._scale = float(scale)

    @property
    def scale(self) -> float:
        return self._scale

    def __repr__(self) -> str:
        return f"ScaledArray(shape={self.shape}, dtype={self.dtype}, scale={self._scale}, name={self.name!r})"

    def __reduce__(self):
        return ScaledArray, (self._shape, self._dtype, self._scale, self._name)


class Reach(base.Task):
    """Reach the target: reward = -distance, terminal inside the target zone (:meth:`reached`; a task with a
    stop criterion, ``TaskSpec.stop_speed``: inside the zone and slower than ``stop_speed``).

    Observations (the paper's 6-vector state plus a vision flag):
    ``end_effector`` (2), ``elbow`` (2), ``target`` (2) in cm and ``vision``
    (1: seen, 0: withheld). Under occluded vision everything is seen at the
    first step only; afterwards the positions read zero and ``vision`` is 0,
    so nothing of the true state leaks. Under noisy vision every observation
    (the reset one included) adds independent N(0, ``vision_noise_std``^2)
    noise to each position coordinate; under intermittent vision the first
    step is seen and each later one with probability
    ``vision_seen_probability``, an unseen step reading like an occluded one
    (plus the noise, if any, on the seen ones). The draws come from the task's
    own ``random`` (seeded, checkpointed by :meth:`get_state`), once per step
    (:meth:`initialize_episode`, :meth:`after_step`), so repeated
    :meth:`get_observation` calls within a step agree; perfect and occluded
    vision draw nothing. Only the observations are corrupted: reward
    (minus the true distance) and termination (the true hand inside the zone)
    stay the environment's true ones.
    """

    def __init__(self, spec: TaskSpec, actuation: str = "servo", random=None) -> None:
        if actuation not in ACTUATIONS:
            raise ValueError(f"actuation must be one of {ACTUATIONS}, got {actuation!r}")
        super().__init__(random=random)
        self.spec = spec
        self.actuation = actuation
        #: Index of the current episode, 0-based (-1 before the first reset).
        self.episode = -1
        #: Action steps taken in the current episode.
        self.step_count = 0
        self._lengths = np.array(spec.link_lengths, dtype=np.float64)
        self._static_target: np.ndarray | None = None
        self._target_override: np.ndarray | None = None
        #: This step's view: seen or not, and the noise on the 6 seen coordinates (None: none).
        self._seen = True
        self._noise: np.ndarray | None = None
        #: A cued task's cue this episode (-1: none yet, or not a cued task).
        self.cue = -1
        self._cue_override: int | None = None
        self._mapping_override: bool | None = None
        #: The ``[signals]`` table's delays and sensory noise (None: no table, or all of it zero: today's task).
        self.senses = Senses(spec.signals, spec.plant) if spec.signals is not None and spec.signals.active else None
        #: The ``[trials]`` table at run time (:class:`~apac_mj.suite.trials.TrialRunner`; None: no table).
        self.trials = None if spec.trials is None else TrialRunner(spec.trials, trial_key(self.random))

    # -- run-time controls ----------------------------------------------------
    def set_cue_override(self, cue: int | None) -> None:
        """Show cue ``cue`` in the following episodes (None: draw one each episode); a cued task only."""
        cues = self._cues("a cue override")
        if cue is not None and (isinstance(cue, bool) or not isinstance(cue, (int, np.integer)) or not 0 <= cue < cues.n):
            raise ValueError(f"cue must be an integer in 0..{cues.n - 1}, got {cue!r}")
        self._cue_override = None if cue is None else int(cue)

    def set_mapping_override(self, remapped: bool | None) -> None:
        """Use the original (False) or the swapped (True) cue mapping in the following episodes (None: the task's
        schedule, ``[cues] remap_episode``); a cued task only."""
        self._cues("a mapping override")
        self._mapping_override = None if remapped is None else bool(remapped)

    def _cues(self, what: str):
        if self.spec.cues is None:
            raise ValueError(f"{what} needs a cued task ([cues] in the task file); task {self.spec.name!r} has none")
        return self.spec.cues

    def remapped(self) -> bool:
        """The swapped cue mapping is in force this episode (False for tasks without cues)."""
        if self.spec.cues is None:
            return False
        if self._mapping_override is not None:
            return self._mapping_override
        return self.spec.cues.remapped_at(self.episode)
    def set_target_override(self, xy) -> None:
        """Use ``xy`` as the target of the following episodes (None: sample again).

        Raises ValueError if ``xy`` is not a finite point on the task's plane.
        """
        self._target_override = None if xy is None else check_target(xy, self.spec.plane_size).copy()

    def set_link_lengths(self, l1: float, l2: float) -> None:
        """Lengths used from the next reset on (and kept under changing kinematics)."""
        check_link_lengths(l1, l2)
        self._lengths = np.array([l1, l2], dtype=np.float64)

    @property
    def link_lengths(self) -> np.ndarray:
        return self._lengths.copy()

    @property
    def growing(self) -> bool:
        return self.spec.kinematics_mode == "changing" and self.episode >= self.spec.growth_start_episode

    # -- dm_control Task API ---------------------------------------------------
    def initialize_episode(self, physics: Physics) -> None:
        self.episode += 1
        self.step_count = 0
        physics.plane_size = self.spec.plane_size
        physics.set_origin(self.spec.origin)
        physics.set_zone_radius(self.spec.zone_radius)
        if self.spec.kinematics_mode == "static":
            self._lengths = np.array(self.spec.link_lengths, dtype=np.float64)
        physics.set_link_lengths(*self._lengths)
        physics.set_joint_limits(self.spec.at_limit == "clip", self.spec.joint_range)
        if self.trials is not None:  # the episode's trial (its field) before the plant is set for it
            self.trials.new_episode(self.episode)
        self.apply_episode_plant(physics)
        physics.set_joint_angles(*self.spec.start_angles())
        physics.set_target(self._episode_target())
        physics.forward()
        if self.trials is not None:
            self.trials.begin(physics)
        self._draw_view(first=True)
        if self.senses is not None:
            self.senses.start(physics)

    def apply_episode_plant(self, physics: Physics) -> None:
        """This episode's hand load and force field (the ``[plant]`` schedule); nothing for the ideal arm."""
        plant = self.spec.plant
        if plant.dynamic:
            physics.set_load(plant.load_at(self.episode))
            physics.set_field(plant.field_at(self.episode) if self.trials is None else self.trials.field_b)

    def _draw_view(self, first: bool) -> None:
        """Draw this step's view (seen flag, noise) once; :meth:`get_observation` reads it."""
        spec = self.spec
        if spec.vision == "occluded":
            self._seen = first
        elif spec.vision == "intermittent":
            self._seen = first or bool(self.random.uniform() < spec.vision_seen_probability)
        else:
            self._seen = True
        std = spec.observation_noise_std
        self._noise = self.random.normal(0.0, std, size=6) if self._seen and std > 0 else None
        if self.senses is not None:
            self.senses.draw(self.random)

    def _episode_target(self) -> np.ndarray:
        if self.spec.cues is not None:
            return self._cued_target()
        if self._target_override is not None:
            return self._target_override
        if self.trials is not None and self.spec.trials.directions:  # centre-out: the trial's direction
            return self.trials.centre_out_target(motion_function(*self.spec.start_angles(), *self._lengths, self.spec.origin)[0])
        if self.spec.target_mode == "static":
            if self._static_target is None:
                self._static_target = self.sample_target()
            return self._static_target
        return self.sample_target()

    def _cued_target(self) -> np.ndarray:
        """This episode's cue (the override, else one drawn uniformly) and its target under the mapping in force."""
        cues = self.spec.cues
        self.cue = self._cue_override if self._cue_override is not None else int(self.random.randint(cues.n))
        return cues.mapping(self.remapped())[self.cue]

    def sample_target(self, max_tries: int = 10_000) -> np.ndarray:
        """A reachable target: uniform joint angles through the motion function."""
        lo, hi = self.spec.joint_range
        w, h = self.spec.plane_size
        for _ in range(max_tries):
            alpha, beta = self.random.uniform(lo, hi, size=2)
            end, _ = motion_function(alpha, beta, *self._lengths, self.spec.origin)
            if not (0.0 <= end[0] <= w and 0.0 <= end[1] <= h):
                continue
            in_test = self.spec.region.contains_test(end)
            if self.spec.target_region == "test" and not in_test:
                continue
            if self.spec.target_region == "train" and in_test:
                continue
            return end
        raise RuntimeError(
            f"task {self.spec.name!r}: no reachable target in region {self.spec.target_region!r} "
            f"within the plane after {max_tries} draws (lengths {self._lengths.tolist()})"
        )

    def action_spec(self, physics: Physics) -> specs.BoundedArray:
        bound = action_bound(self.spec)
        name = "joint_torque_Nm" if self.spec.plant.actuation == "torque" else "joint_angle_change_deg"
        return specs.BoundedArray((2,), np.float64, -bound, bound, name=name)

    def before_step(self, action, physics: Physics) -> None:
        action = validate_action(action, torque=self.spec.plant.actuation == "torque")
        if self.senses is not None and self.spec.signals.motor_noisy:
            action = motor_command(action, self.spec.signals, self.random)
        if self.growing:
            self._lengths = self._lengths + self.spec.growth_per_step
            physics.set_link_lengths(*self._lengths)
        if self.spec.plant.actuation == "torque":
            bound = self.spec.plant.max_torque
            physics.set_torques(np.minimum(np.maximum(action, -bound), bound))
            return
        change = np.minimum(np.maximum(action, -ACTION_BOUND), ACTION_BOUND)
        setpoint = physics.joint_angles() + change
        if self.spec.at_limit == "clip":
            lo, hi = self.spec.joint_range
            setpoint = np.minimum(np.maximum(setpoint, lo), hi)
        if self.actuation == "kinematic":
            physics.write_joint_angles(setpoint)
        else:
            physics.set_servo_setpoint(setpoint)

    def after_step(self, physics: Physics) -> None:
        self.step_count += 1
        if self.trials is not None:  # the ideal plant's trial measures; the go cue
            self.trials.after_step(physics, self.step_count)
        self._draw_view(first=False)

    def observation_spec(self, physics: Physics) -> collections.OrderedDict:
        """The observations' specs: arrays as dm_control infers them; the joint velocities (if observed) a
        :class:`ScaledArray` carrying the plant's ``velocity_scale`` (deg/s), the scale the agent reads them by.
        Unbounded: the arm may move faster than the scale."""
        obs = self.get_observation(physics)
        spec = collections.OrderedDict((k, specs.Array(np.shape(v), np.asarray(v).dtype, name=k))
                                       for k, v in obs.items())
        if "joint_velocities" in spec:
            spec["joint_velocities"] = ScaledArray(spec["joint_velocities"].shape, np.float64,
                                                   self.spec.plant.velocity_scale, name="joint_velocities")
        if "cue" in spec:  # one-hot: read as it is
            spec["cue"] = ScaledArray(spec["cue"].shape, np.float64, 1.0, name="cue")
        return spec

    def get_observation(self, physics: Physics) -> collections.OrderedDict:
        seen, noise = self._seen, self._noise
        end, elbow, target, velocities = self._signals(physics)
        obs = collections.OrderedDict()
        obs["end_effector"] = end if seen else np.zeros(2)
        obs["elbow"] = elbow if seen else np.zeros(2)
        obs["target"] = target if seen else np.zeros(2)
        if noise is not None:
            for i, name in enumerate(("end_effector", "elbow", "target")):
                obs[name] += noise[2 * i:2 * i + 2]
        obs["vision"] = np.array([1.0 if seen else 0.0])
        if self.spec.plant.observe_velocities:  # proprioception: felt whether the arm is seen or not
            obs["joint_velocities"] = velocities
        if self.spec.cues is not None:  # the stimulus stays on the screen for the whole episode, seen or not
            obs["cue"] = np.eye(self.spec.cues.n)[self.cue] if self.cue >= 0 else np.zeros(self.spec.cues.n)
        return obs

    def _signals(self, physics: Physics) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """(end_effector, elbow, target, joint_velocities) as the agent receives them: the true ones now, or
        (a ``[signals]`` table) delayed and noisy (:class:`~apac_mj.suite.signals.Senses`)."""
        if self.senses is not None:
            return self.senses.read(physics)
        velocities = physics.joint_velocities() if self.spec.plant.observe_velocities else None
        return physics.end_effector(), physics.elbow(), physics.target(), velocities

    def get_reward(self, physics: Physics) -> float:
        if self.trials is not None and self.trials.holding(self.step_count):
            return self.trials.hold_reward(physics)  # before the go cue: hold still
        return -physics.distance_to_target()

    def reached(self, physics: Physics) -> bool:
        """The target is reached: the hand inside the zone and, under a stop criterion (``spec.stop_speed``,
        deg/s), every joint's |angular velocity| at most ``stop_speed``. Without one (the paper's tasks): the
        zone alone. Never before a ``[trials]`` go cue."""
        if not physics.distance_to_target() <= self.spec.zone_radius:
            return False
        if self.trials is not None and self.trials.holding(self.step_count):
            return False
        stop = self.spec.stop_speed
        return stop is None or stopped(physics, stop)

    def get_termination(self, physics: Physics):
        if self.reached(physics) and deliberation.in_time(self.spec, physics):
            return 0.0  # terminal: the target is reached (by the deadline, where the world does not wait)
        if self.step_count >= self.spec.steps_per_episode or deliberation.time_up(self.spec, physics):
            return 1.0  # time limit: a truncation, discount 1
        return None

    # -- checkpointing -----------------------------------------------------------
    def get_state(self) -> dict:
        """Everything that evolves across episodes (for exact resume), and this step's view."""
        return {
            "episode": self.episode,
            "lengths": self._lengths.copy(),
            "static_target": None if self._static_target is None else self._static_target.copy(),
            "random": self.random.get_state(),
            "seen": self._seen,
            "noise": None if self._noise is None else self._noise.copy(),
            "cue": self.cue, "cue_override": self._cue_override, "mapping_override": self._mapping_override,
            "senses": None if self.senses is None else self.senses.get_state(),
            "trials": None if self.trials is None else self.trials.get_state(),
        }

    def set_state(self, state: dict) -> None:
        """Restore :meth:`get_state`'s dict; ``seen``/``noise`` are optional (default: seen, no noise)."""
        self.episode = int(state["episode"])
        self._lengths = np.asarray(state["lengths"], dtype=np.float64).copy()
        st = state["static_target"]
        self._static_target = None if st is None else np.asarray(st, dtype=np.float64).copy()
        self.random.set_state(state["random"])
        self._seen = bool(state.get("seen", True))
        noise = state.get("noise")
        self._noise = None if noise is None else np.asarray(noise, dtype=np.float64).reshape(6).copy()
        self.cue = int(state.get("cue", -1))
        self._cue_override, self._mapping_override = state.get("cue_override"), state.get("mapping_override")
        if self.senses is not None and state.get("senses") is not None:
            self.senses.set_state(state["senses"])
        if self.trials is not None and state.get("trials") is not None:
            self.trials.set_state(state["trials"])


def stopped(physics: Physics, stop_speed: float) -> bool:
    """Every joint's |angular velocity| is at most ``stop_speed`` (deg/s): the stop criterion's speed part."""
    v = physics.joint_velocities()  # as observed: the comparison the agent can make, to the bit
    return bool(abs(v[0]) <= stop_speed and abs(v[1]) <= stop_speed)


def validate_action(action, torque: bool = False) -> np.ndarray:
    """A finite float array of shape (2,); raises ValueError naming the problem and what the action is: the
    joint-angle changes in degrees, or (``torque``: torque actuation) the joint torques in N·m."""
    a = np.asarray(action, dtype=np.float64)
    if a.shape != (2,):
        what = "shoulder, elbow torque in N·m" if torque else "shoulder, elbow change in degrees"
        raise ValueError(f"action must have shape (2,) ({what}), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action must be finite, got {a.tolist()}")
    return a


def make_physics() -> Physics:
    return Physics.from_xml_path(str(paths.arm_xml_path()))


def action_bound(spec: TaskSpec) -> float:
    """Bound of each action component: degrees of joint-angle change, or N·m under torque actuation."""
    return spec.plant.max_torque if spec.plant.actuation == "torque" else ACTION_BOUND


def make_environment(spec: TaskSpec, actuation: str = "servo", random=None, **environment_kwargs) -> control.Environment:
    physics = make_physics()
    physics.plane_size = spec.plane_size
    check_actuation(spec.name, spec.signals, actuation)
    task = Reach(spec, actuation=actuation, random=random)
    if task.senses is not None and spec.signals.delayed:
        physics.sub_step_hook = task.senses.record
    if spec.plant.dynamic:
        if actuation != "servo":
            raise ValueError(f"task {spec.name!r} has a {spec.plant.actuation} plant ([plant]); actuation "
                             f"{actuation!r} would write the joint angles and skip its dynamics: use 'servo'")
        physics.set_plant(spec.plant)
        physics.dynamics.trial = task.trials  # a [trials] table's channel and measures, every sub-step
        environment_kwargs.setdefault("n_sub_steps", spec.plant.sub_steps)
    environment_kwargs.setdefault("n_sub_steps", N_SUB_STEPS if actuation == "servo" else KINEMATIC_SUB_STEPS)
    return control.Environment(physics, task, **environment_kwargs)
