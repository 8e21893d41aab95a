"""Task conditions as data: TOML files in ``tasks/``, read and validated here.

A task file states one condition of the paper's experiments (target
static/changing, kinematics static/changing, vision perfect/occluded/noisy/
intermittent, the generalization region; in its ``[report]`` table, how the report
names and colours it) as what differs from the defaults: the field defaults
of :class:`TaskSpec`, the paper's values (its "Experimental Conditions and
Environment" and Appendix 2 Table 1), documented below. ``apac-mj tasks --show
NAME`` prints every value of a task. Every key is checked: an unknown key or a
bad value raises :class:`TaskSpecError` naming the file, the key and the
problem. Users add a condition by adding a file (docs/extending.md).
"""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path

import numpy as np
from typing import Any

from apac_mj.suite.plant import (PLANT_ACTUATIONS, PLANT_SOURCES, PLANT_UNITS, STANDARD_GRAVITY,  # noqa: F401
                                  PlantSpec, TaskSpecError, check_plant, check_table_keys, check_task_plant, describe_plant,
                                  finite_number, parse_plant, plant_override)
from apac_mj.suite.deliberation import DeliberationSpec, check_deliberation, parse_deliberation
from apac_mj.suite.signals import SignalSpec, check_task_signals, describe_signals, parse_signals
from apac_mj.suite.trials import TrialSpec, check_centre_out, check_task_trials, parse_trials
from apac_mj.util import paths
from apac_mj.util.registry import Registry


#: The arm's (shoulder, elbow) angles at every episode's start (degrees): stretched along the x axis, folded back.
START_ANGLES = (0.0, 180.0)


#: The largest length a task may state (cm): plane sides, link lengths, zone radius, vision noise, one
#: episode's growth. 100 m for a 13 cm arm: larger values are typos, and the plane's distance field,
#: renders and floats stop making sense long before 1e308.
MAX_CM = 1e4


@dataclasses.dataclass(frozen=True)
class Region:
    """The generalization split: the *test* region is ``y >= test_y_min``.

    ``y >= 22.3`` cm is the top band of the reachable area; at the initial
    lengths (5, 8) it covers one third of it (tests/test_suite.py measures the
    fraction). Everything else reachable is the *train* region. The band is
    fixed in the plane, so under growing arms more targets fall inside it, as
    in the paper (39 vs. 42 targets).
    """

    test_y_min: float = 22.3

    def contains_test(self, xy) -> np.ndarray:
        """Which of the points ``xy`` (``[..., 2]``, cm) lie in the test region: ``[...]`` bool."""
        return np.asarray(xy)[..., 1] >= self.test_y_min


#: At most this many cues a cued task may state (``[cues] targets``).
MAX_CUES = 16


