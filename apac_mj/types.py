"""The records and contracts that cross layers: the agent's state layout (:data:`END`, :data:`TARGET`, ...),
what the plant shows (:class:`Observation`), what an
arbitrator sees (:class:`ArbitrationContext`) and decides (:class:`Decision`), what every step did
(:class:`StepInfo`); the time cost of an action; and the extension points' base classes
(:class:`Arbitrator`, :class:`Planner`, :class:`Integrator`) and what the episode loop calls on an agent (:class:`Policy`).

They live below the plant (``suite``), the learner (``agent``) and the run (``run``), so each of those names
them in its signatures without importing the others. Units are the paper's: cm and degrees. This module
loads no torch at import (the report and the command line read it without torch); the records that hold
tensors import it when built.
"""
from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, Callable, NamedTuple, Protocol

import numpy as np

if TYPE_CHECKING:
    import torch

    from apac_mj.config import AgentConfig
    from apac_mj.layout import Sizes

#: Time cost of one action of each controller (the paper's Fig. 6: planning three times slower than a habit).
PLANNING_COST, HABIT_COST = 3, 1
#: The agent's four losses (``Agent.update``), in the order of metrics.parquet's ``<name>_loss`` columns; an agent
#: with a dynamics model adds ``"dynamics"`` (``Agent.loss_names``), its column after the others.
LOSSES = ("critic", "actor", "forward", "inverse")
#: The measured per-episode columns (``EpisodeState.summary``): the decision time where the habit and where the
#: planner acted (s) and the planning iterations. Wall times differ from run to run; the iterations do not.
TIMING_COLUMNS = ("habit_seconds", "planning_seconds", "plan_iterations")

# The agent's state and its named parts (END, TARGET, ...) are apac_mj.layout's; named here too, for the records.
from apac_mj.layout import (ARM, ELBOW, END, EXTRA, MOTION_EXTRA, POSITION_DIM, POSITIONS,  # noqa: E402,F401
                            TARGET, StateLayout)


@dataclasses.dataclass
class Observation:
    """Member-batched view of the last time step of every member (cm).

    Only the members stepped or reset by the call that returned it are fresh;
    the others keep their previous values. Positions read zero where
    ``vision`` is False (occluded vision).
    """

    arm: np.ndarray        # [E, 4] observed [end_x, end_y, elbow_x, elbow_y]
    target: np.ndarray     # [E, 2] observed target
    vision: np.ndarray     # [E] bool: the positions above were seen
    reward: np.ndarray     # [E] the environment's reward (-distance); 0 after a reset
    last: np.ndarray       # [E] bool: the episode ended (target reached or time limit)
    reached: np.ndarray    # [E] bool: the episode ended inside the target zone



