"""Configuration as dataclasses; every field carries its doc and the paper's value.

Defaults are the paper's (Appendix 2, Tables 1 and 2). Where the paper leaves a
choice open, the field says so and ``docs/paper-mapping.md`` lists it.
"""
from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any, Callable

import numpy as np

from apac_mj import rules
from apac_mj.util.memory import check_planner
from apac_mj.util.overrides import MAX_SEEDS, SEED_LIMIT


#: The trained networks, in the paper's terms (the target actor and critic follow their online networks).
TRAINED_NETWORKS = ("actor", "critic", "forward_model", "inverse_model")
#: The learners a lesion can freeze (AgentConfig.frozen) and their networks.
FREEZABLE = {"habit": ("actor", "critic"), "model": ("forward_model", "inverse_model", "dynamics_model")}
#: The numeric precisions a run computes in; a request may also say "auto" (apac_mj.agent.precision).
PRECISIONS = ("fp32", "bf16")
PRECISION_REQUESTS = (*PRECISIONS, "auto")
#: How the arm is driven: MuJoCo position servos, or joint angles written directly.
ACTUATIONS = ("servo", "kinematic")
#: Where the networks run ("cuda:N" names one GPU).
DEVICES = ("cpu", "cuda")
#: At most this many training episodes per seed (and checkpoint interval).
MAX_EPISODES = 10**9