@dataclasses.dataclass(frozen=True)
class Cues:
    """A cued-target task's stimulus-to-target mapping (file table ``[cues]``): each episode shows one cue (a
    symbol: the observation ``cue``, one-hot) drawn uniformly, and the target is that cue's under the mapping in
    force. The habit (actor and critic) reads the cue, not the target's position; the planner is told the target
    (the mapping in force), as participants in a remapping experiment are told the new mapping (docs/forced_response.md).
    """

    #: File key ``[cues] targets``: each cue's target (cm, on the plane, reachable from the start pose), in cue order.
    targets: tuple[tuple[float, float], ...] = ()
    #: File key ``[cues] swap``: pairs of cues whose targets change places at the remap (e.g. ``[[1, 2]]``).
    swap: tuple[tuple[int, int], ...] = ()
    #: File key ``[cues] remap_episode``: the training episode from which the swapped mapping is in force
    #: (None, no key: never during training; the forced-response test remaps after practice).
    remap_episode: int | None = None

    @property
    def n(self) -> int:
        """How many cues."""
        return len(self.targets)

    @property
    def remapped(self) -> tuple[int, ...]:
        """The cues the remap changes, ascending."""
        return tuple(sorted({c for pair in self.swap for c in pair}))

    def mapping(self, remapped: bool) -> np.ndarray:
        """``[n, 2]`` each cue's target: the original mapping, or (``remapped``) with the ``swap`` pairs exchanged."""
        t = np.array(self.targets, dtype=np.float64)
        if remapped:
            for a, b in self.swap:
                t[[a, b]] = t[[b, a]]
        return t

    def remapped_at(self, episode: int) -> bool:
        """The swapped mapping is in force at training episode ``episode``."""
        return self.remap_episode is not None and episode >= self.remap_episode


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """One experimental condition. Field docs double as the file format's docs."""

    name: str
    #: One line a user reads in ``apac-mj tasks``.
    description: str = ""
    #: "static": one target per seed, kept for the whole run; "changing": a new target each episode.
    target_mode: str = "changing"
    #: Which targets may be drawn: "all", "train" (outside the test region) or "test".
    target_region: str = "all"
    #: Radius of the target zone around the target (cm); inside it the target is reached.
    zone_radius: float = 0.5
    #: File key ``[target] stop_speed``: the stop criterion (deg/s). The target is reached (the episode ends,
    #: terminal) only when the hand is inside the zone *and* the arm is slower than this: every joint's
    #: |angular velocity| (the observed ``joint_velocities``) at most ``stop_speed``. It needs a plant whose
    #: velocities the agent observes (``[plant] observe_velocities``). None (no key): the paper's criterion,
    #: the zone alone.
    stop_speed: float | None = None
    #: "static" or "changing" (both lengths grow by ``growth_per_step`` each step).
    kinematics_mode: str = "static"
    #: Initial (upper arm l1, forearm l2) lengths in cm.
    link_lengths: tuple[float, float] = (5.0, 8.0)
    #: Growth of both lengths per environment step under changing kinematics (cm).
    growth_per_step: float = 0.001
    #: Growth starts after this many episodes (the paper: after the 100th).
    growth_start_episode: int = 100
    #: "perfect", "occluded" (target and arm seen at the first step only), "noisy" (every observed
    #: coordinate carries Gaussian noise of std ``vision_noise_std``) or "intermittent" (seen at the first
    #: step, then each step with probability ``vision_seen_probability``; an unseen step reads like occluded).
    #: Only the observations are corrupted: reward and termination stay the true ones.
    vision: str = "perfect"
    #: File key ``[vision] noise_std``: std (cm, finite, >= 0) of the independent Gaussian noise on each
    #: observed coordinate of end_effector, elbow and target. > 0 for "noisy", optional (>= 0) for
    #: "intermittent" (noisy and intermittent together), 0 for the other modes.
    vision_noise_std: float = 0.0
    #: File key ``[vision] seen_probability``: probability (in (0, 1]) that a step after the first is seen.
    #: Strictly between 0 and 1 for "intermittent", 1 for the other modes.
    vision_seen_probability: float = 1.0
    #: (low, high) of both joints in degrees (the paper: "each joint only moves between 0 to 180 degrees");
    #: it must hold the start pose ``START_ANGLES`` (0, 180).
    joint_range: tuple[float, float] = (0.0, 180.0)
    #: What the plant does with a command past a joint limit (``joint_range``):
    #: "clip" (the paper: "each joint only moves between 0 to 180 degrees"; the part past the limit
    #: is lost) or "unbounded" (no limit: the angles go on, as the motion function itself allows).
    at_limit: str = "clip"
    #: Action steps per episode before the time limit.
    steps_per_episode: int = 30
    #: Size (width, height) of the plane in cm; the plane spans [0, w] x [0, h].
    plane_size: tuple[float, float] = (30.0, 30.0)
    #: Shoulder position in the plane (cm).
    origin: tuple[float, float] = (15.0, 15.0)
    #: The generalization split.
    region: Region = Region()
    #: File key ``[report] label``: how the report's figures and report.md call this condition (empty: its
    #: description, else its name).
    report_label: str = ""
    #: File key ``[report] short``: its short name in the report's tables and axes (the paper's "cs" for
    #: changing target / static kinematics; empty: its name).
    report_short: str = ""
    #: File key ``[report] color``: its matplotlib colour in the report's figures (empty: the first of the
    #: report's extra colours that no other condition in the report uses).
    report_color: str = ""
    #: File table ``[plant]``: the arm's dynamics (:class:`PlantSpec`; default: the paper's ideal arm).
    plant: PlantSpec = dataclasses.field(default_factory=PlantSpec)
    #: File table ``[cues]``: a cued-target task (:class:`Cues`: the target is a shown cue's, under a mapping
    #: that a remap may change); None: the target itself is shown (every other task).
    cues: Cues | None = None
    #: File table ``[signals]``: feedback delays and motor and sensory noise (:class:`~apac_mj.suite.signals.SignalSpec`,
    #: docs/environment.md "Signals: delays and noise"); None (no table): none, today's task exactly.
    signals: SignalSpec | None = None
    #: File table ``[deliberation]``: the world does not wait while the agent decides (:class:`DeliberationSpec`,
    #: :mod:`apac_mj.suite.deliberation`); None: it waits (every task before it).
    deliberation: DeliberationSpec | None = None
    #: File table ``[trials]``: channel and catch trials, a go cue, a block schedule of curl fields
    #: (:class:`~apac_mj.suite.trials.TrialSpec`, docs/environment.md "Trial types: channel, catch, go cue,
    #: blocks"); None (no table): every episode as the ``[plant]`` schedule has it (every task before it).
    trials: TrialSpec | None = None

    def __post_init__(self) -> None:
        _check_choice(self, "target_mode", ("static", "changing"))
        _check_choice(self, "target_region", ("all", "train", "test"))
        _check_choice(self, "kinematics_mode", ("static", "changing"))
        _check_choice(self, "vision", VISION_MODES)
        _check_vision(self)
        _check_choice(self, "at_limit", ("clip", "unbounded"))
        _check_report(self)
        _check_positive(self, "zone_radius", self.zone_radius)
        _check_stop_speed(self)
        for k, v in zip(("l1", "l2"), self.link_lengths):
            _check_positive(self, f"link_lengths ({k})", v)
        for k, v in zip(("width", "height"), self.plane_size):
            _check_positive(self, f"plane_size ({k})", v)
        for field, value in (("zone_radius", self.zone_radius), ("link_lengths", max(self.link_lengths)),
                             ("plane_size", max(self.plane_size)), (_NOISE_KEY, self.vision_noise_std),
                             ("growth_per_step x steps_per_episode", self.growth_per_step * self.steps_per_episode)):
            if value > MAX_CM:
                raise TaskSpecError(f"task {self.name!r}: {field} must be at most {MAX_CM:g} cm, got {value!r}")
        if not math.isfinite(self.growth_per_step) or self.growth_per_step < 0:
            raise TaskSpecError(f"task {self.name!r}: growth_per_step must be finite and >= 0, got {self.growth_per_step}")
        if self.growth_start_episode < 0:
            raise TaskSpecError(f"task {self.name!r}: growth_start_episode must be >= 0")
        if self.steps_per_episode < 1:
            raise TaskSpecError(f"task {self.name!r}: steps_per_episode must be >= 1")
        lo, hi = self.joint_range
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise TaskSpecError(f"task {self.name!r}: joint_range must be finite with low < high, got {self.joint_range}")
        if not all(lo <= a <= hi for a in self.start_angles()):
            raise TaskSpecError(f"task {self.name!r}: joint_range {self.joint_range} must hold the start pose "
                                f"{self.start_angles()}")
        ox, oy = self.origin
        if not (0 <= ox <= self.plane_size[0] and 0 <= oy <= self.plane_size[1]):
            raise TaskSpecError(f"task {self.name!r}: origin {self.origin} lies outside the plane {self.plane_size}")
        check_task_plant(self.name, self.plant)
        if self.cues is not None:
            _check_cues(self)
        if self.signals is not None:
            check_task_signals(self.name, self.signals, self.plant, self.steps_per_episode, self.vision_noise_std)
        if self.deliberation is not None:
            check_deliberation(self)
        if self.trials is not None:
            check_task_trials(self.name, self.trials, self.plant, self.steps_per_episode, self.vision)
            check_centre_out(self)

    def start_angles(self) -> tuple[float, float]:
        """The arm's posture at every episode's start (shoulder, elbow; deg): a ``[trials]`` table's
        ``start_angles``, else :data:`START_ANGLES`."""
        angles = getattr(self.trials, "start_angles", None)
        return START_ANGLES if angles is None else tuple(angles)

    @property
    def cued(self) -> bool:
        """The observation shows a cue, not the target (:attr:`cues`)."""
        return self.cues is not None

    @property
    def occluded(self) -> bool:
        return self.vision == "occluded"

    @property
    def observation_noise_std(self) -> float:
        """Std (cm) of the noise every seen observed coordinate carries (0: none)."""
        return self.vision_noise_std

    def replace(self, **overrides: Any) -> "TaskSpec":
        """This task with ``overrides`` (TaskSpec fields), each checked and typed as a task file's value is
        (an integer field refuses 1.5, a number refuses true; a pair takes a list or tuple of two numbers)."""
        unknown = set(overrides) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise TaskSpecError(f"task {self.name!r}: unknown override(s) {sorted(unknown)}")
        typed = {k: v if k == "name" or (k == "region" and isinstance(v, Region))
                 else plant_override(v, f"task {self.name!r}: override plant", self.plant) if k == "plant"
                 else parse_signals(v, f"task {self.name!r}: override", self.signals) if k == "signals"
                 else parse_deliberation(v, f"task {self.name!r}: override", self.deliberation)
                 if k == "deliberation" and v is not None
                 else _coerce(k, v, f"task {self.name!r}: override {k}") for k, v in overrides.items()}
        return dataclasses.replace(self, **typed)