@dataclasses.dataclass
class ArbitrationContext:
    """What an arbitrator sees at one step, member-batched ``[E]`` (CPU tensors except ``state``).

    Members that do not step this time have stale rows; their decision is ignored.
    """

    #: Training episode (0-based; babbling negative) as the arbitrator is to read it.
    episode: torch.Tensor
    #: Step within the episode (0-based).
    step: torch.Tensor
    #: TD error of the member's last transition (float32; NaN: none yet this episode).
    last_delta: torch.Tensor
    #: ``[E, HISTORY]`` TD errors of this episode's last transitions, oldest first, NaN-padded on the left.
    recent_deltas: torch.Tensor | None = None
    #: True where the state the agent acts on was seen (always at an episode's start).
    vision: torch.Tensor | None = None
    #: Forward model's error (cm, Euclidean over end and elbow) at the member's last seen step; NaN: none yet.
    forward_error: torch.Tensor | None = None
    #: The state the agent acts on ``[E, 6 + extra]`` (the integrator's estimate, then the task's extra
    #: observations; read it through :data:`END`, :data:`TARGET`, ...; on the agent's device); None if not given.
    state: torch.Tensor | None = None
    #: The actor's proposal ``[E, 2]`` (degrees, no noise) in ``state``; None if not given (the episode loop gives
    #: it only to rules that read it, :attr:`Arbitrator.needs_habit_action`).
    habit_action: torch.Tensor | None = None
    #: The forward model as a checker: action ``[E, 2]`` -> predicted end effector ``[E, 2]`` after it
    #: (from ``state``); None if not given.
    predict_end: Callable[[torch.Tensor], torch.Tensor] | None = None
    #: The habit's sequence imagined through the forward model (:class:`HabitProbe`), computed when first
    #: called (the rules that need it call it; the planner reuses it); None: no model planner.
    habit_probe: Callable[[], "HabitProbe"] | None = None
    #: Radius of the target zone (cm) the agent judges its estimate by. The episode loop always passes the
    #: task's (``EpisodeLoop.zone_radius``, owned by ``TaskSpec.zone_radius``); the default, the paper's 0.5,
    #: is only for contexts built by hand (tests, a rule tried alone).
    zone_radius: float = 0.5

    def __post_init__(self) -> None:
        import torch

        self.episode, self.step = torch.as_tensor(self.episode), torch.as_tensor(self.step)
        self.last_delta = torch.as_tensor(self.last_delta, dtype=torch.float32)
        if not (self.episode.shape == self.step.shape == self.last_delta.shape) or self.episode.dim() != 1:
            raise ValueError("episode, step and last_delta must be 1-D tensors of equal length [E], got "
                             f"{tuple(self.episode.shape)}, {tuple(self.step.shape)}, {tuple(self.last_delta.shape)}")
        E = len(self.episode)
        nan = torch.full((E,), float("nan"))
        self.recent_deltas = (self.last_delta[:, None] if self.recent_deltas is None
                              else torch.as_tensor(self.recent_deltas, dtype=torch.float32))
        self.vision = torch.ones(E, dtype=torch.bool) if self.vision is None else torch.as_tensor(self.vision)
        self.forward_error = nan if self.forward_error is None else torch.as_tensor(self.forward_error,
                                                                                   dtype=torch.float32)
        for name in ("vision", "forward_error"):
            if tuple(getattr(self, name).shape) != (E,):
                raise ValueError(f"{name} must have shape ({E},), got {tuple(getattr(self, name).shape)}")
        if self.recent_deltas.dim() != 2 or len(self.recent_deltas) != E:
            raise ValueError(f"recent_deltas must have shape ({E}, H), got {tuple(self.recent_deltas.shape)}")

    @property
    def E(self) -> int:
        return len(self.episode)



@dataclasses.dataclass
class StepInfo:
    """What every member did at one step; member-batched numpy arrays (cm, degrees).

    Rows of members that were not ``active`` are stale and must be ignored.
    """

    episode: np.ndarray        # [E] int: training episode (babbling: negative)
    step: np.ndarray           # [E] int: step within the episode at which the action was taken (0-based)
    active: np.ndarray         # [E] bool: the member stepped
    state: np.ndarray          # [E, 6 + extra] the state the agent acted on [end, elbow, target, extra] (END, ...)
    true_arm: np.ndarray       # [E, 4] MuJoCo's arm after the step [end, elbow]
    target: np.ndarray         # [E, 2] the true target
    action: np.ndarray         # [E, 2] commanded action (joint-angle changes, degrees; the plant clips it)
    habit: np.ndarray          # [E] bool: True if the actor acted, False if the inverse model (or babbling)
    delta: np.ndarray          # [E] TD error of this transition
    predicted_arm: np.ndarray  # [E, 4] the forward model's prediction of the arm after the step
    reward: np.ndarray         # [E] reward the agent learned from (see module doc)
    distance: np.ndarray       # [E] true end-effector to target distance after the step
    done: np.ndarray           # [E] bool: the episode ended at this step
    reached: np.ndarray        # [E] bool: ended inside the target zone (true position)
    vision: np.ndarray         # [E] bool: the arm and target were seen after the step
    joint_angles: np.ndarray   # [E, 2] after the step
    link_lengths: np.ndarray   # [E, 2] after the step
    next_state: np.ndarray     # [E, 6 + extra] the state after the step (s_{t+1}), laid out as ``state``
    terminal: np.ndarray       # [E] bool: the transition is terminal for learning (perceived reach)
    zone_radius: float         # radius (cm) of the target zone the agent judged ``terminal`` by
    #: The arbitrator's decision inputs at this step, ``name -> [E]`` (:attr:`Decision.inputs`; empty for
    #: rules without inputs): what recordings show as "why".
    arbitration: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    #: ``[E]`` seconds of computing the decision, each member's share of the measured wall time of the
    #: actor's forward pass (every member) plus, where it planned, of the planner's call (shared by the
    #: planning members in proportion to their iterations). A measurement: it differs between runs.
    decision_seconds: np.ndarray | None = None
    #: ``[E]`` ints: planning iterations run for each member (1 for the inverse model; 0 where the habit acted).
    plan_iterations: np.ndarray | None = None
    #: ``[E, K]`` a model planner's best imagined value after each of its iterations minus the habit's
    #: (cm of return; NaN past a member's budget); None: no model planner.
    plan_gains: np.ndarray | None = None
    #: A model planner's imagined plan at this step (recordings draw it): ``"hand"`` ``[E, H + 1, 2]`` the chosen
    #: sequence's imagined hand, ``"candidates"`` ``[E, C, H + 1, 2]`` a few of the last iteration's sampled
    #: sequences (cm); rows of members that did not plan (``plan_iterations`` 0) are stale. None: no plan made.
    plan: dict[str, np.ndarray] | None = None
    #: The same step in the learner's form, on the agent's device (the tensors the numpy fields above were
    #: copied from once): what the trainer stores and the episode loop carries, so that the step's data
    #: makes no round trip through the host. None: a record built by hand (hooks need only the numpy).
    tensors: StepTensors | None = None