#: ``AgentConfig.executed_action``'s choices.
EXECUTED_ACTIONS = ("auto", "joint_change", "command")


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """The agent: habit system (DDPG), planning system, arbitrator, integrator."""

    #: The agent kind (apac_mj.kinds: its arbitrator decides which controller acts): ddpg (always
    #: the actor), spac (always the inverse model), apac (the arbitrator decides) or a registered one.
    kind: str = rules.DEFAULT_KIND

    # -- networks (Table 2) --------------------------------------------------
    #: Actor hidden layers (relu); output 2 x tanh x action_scale.
    actor_hidden: tuple[int, int] = (400, 300)
    #: Critic hidden layers (relu); output 1 (linear).
    critic_hidden: tuple[int, int] = (400, 600)
    #: How state and action enter the critic (networks.EnsembleCritic): "concat" (Table 2 read
    #: literally: [s, a] (8) -> 400 -> 600 -> 1) or "summed" (the DDPG code: s -> 400;
    #: relu(W h1 + W_a a) (600) -> 1). "separable" is the old bug (Q = V(s) + A(a): dQ/da the
    #: same in every state), kept only as the learning checks' negative control: never use it.
    critic_form: str = "concat"
    #: How the actor's and the inverse model's tanh outputs u in [-1, 1] become joint-angle changes:
    #: "tanh" (the paper: 180 u) or "feasible" (lo + (hi - lo)(u + 1)/2 with [lo, hi] the changes
    #: that keep both joints inside their range from the current pose: no command past a limit).
    action_squash: str = "feasible"
    #: Forward model hidden layers (sigmoid); output 4 x sigmoid x plane_scale.
    forward_hidden: tuple[int, int] = (400, 300)
    #: Inverse model hidden layers (relu); output 2 x tanh x action_scale.
    inverse_hidden: tuple[int, int] = (400, 300)
    #: Scale of the actor's and the inverse model's tanh outputs (degrees).
    action_scale: float = 180.0
    #: Scale of the forward model's sigmoid output (cm): the task's plane size (the Agent reads it from
    #: the task's geometry); a number here must equal it (None: take the task's, whatever it is).
    plane_scale: float | None = 30.0

    # -- optimisation (Table 2; Adam everywhere) -----------------------------
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    #: Table 2 gives 0.01; the text's 0.1 is the outlier.
    forward_lr: float = 1e-2
    inverse_lr: float = 1e-2
    #: L2 regularization on all networks ("weight decay 0.001"), added to the gradient as in torch.optim.Adam.
    weight_decay: float = 1e-3
    gamma: float = 0.99
    tau: float = 1e-3
    replay_size: int = 1000
    batch_size: int = 500
    #: Gradient updates per environment step (paper: one).
    updates_per_step: int = 1
    #: Extra Adam steps of the inverse model alone after every update, each on a fresh minibatch, as
    #: ``mpc.model_updates`` trains the dynamics model (paper: 0; issue 41's equal-budget comparison: 4).
    inverse_updates: int = 0
    #: The inverse model's L2 weight decay; None: ``weight_decay`` (the paper's 1e-3 on every network).
    inverse_weight_decay: float | None = None

    # -- exploration: Ornstein-Uhlenbeck noise on both proposals ---------------
    ou_theta: float = 0.15
    #: OU sigma in degrees (the paper gives no value); the final value when annealed.
    ou_sigma: float = 2.0
    #: OU sigma at training episode 0 (degrees; 18 = 10% of the +-180 action range), annealed
    #: linearly to ``ou_sigma`` over ``ou_sigma_anneal_episodes`` (docs/paper-mapping.md: with a
    #: constant 2 degrees DDPG misses deceptive static targets); None: constant ``ou_sigma``.
    ou_sigma_initial: float | None = 18.0
    ou_sigma_anneal_episodes: int = 150

    # -- arbitration (section "Arbitration") ---------------------------------
    #: APAC uses the inverse model only during this many first episodes.
    planning_episodes: int = 100
    #: After that, the actor acts on the first steps of every episode.
    habit_first_steps: int = 2
    #: Then the actor acts if delta of the last transition is below this.
    delta_threshold: float = 1.0
    #: What is compared with the threshold: "abs" (|delta| < 1: the critic predicted the last
    #: reward well) or "signed" (delta < 1, Algorithm 2 read literally: "RPE < 1").
    delta_rule: str = "abs"

    # -- integrator (apac_mj/agent/integrator.py) ------------------------------------
    #: "pass_through" (the paper: the seen position if seen, else the forward model's prediction) or
    #: "kalman" (a Kalman filter over the forward model: fuses prediction and noisy observation), or one registered by
    #: ``apac_mj.systems.register_integrator`` (checked by ``apac_mj.kinds.check``).
    integrator: str = "pass_through"

    # -- motor babbling -------------------------------------------------------
    #: Episodes of random actions before learning (the paper gives no number).
    babbling_episodes: int = 10
    #: Random babbling actions are uniform in [-babbling_scale, babbling_scale] degrees.
    babbling_scale: float = 180.0

    # -- inputs ---------------------------------------------------------------
    #: Networks see raw cm and degrees as in the paper when False. When True,
    #: positions enter as (x - plane_scale/2) / (plane_scale/2) and actions
    #: entering the critic / forward model as a / action_scale (outputs unchanged).
    #: Default True (a deviation, docs/paper-mapping.md): with raw inputs the
    #: paper-sized inverse model (400-300, lr 0.01) saturates its tanh output
    #: during babbling and commands the joint limits ever after (measured: the
    #: arm never leaves its start pose in 40 SPAC episodes on static_target).
    normalize_inputs: bool = True

    # -- open choices of the DDPG update (docs/agent.md) ----------------------
    #: Which action the critic and the forward model learn from: "executed" (the joint-angle change
    #: the plant made, commands beyond a joint limit clipped) or "commanded" (the arbitrated command
    #: plus noise, as standard DDPG stores it). The inverse model always learns the executed one.
    critic_action: str = "executed"
    #: What the *executed* action is (the inverse model's hindsight label; with critic_action = "executed"
    #: also what the critic and the forward model learn from): "joint_change" (the arm's measured
    #: joint-angle change over the step: the paper's, whose ideal arm executes every command within the joint
    #: limits), "command" (the command as the plant received it: clipped to the joint range, or to the torque
    #: bound) or "auto" (joint_change on the ideal plant, command on a dynamic plant). On a compliant arm the
    #: measured change falls short of the set-point (the servo lags, gravity sags it), so an inverse model
    #: trained on it commands too little and never learns the offset against gravity (docs/agent.md:
    #: measured on changing_target_compliant_gravity).
    executed_action: str = "auto"
    #: Weight of a penalty on actor commands beyond the joint limits (the plant clips them, so the
    #: critic never sees them and extrapolates; 0 = the paper, no penalty).
    feasibility_weight: float = 0.0
    #: Habit formation from planning (not in the paper; 0 = off): the actor's loss adds
    #: ``w * mean |pi(s) - f_I(s)|^2 / action_scale^2``, pulling the habit towards what the inverse
    #: model proposes in the same state (the inverse model is not changed by it). Kinds that arbitrate
    #: only: refused for "ddpg" (no planner to learn from; it would stop being DDPG) and "spac" (the habit
    #: never acts).
    habit_distillation_weight: float = 0.0

    #: Proposals from the target actor (the paper's text says so) instead of
    #: the online actor (standard DDPG, default).
    act_with_target_actor: bool = False

    # -- lesions (issue 44: which controller carries which part of adaptation) ------------------------------
    #: Learners that stop learning from training episode ``frozen_from_episode`` on (:data:`FREEZABLE`):
    #: "habit" (the actor and the critic, with their target networks) and/or "model" (the forward, inverse and
    #: dynamics models). They still act and predict; their weights stay as they were. () = none (the paper).
    frozen: tuple[str, ...] = ()
    #: The member's training episode from which the ``frozen`` learners stop learning (0: from the first).
    frozen_from_episode: int = 0

    # -- reduced precision ------------------------------------------------------
    #: Under ``precision = "bf16"``, the networks whose matrix products run in bf16 (a target network as
    #: its online one); the others stay fp32. No effect in fp32. All four by default; leaving the inverse
    #: model out is issue 19's test of where bf16's failure tail comes from (docs/results/precision).
    bf16_networks: tuple[str, ...] = ("actor", "critic", "forward_model", "inverse_model")

    # -- rules and integrators beyond the paper (apac_mj/rules.py, docs/arbitrators.md) ----------
    #: Each rule's and integrator's own parameters, one table each (``agent.<table>.<field>``; apac_mj.rules).
    params: dict[str, Any] = dataclasses.field(default_factory=dict, metadata={"tables": True})

    def ou_sigma_at(self, episode: "np.ndarray") -> "np.ndarray":
        """OU sigma (degrees) per member at training ``episode`` (``[E]``; babbling counts as 0)."""
        import numpy as np

        episode = np.asarray(episode, dtype=float)
        if self.ou_sigma_initial is None or self.ou_sigma_anneal_episodes <= 0:
            return np.full(episode.shape, self.ou_sigma)
        frac = np.clip(episode / self.ou_sigma_anneal_episodes, 0.0, 1.0)
        return self.ou_sigma_initial + frac * (self.ou_sigma - self.ou_sigma_initial)

    def __post_init__(self) -> None:
        """Every value checked (the kind by ``apac_mj.kinds.check``); ``params`` completed with defaults."""
        for name in ("actor_lr", "critic_lr", "forward_lr", "inverse_lr", "tau", "gamma"):
            v = getattr(self, name)
            if not (0 < v <= 1):
                raise ValueError(f"{name} must be in (0, 1], got {v}")
        for name, choices in (("critic_form", ("concat", "summed", "separable")), ("action_squash", ("tanh", "feasible")),
                              ("delta_rule", ("abs", "signed")), ("critic_action", ("executed", "commanded")),
                              ("executed_action", EXECUTED_ACTIONS)):
            if getattr(self, name) not in choices:
                raise ValueError(f"{name} must be one of {choices}, got {getattr(self, name)!r}")
        for f in dataclasses.fields(self):  # every number finite: a NaN would change the method silently
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{f.name} must be a finite number, got {v}")
        for name, low, high in _RANGES:
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not low <= v <= high):
                raise ValueError(f"{name} must be in [{low:g}, {high:g}], got {v!r}")
        if any(n not in FREEZABLE for n in self.frozen) or len(set(self.frozen)) != len(self.frozen):
            raise ValueError(f"frozen must be distinct names from {tuple(FREEZABLE)}, got {list(self.frozen)}")
        unknown = [n for n in self.bf16_networks if n not in TRAINED_NETWORKS]
        if unknown or len(set(self.bf16_networks)) != len(self.bf16_networks):
            raise ValueError(f"bf16_networks must be distinct names from {TRAINED_NETWORKS}, "
                             f"got {list(self.bf16_networks)}")
        if self.ou_sigma < 0 or (self.ou_sigma_initial is not None and self.ou_sigma_initial < 0):
            raise ValueError("ou_sigma and ou_sigma_initial must be >= 0 degrees")
        if self.batch_size < 1 or self.replay_size < 1:
            raise ValueError("batch_size and replay_size must be >= 1")
        object.__setattr__(self, "params", rules.resolve(self.params))  # frozen: the one completion
        _check_planner_numbers(self.params.get("mpc"))