def describe(spec: TaskSpec) -> str:
    """Every field of ``spec``, one ``name = value`` line each, ``*`` marking those that differ from the defaults."""
    default = TaskSpec(name=spec.name)
    return "\n".join([*(f"{'*' if getattr(spec, f.name) != getattr(default, f.name) else ' '} {f.name} = "
                       f"{getattr(spec, f.name)!r}" for f in dataclasses.fields(spec)
                         if f.name not in ("name", "plant", "signals")),
                      describe_plant(spec.plant), describe_signals(spec.signals, spec.plant)])


def _check_cues(spec: TaskSpec) -> None:
    """A cued task: 2 to MAX_CUES distinct reachable targets on the plane, swap pairs of distinct cues (each
    cue in one pair at most), a remap episode >= 0; cues draw the target, so the target mode is "changing"."""
    cues, where = spec.cues, f"task {spec.name!r}: [cues]"
    if not 2 <= cues.n <= MAX_CUES:
        raise TaskSpecError(f"{where} targets must list 2 to {MAX_CUES} targets, got {cues.n}")
    if spec.target_mode != "changing" or spec.target_region != "all":
        raise TaskSpecError(f"{where}: a cued task draws each episode's target from its cues: [target] mode must be "
                            f"'changing' and region 'all', got {spec.target_mode!r}, {spec.target_region!r}")
    w, h = spec.plane_size
    l1, l2 = spec.link_lengths
    ox, oy = spec.origin
    for k, (x, y) in enumerate(cues.targets):
        if not (0 <= x <= w and 0 <= y <= h):
            raise TaskSpecError(f"{where} target {k} {[x, y]} lies outside the {w} x {h} plane")
        if joint_angles_for(x - ox, y - oy, l1, l2, spec.joint_range) is None:
            raise TaskSpecError(f"{where} target {k} {[x, y]} is out of the arm's reach (links {l1}, {l2} cm from "
                                f"the shoulder {list(spec.origin)}, both joints in {list(spec.joint_range)} degrees)")
    t = np.array(cues.targets)
    gaps = np.linalg.norm(t[:, None] - t[None], axis=-1)[np.triu_indices(cues.n, 1)]
    if gaps.min() <= 2 * spec.zone_radius:
        raise TaskSpecError(f"{where} targets must lie more than two zone radii ({2 * spec.zone_radius:g} cm) apart, "
                            f"got two {gaps.min():.2f} cm apart")
    seen: set[int] = set()
    for pair in cues.swap:
        if len(pair) != 2 or pair[0] == pair[1] or not all(0 <= c < cues.n for c in pair):
            raise TaskSpecError(f"{where} swap pairs must name two different cues in 0..{cues.n - 1}, got {list(pair)}")
        if seen & set(pair):
            raise TaskSpecError(f"{where} swap: each cue may be in one pair at most, got {[list(p) for p in cues.swap]}")
        seen |= set(pair)
    if cues.remap_episode is not None and cues.remap_episode < 0:
        raise TaskSpecError(f"{where} remap_episode must be an integer >= 0, got {cues.remap_episode}")


