"""Signals take time and are noisy: a task file's ``[signals]`` table and what it does to what the agent sees.

Two things a brain's signals have that the paper's arm lacks (docs/environment.md, "Signals: delays and noise"):

* **feedback delays**: what the agent observes at a step is the arm as it was ``delay`` earlier. The plant's
  observed quantities are recorded at every MuJoCo sub-step (:class:`DelayLine`) and the value from
  ``delay`` earlier (rounded to the nearest sub-step) is delivered. *Visual* signals: ``end_effector``,
  ``elbow`` and ``target`` (positions in the plane: the paper's state is what the eye sees); *proprioceptive*:
  ``joint_velocities``. Before the first delay has elapsed in an episode, the delayed signal is the episode's
  start.
* **noise**: signal-dependent motor noise on the command (std proportional to it, Harris & Wolpert 1998,
  Nature 394:780; plus an optional constant part) and sensory noise on the delivered signals.

Reward and termination stay the true ones: only the observation and the executed command change. MotorNet 0.3.0
(``motornet.environment.Environment``) is the reference: its defaults are ``vision_delay = proprioception_delay
= dt`` (one effector timestep, 0.01 s: 10 ms each) and every noise 0 (its ``action_noise`` is additive, not
signal-dependent); :data:`MOTORNET_DEFAULTS`. The default here (no ``[signals]`` table) is today's task exactly.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from apac_mj.suite.plant import PlantSpec, TaskSpecError, check_table_keys, finite_number

#: MuJoCo's timestep of the paper's ideal arm (s; ``option timestep`` of ``assets/planar_arm.xml``,
#: tests/test_signals.py checks it against the model).
IDEAL_TIMESTEP = 0.01
#: Sub-steps per step of the ideal arm under servo actuation (``planar_arm.N_SUB_STEPS``, checked by the tests).
IDEAL_SUB_STEPS = 40
#: MotorNet 0.3.0's defaults (``Environment.__init__``): both delays one effector timestep (10 ms), no noise.
MOTORNET_DEFAULTS = {"visual_delay_ms": 10.0, "proprioceptive_delay_ms": 10.0, "motor_noise": 0.0,
                     "motor_noise_constant": 0.0, "visual_noise": 0.0, "proprioceptive_noise": 0.0}
#: The observations that are visual (positions in the plane, cm) and proprioceptive (deg/s), in the order a
#: :class:`DelayLine` records them.
VISUAL = ("end_effector", "elbow", "target")
PROPRIOCEPTIVE = ("joint_velocities",)


@dataclasses.dataclass(frozen=True)
class SignalSpec:
    """The file's ``[signals]`` table: feedback delays and noise. Every key is a field of the same name."""

    #: Delay of the visual signals (``end_effector``, ``elbow``, ``target``), ms, >= 0; rounded to the nearest
    #: MuJoCo sub-step (:func:`delay_sub_steps`). MotorNet's default: 10 ms.
    visual_delay_ms: float = 0.0
    #: Delay of the proprioceptive signal (``joint_velocities``; needs ``[plant] observe_velocities``), ms, >= 0.
    #: MotorNet's default: 10 ms.
    proprioceptive_delay_ms: float = 0.0
    #: Signal-dependent motor noise (dimensionless, >= 0): each command component u is executed as
    #: u (1 + k e), e ~ N(0, 1), so its std is k |u| (Harris & Wolpert 1998). The command is the action: the
    #: joint-angle change (deg) on servo arms, the joint torque (N·m) on the torque arm. MotorNet: none.
    motor_noise: float = 0.0
    #: Constant motor noise (std, >= 0, in the action's unit), added to the signal-dependent part (MotorNet's
    #: ``action_noise``, default 0).
    motor_noise_constant: float = 0.0
    #: Std of Gaussian noise on each delivered visual coordinate (cm, >= 0), under every vision mode (the
    #: ``[vision] noise_std`` of the "noisy" mode is the same noise: a task sets one of them). MotorNet: 0.
    visual_noise: float = 0.0
    #: Std of Gaussian noise on each delivered joint velocity (deg/s, >= 0; needs observed velocities). MotorNet: 0.
    proprioceptive_noise: float = 0.0

    @property
    def delayed(self) -> bool:
        """Some delay is set."""
        return self.visual_delay_ms > 0 or self.proprioceptive_delay_ms > 0

    @property
    def sensory_noise(self) -> bool:
        """Some sensory noise is set."""
        return self.visual_noise > 0 or self.proprioceptive_noise > 0

    @property
    def motor_noisy(self) -> bool:
        """Some motor noise is set."""
        return self.motor_noise > 0 or self.motor_noise_constant > 0

    @property
    def active(self) -> bool:
        """Any setting is not zero (an all-zero table is today's task, to the bit)."""
        return self.delayed or self.sensory_noise or self.motor_noisy


