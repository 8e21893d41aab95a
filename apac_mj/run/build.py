"""A run built from its config, once: the task resolved, the environments, the agent and the episode loop.

TD-MPC2's ``train.py`` is the model: every part is built once, here, and handed to whoever runs it::

    spec = check(cfg)                       # the task read once; the machine checks (GPU, memory)
    run = build(cfg, spec, hooks)           # Run(cfg, spec, env, agent, loop)
    Trainer(run, RunDir(out)).train()

* :func:`check` validates what only this machine and the task files can tell (:class:`TrainConfig` checks
  its own fields when made) and returns the run's :class:`TaskSpec`: the one read of its task file.
* :func:`environments` builds the E environments from that spec; training's start their episode count at
  ``-babbling_episodes`` (:class:`VecEnv`'s ``episode_offset``, the one owner of the babbling offset).
* :func:`make_agent` is the one place an :class:`Agent` is constructed, sized by the environments it acts in
  (:attr:`VecEnv.sizes`: no environment is built only to read two specs), with a dynamics model where its
  kind's planner plans through one (:attr:`apac_mj.systems.PlannerKind.model`).
* :func:`episode_loop` is the episode loop of an agent in its environments: the kind's arbitrator and planner
  and the run's integrator, each asked of its registry (:mod:`apac_mj.kinds`, :mod:`apac_mj.systems`).
* :func:`load_run` is a written run's config, spec, environments and agent with its newest intact checkpoint's
  weights (the frozen tests, recordings and the benches); a task changed since the run trained is refused.
* :func:`task_record` is the task as a run's config.json records it (:class:`~apac_mj.run.run_dir.TaskRecord`).

The run directory (:mod:`apac_mj.run.run_dir`) only reads and writes files; this module is where the plant
and the learner meet a run.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Sequence

from apac_mj import kinds, systems
from apac_mj.agent.agent import Agent
from apac_mj.agent.arbitrators import held_out_dynamics
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.kinds import arbitrator_for, check as check_kind
from apac_mj.kinematics import Geometry
from apac_mj.layout import Sizes
from apac_mj.rules import MPCParams
from apac_mj.run.rollout import EpisodeLoop, Hook
from apac_mj.run.run_dir import NETWORK_KEYS, RunCheckpoint, RunDir, TaskRecord
from apac_mj.suite import spec_for
from apac_mj.suite.task_spec import TaskSpec
from apac_mj.suite.vec_env import VecEnv
from apac_mj.types import Arbitrator, Integrator, Planner, PlanningTask
from apac_mj.util import paths
from apac_mj.util.files import jsonable

#: TaskSpec fields that only name and colour a task (``name`` is the config's ``task``): a run's task record
#: leaves them out, so that a new label or description does not stop a run from resuming.
_NOT_TRAINED = ("name", "description", "report_label", "report_short", "report_color")
#: Optional TaskSpec tables added after runs and zoo cells were written: left out of a task record while absent
#: (None), so that a run or a shipped cell written before them keeps its task digest and its contract.
OPTIONAL_TABLES = ("signals", "trials", "deliberation")
#: Floats one replay transition holds per member (s, a, r, s', done, executed a, spare: the Agent's replay).
_FLOATS_PER_TRANSITION = 4 + 2 + 1 + 4 + 1 + 2 + 4


@dataclasses.dataclass
class Run:
    """A run's parts, each built once (:func:`build`)."""

    cfg: TrainConfig
    #: The task with the run's overrides (read once).
    spec: TaskSpec
    #: The E environments (one per seed).
    env: VecEnv
    agent: Agent
    #: The episode loop: the arbitrator of ``cfg.agent.kind``, the integrator, the hooks.
    loop: EpisodeLoop


@dataclasses.dataclass
class LoadedRun:
    """A written run (:func:`load_run`): its config, task, environments and agent with the checkpoint's weights."""

    cfg: TrainConfig
    spec: TaskSpec
    env: VecEnv
    agent: Agent
    #: The newest intact checkpoint (its environment state, running statistics, per-member episodes).
    ckpt: RunCheckpoint