#: (field, low, high) of AgentConfig's numbers beyond finiteness: degrees within a turn, weights and
#: counts >= 0, sizes that a machine's memory can hold (the replay buffer is checked against it per run).
_RANGES = (("action_scale", 1e-6, 360.0), ("babbling_scale", 0.0, 360.0), ("ou_sigma", 0.0, 360.0),
           ("ou_sigma_initial", 0.0, 360.0), ("ou_theta", 0.0, 10.0), ("ou_sigma_anneal_episodes", 0, 10**9),
           ("weight_decay", 0.0, 1.0), ("feasibility_weight", 0.0, 1e6), ("habit_distillation_weight", 0.0, 1e6),
           ("plane_scale", 1e-6, 1e4), ("planning_episodes", 0, 10**9), ("habit_first_steps", 0, 10**9), ("frozen_from_episode", 0, 10**9),
           ("babbling_episodes", 0, 10**9), ("updates_per_step", 1, 10**3), ("batch_size", 1, 10**8),
           ("replay_size", 1, 10**10), ("inverse_updates", 0, 10**3), ("inverse_weight_decay", 0.0, 1.0))


#: The MPC planner's numbers' upper bounds (agent.mpc; rules.MPCParams checks the lower ones): spreads in tanh
#: units (the samples are clipped to [-1, 1], so a spread beyond 100 only saturates them) and the MPPI temperature
#: (weights exp(temperature x value difference) in float32: 1e308 overflowed it).
_PLANNER_MAX = {"habit_noise": 100.0, "min_std": 100.0, "max_std": 100.0, "temperature": 1e6}