SIGNAL_KEYS = tuple(f.name for f in dataclasses.fields(SignalSpec))
#: Each key's unit, for ``apac-mj tasks --show``.
SIGNAL_UNITS = {"visual_delay_ms": "ms", "proprioceptive_delay_ms": "ms", "motor_noise": "x |command|",
                "motor_noise_constant": "action unit", "visual_noise": "cm", "proprioceptive_noise": "deg/s"}


def parse_signals(table: Any, where: str, current: SignalSpec | None = None) -> SignalSpec | None:
    """A ``[signals]`` table (or an override: a partial table merged into ``current``) as :class:`SignalSpec`;
    None stays None (no table). Unknown keys and values that are not finite numbers >= 0 are refused."""
    if table is None or isinstance(table, SignalSpec):
        return table
    check_table_keys(table, SIGNAL_KEYS, f"{where} [signals]", "[signals]")
    values = {k: finite_number(v, f"{where} signals.{k}") for k, v in table.items()}
    return dataclasses.replace(current or SignalSpec(), **values)


def step_seconds(plant: PlantSpec) -> tuple[float, int]:
    """(MuJoCo timestep in s, sub-steps per environment step) of ``plant`` under servo actuation."""
    if plant.dynamic:
        return plant.timestep, plant.sub_steps
    return IDEAL_TIMESTEP, IDEAL_SUB_STEPS


def delay_sub_steps(delay_ms: float, timestep: float) -> int:
    """``delay_ms`` in whole MuJoCo sub-steps of ``timestep`` s: the nearest, a half rounding up (70 ms at 2 ms:
    35; 5 ms at 2 ms: 3; 1 ms at 10 ms: 0)."""
    return int(math.floor(delay_ms / (1000.0 * timestep) + 0.5 + 1e-9))