def check(cfg: TrainConfig) -> TaskSpec:
    """Refuse a run that cannot run here (a ValueError naming the problem; writes nothing) and return its task.

    The fields were checked when ``cfg`` was made; here: the kind is registered, the task resolves (an unknown
    one lists the known ones; a bad override is a TaskSpecError), a dynamic plant is on servos, the device
    exists, the replay buffers fit in memory."""
    check_kind(cfg.agent)
    spec = spec_for(cfg)
    if spec.plant.dynamic and cfg.actuation != "servo":
        raise ValueError(f"task {cfg.task!r} has a {spec.plant.actuation} plant ([plant]); actuation "
                         f"{cfg.actuation!r} would write the joint angles and skip its dynamics: use 'servo'")
    if cfg.agent.executed_action == "joint_change" and spec.plant.actuation == "torque":
        raise ValueError(f"task {cfg.task!r} is torque-driven: its actions are torques, not joint-angle "
                         "changes; agent.executed_action must be 'command' or 'auto' (a torque run written before the "
                         "internal models read the joint velocities cannot be resumed or evaluated: train it anew)")
    check_device(cfg.device)
    _check_memory(cfg)
    return spec


def check_device(device: str) -> None:
    """A CUDA device that this machine (or this torch build) lacks is an error naming the way out."""
    if not device.startswith("cuda"):
        return
    import torch

    if not torch.cuda.is_available():
        build_ = "a CPU-only build" if torch.version.cuda is None else f"built for CUDA {torch.version.cuda}"
        raise ValueError(f"device {device!r}: CUDA is not available here (torch {torch.__version__}, {build_}); "
                         "use --device cpu, or set up with APAC_MJ_TORCH=cuda on a machine with a GPU (README)")
    index = int(device.split(":")[1]) if ":" in device else 0
    if index >= torch.cuda.device_count():
        raise ValueError(f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")


def _check_memory(cfg: TrainConfig) -> None:
    """The replay buffers (the largest part of a run that its settings size) fit in this machine's memory."""
    need = cfg.agent.replay_size * len(cfg.seeds) * _FLOATS_PER_TRANSITION * 4
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return
    if need > have:
        raise ValueError(f"agent.replay_size = {cfg.agent.replay_size} for {len(cfg.seeds)} seeds needs about "
                         f"{need / 2**30:.3g} GiB of replay buffers; this machine has {have / 2**30:.3g} GiB")


def environments(cfg: TrainConfig, spec: TaskSpec, seeds: Sequence[int] | None = None,
                 training: bool = True) -> VecEnv:
    """The run's E environments of ``spec`` (one per seed: ``seeds``, default the run's). ``training``: their
    episode count starts at ``-babbling_episodes`` (changing kinematics and the plant's schedule count training
    episodes); else at 0."""
    offset = cfg.agent.babbling_episodes if training else 0
    return VecEnv(spec, list(cfg.seeds if seeds is None else seeds), cfg.actuation, episode_offset=offset)


def make_agent(cfg: TrainConfig, spec: TaskSpec, sizes: Sizes, device: str | None = None,
               precision: str | None = None) -> Agent:
    """The run's agent (fresh networks) for ``spec``'s geometry and the environments' ``sizes``; on ``device``
    in ``precision`` (default: the run's)."""
    dynamics = cfg.agent.params[MPCParams.table] if planner_kind(cfg.agent).model else None
    if dynamics is not None:  # the graded rule's held-out head (voc.gain = "heldout")
        dynamics = held_out_dynamics(arbitrator_for(cfg.agent), dynamics)
    return Agent(cfg.agent, list(cfg.seeds), device=cfg.device if device is None else device,
                 precision=precision or cfg.precision, geometry=Geometry.from_spec(spec), sizes=sizes,
                 dynamics=dynamics)


def planner_kind(cfg: AgentConfig) -> systems.PlannerKind:
    """The planner that ``cfg.kind`` names (:mod:`apac_mj.systems`)."""
    return systems.planner(kinds.get(cfg.kind).planner)


def make_planner(cfg: AgentConfig, task: PlanningTask) -> Planner:
    """The planning system of ``cfg.kind`` for ``task``; a factory that builds no :class:`Planner` is an error
    naming it."""
    kind = planner_kind(cfg)
    planner = kind.build(cfg, task)
    if not isinstance(planner, Planner):
        raise TypeError(f"planner {kind.name!r} built a {type(planner).__name__}, not an apac_mj.types.Planner")
    return planner


def make_integrator(cfg: AgentConfig, E: int, obs_std: float, device: Any) -> Integrator:
    """The integrator ``cfg.integrator`` for ``E`` members; ``obs_std``: the task's observation noise (cm)."""
    kind = systems.integrator(cfg.integrator)
    integrator = kind.build(cfg, E, obs_std, device)
    if not isinstance(integrator, Integrator):
        raise TypeError(f"integrator {kind.name!r} built a {type(integrator).__name__}, not an "
                        "apac_mj.types.Integrator")
    return integrator


def episode_loop(agent: Agent, env: VecEnv, arbitrator: Arbitrator | None = None, hooks: Sequence[Hook] = (),
                 adapt: bool = True, zone_radius: float | None = None) -> EpisodeLoop:
    """The episode loop of ``agent`` in ``env``: ``arbitrator`` (default the kind's), the kind's planner judging
    imagined arrival by the loop's zone (``zone_radius``, default the task's) and the task's stop speed, and the
    run's integrator with the task's observation noise. ``adapt``: the running statistics learn (training)."""
    cfg = agent.cfg
    zone = env.spec.zone_radius if zone_radius is None else zone_radius
    task = PlanningTask(tuple(agent.seeds), agent.action_dim, zone, env.spec.stop_speed)
    integrator = make_integrator(cfg, env.E, env.spec.observation_noise_std, agent.device)
    return EpisodeLoop(agent, arbitrator_for(cfg) if arbitrator is None else arbitrator, env, zone_radius=zone_radius,
                       hooks=hooks, adapt=adapt, integrator=integrator, planner=make_planner(cfg, task))


def build(cfg: TrainConfig, spec: TaskSpec, hooks: Sequence[Hook] = ()) -> Run:
    """A new run's parts: the training environments, the agent, the episode loop (the kind's arbitrator and
    planner, the run's integrator)."""
    env = environments(cfg, spec)
    agent = make_agent(cfg, spec, env.sizes)
    return Run(cfg, spec, env, agent, episode_loop(agent, env, hooks=hooks))


def load_run(run_dir: str | Path, device: str | None = None, precision: str | None = None,
             env: VecEnv | None = None, spec: TaskSpec | None = None) -> LoadedRun:
    """A written run with its newest intact checkpoint's weights (on ``device``, in ``precision``: default the
    run's). The agent acts in ``env`` (default: the run's training environments, not yet restored to the
    checkpoint's state: ``env.set_state(loaded.ckpt.env)`` does that); ``spec``: the run's task if the caller
    resolved it already (default: resolved here)."""
    run = RunDir(run_dir)
    cfg = run.train_config()
    device = cfg.device if device is None else device
    check_device(device)  # a missing GPU: a clear error before anything is loaded
    ckpt = run.load_checkpoint(required=NETWORK_KEYS)
    run.check_config(ckpt)  # config.json says what the checkpoint trained (an edited one: an error naming it)
    spec = spec_for(cfg) if spec is None else spec
    run.check_task(task_record(cfg, spec), "the networks would act in a task they were not trained on")
    env = environments(cfg, spec) if env is None else env
    agent = make_agent(cfg, spec, env.sizes, device=device, precision=precision)
    agent.load_state_dict(ckpt.agent)
    return LoadedRun(cfg, spec, env, agent, ckpt)


def task_record(cfg: TrainConfig, spec: TaskSpec) -> TaskRecord:
    """``spec`` (``cfg``'s task resolved: :func:`apac_mj.suite.spec_for`) as a run records it: every field that
    changes what is trained, in JSON form, and where it was read."""
    def trained(s: TaskSpec) -> dict[str, Any]:
        return {k: v for k, v in jsonable(dataclasses.asdict(s)).items()
                if k not in _NOT_TRAINED and not (k in OPTIONAL_TABLES and v is None)}

    file = paths.tasks_dir() / f"{cfg.task}.toml"
    return TaskRecord(trained(spec), f"task file {file}" if file.is_file() else
                      f"task {cfg.task!r} (registered at run time)", trained(TaskSpec(name=spec.name)))


def loaded_agent(cfg: TrainConfig, spec: TaskSpec, sizes: Sizes, state: dict[str, Any], device: str | None = None,
                 precision: str | None = None) -> Agent:
    """:func:`make_agent` with the weights of a checkpoint's ``state`` (``RunCheckpoint.agent``)."""
    agent = make_agent(cfg, spec, sizes, device=device, precision=precision)
    agent.load_state_dict(state)
    return agent
