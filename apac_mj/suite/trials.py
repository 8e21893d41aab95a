"""Trial types a motor-control laboratory runs: force-channel (error-clamp) trials, catch trials, a go cue and block
schedules, as a task file's ``[trials]`` table (:class:`TrialSpec`; docs/environment.md, "Trial types: channel,
catch, go cue, blocks").

Interface
---------
The file format (every key but the blocks optional; the defaults shown)::

    [trials]
    channel_stiffness = 6000.0   # N/m: the channel's spring, across the straight line to the target
    channel_damping = 150.0      # N·s/m: its damper
    channel_probability = 0.0    # every block's default: the chance that a trial is a channel trial
    catch_probability = 0.0      # every field block's default: the chance that a trial has the field off
    go_cue_step = 0              # control steps of hold before the go cue (0: no go cue, no hold)
    early_movement_cm = 0.5      # hand displacement before the go cue counted as an early movement (cm)
    directions = 0               # centre-out: n > 0 fixed target directions around the hand's start (0: the task's)
    distance_cm = 3.0            # centre-out: the targets' distance from the hand's start (cm)
    first_direction_deg = 90.0   # centre-out: the first direction (deg; 90: +y, away from the shoulder)
    start_angles = [45.0, 90.0]  # the start posture (shoulder, elbow; deg); absent: the task's (0, 180)

    [[trials.block]]             # one table per block, in the order they run
    name = "baseline"            # the block's label (metrics column ``trial_block``)
    episodes = 50                # its length in episodes (an integer >= 1)
    field_b = 0.0                # the curl field's b here (N·s/m; < 0: the reverse field; 0: the null field)
    channel = false              # true: every trial of the block is a channel trial (an error-clamp block)
    channel_probability = 0.1    # this block's own (else the table's)
    catch_probability = 0.1      # this block's own (else the table's); a block with a field only

**The schedule.** Episodes are counted as the plant's schedule counts them: training episodes from 0, after
the motor babbling (a run's environments are told the babbling, ``VecEnv(episode_offset=...)``, and shift the
schedule by it: :meth:`TrialSpec.shifted`, as ``PlantSpec.shifted``). Block ``i`` holds episodes
``sum(episodes[:i]) .. sum(episodes[:i + 1]) - 1``; the babbling episodes (before episode 0) run the first
block's settings and the episodes after the last block the last block's (:meth:`TrialSpec.block_at`).

**The trial types** (:data:`TRIAL_TYPES`): "channel" (a channel block, or a draw under the block's
``channel_probability``): the field is off and the channel on; else, in a block with a field (``field_b`` != 0),
"catch" (a draw under ``catch_probability``: the field off without warning) or "field"; in a block without a
field, "null". Each episode's two draws (channel, catch) come from a generator seeded by ``(key, episode)``
(:meth:`TrialSpec.trial_at`), where ``key`` is drawn from a copy of the task's random stream
(:func:`trial_key`: the seed's stream, left untouched): the same seed gives the same schedule, the trial type of
every episode is a pure function of (seed, episode), so a resumed run agrees, and a task with a ``[trials]``
table draws the same targets as the same task without one.

**Centre-out targets** (``directions = n > 0``): every trial starts at the start posture (``start_angles``, else
the task's) and its target lies ``distance_cm`` from the hand's start in one of ``n`` fixed directions,
``first_direction_deg + 360 k / n`` (k = 0 .. n-1), as in a motor-control laboratory's centre-out task: each
direction comes once in every cycle of ``n`` trials, in an order drawn per cycle from ``(key, cycle)``
(:meth:`TrialSpec.direction_at`), so each trial can be measured against its own direction's baseline. The
episode's direction is the metrics column ``trial_direction`` (a task without centre-out targets has no such
column). The targets must be reachable within the joint range and on the plane (checked with the task).

**The channel** (an error clamp, Scheidt et al. 2000; Smith, Ghazizadeh & Shadmehr 2006): a spring-damper on the
hand across the straight line from the hand's position at the movement's start (the episode's start; with a go
cue, the hand's position at the cue) to the target, applied every MuJoCo sub-step as the curl field is
(``plant.Plant.apply_field``): with ``n`` the unit normal of the line, ``d`` the hand's lateral deviation and
``d'`` its rate, the channel's force is ``-(K d + B d') n``; the field is off.

**Sign convention.** ``n`` is the line's direction turned 90 degrees clockwise: the direction in which the curl
field with b > 0 pushes a hand moving along the line (``F = B v``, ``plant.curl_force``). A lateral error or
force is positive along ``n``. The agent's lateral force in a channel is the negative of the channel's force
along ``n``, ``K d + B d'`` (N): a hand pushing towards ``+n`` reads positive. Compensating a b > 0 field means
pushing against it, so an agent adapted to b > 0 shows a negative channel force (and a negative after-effect on a
catch trial); its adaptation coefficient is ``-force_at_peak_speed / (b * peak_speed)`` (SI units).

**The go cue** (``go_cue_step = g > 0``): a hold period of ``g`` control steps. During it the shown target (the
observation's and the physics' target site) is the hand's start position and the reward is minus the hand's
distance from it, so holding still is what is rewarded; the episode cannot end by reaching. After the ``g``-th
step the real target is shown (the go cue), the channel (if any) is anchored at the hand's position then, and
the reward is the task's. An episode whose hand moved more than ``early_movement_cm`` from its start before the
cue counts an early movement. The agent learns the cue from the target's appearance: a cue shown beside a
previewed target would need a state entry of its own (``apac_mj.layout``), which this table does not add.

**Per-trial measures** (:data:`TRIAL_COLUMNS`, the columns of metrics.parquet on a task with the table; none on
any other task): the block, the trial type, the field's b applied, the signed lateral error (cm: the largest
|d| of the movement, with its sign), the agent's lateral force in a channel (N: its peak, the signed value of
largest magnitude, and its value at the movement's peak hand speed; NaN on other trials), the peak hand speed
(cm/s) and the early movement. A dynamic plant measures every MuJoCo sub-step; the ideal plant (no forces, so no
channel and no field) once per control step.

Python: :class:`TrialSpec` and :class:`Block` (the table), :func:`parse_trials`, :func:`check_task_trials`
(against the task: the plant, the episode's length, the vision), :class:`Trial` (one episode's type),
:func:`trial_key`, and :class:`TrialRunner`, which ``planar_arm.Reach`` holds as ``trials`` (the episode's trial,
its forces through the plant, its measures: :meth:`TrialRunner.record`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from apac_mj.suite.plant import FORCE_UNIT, PlantSpec, TaskSpecError, check_table_keys, finite_number

#: The trial types, as the metrics' ``trial_type`` names them.
TRIAL_TYPES = ("field", "null", "channel", "catch")
#: The channel's spring (N/m) and damper (N·s/m): the error clamp's values reported for Smith, Ghazizadeh &
#: Shadmehr 2006 (PLoS Biol 4:e179) and used since; docs/environment.md says how they were checked.
CHANNEL_STIFFNESS, CHANNEL_DAMPING = 6000.0, 150.0
#: The metrics columns a task with a ``[trials]`` table adds, with their meaning (``run_dir.TRIAL_COLUMNS`` the same).
TRIAL_COLUMNS = {
    "trial_block": "the block's name ([[trials.block]] name)",
    "trial_type": "field, null, channel or catch (suite.trials.TRIAL_TYPES)",
    "trial_field_b": "the curl field's b applied in the episode (N·s/m; 0 in channel, catch and null trials)",
    "lateral_error": "signed largest perpendicular deviation from the straight line to the target (cm; + along "
                     "the b > 0 field's push)",
    "channel_force_peak": "the agent's lateral force against the channel, its signed peak (N; NaN off channel trials)",
    "channel_force_at_peak_speed": "the agent's lateral force against the channel at the peak hand speed (N; NaN "
                                   "off channel trials)",
    "peak_speed": "the hand's peak speed in the movement (cm/s)",
    "early_movement": "the hand moved more than early_movement_cm before the go cue (False without a go cue)",
    "trial_direction": "centre-out targets only: the target's direction index k (suite.trials.TrialSpec.direction_at)",
}
_BLOCK_KEYS = ("name", "episodes", "field_b", "channel", "channel_probability", "catch_probability")
_TABLE_KEYS = ("block", "channel_stiffness", "channel_damping", "channel_probability", "catch_probability",
               "go_cue_step", "early_movement_cm", "directions", "distance_cm", "first_direction_deg", "start_angles")


@dataclasses.dataclass(frozen=True)
class Block:
    """One ``[[trials.block]]``: a run of episodes with one field and one mix of trial types."""

    #: Its label (the metrics' ``trial_block``).
    name: str
    #: How many episodes it lasts (>= 1).
    episodes: int
    #: The curl field's b in this block (N·s/m; negative: the reverse field; 0: none).
    field_b: float = 0.0
    #: Every trial of the block is a channel trial.
    channel: bool = False
    #: The chance that a trial of the block is a channel trial (in [0, 1]).
    channel_probability: float = 0.0
    #: The chance that a trial of a field block has the field off (in [0, 1]; a catch trial).
    catch_probability: float = 0.0


@dataclasses.dataclass(frozen=True)
class Trial:
    """One episode's trial: its block (index and name), type (:data:`TRIAL_TYPES`) and the field's b applied."""

    block: int
    name: str
    type: str
    field_b: float
    #: The centre-out direction's index (-1: the task's own target).
    direction: int = -1

    @property
    def channel(self) -> bool:
        return self.type == "channel"


@dataclasses.dataclass(frozen=True)
class TrialSpec:
    """A task file's ``[trials]`` table (the module docstring has the format)."""

    #: The blocks, in the order they run (``[[trials.block]]``).
    blocks: tuple[Block, ...]
    #: The channel's spring across the line to the target (N/m).
    channel_stiffness: float = CHANNEL_STIFFNESS
    #: The channel's damper (N·s/m).
    channel_damping: float = CHANNEL_DAMPING
    #: Control steps of hold before the go cue (0: none).
    go_cue_step: int = 0
    #: Hand displacement before the go cue counted as an early movement (cm).
    early_movement_cm: float = 0.5
    #: Centre-out: the number of fixed target directions (0: the task's targets).
    directions: int = 0
    #: Centre-out: the targets' distance from the hand's start (cm).
    distance_cm: float = 3.0
    #: Centre-out: the angle of direction 0 (deg, counter-clockwise from +x).
    first_direction_deg: float = 90.0
    #: The start posture (shoulder, elbow; deg); None: the task's (``task_spec.START_ANGLES``).
    start_angles: tuple[float, float] | None = None
    #: The environment's episode at which the first block starts: 0 in a task file (no key), a run's babbling
    #: episodes in its environments (:meth:`shifted`).
    start_episode: int = 0

    def shifted(self, episodes: int) -> "TrialSpec":
        """This schedule ``episodes`` later (a run's environments count the babbling resets too)."""
        return dataclasses.replace(self, start_episode=self.start_episode + episodes)

    def block_at(self, episode: int) -> int:
        """The index of the block that runs environment episode ``episode`` (the first before it starts, the last
        after the schedule ends)."""
        e = episode - self.start_episode
        for i, block in enumerate(self.blocks):
            if e < block.episodes:
                return i
            e -= block.episodes
        return len(self.blocks) - 1

    def trial_at(self, key: int, episode: int) -> Trial:
        """Environment episode ``episode``'s trial under the draws of ``key`` (:func:`trial_key`)."""
        i = self.block_at(episode)
        block = self.blocks[i]
        e = episode - self.start_episode
        u_channel, u_catch = np.random.default_rng([int(key), int(e < 0), abs(e)]).random(2)
        k = self.direction_at(key, episode)
        if block.channel or u_channel < block.channel_probability:
            return Trial(i, block.name, "channel", 0.0, k)
        if block.field_b == 0.0:
            return Trial(i, block.name, "null", 0.0, k)
        if u_catch < block.catch_probability:
            return Trial(i, block.name, "catch", 0.0, k)
        return Trial(i, block.name, "field", block.field_b, k)

    def direction_at(self, key: int, episode: int) -> int:
        """Environment episode ``episode``'s centre-out direction index (-1 without centre-out targets): each
        direction once per cycle of :attr:`directions` trials, in an order drawn from ``(key, cycle)``."""
        n = self.directions
        if n <= 0:
            return -1
        e = episode - self.start_episode
        cycle = e // n  # floor: the babbling episodes (e < 0) have cycles of their own
        order = np.random.default_rng([int(key), 2 + int(cycle < 0), abs(cycle)]).permutation(n)
        return int(order[e % n])

    def centre_out_target(self, direction: int, start: Any) -> np.ndarray:
        """The target of direction ``direction`` for the hand starting at ``start`` (cm)."""
        theta = math.radians(self.first_direction_deg + 360.0 * direction / self.directions)
        return np.array([start[0] + self.distance_cm * math.cos(theta), start[1] + self.distance_cm * math.sin(theta)])

    @property
    def forces(self) -> bool:
        """Some block applies a force at the hand (a field or a channel): the plant must have dynamics."""
        return any(b.field_b != 0.0 or b.channel or b.channel_probability > 0 for b in self.blocks)


