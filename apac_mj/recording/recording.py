"""Rollouts as Rerun recordings (.rrd). **Every** Rerun call of the project lives here.

A recording shows what the agent did (the MuJoCo render and the arm in the
plane), why the arbitrator chose what it chose (|delta| against the threshold,
the controller that acted) and that the physics matches the paper's motion
function (the MuJoCo arm and the motion-function arm overlaid, and their
maximum difference as a time series). ``docs/recording.md`` describes every
entity path; :data:`ALL_ENTITY_PATHS` lists them (a test compares the two).

Timelines: ``episode`` and ``step`` (the step within the episode; step 0 is
the start pose), plus ``frame``, a counter over the whole recording, so that
several episodes play one after another.
"""
from __future__ import annotations

import dataclasses
import errno
import os
import shutil
import sys
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from apac_mj.kinematics import DEFAULT_ORIGIN, motion_function
from apac_mj.run.rollout import Hook
from apac_mj.run.run_dir import git_commit
from apac_mj.suite.render import Renderer, encode_jpeg
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.types import POSITIONS, StepInfo
from apac_mj.util.files import current_umask, remove_stale_temporaries, temporary_name

if TYPE_CHECKING:
    import dm_env
    from dm_control.rl import control

    from apac_mj.suite.vec_env import VecEnv

APPLICATION_ID = "apac_mj"

# -- entity paths -----------------------------------------------------------------
RENDER = "render/overhead"
PLANE = "plane"
FIELD = "plane/distance_field"
ARM_MUJOCO = "plane/arm/mujoco"
ARM_MOTION_FUNCTION = "plane/arm/motion_function"
ARM_FORWARD_MODEL = "plane/arm/forward_model"
TARGET = "plane/target"
TARGET_ZONE = "plane/target_zone"
PATH = "plane/end_effector_path"
BORDER = "plane/border"
SHOULDER = "plane/shoulder"
REWARD = "series/reward"
DISTANCE = "series/distance"
ABS_DELTA = "series/arbitration/abs_delta"
DELTA_THRESHOLD = "series/arbitration/threshold"
CONTROLLER = "series/arbitration/controller"
#: The arbitrator's decision inputs, one series each: ``ARBITRATION_INPUTS/<name>`` (``Decision.inputs``).
ARBITRATION_INPUTS = "series/arbitration/inputs"
#: The integrator's error: mean over hand, elbow and target of |estimate - truth| (cm).
ESTIMATE_ERROR = "series/state_estimate_error"
FORWARD_ERROR = "series/forward_model_error"
KINEMATICS_ERROR = "series/kinematics_error"
L1 = "series/link_lengths/l1"
L2 = "series/link_lengths/l2"
VISION = "series/vision"
EVENTS = "events"
# The plant's dynamics (tasks with a [plant] table only; docs/environment.md):
#: The arm at the servos' commanded angles (compliant actuation: where the arm is told to go).
ARM_COMMANDED = "plane/arm/commanded"
#: The force field's force at the hand, drawn from the hand, FORCE_CM_PER_N cm per newton.
HAND_FORCE = "plane/hand_force"
LOAD = "series/plant/load_kg"
HAND_FORCE_SIZE = "series/plant/hand_force_N"
JOINT_VELOCITY = "series/plant/joint_velocity"
#: A model planner's plan (kinds with an MPC planner): the chosen sequence's imagined hand, a few sampled
#: candidates', the iterations run and the decision's measured time.
PLAN = "plane/plan/chosen"
PLAN_CANDIDATES = "plane/plan/candidates"
PLAN_ITERATIONS = "series/planning/iterations"
DECISION_MS = "series/planning/decision_ms"
#: The plane view's legend: a swatch and a name per drawn line entity of the recording (:data:`LEGEND_ENTRIES`),
#: shown in a view of its own below the plane, on LEGEND_BACKGROUND.
LEGEND = "legend"
LEGEND_BACKGROUND = "legend/background"
#: Entity paths a recording of a task with dynamics adds.
PLANT_PATHS = (ARM_COMMANDED, HAND_FORCE, LOAD, HAND_FORCE_SIZE, f"{JOINT_VELOCITY}/shoulder",
               f"{JOINT_VELOCITY}/elbow")
#: Length of the drawn hand force (cm per N).
FORCE_CM_PER_N = 0.5
# A task's trials (tasks with a [trials] table only; apac_mj.suite.trials):
#: A channel trial's two walls, either side of the straight line to the target (CHANNEL_HALF_WIDTH cm off it).
CHANNEL = "plane/trial/channel"
#: A trial's markers: a cross at the hand's start on a catch trial (the field off), a cross on the target the go
#: cue shows.
TRIAL_MARKER = "plane/trial/marker"
#: Entity paths a recording of a task with a [trials] table adds (its events name each trial and the go cue).
TRIAL_PATHS = (CHANNEL, TRIAL_MARKER)
#: How far the drawn channel walls lie either side of the line (cm): drawn, not felt (the channel is a spring).
CHANNEL_HALF_WIDTH = 0.3

#: Entity paths every recording holds (the forward-model arm, the state-estimate error and the arbitrator's
#: inputs only where an agent acted).
ENTITY_PATHS = (
    RENDER, FIELD, ARM_MUJOCO, ARM_MOTION_FUNCTION, TARGET, TARGET_ZONE, PATH, REWARD, DISTANCE,
    ABS_DELTA, DELTA_THRESHOLD, CONTROLLER, FORWARD_ERROR, KINEMATICS_ERROR, L1, L2, VISION, EVENTS,
)
#: Entity paths a recording of a kind with a model planner (an MPC) adds.
PLAN_PATHS = (PLAN, PLAN_CANDIDATES, PLAN_ITERATIONS, DECISION_MS)
#: Every entity path a recording may log (docs/recording.md lists each; the arbitrator's inputs are
#: ``ARBITRATION_INPUTS/<name>``, the legend's swatches ``LEGEND/<n>``): the per-step ones, then the static ones.
ALL_ENTITY_PATHS = (*ENTITY_PATHS, ARM_FORWARD_MODEL, ESTIMATE_ERROR, *PLANT_PATHS, *PLAN_PATHS, *TRIAL_PATHS,
                    PLANE, BORDER, SHOULDER, LEGEND_BACKGROUND)