def joint_angles_for(dx: float, dy: float, l1: float, l2: float,
                     joint_range: tuple[float, float]) -> tuple[float, float] | None:
    """(shoulder, elbow) angles in degrees inside ``joint_range`` that put the hand at ``(dx, dy)`` from the
    shoulder (the motion function inverted: hand = l1 (cos a, sin a) + l2 (cos(a + b), sin(a + b))); None: none."""
    c = (dx * dx + dy * dy - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if not -1 <= c <= 1:
        return None
    lo, hi = joint_range
    for beta in (math.acos(c), -math.acos(c)):
        alpha = math.atan2(dy, dx) - math.atan2(l2 * math.sin(beta), l1 + l2 * math.cos(beta))
        a, b = math.degrees(alpha), math.degrees(beta)
        for turns_a in (-360, 0, 360):
            for turns_b in (-360, 0, 360):
                if lo <= a + turns_a <= hi and lo <= b + turns_b <= hi:
                    return a + turns_a, b + turns_b
    return None


def _check_choice(spec: TaskSpec, field: str, choices: tuple[str, ...]) -> None:
    value = getattr(spec, field)
    if value not in choices:
        raise TaskSpecError(f"task {spec.name!r}: {field} must be one of {choices}, got {value!r}")


#: The vision conditions (``TaskSpec.vision``).
VISION_MODES = ("perfect", "occluded", "noisy", "intermittent")
_NOISE_KEY = "vision_noise_std ([vision] noise_std)"
_SEEN_KEY = "vision_seen_probability ([vision] seen_probability)"


def _check_vision(spec: TaskSpec) -> None:
    """The two vision parameters are well-formed and fit ``spec.vision``."""
    std, p, mode = spec.vision_noise_std, spec.vision_seen_probability, spec.vision
    where = f"task {spec.name!r}"
    if isinstance(std, bool) or not isinstance(std, (int, float)) or not math.isfinite(std) or std < 0:
        raise TaskSpecError(f"{where}: {_NOISE_KEY} must be a finite number >= 0 (cm), got {std!r}")
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p) or not 0 < p <= 1:
        raise TaskSpecError(f"{where}: {_SEEN_KEY} must be a number in (0, 1], got {p!r}")
    if mode == "noisy" and std == 0:
        raise TaskSpecError(f"{where}: vision 'noisy' needs {_NOISE_KEY} > 0")
    if mode == "intermittent" and p == 1:
        raise TaskSpecError(f"{where}: vision 'intermittent' needs {_SEEN_KEY} strictly between 0 and 1")
    if mode in ("perfect", "occluded") and std != 0:
        raise TaskSpecError(f"{where}: {_NOISE_KEY} must be 0 under vision {mode!r} (use 'noisy'), got {std!r}")
    if mode != "intermittent" and p != 1:
        raise TaskSpecError(f"{where}: {_SEEN_KEY} must be 1 under vision {mode!r} (use 'intermittent'), "
                            f"got {p!r}")