@dataclasses.dataclass(frozen=True)
class StepTensors:
    """A step's learner-side data, ``[E, ...]`` tensors on the agent's device (float32; ``terminal`` bool)."""

    state: torch.Tensor       # [E, 6 + extra] s_t, the estimate acted on
    action: torch.Tensor      # [E, 2] the command (after the arbitrator, noise, bounds and any override)
    reward: torch.Tensor      # [E] the reward learned from
    next_state: torch.Tensor  # [E, 6 + extra] s_{t+1}
    terminal: torch.Tensor    # [E] bool


class Decision(NamedTuple):
    """An arbitrator's decision at one step: where the habit acts, and why."""

    #: ``[E]`` bool: True where the actor (habit) acts, False where the inverse model (planning) does.
    habit: torch.Tensor
    #: The decision's inputs, ``name -> [E]`` (recordings show them per step); empty: none to show.
    inputs: dict[str, torch.Tensor] = {}
    #: ``[E]`` ints: how many iterations an anytime planner may run for each member that plans (a graded
    #: arbitrator's choice); None: the planner's own maximum (``agent.mpc.iterations``).
    iterations: torch.Tensor | None = None


class Arbitrator(abc.ABC):
    """Decides per member whether the habit (actor) or the planner (inverse model) acts.

    A rule implements :meth:`use_habit`; a rule with running statistics also :meth:`observe`,
    :meth:`state_dict` and :meth:`load_state_dict` (the defaults: nothing learned, nothing kept).
    """

    #: Whether :meth:`use_habit` reads :attr:`ArbitrationContext.habit_action` (the actor's proposal before the
    #: decision). False (the default): the episode loop computes the actor's pass only where the habit acts, so a
    #: step's measured decision time holds no habit pass that no member uses.
    needs_habit_action: bool = False
    #: Whether :meth:`use_habit` reads :attr:`ArbitrationContext.last_delta` (the paper's delta rule): the
    #: forced-response test then also tests the rule on the delta of the habit's imagined transition, the only
    #: delta a trial's first decision could read (:mod:`apac_mj.run.variants`).
    reads_last_delta: bool = False
    #: Whether :meth:`use_habit` reads :attr:`ArbitrationContext.habit_probe` (the habit's sequence imagined
    #: through the forward model, ``agent.mpc.horizon`` model passes): the forced-response test
    #: (:mod:`apac_mj.run.forced_response`) charges the rule their time before its decision is ready.
    needs_habit_probe: bool = False
    #: Set by the episode loop before every decision: whether the actor explores at this step (training). A rule
    #: that re-explores its choice does so only then.
    exploring: bool = False

    @abc.abstractmethod
    def use_habit(self, ctx: ArbitrationContext) -> Decision:
        """The decision for every member at the step ``ctx`` describes."""

    def plan_gains(self, agent: Any, ctx: ArbitrationContext, plan: "Proposal", planner: "Planner"
                   ) -> np.ndarray | None:
        """``[E, K]`` the rule's own estimate of what ``plan`` gained over the habit after each iteration. Default:
        None, the planner's imagined gain (``plan.best_values - plan.habit_value``)."""
        return None

    def observe(self, info: StepInfo, mask: np.ndarray, adapt: bool) -> None:
        """After every step: learn from ``info`` for the members in ``mask`` (``adapt``: update the running
        statistics, True in training, False in frozen tests). Default: nothing."""

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The running statistics a checkpoint keeps (any tensors). Default: none."""
        return {}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state_dict`'s output. Default: only an empty one is accepted."""
        if d:
            raise ValueError(f"the {type(self).__name__} rule keeps no statistics, but the checkpoint has {sorted(d)}")


