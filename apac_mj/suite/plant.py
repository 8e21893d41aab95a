"""The plant's dynamics: a task file's ``[plant]`` table and what it does to the arm.

MotorNet splits a plant into a skeleton, its muscles and an effector; here the skeleton is the MJCF arm
(``assets/planar_arm.xml``, :mod:`apac_mj.suite.planar_arm`) and this module is the rest, in two parts:

* the data: :class:`PlantSpec` (the ``[plant]`` table, each field with its unit and source), its parsing
  (:func:`parse_plant`), checks (:func:`check_plant`) and description (:func:`describe_plant`, for
  ``apac-mj tasks --show``), and its schedule (:meth:`PlantSpec.load_at`, :meth:`PlantSpec.field_at`,
  :meth:`PlantSpec.shifted`);
* the dynamics: a :class:`Plant`, held by ``planar_arm.Physics`` (its ``set_plant``), that edits the compiled
  model (actuation, masses, damping, gravity), holds the hand load and the force field and applies the field
  every sub-step.

A new force field or hand load is a change to this module only (a new actuation also changes what an action
means: ``planar_arm.Reach``). MuJoCo works in this model's units (cm, kg, s); a task file states SI values,
converted here (the ``*_UNIT`` factors).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import mujoco
import numpy as np

# MuJoCo's units for this model are cm, kg and s: these convert the plant's SI values (PlantSpec).
_SITE = mujoco.mjtObj.mjOBJ_SITE
#: N·m -> kg·cm^2/s^2 (torque, and stiffness per rad, damping per rad/s).
TORQUE_UNIT = 1e4
#: N -> kg·cm/s^2.
FORCE_UNIT = 100.0
#: kg·m^2 -> kg·cm^2.
INERTIA_UNIT = 1e4
#: m -> cm.
LENGTH_UNIT = 100.0


class TaskSpecError(ValueError):
    """A task file (or task override) is malformed: its ``[plant]`` table (here) or any other part
    (:mod:`apac_mj.suite.task_spec`, which re-exports this class)."""


def check_table_keys(table: Any, known: Any, where: str, form: str) -> dict:
    """``table`` (a task file's table, ``form`` as the file writes it: "[signals]") as a dict whose keys are all
    ``known``; else :class:`TaskSpecError` naming ``where`` and the unknown keys."""
    if not isinstance(table, dict):
        raise TaskSpecError(f"{where} must be a table ({form}) with keys {list(known)}, got {table!r}")
    unknown = sorted(set(table) - set(known))
    if unknown:
        raise TaskSpecError(f"{where}: unknown key(s) {unknown}; known: {list(known)}")
    return table


def finite_number(value: Any, where: str) -> float:
    """``value`` as a float; :class:`TaskSpecError` naming ``where`` unless it is a finite real number."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
        raise TaskSpecError(f"{where} must be a finite number, got {value!r}")
    return float(value)


# -- the data: the file's [plant] table -----------------------------------------------------------------------------

#: ``[plant] actuation``: "ideal" (the paper's arm: stiff servos reach every command within the step),
#: "compliant" (position servos with a human arm's stiffness and damping, a fixed control interval per step)
#: or "torque" (the action is the joint torques, as dm_control's reacher).
PLANT_ACTUATIONS = ("ideal", "compliant", "torque")
#: Standard gravity (m/s^2).
STANDARD_GRAVITY = 9.81


@dataclasses.dataclass(frozen=True)
class PlantSpec:
    """The arm's dynamics, the file's ``[plant]`` table. Every field: unit and source.

    The default is the paper's idealized arm (``actuation = "ideal"``): the stiff servos of
    ``assets/planar_arm.xml`` (kp 1e4, kv 200, rotor armature 1, 40 sub-steps of 10 ms) reach every
    command within the step, the links are nearly massless, no gravity, no external force. Every other
    field applies to the "compliant" and "torque" plants only (an ideal plant with any of them set is an
    error). Segment masses and joint impedance are a human arm's; the geometry stays the paper's (cm), so
    the links' rotational inertia is a human arm's scaled by (5/31)^2 and (8/34)^2 (docs/environment.md).
    """

    #: "ideal", "compliant" or "torque" (:data:`PLANT_ACTUATIONS`).
    actuation: str = "ideal"
    #: Compliant servos' joint stiffness (shoulder, elbow), N·m/rad: the diagonal of the joint stiffness
    #: matrix K = [[15, 6], [6, 16]] N·m/rad of Shadmehr & Mussa-Ivaldi (1994, J Neurosci 14:3208, their arm
    #: model); MuJoCo's position servos act per joint, so the off-diagonal coupling (6) is left out.
    stiffness: tuple[float, float] = (15.0, 16.0)
    #: Compliant servos' joint damping (shoulder, elbow), N·m·s/rad: the diagonal of the viscosity matrix
    #: V = [[2.3, 0.9], [0.9, 2.4]] N·m·s/rad of the same model.
    damping: tuple[float, float] = (2.3, 2.4)
    #: Duration of one environment step (s): the servos track the command for this long, then the next
    #: command comes, whether the arm got there or not (10 Hz: the order of the ~100 ms visuomotor loop).
    control_interval: float = 0.1
    #: MuJoCo's integration time step (s); a step runs ``control_interval / timestep`` sub-steps.
    timestep: float = 0.002
    #: Torque actuation: bound of each joint torque (N·m), the action's bound. A design choice: 3x the
    #: gravity torque the unloaded arm needs held out straight (1.8 N·m at the shoulder).
    max_torque: float = 5.0
    #: Link masses (upper arm, forearm + hand), kg: a human arm's segments (Shadmehr & Mussa-Ivaldi 1994;
    #: Selen, Franklin & Wolpert 2009, J Neurosci 29:12606, Table 1: 1.93 and 1.52 kg).
    link_masses: tuple[float, float] = (1.93, 1.52)
    #: Rotational inertia of each link about its centre of mass (kg·m^2); 0 = a uniform rod, m l^2 / 12,
    #: at the current link length.
    link_inertias: tuple[float, float] = (0.0, 0.0)
    #: Passive joint damping (shoulder, elbow), N·m·s/rad, beside the servos' (MuJoCo's dof_damping).
    joint_damping: tuple[float, float] = (0.0, 0.0)
    #: Gravity on: the arm's plane is vertical, gravity (9.81 m/s^2) along -y of the plane (the plane's
    #: "down" is its bottom edge). Off: a horizontal plane, as the paper's and a manipulandum's.
    gravity: bool = False
    #: Point load held in the hand (kg), from the first episode.
    load: float = 0.0
    #: Episode (0-based, the task's episode counter as ``growth_start_episode``) from which the load is
    #: ``load_after``; -1: never (the dynamics counterpart of changing kinematics).
    load_change_episode: int = -1
    #: The hand load from ``load_change_episode`` on (kg).
    load_after: float = 0.0
    #: Curl field strength b (N·s/m): force at the hand F = B v, B = [[0, b], [-b, 0]], v the hand's velocity
    #: (Shadmehr & Mussa-Ivaldi 1994); b > 0 turns the force clockwise from the velocity. Curl-field studies
    #: use b of the order of 10-15 N·s/m on a human-sized arm.
    field_b: float = 0.0
    #: First episode with the field on; -1: never.
    field_on_episode: int = -1
    #: First episode with the field off again (the after-effect episodes); -1: never off.
    field_off_episode: int = -1
    #: Observe the joint velocities (deg/s, observation ``joint_velocities``) beside the positions, as
    #: dm_control's reacher does.
    observe_velocities: bool = False
    #: The joint speed (deg/s) the observed velocities are scaled by: the scale their observation spec carries
    #: (``planar_arm.ScaledArray``), which the agent's networks and the Gym adapter's ``observation="normalized"`` divide them by (order 1, as the
    #: positions). Not a limit: the arm may move faster. 500 deg/s is about the 95th percentile of the joint
    #: speeds under uniform random actions on the torque and compliant arms (docs/environment.md).
    velocity_scale: float = 500.0

    @property
    def dynamic(self) -> bool:
        """Not the paper's ideal arm: masses, compliant or torque actuation."""
        return self.actuation != "ideal"

    @property
    def sub_steps(self) -> int:
        """Physics sub-steps per environment step."""
        return int(round(self.control_interval / self.timestep))

    def shifted(self, episodes: int) -> "PlantSpec":
        """This plant with every scheduled episode (load change, field on and off) ``episodes`` later: a run's
        environment counts its babbling resets too (as ``growth_start_episode``)."""
        def later(e: int) -> int:
            return e + episodes if e >= 0 else e

        return dataclasses.replace(self, load_change_episode=later(self.load_change_episode),
                                   field_on_episode=later(self.field_on_episode),
                                   field_off_episode=later(self.field_off_episode))

    def load_at(self, episode: int) -> float:
        """The hand load (kg) in ``episode``."""
        changed = self.load_change_episode >= 0 and episode >= self.load_change_episode
        return self.load_after if changed else self.load

    def field_at(self, episode: int) -> float:
        """The curl field's b (N·s/m) in ``episode`` (0: off)."""
        on = self.field_on_episode >= 0 and episode >= self.field_on_episode
        off = self.field_off_episode >= 0 and episode >= self.field_off_episode
        return self.field_b if on and not off else 0.0


#: Units of the ``[plant]`` fields, for ``apac-mj tasks --show``.
PLANT_UNITS = {"stiffness": "N·m/rad", "damping": "N·m·s/rad", "control_interval": "s", "timestep": "s",
               "max_torque": "N·m", "link_masses": "kg", "link_inertias": "kg·m^2 (0: uniform rod)",
               "joint_damping": "N·m·s/rad", "load": "kg", "load_change_episode": "episode (-1: never)",
               "load_after": "kg", "field_b": "N·s/m", "field_on_episode": "episode (-1: never)",
               "field_off_episode": "episode (-1: never)", "velocity_scale": "deg/s"}
#: Where each default comes from (``apac-mj tasks --show``; docs/environment.md has the full references).
PLANT_SOURCES = {
    "stiffness": "diagonal of K = [[15, 6], [6, 16]], Shadmehr & Mussa-Ivaldi 1994",
    "damping": "diagonal of V = [[2.3, 0.9], [0.9, 2.4]], Shadmehr & Mussa-Ivaldi 1994",
    "control_interval": "design: ~100 ms visuomotor loop", "timestep": "design: 50 sub-steps per step",
    "max_torque": "design: 3x the unloaded arm's gravity torque", "link_masses":
        "human arm: Shadmehr & Mussa-Ivaldi 1994; Selen, Franklin & Wolpert 2009, Table 1",
    "gravity": "9.81 m/s^2 along -y",
    "velocity_scale": "design: ~95th percentile of joint speeds under random actions; networks read v / scale",
    "field_b": "F = B v, B = [[0, b], [-b, 0]], Shadmehr & Mussa-Ivaldi 1994",
}
#: The largest ``plant.max_torque`` (N·m): it becomes the agent's action bound, ``agent.action_scale``, whose range
#: ends here (apac_mj/config.py).
MAX_TORQUE = 360.0
#: ``plant.velocity_scale``'s range (deg/s): the networks read velocity / scale (1e-300 overflowed them to NaN).
VELOCITY_SCALE_RANGE = (1e-2, 1e6)
#: Physics sub-steps per environment step at most (``control_interval / timestep``; the design runs 50).
MAX_SUB_STEPS = 10_000
#: Seconds one environment step of :data:`MAX_SUB_STEPS` sub-steps took (changing_target_torque, timestep 1e-5, on
#: the shared 2-core machine; 50 sub-steps: 0.00015 s): 1.6 s per 30-step episode and seed.
SUB_STEPS_SECONDS = 0.054
_PLANT_PAIRS = {"stiffness", "damping", "link_masses", "link_inertias", "joint_damping"}
_PLANT_INTS = {"load_change_episode", "field_on_episode", "field_off_episode"}
_PLANT_BOOLS = {"gravity", "observe_velocities"}


def parse_plant(table: Any, source: str) -> PlantSpec:
    """The ``[plant]`` table as a :class:`PlantSpec`; an unknown key or a bad value raises
    :class:`TaskSpecError` naming the file, the key and the problem."""
    if not isinstance(table, dict):
        raise TaskSpecError(f"{source}: [plant] must be a table")
    known = {f.name for f in dataclasses.fields(PlantSpec)}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        where = f"{source}: plant.{key}"
        if key not in known:
            raise TaskSpecError(f"{source}: unknown key plant.{key}; known in [plant]: {sorted(known)}")
        if key in _PLANT_PAIRS:
            if not isinstance(value, list) or len(value) != 2:
                raise TaskSpecError(f"{where} must be a list of two numbers, got {value!r}")
            kwargs[key] = (finite_number(value[0], where), finite_number(value[1], where))
        elif key in _PLANT_INTS:
            if not isinstance(value, int) or isinstance(value, bool):
                raise TaskSpecError(f"{where} must be an integer, got {value!r}")
            kwargs[key] = value
        elif key in _PLANT_BOOLS:
            if not isinstance(value, bool):
                raise TaskSpecError(f"{where} must be true or false, got {value!r}")
            kwargs[key] = value
        elif key == "actuation":
            if not isinstance(value, str):
                raise TaskSpecError(f"{where} must be a string, got {value!r}")
            kwargs[key] = value
        else:
            kwargs[key] = finite_number(value, where)
    plant = PlantSpec(**kwargs)
    try:
        check_plant(plant)
    except TaskSpecError as e:
        raise TaskSpecError(f"{source}: {e}") from None
    return plant


def check_plant(plant: PlantSpec) -> None:
    """Raise :class:`TaskSpecError` naming the ``[plant]`` key unless every value is well-formed and fits
    the actuation."""
    if plant.actuation not in PLANT_ACTUATIONS:
        raise TaskSpecError(f"plant.actuation must be one of {PLANT_ACTUATIONS}, got {plant.actuation!r}")
    if not plant.dynamic:
        changed = [f.name for f in dataclasses.fields(plant)
                   if f.name != "actuation" and getattr(plant, f.name) != getattr(PlantSpec(), f.name)]
        if changed:
            raise TaskSpecError(f"plant.{changed[0]} needs a plant with dynamics: the ideal plant (the paper's "
                                "arm) reaches every command; set plant.actuation = 'compliant' or 'torque'")
        return
    for name in ("stiffness", "damping", "link_masses"):
        for v in getattr(plant, name):
            if not math.isfinite(v) or v <= 0:
                raise TaskSpecError(f"plant.{name} must be positive finite numbers, got {getattr(plant, name)}")
    for name in ("link_inertias", "joint_damping"):
        for v in getattr(plant, name):
            if not math.isfinite(v) or v < 0:
                raise TaskSpecError(f"plant.{name} must be finite numbers >= 0, got {getattr(plant, name)}")
    for name in ("control_interval", "timestep", "max_torque", "velocity_scale"):
        v = getattr(plant, name)
        if not math.isfinite(v) or v <= 0:
            raise TaskSpecError(f"plant.{name} must be a positive finite number, got {v!r}")
    _check_plant_bounds(plant)
    if plant.timestep > plant.control_interval or \
            abs(plant.sub_steps * plant.timestep - plant.control_interval) > 1e-9 * plant.control_interval:
        raise TaskSpecError(f"plant.control_interval ({plant.control_interval} s) must be a whole number of "
                            f"plant.timestep ({plant.timestep} s)")
    for name in ("load", "load_after", "field_b"):
        v = getattr(plant, name)
        if not math.isfinite(v) or (v < 0 and name != "field_b"):
            raise TaskSpecError(f"plant.{name} must be a finite number{' >= 0' if name != 'field_b' else ''}, "
                                f"got {v!r}")
    for name in ("load_change_episode", "field_on_episode", "field_off_episode"):
        if getattr(plant, name) < -1:
            raise TaskSpecError(f"plant.{name} must be an episode >= 0, or -1 for never, got {getattr(plant, name)}")
    if plant.field_b != 0 and plant.field_on_episode < 0:
        raise TaskSpecError("plant.field_b is set but plant.field_on_episode is -1 (never on)")
    if plant.field_off_episode >= 0 and plant.field_off_episode <= plant.field_on_episode:
        raise TaskSpecError(f"plant.field_off_episode ({plant.field_off_episode}) must come after "
                            f"plant.field_on_episode ({plant.field_on_episode})")


def _check_plant_bounds(plant: PlantSpec) -> None:
    """The plant's sizes that other parts must carry: the torque bound is the agent's action bound
    (``agent.action_scale``, at most :data:`MAX_TORQUE`), the networks read ``velocity / velocity_scale``
    (:data:`VELOCITY_SCALE_RANGE`), and each step runs ``control_interval / timestep`` sub-steps
    (at most :data:`MAX_SUB_STEPS`). Each error names the ``[plant]`` key, its limit and its default."""
    default = PlantSpec()
    if plant.max_torque > MAX_TORQUE:
        raise TaskSpecError(f"plant.max_torque must be at most {MAX_TORQUE:g} N·m (it becomes the agent's action "
                            f"bound, agent.action_scale, which is at most {MAX_TORQUE:g}; the design value is "
                            f"{default.max_torque:g}), got {plant.max_torque!r}")
    low, high = VELOCITY_SCALE_RANGE
    if not low <= plant.velocity_scale <= high:
        raise TaskSpecError(f"plant.velocity_scale must be in [{low:g}, {high:g}] deg/s (the networks read the "
                            "joint velocities divided by it, which must stay finite and of order 1; the design value "
                            f"is {default.velocity_scale:g}), got {plant.velocity_scale!r}")
    sub_steps = plant.control_interval / plant.timestep
    if sub_steps > MAX_SUB_STEPS + 0.5:
        raise TaskSpecError(f"plant.timestep = {plant.timestep:g} s gives {sub_steps:.0f} physics sub-steps per "
                            f"step (plant.control_interval {plant.control_interval:g} s / timestep); at most "
                            f"{MAX_SUB_STEPS} ({MAX_SUB_STEPS} took {SUB_STEPS_SECONDS:g} s per step when measured, "
                            f"{SUB_STEPS_SECONDS * 30:.1f} s per 30-step episode and seed), so timestep must be >= "
                            f"{plant.control_interval / MAX_SUB_STEPS:g} s (the design: {default.timestep:g} s, "
                            f"{default.sub_steps} sub-steps)")


def describe_plant(plant: PlantSpec) -> str:
    """Every ``[plant]`` value with its unit and the source of its default, ``*`` marking those that differ
    from the defaults."""
    default = PlantSpec()
    lines = []
    for f in dataclasses.fields(plant):
        v = getattr(plant, f.name)
        unit = PLANT_UNITS.get(f.name, "")
        source = PLANT_SOURCES.get(f.name, "")
        lines.append(f"{'*' if v != getattr(default, f.name) else ' '} plant.{f.name} = {v!r}"
                     + (f"  [{unit}]" if unit else "") + (f"  ({source})" if source else ""))
    return "\n".join(lines)


def check_task_plant(task: str, plant: Any) -> None:
    """Task ``task``'s ``plant`` is a well-formed :class:`PlantSpec` (else :class:`TaskSpecError` naming the task)."""
    if not isinstance(plant, PlantSpec):
        raise TaskSpecError(f"task {task!r}: plant must be a PlantSpec, got {type(plant).__name__}")
    try:
        check_plant(plant)
    except TaskSpecError as e:
        raise TaskSpecError(f"task {task!r}: {e}") from None


def plant_override(value: Any, where: str, base: PlantSpec | None = None) -> PlantSpec:
    """A ``plant`` override: a :class:`PlantSpec` (the whole plant), or a table of ``[plant]`` keys merged into
    ``base`` (the task's own ``[plant]``: the keys given replace those, the others stay) and checked as in a file."""
    if isinstance(value, PlantSpec):
        return value
    if isinstance(value, dict):
        table = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(base or PlantSpec()).items()}
        return parse_plant({**table, **value}, where)
    raise TaskSpecError(f"{where} must be a PlantSpec or a table of [plant] keys, got {value!r}")