def _check_report(spec: TaskSpec) -> None:
    """The ``[report]`` entries are one-line strings, the colour one matplotlib knows."""
    for field, key in (("report_label", "label"), ("report_short", "short"), ("report_color", "color")):
        value = getattr(spec, field)
        if not isinstance(value, str) or "\n" in value:
            raise TaskSpecError(f"task {spec.name!r}: {field} ([report] {key}) must be a one-line string, "
                                f"got {value!r}")
    if spec.report_color:
        from matplotlib.colors import is_color_like  # only for a task that sets a colour

        if not is_color_like(spec.report_color):
            raise TaskSpecError(f"task {spec.name!r}: report_color ([report] color) {spec.report_color!r} is not a "
                                "matplotlib colour (e.g. 'tab:olive', 'navy', '#1f77b4')")


_STOP_KEY = "stop_speed ([target] stop_speed)"


def _check_stop_speed(spec: TaskSpec) -> None:
    """The stop criterion is None or a positive finite speed (deg/s), on a plant whose velocities are observed."""
    v = spec.stop_speed
    if v is None:
        return
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) \
            or v <= 0:
        raise TaskSpecError(f"task {spec.name!r}: {_STOP_KEY} must be a positive finite number (deg/s, the "
                            f"largest joint speed that counts as stopped), got {v!r}")
    if not spec.plant.observe_velocities:
        raise TaskSpecError(f"task {spec.name!r}: {_STOP_KEY} needs a plant whose joint velocities are observed "
                            "([plant] observe_velocities = true, with actuation 'compliant' or 'torque'): the "
                            "agent must see the speed it is judged by")