@dataclasses.dataclass(frozen=True)
class HabitProbe:
    """The habit's sequence imagined through the forward model from every member's state (``[E]`` each)."""

    #: Its value: discounted -distance over the horizon, then the critic's Q(s_H, pi(s_H)) (cm of return).
    value: torch.Tensor
    #: The imagined hand's distance to the target at the horizon (cm; at the step it was imagined to arrive).
    final_distance: torch.Tensor


@dataclasses.dataclass
class Proposal:
    """A planner's proposals for every member at one step."""

    #: ``[E, 2]`` the first action (degrees or N·m, no noise).
    action: torch.Tensor
    #: ``[E]`` ints: the iterations each member's plan ran (0: it did not plan).
    iterations: torch.Tensor
    #: ``[E, iterations_max]`` the best value found after each iteration (cm of return; NaN past a member's
    #: budget), beside :attr:`habit_value`: what an anytime plan gains per iteration. None: not a model planner.
    best_values: torch.Tensor | None = None
    #: ``[E]`` the habit's imagined value (:class:`HabitProbe`); None: not a model planner.
    habit_value: torch.Tensor | None = None
    #: ``[E, iterations_max, H, A]`` the best sequence (tanh units) after each iteration (zeros past a member's
    #: budget): what an estimate of a plan's gain independent of its selection values. None: not recorded.
    best_sequences: torch.Tensor | None = None


@dataclasses.dataclass(frozen=True)
class PlanningTask:
    """What a planner is built for (``apac_mj.systems.PlannerKind.build``): the members, the action's size and the
    task's success criterion its imagined rollouts stop at."""

    #: The members' seeds (a planner's random streams derive from them).
    seeds: tuple[int, ...]
    #: Length of an action.
    action_dim: int
    #: Radius (cm) of the target zone.
    zone_radius: float
    #: Every joint slower than this (deg/s) counts as stopped (a task with a stop criterion); None: the zone alone.
    stop_speed: float | None = None


class Planner(abc.ABC):
    """The planning system's proposal (``apac_mj.agent.planner``): the paper's inverse model, or a planner
    through the forward model. It may keep what it carries between steps (a warm start) and random streams
    (:meth:`state_dict`); the defaults keep nothing."""

    #: How many iterations one decision may run at most (1: a single query, the inverse model).
    max_iterations: int = 1
    #: The last decision's imagined plan for recordings (:attr:`StepInfo.plan`); None: none (no model planner).
    last_plan: dict[str, torch.Tensor] | None = None

    @abc.abstractmethod
    def propose(self, agent: "WorldModel", ctx: ArbitrationContext, iterations: torch.Tensor) -> Proposal:
        """Proposals for every member from ``ctx.state``; ``iterations`` ``[E]`` ints: each member's budget
        (0: the member does not plan this step; its row is not used)."""

    def probe(self, agent: "WorldModel", state: torch.Tensor) -> HabitProbe | None:
        """The habit imagined through the model (for the arbitrators that weigh planning); None: no model."""
        return None

    def reset(self, mask: np.ndarray) -> None:
        """New episodes for the members in ``mask``. Default: nothing carried."""

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint keeps. Default: nothing."""
        return {}

    def load_state_dict(self, d: dict[str, Any]) -> None:
        """Restore :meth:`state_dict`'s output. Default: only an empty one is accepted."""
        if d:
            raise ValueError(f"{type(self).__name__} has no state; got keys {sorted(d)}")