# -- the dynamics: a PlantSpec acting on the arm's model ------------------------------------------------------------

def check_field(b: float) -> None:
    """Raise ValueError unless the force field's strength ``b`` (N·s/m) is finite."""
    if not math.isfinite(b):
        raise ValueError(f"field strength b must be finite (N·s/m), got {b!r}")


def curl_force(b: float, hand_velocity) -> np.ndarray:
    """The curl field's force at the hand, F = B v, B = [[0, b], [-b, 0]], for the hand's (x, y) velocity
    ``hand_velocity``: in MuJoCo's units (kg·cm/s^2) for a velocity in cm/s (N·s/m = kg/s in cm units too)."""
    vx, vy = hand_velocity
    return np.array([b * vy, -b * vx])


class Plant:
    """A :class:`PlantSpec`'s dynamics on one arm model: what ``planar_arm.Physics.set_plant`` gives the arm.

    It edits the compiled model in place (:meth:`apply`), keeps the link masses at the current lengths and the
    hand load (:meth:`apply_masses`, :meth:`set_load`), and applies the force field at the hand every physics
    sub-step (:meth:`step`, :meth:`set_field`). The ideal plant has none: the MJCF is that plant.

    ``model``, ``data`` and ``ids`` are the physics' raw ``MjModel`` and ``MjData`` and its element indices
    (``planar_arm._Ids``); the physics binds them again (:meth:`bind`) whenever it reloads.
    """

    def __init__(self, spec: PlantSpec, model: mujoco.MjModel, data: mujoco.MjData, ids: Any) -> None:
        if not spec.dynamic:
            raise ValueError("set_plant needs a plant with dynamics ('compliant' or 'torque'); the MJCF is the "
                             "ideal one")
        #: The plant's data (the task file's ``[plant]`` table).
        self.spec = spec
        #: Point load in the hand (kg) and the curl field's b (N·s/m) now.
        self.load: float = spec.load
        self.field_b: float = 0.0
        #: The task's trials (``suite.trials.TrialRunner``: a force channel in place of the field, and the
        #: per-trial measures, every sub-step); None: the field alone (every task without a ``[trials]`` table).
        self.trial: Any = None
        self.bind(model, data, ids)

    def bind(self, model: mujoco.MjModel, data: mujoco.MjData, ids: Any) -> None:
        """Act on ``model`` and ``data`` (again after the physics reloads), with views the force field reads
        and writes every sub-step."""
        self._m, self._d, self.ids = model, data, ids
        self._vel6 = np.zeros(6)
        self._hand_x = data.site_xpos[ids.end_site]
        self._fore_com = data.xipos[ids.fore_body]
        self._fore_xfrc = data.xfrc_applied[ids.fore_body]

    def apply(self) -> None:
        """Give the model this plant's dynamics (compliant or torque actuation, masses, damping, gravity).

        Edits the compiled model in place: integration time step, rotor armature 0, the actuators' gain and
        bias (compliant: kp = stiffness, kv = damping; torque: ctrl is the joint torque in N·m), passive joint
        damping, gravity along -y, link masses and inertias (:meth:`apply_masses`), MuJoCo's energy
        computation on; the field off.
        """
        m, ids, plant = self._m, self.ids, self.spec
        m.opt.timestep = plant.timestep
        m.opt.gravity[:] = (0.0, -STANDARD_GRAVITY * LENGTH_UNIT if plant.gravity else 0.0, 0.0)
        m.opt.enableflags |= int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        m.dof_armature[ids.qvel] = 0.0
        m.dof_damping[ids.qvel] = np.asarray(plant.joint_damping) * TORQUE_UNIT
        for k, a in enumerate(ids.ctrl):
            m.actuator_gainprm[a, :3] = 0.0
            m.actuator_biasprm[a, :3] = 0.0
            if plant.actuation == "compliant":
                kp, kv = plant.stiffness[k] * TORQUE_UNIT, plant.damping[k] * TORQUE_UNIT
                m.actuator_gainprm[a, 0] = kp
                m.actuator_biasprm[a, 1:3] = (-kp, -kv)
            else:  # torque: ctrl in N·m
                m.actuator_gainprm[a, 0] = TORQUE_UNIT
        # The capsules follow their geom frame, not the centre of mass a hand load moves.
        m.geom_sameframe[[ids.upper_geom, ids.fore_geom]] = 0
        self.apply_masses()
        mujoco.mj_setConst(m, self._d)
        self.set_field(0.0)

    def set_load(self, kg: float) -> None:
        """Hold a point load of ``kg`` in the hand; call between episodes."""
        if not math.isfinite(kg) or kg < 0:
            raise ValueError(f"hand load must be a finite number >= 0 (kg), got {kg!r}")
        if kg != self.load:
            self.load = float(kg)
            self.apply_masses()
            mujoco.mj_setConst(self._m, self._d)

    def set_field(self, b: float) -> None:
        """Curl field F = B v, B = [[0, b], [-b, 0]] (N·s/m) at the hand from the next sub-step; 0: off."""
        check_field(b)
        self.field_b = float(b)
        self._d.xfrc_applied[self.ids.fore_body] = 0.0

    def apply_masses(self) -> None:
        """Link masses and inertias of uniform rods (or the plant's stated inertias) at the current lengths,
        with the hand load as a point mass at the forearm's end (its centre of mass moves towards the hand)."""
        m, ids, plant = self._m, self.ids, self.spec
        for body, geom, k in ((ids.upper_body, ids.upper_geom, 0), (ids.fore_body, ids.fore_geom, 1)):
            length = m.body_pos[ids.fore_body, 0] if k == 0 else m.site_pos[ids.end_site, 0]
            mass, radius = plant.link_masses[k], m.geom_size[geom, 0]
            rod = plant.link_inertias[k] * INERTIA_UNIT or mass * length ** 2 / 12.0
            load = self.load if k == 1 else 0.0
            total = mass + load
            com = (mass * length / 2.0 + load * length) / total
            perp = rod + mass * (length / 2.0 - com) ** 2 + load * (length - com) ** 2
            m.body_mass[body] = total
            m.body_ipos[body] = (com, 0.0, 0.0)
            # principal axes as compiled (body_iquat): the rod's axis is the third
            m.body_inertia[body] = (perp, perp, mass * radius ** 2 / 2.0)

    def step(self, nstep: int) -> None:
        """``nstep`` physics sub-steps with the field's force set before each from the hand's velocity then
        (mj_step1 / field / mj_step2, MuJoCo's scheme for state-dependent inputs), then mj_step1 as
        dm_control's step ends. The physics runs it inside its invalid-state check, with the field on."""
        m, d = self._m, self._d
        for _ in range(nstep):
            mujoco.mj_step1(m, d)
            self.apply_field()
            mujoco.mj_step2(m, d)
        mujoco.mj_step1(m, d)

    def field_force(self, hand_velocity) -> np.ndarray:
        """The field's force at the hand moving at ``hand_velocity`` ((x, y), cm/s), in MuJoCo's units
        (kg·cm/s^2): :func:`curl_force` with this plant's b now."""
        return curl_force(self.field_b, hand_velocity)

    def apply_field(self) -> None:
        """xfrc_applied on the forearm: the field's force at the hand (:func:`curl_force`), as a force and
        torque at the centre of mass (MuJoCo applies xfrc_applied there). Scalar arithmetic on cached views:
        this runs every sub-step."""
        v, hand, com, b = self._vel6, self._hand_x, self._fore_com, self.field_b
        mujoco.mj_objectVelocity(self._m, self._d, _SITE, self.ids.end_site, v, 0)
        if self.trial is None:
            fx, fy = b * v[4], -b * v[3]  # F = B v, B = [[0, b], [-b, 0]]; N·s/m = kg/s in cm units too
        else:  # the trial's force (a channel, or this field) and its measures
            fx, fy = self.trial.sub_step(hand[0], hand[1], v[3], v[4], b)
        ax, ay, az = hand[0] - com[0], hand[1] - com[1], hand[2] - com[2]
        self._fore_xfrc[:] = (fx, fy, 0.0, -az * fy, az * fx, ax * fy - ay * fx)  # force; arm x force