def _check_positive(spec: TaskSpec, field: str, value: float) -> None:
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise TaskSpecError(f"task {spec.name!r}: {field} must be a positive finite number, got {value!r}")


# File layout: section -> {key in file: TaskSpec field}.
_LAYOUT: dict[str, dict[str, str]] = {
    "": {"description": "description"},
    "target": {"mode": "target_mode", "region": "target_region", "zone_radius": "zone_radius",
               "stop_speed": "stop_speed"},
    "kinematics": {
        "mode": "kinematics_mode",
        "link_lengths": "link_lengths",
        "growth_per_step": "growth_per_step",
        "growth_start_episode": "growth_start_episode",
    },
    "vision": {"mode": "vision", "noise_std": "vision_noise_std", "seen_probability": "vision_seen_probability"},
    "joints": {"range": "joint_range", "at_limit": "at_limit"},
    "episode": {"steps": "steps_per_episode"},
    "plane": {"size": "plane_size", "origin": "origin"},
    "region": {"test_y_min": "region"},
    "report": {"label": "report_label", "short": "report_short", "color": "report_color"},
}
_PAIRS = {"link_lengths", "plane_size", "origin", "joint_range"}
_FLOATS = {"zone_radius", "growth_per_step", "vision_noise_std", "vision_seen_probability", "stop_speed"}
_INTS = {"growth_start_episode", "steps_per_episode"}


def parse_task(data: dict[str, Any], name: str, source: str = "<dict>") -> TaskSpec:
    """Validate a parsed TOML document and build the :class:`TaskSpec`."""
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key == "cues":
            kwargs["cues"] = parse_cues(value, source)
        elif key == "signals":
            kwargs["signals"] = parse_signals(value, f"{source}:")
        elif key == "deliberation":
            kwargs["deliberation"] = parse_deliberation(value, source)
        elif key == "trials":
            kwargs["trials"] = parse_trials(value, source)
        elif isinstance(value, dict) and key != "plant":
            if key not in _LAYOUT or key == "":
                known = [*(k for k in _LAYOUT if k), 'plant', 'cues', 'deliberation', 'signals', 'trials']
                raise TaskSpecError(f"{source}: unknown section [{key}]; known: {sorted(known)}")
            for sub, sub_value in value.items():
                if sub not in _LAYOUT[key]:
                    raise TaskSpecError(f"{source}: unknown key {key}.{sub}; known in [{key}]: {sorted(_LAYOUT[key])}")
                kwargs[_LAYOUT[key][sub]] = _coerce(_LAYOUT[key][sub], sub_value, f"{source}: {key}.{sub}")
        elif key == "plant":
            kwargs["plant"] = parse_plant(value, source)
        elif key in _LAYOUT[""]:
            kwargs[_LAYOUT[""][key]] = str(value)
        else:
            raise TaskSpecError(f"{source}: unknown top-level key {key!r}")
    try:
        return TaskSpec(name=name, **kwargs)
    except TaskSpecError as e:
        raise TaskSpecError(f"{source}: {e}") from None


_CUE_KEYS = ("targets", "swap", "remap_episode")


def parse_cues(table: Any, source: str) -> Cues:
    """The ``[cues]`` table as :class:`Cues` (its keys checked; the spec checks the rest against the arm)."""
    where = f"{source}: [cues]"
    if isinstance(table, Cues):
        return table
    check_table_keys(table, _CUE_KEYS, where, "[cues]")
    if "targets" not in table:
        raise TaskSpecError(f"{where} needs targets = [[x, y], ...] (cm), one per cue")
    targets = table["targets"]
    if not isinstance(targets, (list, tuple)):
        raise TaskSpecError(f"{where} targets must be a list of [x, y] pairs (cm), got {targets!r}")
    pairs = tuple(_coerce("origin", t, f"{where} targets[{k}]") for k, t in enumerate(targets))
    swap = table.get("swap", [])
    if not isinstance(swap, (list, tuple)) or not all(
            isinstance(p, (list, tuple)) and all(isinstance(c, int) and not isinstance(c, bool) for c in p) for p in swap):
        raise TaskSpecError(f"{where} swap must be a list of [cue, cue] integer pairs, got {swap!r}")
    remap = table.get("remap_episode")
    if remap is not None and (not isinstance(remap, int) or isinstance(remap, bool)):
        raise TaskSpecError(f"{where} remap_episode must be an integer, got {remap!r}")
    return Cues(targets=pairs, swap=tuple(tuple(p) for p in swap), remap_episode=remap)