#: Chunk batching of the file sink: flush after this many seconds or bytes (or at close).
BATCH_SECONDS, BATCH_BYTES = 60.0, 8 * 1024 * 1024
#: Controller series values.
HABIT, PLANNING = 1.0, 0.0
#: Pixels per cm of the distance-field image.
FIELD_PX_PER_CM = 5
#: The distance field's longest side at most (pixels): a larger plane gets fewer pixels per cm
#: (:func:`field_px_per_cm`), so its image stays a few MB whatever the plane's size.
FIELD_MAX_PX = 1024
#: Spacing of the contour bands in the distance field (cm).
CONTOUR_CM = 2.0

_BLACK, _GREY, _PURPLE = (20, 20, 20), (170, 170, 170), (170, 90, 230)
_ORANGE, _GREEN, _RED, _BLUE = (255, 140, 0), (30, 170, 60), (220, 30, 30), (30, 80, 240)
#: The MPC's plan (not the target's red) and the field's force at the hand (not the target's red either).
_MAGENTA, _BROWN = (205, 0, 160), (130, 80, 30)


@dataclasses.dataclass
class StepRecord:
    """What one member did at one step, in the paper's units (cm, degrees).

    ``true_arm`` is ``[end_x, end_y, elbow_x, elbow_y]`` read from MuJoCo's
    sites; ``predicted_arm`` is the forward model's prediction of it (NaN where
    the agent made none); ``delta`` is this transition's TD error, which the
    arbitrator weighs at the next step (NaN where none); ``habit`` says
    whether the actor acted.
    """

    episode: int
    step: int
    true_arm: np.ndarray
    joint_angles: np.ndarray
    link_lengths: np.ndarray
    target: np.ndarray
    reward: float = float("nan")
    distance: float = float("nan")
    delta: float = float("nan")
    habit: bool = False
    predicted_arm: np.ndarray = dataclasses.field(default_factory=lambda: np.full(4, np.nan))
    vision: bool = True
    reached: bool = False
    done: bool = False
    #: The integrator's estimate of ``[true_arm, target]`` after the step (NaN where none).
    estimated_state: np.ndarray = dataclasses.field(default_factory=lambda: np.full(6, np.nan))
    #: The arbitrator's inputs to the decision that chose this step's controller (``name -> value``).
    arbitration: dict[str, float] = dataclasses.field(default_factory=dict)
    #: The plant (tasks with dynamics; NaN for the paper's ideal arm): the servos' commanded angles (degrees;
    #: NaN under torque actuation), the joint velocities (deg/s), the field's force at the hand (N) and the
    #: hand load (kg).
    commanded_angles: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    joint_velocities: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    hand_force: np.ndarray = dataclasses.field(default_factory=lambda: np.full(2, np.nan))
    load: float = float("nan")
    #: A model planner's imagined hand along its chosen plan ``[H + 1, 2]`` and a few candidates'
    #: ``[C, H + 1, 2]`` (cm), where the member planned at this step; None: no plan.
    plan_hand: np.ndarray | None = None
    plan_candidates: np.ndarray | None = None
    #: Planning iterations run for the decision (0: the habit acted; NaN: not recorded) and its measured time (ms).
    plan_iterations: float = float("nan")
    decision_ms: float = float("nan")

    def with_plant(self, physics: Any) -> "StepRecord":
        """This record with the plant's readings from ``physics`` (a ``planar_arm.Physics``); unchanged for
        the paper's ideal arm."""
        plant = physics.plant
        if plant is None:
            return self
        commanded = physics.servo_setpoint() if plant.actuation == "compliant" else np.full(2, np.nan)
        return dataclasses.replace(self, commanded_angles=_f64(commanded),
                                   joint_velocities=_f64(physics.joint_velocities()),
                                   hand_force=_f64(physics.field_force()), load=float(physics.load))

    @classmethod
    def from_step_info(cls, info: StepInfo, member: int) -> "StepRecord":
        """The record of ``member`` from a member-batched ``apac_mj.types.StepInfo``."""
        def at(name: str) -> Any:
            return np.asarray(getattr(info, name))[member]

        iterations = float("nan") if info.plan_iterations is None else float(info.plan_iterations[member])
        planned = info.plan is not None and iterations > 0
        return cls(
            episode=int(at("episode")), step=int(at("step")),
            true_arm=_f64(at("true_arm")), joint_angles=_f64(at("joint_angles")),
            link_lengths=_f64(at("link_lengths")), target=_f64(at("target")),
            reward=float(at("reward")), distance=float(at("distance")), delta=float(at("delta")),
            habit=bool(at("habit")), predicted_arm=_f64(at("predicted_arm")),
            vision=bool(at("vision")), reached=bool(at("reached")), done=bool(at("done")),
            estimated_state=_f64(np.asarray(info.next_state)[member, POSITIONS]),  # not the plant's extra
            arbitration={k: float(np.asarray(v)[member]) for k, v in getattr(info, "arbitration", {}).items()},
            plan_hand=_f64(info.plan["hand"][member]) if planned else None,
            plan_candidates=_f64(info.plan["candidates"][member]) if planned else None,
            plan_iterations=iterations,
            decision_ms=float("nan") if info.decision_seconds is None else 1e3 * float(info.decision_seconds[member]),
        )


def _f64(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).copy()


def kinematics_error(rec: StepRecord, origin: Sequence[float] = DEFAULT_ORIGIN) -> float:
    """max |MuJoCo arm - motion function arm| over both points and both coordinates (cm)."""
    end, elbow = motion_function(*rec.joint_angles, *rec.link_lengths, origin)
    return float(np.max(np.abs(rec.true_arm - np.concatenate([end, elbow]))))


def estimate_error(rec: StepRecord) -> float:
    """Mean over hand, elbow and target of the integrator's error |estimate - truth| (cm); NaN without one."""
    truth = np.concatenate([rec.true_arm, rec.target])
    return float(np.linalg.norm((rec.estimated_state - truth).reshape(3, 2), axis=1).mean())


def forward_model_error(rec: StepRecord) -> float:
    """Distance between the predicted and the true end-effector (cm); NaN without a prediction."""
    return float(np.linalg.norm(rec.predicted_arm[:2] - rec.true_arm[:2]))


#: Frames per second the viewer plays a recording at: one frame per step of the arm's 100 ms control
#: interval (plant.control_interval), i.e. real time (the viewer's own default, 30, plays 3x too fast).
PLAYBACK_FPS = 10.0


