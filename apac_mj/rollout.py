"""One agent-environment step, shared by training, evaluation and recordings.

:func:`agent_step` is the body of Algorithm 2's inner loop up to the store:
arbitrate between the actor and the inverse model (plus OU noise), feed the
action and the current arm estimate to the forward model, step the plant,
integrate (observed position with vision, the forward model's prediction
without), build ``s_{t+1}`` and compute this transition's TD error ``delta``
on the executable part of the command (:meth:`Agent.executable`, what the
critic and the forward model learn from)
(the arbitrator's reliability signal for the next step). It returns a
:class:`StepInfo`, the per-step record that hooks receive::

    on_step(info: StepInfo, vec_env: VecEnv) -> None
    on_episode_start(members: np.ndarray, vec_env: VecEnv) -> None   # members: [E] bool, just reset

Both hooks are accepted by :func:`apac_mj.trainer.train` and by the
evaluation runners in :mod:`apac_mj.evaluate`.

What the agent perceives: with vision, the environment's reward and
termination; without vision (occluded), the reward and termination of its
own estimate (``-|end_est - target_remembered|`` and "estimate inside the
zone"), so nothing true leaks after step 0.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Protocol

import numpy as np
import torch

from apac_mj.arbitrator import Arbitrator
from apac_mj.integrator import integrate
from apac_mj.suite.planar_arm import ACTION_BOUND
from apac_mj.vec_env import Observation, VecEnv


@dataclasses.dataclass
class StepInfo:
    """What every member did at one step; member-batched numpy arrays (cm, degrees).

    Rows of members that were not ``active`` are stale and must be ignored.
    """

    episode: np.ndarray        # [E] int: training episode (babbling: negative)
    step: np.ndarray           # [E] int: step within the episode at which the action was taken (0-based)
    active: np.ndarray         # [E] bool: the member stepped
    state: np.ndarray          # [E, 6] the integrator's state the agent acted on [end, elbow, target]
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
    next_state: np.ndarray     # [E, 6] the integrator's state after the step (s_{t+1})
    terminal: np.ndarray       # [E] bool: the transition is terminal for learning (perceived reach)


class StepHook(Protocol):
    def __call__(self, info: StepInfo, vec_env: VecEnv) -> None: ...


class EpisodeStartHook(Protocol):
    def __call__(self, members: np.ndarray, vec_env: VecEnv) -> None: ...


def observed_state(obs: Observation, device: torch.device) -> torch.Tensor:
    """``[E, 6]`` state from an observation that was seen (episode start)."""
    return torch.as_tensor(np.concatenate([obs.arm, obs.target], axis=1), dtype=torch.float32, device=device)


def select_action(agent: Any, arbitrator: Arbitrator, state: torch.Tensor, episode: np.ndarray,
                  step: np.ndarray, last_delta: np.ndarray, active: np.ndarray,
                  explore: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """The arbitrator's choice between the actor's and the inverse model's proposals (+ OU noise)."""
    habit = arbitrator.use_habit(torch.as_tensor(episode), torch.as_tensor(step),
                                 torch.as_tensor(last_delta, dtype=torch.float32)).to(state.device)
    proposal = torch.where(habit[:, None], agent.actor_action(state), agent.inverse_action(state))
    if explore:
        sigma = agent.cfg.ou_sigma_at(np.asarray(episode))
        proposal = proposal + agent.noise.sample(torch.as_tensor(active), sigma).to(state.device)
    return proposal.clamp(-ACTION_BOUND, ACTION_BOUND), habit


def agent_step(agent: Any, arbitrator: Arbitrator, vec_env: VecEnv, state: torch.Tensor, episode: np.ndarray,
               step: np.ndarray, last_delta: np.ndarray, active: np.ndarray, explore: bool = True,
               zone_radius: float | None = None, action: torch.Tensor | None = None,
               habit: torch.Tensor | None = None) -> StepInfo:
    """One step for the ``active`` members.

    ``action`` (``[E,2]``) and ``habit`` (``[E]`` bool) given: executed as they are
    (the trainer's babbling); otherwise the arbitrator selects (:func:`select_action`).

    ``zone_radius`` is the radius the agent uses to judge its own estimate
    under occlusion (default: the task's).
    """
    device = state.device
    if action is None:
        action, habit = select_action(agent, arbitrator, state, episode, step, last_delta, active, explore)
    elif habit is None:
        habit = torch.zeros(vec_env.E, dtype=torch.bool, device=device)
    executable = agent.executable(action, state)  # what the plant will do: every network sees this action
    predicted = agent.predict_arm(state[:, :4], executable)
    obs = vec_env.step(action.detach().cpu().double().numpy(), active)
    vision = torch.as_tensor(obs.vision, device=device)
    seen = observed_state(obs, device)
    next_arm = integrate(seen[:, :4], predicted, vision)
    next_target = torch.where(vision[:, None], seen[:, 4:], state[:, 4:])
    next_state = torch.cat([next_arm, next_target], dim=1)
    radius = vec_env.spec.zone_radius if zone_radius is None else zone_radius
    est_distance = torch.linalg.vector_norm(next_state[:, :2] - next_state[:, 4:], dim=1)
    reward = torch.where(vision, torch.as_tensor(obs.reward, dtype=torch.float32, device=device), -est_distance)
    terminal = torch.where(vision, torch.as_tensor(obs.reached, device=device), est_distance <= radius)
    delta = agent.td_error(state, executable, reward, next_state, terminal.float())
    return _info(vec_env, obs, episode, step, active, state, action, habit, delta, predicted, reward,
                 next_state, terminal)


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().float().cpu().numpy() if t.dtype.is_floating_point else t.detach().cpu().numpy()


def _info(vec_env: VecEnv, obs: Observation, episode, step, active, state, action, habit, delta, predicted,
          reward, next_state, terminal) -> StepInfo:
    return StepInfo(
        episode=np.asarray(episode, dtype=np.int64).copy(), step=np.asarray(step, dtype=np.int64).copy(),
        active=np.asarray(active, dtype=bool).copy(), state=_np(state), action=_np(action),
        habit=_np(habit).astype(bool), delta=_np(delta), predicted_arm=_np(predicted), reward=_np(reward),
        done=obs.last.copy(), reached=obs.reached.copy(), vision=obs.vision.copy(), next_state=_np(next_state),
        terminal=_np(terminal).astype(bool), **vec_env.snapshot())


#: Hooks as plain callables (the Protocols above document the signatures).
OnStep = Callable[[StepInfo, VecEnv], None]
OnEpisodeStart = Callable[[np.ndarray, VecEnv], None]