def _coerce(field: str, value: Any, where: str) -> Any:
    if field == "region":
        return Region(test_y_min=finite_number(value, where))
    if field == "deliberation":
        return None if value is None else parse_deliberation(value, where)
    if field == "trials":
        return None if value is None else parse_trials(value, where)
    if field == "cues":
        return None if value is None else parse_cues(value, where)
    if field in _PAIRS:
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise TaskSpecError(f"{where} must be a list of two numbers, got {value!r}")
        return (finite_number(value[0], where), finite_number(value[1], where))
    if field == "stop_speed" and value is None:  # an override back to the paper's criterion (no TOML spelling)
        return None
    if field in _FLOATS:
        return finite_number(value, where)
    if field in _INTS:
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            raise TaskSpecError(f"{where} must be an integer, got {value!r}")
        return int(value)
    if not isinstance(value, str):
        raise TaskSpecError(f"{where} must be a string, got {value!r}")
    return value


def load_task_file(path: str | Path) -> TaskSpec:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as e:
        raise TaskSpecError(f"{path}: not a task file: not UTF-8 text ({e}); a task file is TOML text "
                            "(docs/extending.md)") from None
    except tomllib.TOMLDecodeError as e:
        raise TaskSpecError(f"{path}: not valid TOML: {e}") from None
    except OSError as e:
        raise TaskSpecError(f"{path}: cannot be read: {e.strerror or e}") from None
    return parse_task(data, name=path.stem, source=str(path))


#: Tasks added at run time by :func:`register_task` (name -> spec), beside the files in tasks/.
_REGISTERED: Registry[TaskSpec] = Registry(
    "task", unknown="task {name!r} was not registered at run time (registered at run time: {names})")


def register_task(task: TaskSpec | str | Path, replace: bool = False) -> TaskSpec:
    """Add a task from user code: a :class:`TaskSpec` or the path of a task file (named by its stem).

    It is then known by name everywhere a task file is (``suite.load``, ``TrainConfig.task``, grid
    conditions), in this process; a name that is taken needs ``replace=True``."""
    spec = task if isinstance(task, TaskSpec) else load_task_file(task)
    if not replace and (spec.name in _REGISTERED or spec.name in task_names(paths.tasks_dir())):
        raise TaskSpecError(f"task {spec.name!r} already exists (pass replace=True to redefine it)")
    return _REGISTERED.replace(spec.name, spec)


def unregister_task(name: str) -> None:
    """Remove a task added by :func:`register_task`."""
    _REGISTERED.unregister(name)


def task_names(directory: Path | None = None) -> list[str]:
    """The tasks in ``directory`` (default: tasks/ and those registered at run time)."""
    if directory is not None:
        return sorted(p.stem for p in directory.glob("*.toml"))
    return sorted({p.stem for p in paths.tasks_dir().glob("*.toml")} | set(_REGISTERED))


#: What a task name may be: a file name in tasks/ without ``.toml`` (no folders, not hidden).
_TASK_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+-]*")


def load_task(name: str, directory: Path | None = None) -> TaskSpec:
    """Load ``tasks/<name>.toml`` (or a registered task); an unknown name lists the known ones. A name is
    a file's name in the task directory, never a path out of it (a task file elsewhere: register_task)."""
    if directory is None and name in _REGISTERED:
        return _REGISTERED.get(name)
    where = directory or paths.tasks_dir()
    if not isinstance(name, str) or not _TASK_NAME.fullmatch(name) or len(name) > 200:
        raise KeyError(f"task {name!r} is not a task name: a task is a file in {where} named by its stem "
                       f"(known: {', '.join(task_names(directory))}); for a task file elsewhere, copy it into "
                       "that folder or add it with apac_mj.suite.register_task (docs/extending.md)")
    path = where / f"{name}.toml"
    if not path.is_file():
        raise KeyError(f"unknown task {name!r}; known tasks: {', '.join(task_names(directory))}")
    return load_task_file(path)