#: The unit of each arbitrator input (``Decision.inputs``; docs/arbitrators.md defines them): the "why" panel draws
#: one plot per unit, so that cm, values and gains never share an axis. An input not listed gets a plot of its own.
INPUT_UNITS = {
    "abs_delta": "|δ| (reward units)", "delta": "δ (reward units)", "threshold": "|δ| (reward units)",
    "habit_uncertainty": "uncertainty (cm²)", "planning_uncertainty": "uncertainty (cm²)",
    "habit_reliability": "probability", "planning_reliability": "probability", "p_planning": "probability",
    "distance": "cm", "habit_final_distance": "cm", "predicted_habit_distance": "cm",
    "time_if_habit": "steps", "time_if_planning": "steps", "planning_gain": "steps", "planning_extra_cost": "steps",
    "habit_value": "value (reward units)", "expected_gain": "value (reward units)",
    "planning_cost": "value (reward units)", "iterations": "iterations", "vision": "vision (1 seen, 0 not)",
    "explored": "re-explored (1 yes, 0 no)",
}
#: The legend of the plane view: (entity path, name); a recording shows the entries it drew.
LEGEND_ENTRIES = (
    (ARM_MUJOCO, "MuJoCo arm"), (ARM_MOTION_FUNCTION, "motion function"), (ARM_FORWARD_MODEL, "forward model, dashed"),
    (PATH, "hand path"), (TARGET, "target and zone"), (ARM_COMMANDED, "commanded arm, dashed"),
    (HAND_FORCE, "field force at the hand"), (PLAN, "MPC plan"), (PLAN_CANDIDATES, "plan candidates"),
)
#: The legend's grid: columns, and the size of a cell (legend units; its swatch is 60% of the width, its name
#: drawn under it): about the aspect of the legend's view under the plane.
LEGEND_COLUMNS, LEGEND_CELL = 3, (16.0, 3.2)


def why_groups(inputs: Sequence[str]) -> list[tuple[str, list[str]]]:
    """The arbitrator's ``inputs`` grouped by unit (:data:`INPUT_UNITS`), in the order they first appear:
    ``[(unit, names)]``; an input of unknown unit is a group of its own."""
    groups: dict[str, list[str]] = {}
    for name in inputs:
        groups.setdefault(INPUT_UNITS.get(name, name), []).append(name)
    return list(groups.items())


def why_view(inputs: Sequence[str]) -> rrb.TimeSeriesView | rrb.Tabs:
    """The "why" panel: one plot per unit of the arbitrator's inputs (tabs when there are several)."""
    groups = why_groups(inputs)
    if not groups:
        return rrb.TimeSeriesView(origin=ARBITRATION_INPUTS, name="why: the arbitrator's inputs to each decision")
    views = [rrb.TimeSeriesView(origin=ARBITRATION_INPUTS, contents=[f"+ $origin/{n}" for n in names],
                                name=f"why ({unit}): {', '.join(names)}") for unit, names in groups]
    return views[0] if len(views) == 1 else rrb.Tabs(*views, name="why: the arbitrator's inputs, by unit")