class Integrator(abc.ABC):
    """Makes the estimate of the state's positions (:data:`POSITIONS`, ``[E, 6]``) the agent acts and learns on
    (``apac_mj.agent.integrator``); the task's extra observations pass it by.

    The estimate itself is carried by the caller (``prior_state`` in, next estimate out); an integrator
    keeps only what it learns (:meth:`state_dict`).
    """

    #: The integrator's running statistics learn from the steps (training); False: frozen (tests).
    adapt: bool = True

    def __init__(self, E: int, device: torch.device | str = "cpu") -> None:
        import torch

        if not isinstance(E, int) or isinstance(E, bool) or E < 1:
            raise ValueError(f"E must be an int >= 1, got {E!r}")
        self.E, self.device = E, torch.device(device)

    @abc.abstractmethod
    def reset(self, mask: np.ndarray | torch.Tensor, seen_state: torch.Tensor) -> None:
        """Start new episodes for the members in ``mask`` ``[E]`` from ``seen_state`` ``[E, 6]``."""

    @abc.abstractmethod
    def update(self, prior_state: torch.Tensor, predicted_arm: torch.Tensor, observed_state: torch.Tensor,
               vision: np.ndarray | torch.Tensor, active: np.ndarray | torch.Tensor) -> torch.Tensor:
        """The next estimate ``[E, 6]`` from the estimate acted on, the forward model's prediction ``[E, 4]``
        and the observation ``[E, 6]`` (``vision`` ``[E]``: seen); rows of inactive members unchanged."""

    def state_dict(self) -> dict[str, torch.Tensor]:
        """What a checkpoint keeps. Default: nothing."""
        return {}

    def load_state_dict(self, d: dict[str, torch.Tensor]) -> None:
        """Restore :meth:`state_dict`'s output. Default: only an empty one is accepted."""
        if d:
            raise ValueError(f"{type(self).__name__} has no state; got keys {sorted(d)}")


class Noise(Protocol):
    """The exploration noise, one process per member (``apac_mj.agent.noise.OUNoise``)."""

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Restart the processes of the members in ``mask`` ``[E]`` (None: all)."""

    def sample(self, mask: torch.Tensor | None = None, sigma: Any = None) -> torch.Tensor:
        """The next noise ``[E, A]`` of the members in ``mask`` (the others' rows zero), at ``sigma`` ``[E]``."""


class Policy(Protocol):
    """What the episode loop (``apac_mj.run.rollout``) calls on an agent (``apac_mj.agent.agent.Agent``)."""

    cfg: AgentConfig  # the exploration schedule (``ou_sigma_at``), gamma
    device: torch.device
    noise: Noise  # the exploration noise: ``reset(mask)``, ``sample(active, sigma)``
    sizes: Sizes  # the task's sizes: state and action dimensions, action bound

    def actor_action(self, state: torch.Tensor) -> torch.Tensor:
        """Habit proposal ``[E, 6 + extra] -> [E, 2]`` degrees (no noise)."""

    def inverse_action(self, state: torch.Tensor) -> torch.Tensor:
        """Planning proposal ``[E, 6 + extra] -> [E, 2]`` degrees (no noise)."""

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """The part of command ``a`` ``[E, 2]`` the plant can execute from the pose in ``s``."""

    def predict_arm(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Forward model: state ``[E, 6 + extra]`` + action ``[E, 2]`` -> next ``[end, elbow]`` ``[E, 4]``."""

    def td_error(self, s: torch.Tensor, a: torch.Tensor, r: torch.Tensor, s2: torch.Tensor,
                 done: torch.Tensor) -> torch.Tensor:
        """This transition's TD error ``[E]``."""


class WorldModel(Policy, Protocol):
    """What a planner (:class:`Planner`) calls on an agent: the episode loop's calls and the learned model,
    batched over candidates (``[E, B, ...]``)."""

    layout: StateLayout  # the state's parts (``layout.motion``: the joint velocities where observed)

    def imagine(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The next state ``[E, B, S]`` the model predicts after the executable ``action`` ``[E, B, A]``."""

    def value(self, state: torch.Tensor) -> torch.Tensor:
        """The critic's ``Q(s, pi(s))`` ``[E, B]`` (cm of return)."""

    def habit_u(self, state: torch.Tensor) -> torch.Tensor:
        """The actor's tanh output ``[E, B, A]`` in ``state`` ``[E, B, S]``."""

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """A tanh output ``u`` in [-1, 1] as an action in state ``s``."""

    def inverse_action(self, state: torch.Tensor) -> torch.Tensor:
        """The inverse model's proposal ``[E, S] -> [E, A]`` with the target as the hand's goal."""