def _check_planner_numbers(mpc: Any) -> None:
    """``agent.mpc``'s spreads and temperature within :data:`_PLANNER_MAX` (a ValueError naming the field)."""
    for name, high in _PLANNER_MAX.items():
        v = getattr(mpc, name, None)
        if v is not None and v > high:
            raise ValueError(f"agent.mpc.{name} must be at most {high:g}, got {v!r}")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """A training run: which task, how many seeds and episodes, where outputs go. Frozen: a changed copy
    is ``dataclasses.replace(cfg, episodes=...)``. Checked when made (:meth:`__post_init__`); what only a
    machine can tell (a GPU, memory, that the task resolves) is checked where a run is built
    (:func:`apac_mj.run.build.check`)."""

    #: Task name (a file in tasks/).
    task: str = "changing_target"
    #: Independent seeds trained side by side as one ensemble.
    seeds: tuple[int, ...] = (0,)
    #: Training episodes per seed (after babbling).
    episodes: int = 1000
    #: "cpu" or "cuda" (or "cuda:N"; DEVICES).
    device: str = "cpu"
    #: "fp32" (reference) or "bf16" (autocast of the matrix products); "auto": bf16 where the hardware
    #: has bf16 dot products, else fp32 (apac_mj.agent.precision), resolved before the run starts.
    precision: str = "fp32"
    #: Save a checkpoint every this many episodes (of the slowest seed).
    checkpoint_every: int = 50
    #: Arm actuation: "servo" (MuJoCo position servos) or "kinematic" (ACTUATIONS).
    actuation: str = "servo"
    #: TaskSpec fields that replace the task file's (e.g. {"at_limit": "unbounded"}); empty: the file as it is.
    task_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    agent: AgentConfig = dataclasses.field(default_factory=AgentConfig)

    def __post_init__(self) -> None:
        """Every field checked (a ValueError naming it); what needs the machine or the task files is
        :func:`apac_mj.run.build.check`'s."""
        if not self.seeds:
            raise ValueError("at least one seed is needed")
        if len(self.seeds) > MAX_SEEDS:
            raise ValueError(f"{len(self.seeds)} seeds: at most {MAX_SEEDS} fit in one run (each is an ensemble "
                             "member with its own networks); split them over several runs")
        if (any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s < SEED_LIMIT
                for s in self.seeds) or len(set(self.seeds)) != len(self.seeds)):
            raise ValueError(f"seeds must be distinct integers in [0, 2^32), got {_short(list(self.seeds))}")
        for name in ("episodes", "checkpoint_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_EPISODES:
                raise ValueError(f"{name} must be an integer in [1, {MAX_EPISODES}], got {value!r}")
        if not isinstance(self.device, str) or (self.device not in DEVICES and not self.device.startswith("cuda:")):
            raise ValueError(f"device must be one of {DEVICES} (or 'cuda:N'), got {self.device!r}")
        if self.precision not in PRECISION_REQUESTS:  # auto: resolved by the trainer before the run starts
            raise ValueError(f"precision must be one of {PRECISION_REQUESTS}, got {self.precision!r}")
        if self.actuation not in ACTUATIONS:
            raise ValueError(f"actuation must be one of {ACTUATIONS}, got {self.actuation!r}")
        if not isinstance(self.agent, AgentConfig):
            raise ValueError(f"agent must be an AgentConfig, got {type(self.agent).__name__}")
        check_planner(self.agent, len(self.seeds))  # agent.mpc's work per decision and memory (F8)


def _short(values: list[Any], n: int = 10) -> str:
    """A list for a message, at most ``n`` entries shown."""
    return str(values) if len(values) <= n else f"[{', '.join(map(str, values[:n]))}, ... ({len(values)} in all)]"


def to_dict(cfg: TrainConfig) -> dict[str, Any]:
    """``cfg`` as the dict config.json holds: each parameter table at ``agent.<table>``."""
    d = dataclasses.asdict(cfg)
    d["agent"].update(d["agent"].pop("params"))
    return d


def train_config_from_dict(d: dict[str, Any]) -> TrainConfig:
    """The inverse of :func:`to_dict`, for dicts of any release (:func:`migrate`)."""
    d = migrate(d)
    agent = dict(d.pop("agent", {}))
    params = {name: agent.pop(name) for name in rules.tables() if name in agent}
    return TrainConfig(agent=AgentConfig(params=params, **_tuples(agent)), **_tuples(d))


#: Where the flat rule fields of the releases up to 936695d went: ``agent.<old>`` -> ``agent.<table>.<field>``.
MOVED = {"arbitration_window": (("uncertainty", "window"), ("reliability", "window")),
         "arbitration_prior_weight": (("uncertainty", "prior_weight"), ("reliability", "prior_weight")),
         "reliability_rate": (("reliability", "rate"),), "reliability_slope": (("reliability", "slope"),),
         "speed_accuracy_window": (("speed_accuracy", "window"),),
         "vision_aware_base": (("vision_aware", "base"),), "vision_aware_dark": (("vision_aware", "dark"),),
         "vision_check_ratio": (("vision_aware", "check_ratio"),),
         "kalman_window": (("kalman", "window"),), "kalman_process_floor": (("kalman", "process_floor"),),
         "kalman_initial_process_var": (("kalman", "initial_process_var"),)}


#: AgentConfig fields added after a release, with the value that behaves as that release did (JSON shape).
ADDED = {"bf16_networks": list(TRAINED_NETWORKS),
         # releases up to 192b762 learned the measured joint change on every joint-angle plant (torque plants:
         # the command, but their networks predate the velocity inputs and cannot be loaded any more)
         "executed_action": "joint_change",
         # issue 41: the inverse model's own budget; before it, one step and the agent's weight_decay
         "inverse_updates": 0, "inverse_weight_decay": None,
         # issue 44: lesions; every release before it learned with every learner
         "frozen": [], "frozen_from_episode": 0}

#: Fields added to a parameter table after it was released: ``table -> field -> f(agent dict)``, the value that
#: behaves as that release did. Issue 28's ``mpc`` table had no ``model_weight_decay`` (its dynamics model was
#: decayed by the paper's ``weight_decay``, as every network) and no ``model_heads`` (one model).
TABLE_ADDED: dict[str, dict[str, Callable[[dict[str, Any]], Any]]] = {
    "mpc": {"model_weight_decay": lambda agent: agent.get("weight_decay", 1e-3), "model_heads": lambda agent: 1},
    # issue 42: the graded rule measured a plan's gain through the model that selected it, on the steps it planned
    "voc": {"gain": lambda agent: "imagined", "learn_on": lambda agent: "planned", "explore": lambda agent: 0.0}}


def migrate(d: dict[str, Any]) -> dict[str, Any]:
    """A config dict (config.json, cell.json's run, a checkpoint's) of any release in today's shape:
    ``agent.agent`` -> ``agent.kind``, the flat rule fields (:data:`MOVED`) -> their tables, fields added
    since (:data:`ADDED`, and to a table: :data:`TABLE_ADDED`) at the value the release behaved as, parameter
    tables registered since at their defaults. Pure and idempotent; every value is kept."""
    agent = dict(d.get("agent", {}))
    if "agent" in agent:
        agent["kind"] = agent.pop("agent")
    if agent:
        for name, value in ADDED.items():
            agent.setdefault(name, copy.deepcopy(value))
    for old, places in MOVED.items():
        if old in agent:
            value = agent.pop(old)
            for table, field in places:
                agent[table] = {**agent.get(table, {}), field: value}
    for table, fields in TABLE_ADDED.items():
        if isinstance(agent.get(table), dict):
            agent[table] = {**{f: value(agent) for f, value in fields.items()}, **agent[table]}
    if agent:  # tables registered since (issue 28: mpc, voc), at their defaults: they act only in their own kinds
        for name, cls in rules.tables().items():
            agent.setdefault(name, {f.name: _json(getattr(cls(), f.name)) for f in dataclasses.fields(cls)})
    return {**d, "agent": agent} if "agent" in d else dict(d)


def migrate_study(record: dict[str, Any]) -> dict[str, Any]:
    """A study's protocol record (protocol.json, its ``run`` a TrainConfig as ``dataclasses.asdict`` writes it)
    with the agent fields added since (:data:`ADDED`) at the value the study's release behaved as, so that a study
    made before a field was added resumes."""
    run = record.get("run")
    if not isinstance(run, dict) or not isinstance(run.get("agent"), dict):
        return dict(record)
    agent = {**copy.deepcopy(ADDED), **run["agent"]}
    return {**record, "run": {**run, "agent": agent}}


def _json(v: Any) -> Any:
    return list(v) if isinstance(v, tuple) else v


def _tuples(d: dict[str, Any]) -> dict[str, Any]:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