def trial_key(random: np.random.RandomState) -> int:
    """The trial draws' key: one draw from a copy of the task's random stream (``random`` is left as it was)."""
    copy = np.random.RandomState()
    copy.set_state(random.get_state())
    return int(copy.randint(2 ** 31 - 1))


# -- parsing and checks ---------------------------------------------------------------------------------------------

def _integer(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TaskSpecError(f"{where} must be an integer, got {value!r}")
    return int(value)


def _probability(value: Any, where: str) -> float:
    p = finite_number(value, where)
    if not 0.0 <= p <= 1.0:
        raise TaskSpecError(f"{where} must be a probability in [0, 1], got {value!r}")
    return p


def _angles(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise TaskSpecError(f"{where} must be [shoulder, elbow] in degrees, got {value!r}")
    return finite_number(value[0], f"{where}[0]"), finite_number(value[1], f"{where}[1]")


def _parse_block(table: Any, k: int, defaults: dict[str, float], where: str) -> Block:
    here = f"{where}.block[{k}]"
    check_table_keys(table, _BLOCK_KEYS, here, "[[trials.block]]")
    for key in ("name", "episodes"):
        if key not in table:
            raise TaskSpecError(f"{here} needs {key}")
    name = table["name"]
    if not isinstance(name, str) or not name.strip():
        raise TaskSpecError(f"{here}.name must be a non-empty string, got {name!r}")
    episodes = _integer(table["episodes"], f"{here}.episodes")
    if episodes < 1:
        raise TaskSpecError(f"{here}.episodes must be an integer >= 1, got {episodes}")
    channel = table.get("channel", False)
    if not isinstance(channel, bool):
        raise TaskSpecError(f"{here}.channel must be true or false, got {channel!r}")
    field_b = finite_number(table.get("field_b", 0.0), f"{here}.field_b")
    if "catch_probability" in table and field_b == 0.0 and table["catch_probability"] != 0:
        raise TaskSpecError(f"{here}.catch_probability: block {name!r} has no field (field_b = 0) to switch off")
    probabilities = {key: _probability(table.get(key, defaults[key]), f"{here}.{key}")
                     for key in ("channel_probability", "catch_probability")}
    return Block(name=name, episodes=episodes, field_b=field_b, channel=channel, **probabilities)


def parse_trials(table: Any, source: str) -> TrialSpec:
    """The ``[trials]`` table as a :class:`TrialSpec`; an unknown key or a bad value raises :class:`TaskSpecError`
    naming the file and the key (``trials.block[k].episodes``, ...)."""
    if isinstance(table, TrialSpec):
        return table
    where = f"{source}: trials"
    check_table_keys(table, _TABLE_KEYS, where, "[trials]")
    blocks = table.get("block")
    if not isinstance(blocks, list) or not blocks:
        raise TaskSpecError(f"{where}.block: [trials] needs at least one [[trials.block]] table, got {blocks!r}")
    defaults = {key: _probability(table.get(key, 0.0), f"{where}.{key}")
                for key in ("channel_probability", "catch_probability")}
    kwargs: dict[str, Any] = {}
    for key in ("channel_stiffness", "channel_damping", "early_movement_cm", "distance_cm", "first_direction_deg"):
        if key in table:
            kwargs[key] = finite_number(table[key], f"{where}.{key}")
    for key in ("go_cue_step", "directions"):
        if key in table:
            kwargs[key] = _integer(table[key], f"{where}.{key}")
    if "start_angles" in table:
        kwargs["start_angles"] = _angles(table["start_angles"], f"{where}.start_angles")
    spec = TrialSpec(blocks=tuple(_parse_block(b, k, defaults, where) for k, b in enumerate(blocks)), **kwargs)
    try:
        check_trials(spec)
    except TaskSpecError as e:
        raise TaskSpecError(f"{source}: {e}") from None
    return spec


def check_trials(spec: TrialSpec) -> None:
    """The table's own values (:class:`TaskSpecError` naming the key): the channel's spring > 0 and damper >= 0,
    the go cue step >= 0, the early-movement threshold > 0."""
    if not (math.isfinite(spec.channel_stiffness) and spec.channel_stiffness > 0):
        raise TaskSpecError(f"trials.channel_stiffness must be a positive number (N/m), got {spec.channel_stiffness!r}")
    if not (math.isfinite(spec.channel_damping) and spec.channel_damping >= 0):
        raise TaskSpecError(f"trials.channel_damping must be a number >= 0 (N·s/m), got {spec.channel_damping!r}")
    if spec.go_cue_step < 0:
        raise TaskSpecError(f"trials.go_cue_step must be an integer >= 0 (0: no go cue), got {spec.go_cue_step}")
    if not (math.isfinite(spec.early_movement_cm) and spec.early_movement_cm > 0):
        raise TaskSpecError(f"trials.early_movement_cm must be a positive number (cm), got {spec.early_movement_cm!r}")
    if spec.directions < 0:
        raise TaskSpecError(f"trials.directions must be an integer >= 0 (0: the task's targets), got {spec.directions}")
    if not (math.isfinite(spec.distance_cm) and spec.distance_cm > 0):
        raise TaskSpecError(f"trials.distance_cm must be a positive number (cm), got {spec.distance_cm!r}")


def check_task_trials(task: str, spec: TrialSpec, plant: PlantSpec, steps_per_episode: int, vision: str) -> None:
    """``spec`` against its task: a field or a channel needs a plant with dynamics (the ideal arm has no forces),
    the blocks set the field (``plant.field_b`` stays 0), the go cue comes before the episode's last step, and a
    go cue needs a target seen when it appears (perfect or noisy vision)."""
    where = f"task {task!r}: trials"
    if not isinstance(spec, TrialSpec):
        raise TaskSpecError(f"{where} must be a TrialSpec, got {type(spec).__name__}")
    check_trials(spec)
    if spec.forces and not plant.dynamic:
        i, block = next((i, b) for i, b in enumerate(spec.blocks)
                        if b.field_b != 0.0 or b.channel or b.channel_probability > 0)
        key = "field_b" if block.field_b != 0.0 else "channel" if block.channel else "channel_probability"
        raise TaskSpecError(f"{where}.block[{i}].{key}: a force field or a force channel needs a plant with "
                            "dynamics; the ideal plant (the paper's arm, and kinematic actuation) has no forces: set "
                            "plant.actuation = 'compliant' or 'torque'")
    if plant.field_b != 0.0 or plant.field_on_episode >= 0:
        raise TaskSpecError(f"{where}: the blocks set the curl field (trials.block[k].field_b); plant.field_b and "
                            "plant.field_on_episode must stay unset beside a [trials] table")
    if spec.go_cue_step >= steps_per_episode:
        raise TaskSpecError(f"{where}.go_cue_step ({spec.go_cue_step}) must come before the episode's end "
                            f"(episode.steps = {steps_per_episode}): at most {steps_per_episode - 1}")
    if spec.go_cue_step > 0 and vision not in ("perfect", "noisy"):
        raise TaskSpecError(f"{where}.go_cue_step: the go cue shows the target at step {spec.go_cue_step}, which "
                            f"vision {vision!r} may not see; use vision 'perfect' or 'noisy'")


def reaching_angles(target: Any, lengths: tuple[float, float], origin: Any) -> list[tuple[float, float]]:
    """The (shoulder, elbow) angle pairs (deg, in [-180, 180)) that put the hand at ``target`` (cm): both elbow
    solutions of the two-link arm (Algorithm 1 inverted), none where the target is out of reach."""
    (l1, l2), dx, dy = lengths, target[0] - origin[0], target[1] - origin[1]
    c = (dx * dx + dy * dy - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    if abs(c) > 1.0:
        return []
    pairs = []
    for beta in {math.acos(c), -math.acos(c)}:
        alpha = math.atan2(dy, dx) - math.atan2(l2 * math.sin(beta), l1 + l2 * math.cos(beta))
        pairs.append(tuple((math.degrees(a) + 180.0) % 360.0 - 180.0 for a in (alpha, beta)))
    return pairs


def check_centre_out(task: Any) -> None:
    """A ``[trials]`` table's centre-out targets against its task (a ``TaskSpec``): its own targets (cues, a
    static target) would conflict, the arm's lengths must not change, and every target must lie on the plane and be
    reachable within the joint range from the start posture."""
    from apac_mj.kinematics import motion_function

    spec, where = task.trials, f"task {task.name!r}: trials.directions"
    if spec is None or not spec.directions:
        return
    if task.cues is not None or task.target_mode != "changing" or task.kinematics_mode != "static":
        raise TaskSpecError(f"{where}: centre-out targets need a task of changing targets without cues and with "
                            f"static kinematics (got target_mode {task.target_mode!r}, kinematics_mode "
                            f"{task.kinematics_mode!r}, cues {'set' if task.cues is not None else 'none'})")
    start, _ = motion_function(*task.start_angles(), *task.link_lengths, task.origin)
    lo, hi = task.joint_range
    for k in range(spec.directions):
        t = spec.centre_out_target(k, start)
        on_plane = 0.0 <= t[0] <= task.plane_size[0] and 0.0 <= t[1] <= task.plane_size[1]
        if not on_plane or not any(lo <= a <= hi and lo <= b <= hi
                                   for a, b in reaching_angles(t, task.link_lengths, task.origin)):
            raise TaskSpecError(f"{where}: direction {k}'s target ({t[0]:.2f}, {t[1]:.2f}) cm, {spec.distance_cm} cm "
                                f"from the hand's start ({start[0]:.2f}, {start[1]:.2f}), is off the plane or out of "
                                f"reach within the joint range {task.joint_range}: shorten trials.distance_cm or move "
                                "trials.start_angles")


# -- one episode's trial: forces and measures -----------------------------------------------------------------------

class TrialRunner:
    """A task's trials at run time (``planar_arm.Reach.trials``): the episode's trial, the channel's force, the go
    cue and the per-trial measures.

    The plant calls :meth:`sub_step` every MuJoCo sub-step (its force at the hand, measured there); the ideal plant's
    task calls :meth:`after_step` alone, which measures once per control step. Lengths in cm, speeds in cm/s, the
    spring and damper in N/m and N·s/m (kg/s^2 and kg/s in any length unit), forces returned in MuJoCo's units
    (kg·cm/s^2) and recorded in N.
    """

    def __init__(self, spec: TrialSpec, key: int) -> None:
        self.spec, self.key = spec, int(key)
        #: The episode's trial (None before the first).
        self.trial: Trial | None = None
        self.episode = -1
        self._fresh(np.zeros(2), np.zeros(2))

    def _fresh(self, hand: np.ndarray, target: np.ndarray) -> None:
        """Measures and geometry of a new episode starting with the hand at ``hand``, the target at ``target``."""
        self.start, self.target = [float(v) for v in hand], [float(v) for v in target]
        self.moving = self.spec.go_cue_step == 0
        self._anchor(hand)
        self.lateral, self.force_peak, self.force_at_peak_speed = 0.0, math.nan, math.nan
        self.peak_speed, self.hold_displacement = 0.0, 0.0

    def _anchor(self, hand) -> None:
        """The channel's line from ``hand`` to the target: its origin and unit normal ``n`` (the direction turned
        clockwise: where the b > 0 field pushes a hand moving along it)."""
        self.anchor = [float(hand[0]), float(hand[1])]
        dx, dy = self.target[0] - self.anchor[0], self.target[1] - self.anchor[1]
        length = math.hypot(dx, dy)
        self.normal = [dy / length, -dx / length] if length > 0 else [0.0, 0.0]

    # -- the episode ------------------------------------------------------------------------------------------------
    def new_episode(self, episode: int) -> Trial:
        """Environment episode ``episode``'s trial (before the plant is set up for it)."""
        self.episode = int(episode)
        self.trial = self.spec.trial_at(self.key, self.episode)
        return self.trial

    def centre_out_target(self, start: Any) -> np.ndarray:
        """The episode's centre-out target for the hand starting at ``start`` (cm; :meth:`new_episode` first)."""
        if self.trial is None or self.trial.direction < 0:
            raise RuntimeError("no centre-out trial: the [trials] table has no directions, or no episode began")
        return self.spec.centre_out_target(self.trial.direction, start)

    @property
    def field_b(self) -> float:
        """The curl field's b this episode (N·s/m; 0: off)."""
        return 0.0 if self.trial is None else self.trial.field_b

    def begin(self, physics: Any) -> None:
        """The episode's start, the arm and target in place: measure from here; with a go cue, show the hand's
        start position as the target until the cue."""
        self._fresh(physics.end_effector(), physics.target())
        if not self.moving:
            physics.set_target(self.start)

    def holding(self, step: int) -> bool:
        """The transition into step ``step`` (steps taken) belongs to the hold before the go cue."""
        return 0 < self.spec.go_cue_step and step <= self.spec.go_cue_step

    def after_step(self, physics: Any, step: int) -> None:
        """After the ``step``-th control step: the ideal plant's measures, and the go cue at step ``go_cue_step``."""
        if physics.dynamics is None:
            (hx, hy), (vx, vy) = physics.end_effector(), physics.hand_velocity()
            d = (hx - self.anchor[0]) * self.normal[0] + (hy - self.anchor[1]) * self.normal[1]
            self._measure(hx, hy, vx, vy, d, math.nan)
        if not self.moving and step == self.spec.go_cue_step:
            self.moving = True
            physics.set_target(self.target)
            self._anchor(physics.end_effector())

    def hold_reward(self, physics: Any) -> float:
        """The reward during the hold: minus the hand's distance from its start (cm)."""
        hand = physics.end_effector()
        return -math.hypot(hand[0] - self.start[0], hand[1] - self.start[1])

    # -- every sub-step (the plant's loop) ---------------------------------------------------------------------------
    def sub_step(self, hx: float, hy: float, vx: float, vy: float, b: float) -> tuple[float, float]:
        """The force at the hand (MuJoCo's units, kg·cm/s^2) for the hand at (hx, hy) cm moving at (vx, vy) cm/s:
        the channel's ``-(K d + B d') n`` on a channel trial, else the curl field's ``B v`` (b N·s/m); measured."""
        nx, ny = self.normal
        d = (hx - self.anchor[0]) * nx + (hy - self.anchor[1]) * ny
        if self.trial is not None and self.trial.channel:
            push = self.spec.channel_stiffness * d + self.spec.channel_damping * (vx * nx + vy * ny)
            self._measure(hx, hy, vx, vy, d, push / FORCE_UNIT)
            return -push * nx, -push * ny
        self._measure(hx, hy, vx, vy, d, math.nan)
        return b * vy, -b * vx

    def _measure(self, hx: float, hy: float, vx: float, vy: float, d: float, force: float) -> None:
        """Fold one sample into the episode's measures (``force``: the agent's lateral force, N, or NaN)."""
        if not self.moving:
            shift = math.hypot(hx - self.start[0], hy - self.start[1])
            self.hold_displacement = max(self.hold_displacement, shift)
            return
        if abs(d) > abs(self.lateral):
            self.lateral = d
        speed = math.hypot(vx, vy)
        if speed > self.peak_speed:
            self.peak_speed, self.force_at_peak_speed = speed, force
        if not math.isnan(force) and not abs(force) <= abs(self.force_peak):
            self.force_peak = force

    # -- what is recorded ---------------------------------------------------------------------------------------------
    def record(self) -> dict[str, Any]:
        """The episode's :data:`TRIAL_COLUMNS`."""
        trial = self.trial
        channel = trial is not None and trial.channel
        row = {"trial_block": "" if trial is None else trial.name, "trial_type": "" if trial is None else trial.type,
               "trial_field_b": self.field_b, "lateral_error": float(self.lateral),
               "channel_force_peak": float(self.force_peak) if channel else math.nan,
               "channel_force_at_peak_speed": float(self.force_at_peak_speed) if channel else math.nan,
               "peak_speed": float(self.peak_speed),
               "early_movement": bool(self.hold_displacement > self.spec.early_movement_cm)}
        if self.spec.directions:  # centre-out only: every other task's metrics stay as they were
            row["trial_direction"] = -1 if trial is None else int(trial.direction)
        return row

    def view(self) -> dict[str, Any]:
        """What a recording shows: the trial's type, block and field, the hand's start, the channel (its line's two
        ends and unit normal, cm; None off channel trials), the real target, and the go cue's step."""
        channel = None
        if self.trial is not None and self.trial.channel:
            channel = (np.array(self.anchor), np.array(self.target), np.array(self.normal))
        return {"type": None if self.trial is None else self.trial.type,
                "block": None if self.trial is None else self.trial.name, "field_b": self.field_b,
                "start": np.array(self.start), "channel": channel, "target": np.array(self.target),
                "go_cue_step": self.spec.go_cue_step}

    # -- checkpoints: plain numbers (weights_only-safe) ------------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        return {"episode": self.episode, "start": list(self.start), "target": list(self.target),
                "anchor": list(self.anchor), "moving": bool(self.moving),
                "measures": [float(self.lateral), float(self.force_peak), float(self.force_at_peak_speed),
                             float(self.peak_speed), float(self.hold_displacement)]}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore :meth:`get_state`'s dict (the trial is recomputed from the episode: a pure function of it)."""
        self.episode = int(state["episode"])
        self.trial = None if self.episode < 0 else self.spec.trial_at(self.key, self.episode)
        self.start, self.target = [float(v) for v in state["start"]], [float(v) for v in state["target"]]
        self._anchor(state["anchor"])
        self.moving = bool(state["moving"])
        (self.lateral, self.force_peak, self.force_at_peak_speed, self.peak_speed,
         self.hold_displacement) = (float(v) for v in state["measures"])