def legend_layout(count: int) -> tuple[list[np.ndarray], tuple[float, float]]:
    """The swatches of ``count`` legend entries (a strip each, its name drawn under it) and the legend's size."""
    w, h = LEGEND_CELL
    strips = [np.array([[(k % LEGEND_COLUMNS + 0.2) * w, (k // LEGEND_COLUMNS + 0.25) * h],
                        [(k % LEGEND_COLUMNS + 0.8) * w, (k // LEGEND_COLUMNS + 0.25) * h]]) for k in range(count)]
    rows = max(1, -(-count // LEGEND_COLUMNS))
    return strips, (LEGEND_COLUMNS * w, rows * h)


def default_blueprint(plane_size: Sequence[float] = (30.0, 30.0), inputs: Sequence[str] = ()) -> rrb.Blueprint:
    """Two rows: the render, the plane view (its legend below it) and the arbitration's series (the "why" inputs
    one plot per unit, :func:`why_view`) on top, what a reader looks at first; the events log and the plant's and
    the checks' series, one tab each, below. The time panel is collapsed to its play bar, so the views get the
    window's height."""
    w, h = plane_size

    def view(name: str, *paths: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(origin="series", contents=[f"+ {p}" for p in paths], name=name)

    arbitration = rrb.Vertical(
        view("distance (cm), reward", DISTANCE, REWARD),
        view("|delta| vs threshold; controller (1 habit, 0 planning)", ABS_DELTA, DELTA_THRESHOLD, CONTROLLER),
        why_view(inputs),
    )
    details = rrb.Tabs(
        view("forward-model and state-estimate error (cm); vision (1 seen)", FORWARD_ERROR, ESTIMATE_ERROR,
             VISION),
        rrb.TimeSeriesView(origin="series/plant",
                           name="plant: joint velocities (deg/s), field force at the hand (N), hand load (kg)"),
        view("link lengths (cm)", L1, L2),
        view("kinematics check: max |MuJoCo - motion function| (cm)", KINEMATICS_ERROR),
        view("planning: iterations run; the decision's measured time (ms)", PLAN_ITERATIONS, DECISION_MS),
        name="details",
    )
    _, (lw, lh) = legend_layout(len(LEGEND_ENTRIES))
    plane = rrb.Vertical(
        # Origin "/" so that the plane entity's y-flip applies (a view's own origin transform is ignored).
        rrb.Spatial2DView(origin="/", contents=f"+ {PLANE}/**", name="plane (cm)",
                          visual_bounds=rrb.VisualBounds2D(x_range=[0, w], y_range=[0, h])),
        rrb.Spatial2DView(origin=LEGEND, name="legend",
                          visual_bounds=rrb.VisualBounds2D(x_range=[0, lw], y_range=[0, lh])),
        row_shares=[3.2, 1],
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial2DView(origin="render", name="MuJoCo overhead render"),
                plane,
                arbitration,
                column_shares=[1, 1.1, 1.3],
            ),
            rrb.Horizontal(rrb.TextLogView(origin=EVENTS, name="events"), details, column_shares=[1, 1.4]),
            row_shares=[2.4, 1],
        ),
        rrb.TimePanel(timeline="frame", play_state="following", state="collapsed", fps=PLAYBACK_FPS),
        collapse_panels=True,
    )


def field_px_per_cm(plane_size: Sequence[float]) -> float:
    """The distance field's resolution: FIELD_PX_PER_CM, less for a plane wider than FIELD_MAX_PX at that."""
    return min(float(FIELD_PX_PER_CM), FIELD_MAX_PX / max(float(v) for v in plane_size))


def distance_field(target: Sequence[float], plane_size: Sequence[float]) -> np.ndarray:
    """The paper's contour plot as an RGB image: distance to the target with contour bands.

    Row ``r`` covers ``y = r / px`` with ``px = field_px_per_cm(plane_size)`` (row 0 is y = 0): the plane
    entity's transform flips it so that +y points up.
    """
    import matplotlib

    w, h = plane_size
    px = field_px_per_cm(plane_size)
    xs = (np.arange(max(1, int(w * px))) + 0.5) / px
    ys = (np.arange(max(1, int(h * px))) + 0.5) / px
    d = np.hypot(xs[None, :] - target[0], ys[:, None] - target[1])
    rgb = matplotlib.colormaps["viridis"](d / np.hypot(w, h))[..., :3]
    rgb = 0.45 * rgb + 0.55  # pastel, so that the arms drawn on top stand out
    band = (d % CONTOUR_CM) < (1.2 / px)
    rgb[band] *= 0.75
    return (rgb * 255).astype(np.uint8)


def _arm_strip(arm: np.ndarray, origin: Sequence[float]) -> np.ndarray:
    """Shoulder -> elbow -> end-effector polyline from ``[end_x, end_y, elbow_x, elbow_y]``."""
    return np.array([origin, arm[2:4], arm[0:2]], dtype=np.float64)


def _dashed(strip: np.ndarray, dash: float = 0.6) -> np.ndarray:
    """Split a polyline into dashes of length ``dash`` (the paper draws the prediction dashed):
    ``[n, 2, 2]`` (start and end point of every dash)."""
    dashes = []
    for a, b in zip(strip[:-1], strip[1:]):
        n = max(1, int(np.linalg.norm(b - a) / dash))
        starts = np.arange(0, n, 2)
        ts = np.stack([starts, starts + 1], axis=1) / n  # [k, 2] fractions along the segment
        dashes.append(a + (b - a) * ts[..., None])
    return np.concatenate(dashes)


class Recording:
    """One .rrd file being written: episodes, steps, events, properties, blueprint.

    The file is written under a temporary name beside ``path`` and renamed to ``path`` when it is closed
    complete: an existing file at ``path`` stays as it was until then. Closed after an error or an
    interrupt (``close(complete=False)``, or leaving the ``with`` block by an exception) it becomes
    ``NAME.partial.rrd`` instead, with the ``status`` property ``complete = false``
    (:func:`recording_complete`). The temporary of a killed writer is removed by the next recording of
    the same path.

    Args:
      path: the .rrd file to write (its folder is created).
      config: the run's configuration, saved as the ``config`` recording property.
      name: the recording's name in the viewer.
      origin, plane_size, zone_radius, delta_threshold: the task's geometry and the arbitration threshold.
    """

    def __init__(self, path: str | Path, config: dict[str, Any] | None = None, *, name: str = "rollout",
                 origin: Sequence[float] = DEFAULT_ORIGIN, plane_size: Sequence[float] = (30.0, 30.0),
                 zone_radius: float = TaskSpec.zone_radius, delta_threshold: float = 1.0) -> None:
        self.path = Path(path)
        if self.path.suffix != ".rrd":
            raise ValueError(f"recording file must end in .rrd, got {str(path)!r}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(self.path.parent, recursive=False, name=self.path.name)
        fd, tmp = tempfile.mkstemp(prefix=temporary_name(self.path), suffix=".tmp", dir=self.path.parent)
        os.fchmod(fd, 0o666 & ~current_umask())  # the mode an ordinary open gives (mkstemp's is 0600)
        os.close(fd)
        #: Where the file is written until it is closed.
        self.writing = Path(tmp)
        self.episodes = 0
        self.origin = tuple(float(v) for v in origin)
        self.plane_size = tuple(float(v) for v in plane_size)
        self.zone_radius = float(zone_radius)
        self.delta_threshold = float(delta_threshold)
        self.frames = 0
        self._path_points: list[np.ndarray] = []
        #: Buffered rows (episode, step, frame, payload) per entity, sent at each episode start and at close.
        self._rows: dict[str, list[tuple[int, int, int, Any]]] = {}
        # Batch generously: a file gains nothing from low latency, and every chunk carries its own schema.
        batching = rr.ChunkBatcherConfig(flush_tick=BATCH_SECONDS, flush_num_bytes=BATCH_BYTES)
        # A fresh random recording id (Rerun's default): two files opened together never merge.
        self._stream = rr.RecordingStream(APPLICATION_ID, make_default=False, batcher_config=batching)
        # The blueprint and the legend are sent at close, when what was drawn (and the "why" inputs) is known.
        self._stream.save(str(self.writing))
        #: Entities drawn so far, and the arbitrator's inputs in the order they first came (for the blueprint).
        self._drawn: set[str] = set()
        self._inputs: dict[str, None] = {}
        self._trial_styled = False  # the trials' strip styles logged (at the first trial: log_trial)
        self._stream.send_recording_name(name)
        self._send_properties(config or {})
        self._log_static()

    # -- set-up ---------------------------------------------------------------------
    def _send_properties(self, config: dict[str, Any]) -> None:
        flat = {k: _property_value(v) for k, v in _flatten(config).items()}
        flat.setdefault("git_commit", git_commit())
        self._stream.send_property("config", rr.AnyValues(**flat))

    def _log_static(self) -> None:
        s = self._stream
        h = self.plane_size[1]
        # The 2D view draws +y down; flip it so that the plane reads as in the paper (+y up).
        s.log(PLANE, rr.Transform3D(translation=[0.0, h, 0.0], scale=[1.0, -1.0, 1.0]), static=True)
        s.log(FIELD, rr.Transform3D(scale=[1.0 / field_px_per_cm(self.plane_size)] * 3), static=True)
        w = self.plane_size[0]
        border = np.array([[0, 0], [w, 0], [w, h], [0, h], [0, 0]], dtype=np.float64)
        s.log(BORDER, rr.LineStrips2D([border], colors=[_GREY], radii=[0.05]), static=True)
        s.log(SHOULDER, rr.Points2D([self.origin], radii=[0.35], colors=[_BLACK]), static=True)
        styles = {
            REWARD: _ORANGE, DISTANCE: _BLUE, ABS_DELTA: _ORANGE, DELTA_THRESHOLD: _GREY, CONTROLLER: _GREEN,
            FORWARD_ERROR: _GREEN, KINEMATICS_ERROR: _RED, L1: _PURPLE, L2: _GREY, VISION: _BLUE,
        }
        for path, color in styles.items():
            s.log(path, rr.SeriesLines(colors=[color], names=[path.rsplit("/", 1)[-1]]), static=True)
        for path, (color, radius, order) in _STRIP_STYLES.items():
            s.log(path, rr.LineStrips2D.from_fields(colors=[color], radii=[radius], draw_order=order), static=True)

    # -- logging ----------------------------------------------------------------------
    # Per-step data is buffered and sent as columns once per episode (at the next episode start and
    # at close): one Rerun call per entity and episode instead of one per entity and step.
    def _buffer(self, path: str, episode: int, step: int, payload: Any) -> None:
        self._rows.setdefault(path, []).append((int(episode), int(step), self.frames, payload))

    def start_episode(self, episode: int, target: Sequence[float], link_lengths: Sequence[float],
                      note: str = "", title: str = "") -> None:
        """Log the episode's target, target zone and distance field, and the start event (``title``: what the
        episode is, e.g. a forced-response trial; default "episode N")."""
        self.flush()
        self._path_points = []
        self.episodes += 1
        s = self._stream
        s.set_time("episode", sequence=int(episode))
        s.set_time("step", sequence=0)
        s.set_time("frame", sequence=self.frames)
        target = np.asarray(target, dtype=np.float64)
        s.log(TARGET, rr.Points2D([target], radii=[0.25], colors=[_RED]))
        s.log(TARGET_ZONE, rr.Ellipses2D(centers=[target], half_sizes=[[self.zone_radius] * 2],
                                         colors=[_RED], line_radii=[0.05]))
        field = distance_field(target, self.plane_size)
        s.log(FIELD, rr.EncodedImage(contents=encode_jpeg(field, quality=80), media_type="image/jpeg",
                                     draw_order=-10.0, magnification_filter="Linear"))
        l1, l2 = (float(v) for v in link_lengths)
        extra = f" {note}" if note else ""
        self.event(episode, 0, f"{title or f'episode {episode}'} starts: target ({target[0]:.2f}, {target[1]:.2f}) cm, "
                               f"lengths l1={l1:.3f} l2={l2:.3f} cm{extra}")

    def log_trial(self, episode: int, step: int, view: dict[str, Any] | None) -> None:
        """A ``[trials]`` task's trial at (episode, step) (``view``: ``suite.trials.TrialRunner.view``; None: no
        table): the channel's walls on a channel trial; at step 0 an event naming the trial and a cross at the hand's
        start on a catch trial; at the go cue an event and a cross on the target it shows."""
        if view is None:
            return
        if not self._trial_styled:
            for path, (color, radius, order) in _TRIAL_STYLES.items():
                self._stream.log(path, rr.LineStrips2D.from_fields(colors=[color], radii=[radius], draw_order=order),
                                 static=True)
            self._trial_styled = True
        if step == 0:  # the last trial's walls and markers go
            for path in TRIAL_PATHS:
                self._stream.log(path, rr.Clear(recursive=False))
            self.event(episode, 0, f"{view['type']} trial in block {view['block']!r} "
                                   f"(curl field b = {view['field_b']:g} N·s/m)")
            if view["type"] == "catch":
                self._buffer(TRIAL_MARKER, episode, 0, _cross(view["start"]))
        if view["channel"] is not None:
            a, t, n = view["channel"]
            self._buffer(CHANNEL, episode, step, [np.stack([a + side * n, t + side * n])
                                                   for side in (CHANNEL_HALF_WIDTH, -CHANNEL_HALF_WIDTH)])
        if view["go_cue_step"] and step == view["go_cue_step"]:
            t = view["target"]
            self.event(episode, step, f"go cue: the target shown at ({t[0]:.2f}, {t[1]:.2f}) cm")
            self._buffer(TRIAL_MARKER, episode, step, _cross(t))

    def event(self, episode: int, step: int, text: str, level: str = "INFO") -> None:
        """A text event at (episode, step) and the current frame."""
        self._buffer(EVENTS, episode, step, (text, level))

    def log_step(self, rec: StepRecord, frame_jpeg: bytes | None) -> None:
        """Log one step: the render, the three arms, the path, every time series and the events."""
        if frame_jpeg is not None:
            self._buffer(RENDER, rec.episode, rec.step, frame_jpeg)
        self._log_arms(rec)
        self._log_series(rec)
        self._log_step_events(rec)
        self.frames += 1

    def _log_arms(self, rec: StepRecord) -> None:
        e, k = rec.episode, rec.step
        self._buffer(ARM_MUJOCO, e, k, [_arm_strip(rec.true_arm, self.origin)])
        end, elbow = motion_function(*rec.joint_angles, *rec.link_lengths, self.origin)
        self._buffer(ARM_MOTION_FUNCTION, e, k, [_arm_strip(np.concatenate([end, elbow]), self.origin)])
        predicted = np.all(np.isfinite(rec.predicted_arm))
        # No prediction (the start pose): an empty batch, so the previous episode's arm does not linger.
        self._buffer(ARM_FORWARD_MODEL, e, k, _dashed(_arm_strip(rec.predicted_arm, self.origin)) if predicted else [])
        self._path_points.append(rec.true_arm[:2].copy())
        self._buffer(PATH, e, k, [np.array(self._path_points)])
        if np.all(np.isfinite(rec.commanded_angles)):
            end, elbow = motion_function(*rec.commanded_angles, *rec.link_lengths, self.origin)
            self._buffer(ARM_COMMANDED, e, k, _dashed(_arm_strip(np.concatenate([end, elbow]), self.origin)))
        if np.isfinite(rec.plan_iterations):  # an agent with a planner acted: its plan, or none (an empty batch)
            self._buffer(PLAN, e, k, [] if rec.plan_hand is None else [rec.plan_hand])
            self._buffer(PLAN_CANDIDATES, e, k, [] if rec.plan_candidates is None else list(rec.plan_candidates))
        if np.all(np.isfinite(rec.hand_force)):
            hand = rec.true_arm[:2]
            force = [np.array([hand, hand + FORCE_CM_PER_N * rec.hand_force])] if np.any(rec.hand_force) else []
            self._buffer(HAND_FORCE, e, k, force)

    def _log_series(self, rec: StepRecord) -> None:
        values = {
            REWARD: rec.reward, DISTANCE: rec.distance, ABS_DELTA: abs(rec.delta),
            DELTA_THRESHOLD: self.delta_threshold,
            CONTROLLER: float("nan") if rec.step == 0 else HABIT if rec.habit else PLANNING,  # none acts at step 0
            FORWARD_ERROR: forward_model_error(rec), KINEMATICS_ERROR: kinematics_error(rec, self.origin),
            L1: rec.link_lengths[0], L2: rec.link_lengths[1], VISION: 1.0 if rec.vision else 0.0,
            ESTIMATE_ERROR: estimate_error(rec),
            **{f"{ARBITRATION_INPUTS}/{name}": value for name, value in rec.arbitration.items()},
            LOAD: rec.load, HAND_FORCE_SIZE: float(np.hypot(*rec.hand_force)),
            f"{JOINT_VELOCITY}/shoulder": rec.joint_velocities[0], f"{JOINT_VELOCITY}/elbow": rec.joint_velocities[1],
            PLAN_ITERATIONS: rec.plan_iterations, DECISION_MS: rec.decision_ms,
        }
        for path, value in values.items():
            if np.isfinite(value):
                self._buffer(path, rec.episode, rec.step, float(value))
        self._inputs.update(dict.fromkeys(rec.arbitration))

    def _log_step_events(self, rec: StepRecord) -> None:
        e, k = rec.episode, rec.step
        if k > 0 and not rec.vision:
            self.event(e, k, f"occluded: arm and target not seen at step {k}", level="DEBUG")
        if k > 0 and rec.arbitration:
            why = ", ".join(f"{name} {value:.3g}" for name, value in rec.arbitration.items())
            self.event(e, k, f"step {k - 1}: {'habit' if rec.habit else 'planning'} acted ({why})", level="DEBUG")
        if rec.reached:
            self.event(e, k, f"target reached at step {k} (distance {rec.distance:.3f} cm)")
        elif rec.done:
            self.event(e, k, f"time limit at step {k} (distance {rec.distance:.3f} cm)", level="WARN")

    def flush(self) -> None:
        """Send everything buffered since the last episode start as columns."""
        for path, rows in self._rows.items():
            episode, step, frame, payload = zip(*rows)
            if path in _STRIP_STYLES and not any(len(row) for row in payload):
                continue  # only empty batches (no prediction in any row): nothing to draw or clear
            self._drawn.add(path)
            self._stream.send_columns(
                path,
                indexes=[rr.TimeColumn("episode", sequence=episode), rr.TimeColumn("step", sequence=step),
                         rr.TimeColumn("frame", sequence=frame)],
                columns=_columns(path, list(payload)),
            )
        self._rows = {}

    def close(self, complete: bool = True) -> Path:
        """Send the buffered rows, mark the file complete or not, flush, close, check and rename it: to ``path``
        (complete) or ``NAME.partial.rrd``; return where it went.

        A file that cannot be finished (a full disk, a writer that died or hangs: Rerun's writer only logs
        its write errors) is removed with its temporary, and the error says so: an OSError ENOSPC naming
        ``path`` when the disk is full, else a :class:`RecordingError`. Nothing is renamed then, so the file
        at ``path`` (or ``NAME.partial.rrd``) is always one that reads to its end."""
        if self.writing is None:
            return self.path
        final = self.path if complete else partial_path(self.path)
        try:
            self._finish(complete)
        except Exception as e:  # noqa: BLE001 - Rerun raises RuntimeError, the reader RuntimeError or ValueError
            error = write_error(self.path, self.writing, e)
            self._discard()
            raise error from e
        except BaseException:  # Ctrl-C or SIGTERM while the last rows are written: no half file is kept
            self._discard()
            raise
        os.replace(self.writing, final)
        self.writing = None
        return final

    def _finish(self, complete: bool) -> None:
        """Write the last rows and the status, flush within FLUSH_SECONDS, close the stream, read the file back."""
        self.flush()
        self._log_legend()
        self._stream.send_blueprint(default_blueprint(self.plane_size, list(self._inputs)))
        self._stream.send_property("status", rr.AnyValues(complete=complete, episodes=self.episodes,
                                                          frames=self.frames))
        self._stream.flush(timeout_sec=FLUSH_SECONDS)
        self._stream.disconnect()
        check_written(self.writing, complete)

    def _log_legend(self) -> None:
        """The plane view's legend: a swatch in its colour and the name of every line entity drawn, and the
        target's, on a light background (so that the black arm's name reads in the viewer's dark theme)."""
        drawn = [(path, name) for path, name in LEGEND_ENTRIES
                 if path in self._drawn or (path == TARGET and self.episodes)]
        strips, (w, h) = legend_layout(len(drawn))
        s = self._stream
        s.log(LEGEND_BACKGROUND, rr.Image(np.full((2, 2, 3), 235, dtype=np.uint8), draw_order=-10.0), static=True)
        s.log(LEGEND_BACKGROUND, rr.Transform3D(scale=[w / 2, h / 2, 1.0]), static=True)
        for k, ((path, name), strip) in enumerate(zip(drawn, strips)):
            color = _RED if path == TARGET else _STRIP_STYLES[path][0]
            s.log(f"{LEGEND}/{k}", rr.LineStrips2D([strip], colors=[color], radii=[0.35], labels=[name],
                                                   show_labels=True), static=True)

    def _discard(self) -> None:
        """Remove the temporary of a recording that cannot be finished (the stream's file handle closed first)."""
        writing, self.writing = self.writing, None
        try:
            self._stream.disconnect()
        finally:
            writing.unlink(missing_ok=True)

    def __enter__(self) -> "Recording":
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.close(complete=exc_type is None)


class RecordingError(RuntimeError):
    """A recording that could not be written to its end (other than a full disk, an OSError ENOSPC); the message
    names the file and the cause. Nothing was left under its name, and no temporary."""


#: At most this long (s) for a closing recording's last rows to reach its file: a writer that died or hangs (a
#: full disk) is an error within seconds, not a wait without end (a healthy flush of BATCH_BYTES takes < 1 s).
FLUSH_SECONDS = 20.0
#: A file system with less than this free (bytes) after a failed write is full (the write took what was left).
FULL_BELOW = 1 << 20


def check_written(path: Path, complete: bool) -> None:
    """The recording at ``path`` reads back to its end and its status says ``complete`` (Rerun's writer only
    logs a failed write, so a full disk leaves a file that does not); else a RuntimeError saying what is wrong."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "no footer": the reader's warning for a cut file, said below
            status = recording_complete(path)
    except (RuntimeError, ValueError, OSError) as e:
        raise RuntimeError(f"the file does not read back ({e})") from None
    if status is not complete:
        raise RuntimeError("the file ends before its last rows (its status is missing)")


def write_error(path: Path, writing: Path, cause: BaseException) -> Exception:
    """The error for a recording of ``path`` (written at ``writing``) that could not be finished: an OSError
    ENOSPC naming ``path`` if the file system is full now, else a :class:`RecordingError` with ``cause``."""
    try:
        free = shutil.disk_usage(writing.parent).free
    except OSError:
        free = None
    kept = f"; {path} was left as it was and no temporary file remains"
    if free is not None and free < FULL_BELOW:
        return OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)}: {free} bytes free after writing "
                                     f"{_size(writing)} of the recording{kept}", str(path))
    return RecordingError(f"the recording {path} could not be written to its end ({type(cause).__name__}: "
                          f"{cause}){kept}")


def _size(path: Path) -> str:
    try:
        return f"{path.stat().st_size / 1e6:.2f} MB"
    except OSError:
        return "part"


#: (color, radius cm, draw order) of the line-strip entities, logged once as static components.
_STRIP_STYLES = {
    ARM_MUJOCO: (_BLACK, 0.3, 20.0), ARM_MOTION_FUNCTION: (_ORANGE, 0.1, 21.0),
    ARM_FORWARD_MODEL: (_GREEN, 0.15, 22.0), PATH: (_BLUE, 0.08, 15.0),
    ARM_COMMANDED: (_PURPLE, 0.12, 19.0), HAND_FORCE: (_BROWN, 0.12, 23.0),
    PLAN: (_MAGENTA, 0.12, 18.0), PLAN_CANDIDATES: (_GREY, 0.04, 16.0),
}


def _columns(path: str, payload: list[Any]) -> Any:
    """The Rerun columns of one entity's buffered rows."""
    if path == RENDER:
        return rr.EncodedImage.columns(blob=payload, media_type=["image/jpeg"] * len(payload))
    if path == EVENTS:
        text, level = zip(*payload)
        return rr.TextLog.columns(text=list(text), level=list(level))
    if path in _STRIP_STYLES or path in _TRIAL_STYLES:
        strips = [strip for row in payload for strip in row]
        if strips and len({strip.shape for strip in strips}) == 1:
            # equal-length strips (arms, dashes) as one [n, points, 2] array: the SDK's fast path
            # (a list of arrays is converted strip by strip, ~80 us each)
            strips = np.stack(strips).astype(np.float32)
        return rr.LineStrips2D.columns(strips=strips).partition([len(row) for row in payload])
    return rr.Scalars.columns(scalars=np.asarray(payload, dtype=np.float64))


#: The trials' strips (:data:`TRIAL_PATHS`): styled when a recording first draws a trial, so that a recording of a
#: task without a ``[trials]`` table holds none of them.
_TRIAL_STYLES = {CHANNEL: ((90, 90, 90), 0.08, 12.0), TRIAL_MARKER: ((0, 150, 150), 0.1, 24.0)}


def _cross(xy: Sequence[float], size: float = 0.4) -> list[np.ndarray]:
    """Two strokes crossing at ``xy`` (cm), ``size`` long each."""
    x, y, h = float(xy[0]), float(xy[1]), size / 2.0
    return [np.array([[x - h, y - h], [x + h, y + h]]), np.array([[x - h, y + h], [x + h, y - h]])]


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, f"{key}."))
        else:
            out[key] = v
    return out


def _property_value(v: Any) -> Any:
    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, (list, tuple)) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        return [float(x) for x in v]
    return str(v)


# -- reading recordings back (tests, checks) -----------------------------------------------
@dataclasses.dataclass
class EntityRows:
    """The rows of one entity read back from a .rrd: timeline columns and component columns."""

    times: dict[str, list[int]]
    components: dict[str, list[Any]]


def read_recording(path: str | Path) -> tuple[dict[str, EntityRows], dict[str, Any], int]:
    """Read a .rrd back without a viewer.

    Returns ``(entities, properties, blueprints)``: the temporal rows per entity
    path (without the leading "/"), the ``config`` property, and the number of
    blueprint stores in the file.
    """
    from rerun.chunk import RrdReader

    reader = RrdReader(str(path))
    entities: dict[str, EntityRows] = {}
    properties: dict[str, Any] = {}
    for chunk in reader.stream():
        table = chunk.to_record_batch().to_pydict()
        path_ = chunk.entity_path.lstrip("/")
        if path_ == "__properties/config":
            properties.update({k: v[0] for k, v in table.items() if not k.startswith("rerun.")})
        if chunk.is_static:
            continue
        rows = entities.setdefault(path_, EntityRows({}, {}))
        for col, values in table.items():
            if col in chunk.timeline_names:
                rows.times.setdefault(col, []).extend(values)
            elif not col.startswith("rerun."):
                rows.components.setdefault(col, []).extend(values)
    return entities, properties, len(reader.blueprints())


def partial_path(path: str | Path) -> Path:
    """Where an incomplete recording of ``path`` goes: ``NAME.partial.rrd``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def recording_complete(path: str | Path) -> bool | None:
    """Whether the recording at ``path`` was closed complete (None: written before recordings said so)."""
    from rerun.chunk import RrdReader

    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path.lstrip("/") == "__properties/status":
            table = chunk.to_record_batch().to_pydict()
            for k, v in table.items():
                if k.split(":")[-1] == "complete" or k.endswith("complete"):
                    return bool(v[0][0] if isinstance(v[0], list) else v[0])
    return None


def scalar_series(rows: EntityRows, timeline: str = "frame") -> tuple[np.ndarray, np.ndarray]:
    """``(times, values)`` of a ``Scalars`` entity, sorted by ``timeline``."""
    t = np.asarray(rows.times[timeline])
    v = np.asarray([x[0] for x in rows.components["Scalars:scalars"]], dtype=np.float64)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


# -- recording a plain dm_control environment ------------------------------------------------
def step_record_from_env(env: control.Environment, episode: int, timestep: dm_env.TimeStep | None = None, *, habit: bool = False,
                         delta: float = float("nan"), predicted_arm: np.ndarray | None = None) -> StepRecord:
    """A :class:`StepRecord` read from a ``suite`` environment's physics after a reset or a step."""
    physics, task = env.physics, env.task
    distance = physics.distance_to_target()
    first = timestep is None or timestep.first()
    return StepRecord(
        episode=episode, step=task.step_count,
        true_arm=np.concatenate([physics.end_effector(), physics.elbow()]),
        joint_angles=physics.joint_angles(), link_lengths=physics.link_lengths(), target=physics.target(),
        reward=float("nan") if first else float(timestep.reward), distance=distance, delta=delta, habit=habit,
        predicted_arm=np.full(4, np.nan) if predicted_arm is None else _f64(predicted_arm),
        vision=bool(timestep is None or timestep.observation["vision"][0] > 0),
        reached=bool(task.reached(physics)), done=not first and timestep.last(),
    ).with_plant(physics)


def recording_for_env(path: str | Path, env: control.Environment, config: dict[str, Any] | None = None, *,
                      name: str = "rollout", delta_threshold: float = 1.0) -> Recording:
    """A :class:`Recording` with the geometry of a ``suite`` environment's task."""
    spec = env.task.spec
    return Recording(path, config, name=name, origin=spec.origin, plane_size=spec.plane_size,
                     zone_radius=spec.zone_radius, delta_threshold=delta_threshold)


# -- hooks for training and rollouts ----------------------------------------------------------
class EpisodeRecorder(Hook):
    """Records every ``record_every``-th episode of one member: a hook of the episode loop.

    Pass it in the ``hooks`` of :func:`apac_mj.run.trainer.train` (``apac-mj train
    --record-every N`` does it), :func:`apac_mj.run.evaluate.evaluate` or
    :class:`apac_mj.run.rollout.EpisodeLoop`, and close it (or use it as a context manager)
    when the loop is done. Only recorded episodes
    are rendered. Episode ``e`` counts training episodes (babbling negative), as the environments count
    them (:meth:`apac_mj.suite.vec_env.VecEnv.episode`: the reset count minus their episode offset).

    Args:
      directory: where one ``episode_XXXXXX.rrd`` per recorded episode goes (ignored with ``out``).
      record_every: record episodes whose number is a multiple of this.
      config: the run's configuration (saved as the ``config`` recording property).
      member: which ensemble member (seed index) to record.
      out: write every recorded episode into this one .rrd file instead.
      keep_frames: keep the rendered RGB frames in :attr:`frames` (for a video).
    """

    def __init__(self, directory: str | Path, record_every: int = 1, config: dict[str, Any] | None = None, *,
                 member: int = 0, out: str | Path | None = None, keep_frames: bool = False) -> None:
        if record_every < 1:
            raise ValueError(f"record_every must be >= 1, got {record_every}")
        if member < 0:
            raise ValueError(f"member must be >= 0, got {member}")
        self.directory, self.record_every, self.member = Path(directory), int(record_every), int(member)
        self.config = dict(config or {})
        agent_cfg = self.config.get("agent", {})
        self.delta_threshold = float(agent_cfg.get("delta_threshold", 1.0))
        self.out = None if out is None else Path(out)
        self.keep_frames = keep_frames
        #: RGB frames of the recorded steps (with ``keep_frames``).
        self.frames: list[np.ndarray] = []
        #: The .rrd files written so far.
        self.files: list[Path] = []
        self._recording: Recording | None = None
        self._renderer: Renderer | None = None
        self._start: tuple[StepRecord, np.ndarray] | None = None
        self._recording_episode = False
        #: A line logged as an event at each recorded episode's start (e.g. a forced-response trial's timing).
        self.note = ""
        #: What the next recorded episode is, for its start event (e.g. "trial 2 of 3 (deadline 450 ms, cue 1)").
        self.title = ""

    # -- hooks ----------------------------------------------------------------------------------
    def on_episode_start(self, members: np.ndarray, vec_env: VecEnv) -> None:
        """Decide whether the member's new episode is recorded; if so, render its start pose."""
        m = self.member
        if m >= vec_env.E:
            raise ValueError(f"member {m} out of range: the ensemble has {vec_env.E} members")
        if not bool(np.asarray(members)[m]):
            return
        episode = vec_env.episode(m)
        self._recording_episode = episode % self.record_every == 0
        if not self._recording_episode:
            return
        physics = vec_env.physics(m)
        start = StepRecord(
            episode=episode, step=0, true_arm=np.concatenate([physics.end_effector(), physics.elbow()]),
            joint_angles=physics.joint_angles(), link_lengths=physics.link_lengths(), target=physics.target(),
            distance=physics.distance_to_target(), vision=True).with_plant(physics)
        self._start = (start, self._render(physics))

    def on_step(self, info: StepInfo, vec_env: VecEnv) -> None:
        """Log the member's step (the episode's file is opened at its first step)."""
        m = self.member
        if not self._recording_episode or not bool(np.asarray(info.active)[m]):
            return
        rec = StepRecord.from_step_info(info, m).with_plant(vec_env.physics(m))
        rec.step += 1  # StepInfo counts the step at which the action was taken; the record, the arm after it
        if self._start is not None:
            self._open_episode(rec.episode, vec_env)
        self._recording.log_trial(rec.episode, rec.step, vec_env.trial_view(m))
        self._log(rec, self._render(vec_env.physics(m)))
        if rec.done:
            self._recording_episode = False
            if self.out is None:
                self._close_recording()

    def close(self, complete: bool = True) -> None:
        """Close the open recording (``complete=False``: it becomes ``NAME.partial.rrd``) and the renderer (also
        when the recording cannot be finished: :meth:`Recording.close`)."""
        try:
            self._close_recording(complete)
        finally:
            if self._renderer is not None:
                self._renderer.close()
                self._renderer = None

    # -- internals ------------------------------------------------------------------------------
    def _render(self, physics: Any) -> np.ndarray:
        if self._renderer is None or self._renderer.physics is not physics:
            if self._renderer is not None:
                self._renderer.close()
            self._renderer = Renderer(physics)
        return self._renderer.render()

    def _open_episode(self, episode: int, vec_env: VecEnv) -> None:
        start, frame = self._start  # type: ignore[misc]
        self._start = None
        start.episode = episode
        if self._recording is None:
            path = self.out or self.directory / f"episode_{episode:06d}.rrd"
            spec = vec_env.spec
            self._recording = Recording(path, self.config, name=path.stem, origin=spec.origin,
                                        plane_size=spec.plane_size, zone_radius=spec.zone_radius,
                                        delta_threshold=self.delta_threshold)
            self.files.append(path)
        note = "(vision occluded after the first step)" if vec_env.spec.occluded else ""
        self._recording.start_episode(episode, start.target, start.link_lengths, note=note, title=self.title)
        if self.note:
            self._recording.event(episode, 0, self.note)
        self._recording.log_trial(episode, 0, vec_env.trial_view(self.member))
        self._log(start, frame)

    def _log(self, rec: StepRecord, frame: np.ndarray) -> None:
        assert self._recording is not None
        self._recording.log_step(rec, encode_jpeg(frame))
        if self.keep_frames:
            self.frames.append(frame)

    def _close_recording(self, complete: bool = True) -> None:
        recording, self._recording = self._recording, None  # dropped also when it cannot be finished
        if recording is None:
            return
        try:
            final = recording.close(complete)
        except BaseException:
            self.files.pop()  # not written
            raise
        if final != recording.path:
            self.files[-1] = final
            print(f"the recording was interrupted: its episodes so far are in {final} (marked partial); "
                  f"{recording.path} was left as it was", file=sys.stderr)

    def __enter__(self) -> "EpisodeRecorder":
        return self

    def __exit__(self, exc_type: Any, *exc: Any) -> None:
        self.close(complete=exc_type is None)