def check_task_signals(task: str, signals: SignalSpec, plant: PlantSpec, steps_per_episode: int,
                       vision_noise_std: float) -> None:
    """Refuse (:class:`TaskSpecError` naming the field) values a task cannot take: negative or non-finite
    values, a delay longer than an episode, proprioceptive settings on a plant whose joint velocities are not
    observed, visual noise beside ``[vision] noise_std``."""
    where = f"task {task!r}: [signals]"
    for key in SIGNAL_KEYS:
        v = getattr(signals, key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise TaskSpecError(f"{where} {key} must be a finite number >= 0 ({SIGNAL_UNITS[key]}), got {v!r}")
    timestep, sub_steps = step_seconds(plant)
    episode_ms = 1000.0 * timestep * sub_steps * steps_per_episode
    for key in ("visual_delay_ms", "proprioceptive_delay_ms"):
        if getattr(signals, key) > episode_ms:
            step_ms = 1000 * timestep * sub_steps
            raise TaskSpecError(f"{where} {key} = {getattr(signals, key):g} ms is longer than an episode "
                                f"({steps_per_episode} steps of {step_ms:g} ms = {episode_ms:g} ms)")
    if not plant.observe_velocities:
        for key in ("proprioceptive_delay_ms", "proprioceptive_noise"):
            if getattr(signals, key) > 0:
                raise TaskSpecError(f"{where} {key} needs a proprioceptive signal: a plant whose joint velocities "
                                    "are observed ([plant] observe_velocities = true); this one has none")
    if signals.visual_noise > 0 and vision_noise_std > 0:
        raise TaskSpecError(f"{where} visual_noise and [vision] noise_std are the same noise: set one of them "
                            f"(got {signals.visual_noise:g} and {vision_noise_std:g} cm)")


def check_actuation(task: str, signals: SignalSpec | None, actuation: str) -> None:
    """Delays need sub-steps: kinematic actuation writes the joint angles in one sub-step, so a delay there
    (ValueError) has no time resolution to be honoured at."""
    if signals is not None and signals.delayed and actuation != "servo":
        raise ValueError(f"task {task!r}: [signals] delays need the plant's sub-steps; actuation {actuation!r} "
                         "writes the joint angles in one sub-step and has none: use actuation 'servo' or no delay")


def describe_signals(signals: SignalSpec | None, plant: PlantSpec) -> str:
    """The ``[signals]`` table for ``apac-mj tasks --show``: each key, its unit, and the delays in sub-steps."""
    if signals is None:
        return "  signals = None (no [signals] table: no delays, no noise)"
    timestep, sub_steps = step_seconds(plant)
    lines = []
    for key in SIGNAL_KEYS:
        value, extra = getattr(signals, key), ""
        if key.endswith("_delay_ms"):
            n = delay_sub_steps(value, timestep)
            extra = f"  ({n} sub-steps of {1000 * timestep:g} ms = {n * 1000 * timestep:g} ms; a step is {sub_steps})"
        lines.append(f"{'*' if value != 0 else ' '} signals.{key} = {value!r}  [{SIGNAL_UNITS[key]}]{extra}")
    return "\n".join(lines)


class DelayLine:
    """The observed quantities recorded at every sub-step, delivered ``delay`` sub-steps late.

    A row is ``[end_effector (2), elbow (2), target (2), joint_velocities (0 or 2)]``; the line holds the
    newest ``max(delays) + 1`` rows. :meth:`start` fills it with the episode's start (so a delay not yet
    elapsed delivers the start), :meth:`record` appends the state after a sub-step."""

    def __init__(self, visual: int, proprioceptive: int, width: int) -> None:
        self.visual, self.proprioceptive = int(visual), int(proprioceptive)
        self.rows = np.zeros((max(self.visual, self.proprioceptive) + 1, width))
        self.newest = 0

    def start(self, row: np.ndarray) -> None:
        """A new episode: every row is its start."""
        self.rows[:] = row
        self.newest = 0

    def record(self, row: np.ndarray) -> None:
        """The state after one more sub-step."""
        self.newest = (self.newest + 1) % len(self.rows)
        self.rows[self.newest] = row

    def delayed(self, sub_steps: int) -> np.ndarray:
        """The row recorded ``sub_steps`` sub-steps ago (0: the newest)."""
        return self.rows[(self.newest - sub_steps) % len(self.rows)]

    def get_state(self) -> dict[str, Any]:
        return {"rows": self.rows.copy(), "newest": self.newest}

    def set_state(self, state: dict[str, Any]) -> None:
        self.rows[...] = np.asarray(state["rows"], dtype=np.float64)
        self.newest = int(state["newest"])


def motor_command(action: np.ndarray, signals: SignalSpec, random: np.random.RandomState) -> np.ndarray:
    """The command as executed: ``u (1 + k e1) + c e2`` (e1, e2 ~ N(0, 1) per component, drawn from the task's
    ``random``; ``c`` drawn only when set), k = ``motor_noise``, c = ``motor_noise_constant``."""
    noisy = action * (1.0 + signals.motor_noise * random.normal(size=action.shape))
    if signals.motor_noise_constant > 0:
        noisy = noisy + signals.motor_noise_constant * random.normal(size=action.shape)
    return noisy


class Senses:
    """What a task with a ``[signals]`` table delivers: the observed quantities delayed (a :class:`DelayLine`,
    recorded every sub-step through ``Physics.sub_step_hook``) and with this step's sensory noise (drawn once
    per step from the task's ``random``, :meth:`draw`). ``physics`` is the arm's (``planar_arm.Physics``)."""

    def __init__(self, signals: SignalSpec, plant: PlantSpec) -> None:
        timestep, _ = step_seconds(plant)
        self.signals, self.proprioceptive = signals, plant.observe_velocities
        self.width = 6 + (2 if self.proprioceptive else 0)
        self.line = DelayLine(delay_sub_steps(signals.visual_delay_ms, timestep),
                              delay_sub_steps(signals.proprioceptive_delay_ms, timestep), self.width)
        #: This step's sensory noise on a row (None: none set).
        self.noise: np.ndarray | None = None

    def sample(self, physics: Any) -> np.ndarray:
        """The true observed quantities now, as a row."""
        parts = [physics.end_effector(), physics.elbow(), physics.target()]
        if self.proprioceptive:
            parts.append(physics.joint_velocities())
        return np.concatenate(parts)

    def start(self, physics: Any) -> None:
        """A new episode: the delayed signals are its start until the delays have elapsed."""
        self.line.start(self.sample(physics))

    def record(self, physics: Any) -> None:
        """After one sub-step (``Physics.sub_step_hook``)."""
        self.line.record(self.sample(physics))

    def draw(self, random: np.random.RandomState) -> None:
        """This step's sensory noise: std ``visual_noise`` on the 6 visual coordinates, ``proprioceptive_noise``
        on the joint velocities (nothing drawn when both are 0)."""
        s = self.signals
        if not s.sensory_noise:
            return
        std = np.array([s.visual_noise] * 6 + [s.proprioceptive_noise] * (self.width - 6))
        self.noise = std * random.normal(size=self.width)

    def read(self, physics: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(end_effector, elbow, target, joint_velocities) as delivered now: delayed (without delays: ``physics``
        now), plus this step's noise (joint_velocities empty without proprioception)."""
        if self.signals.delayed:
            visual = self.line.delayed(self.line.visual)[:6].copy()
            proprio = self.line.delayed(self.line.proprioceptive)[6:].copy()
        else:
            visual, proprio = np.split(self.sample(physics), [6])
        if self.noise is not None:
            visual += self.noise[:6]
            proprio += self.noise[6:]
        return visual[:2], visual[2:4], visual[4:6], proprio

    def get_state(self) -> dict[str, Any]:
        return {**self.line.get_state(), "noise": None if self.noise is None else self.noise.copy()}

    def set_state(self, state: dict[str, Any]) -> None:
        self.line.set_state(state)
        self.noise = None if state.get("noise") is None else np.asarray(state["noise"], dtype=np.float64).copy()
