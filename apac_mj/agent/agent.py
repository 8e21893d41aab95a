"""Agent: the APAC networks for E independent seeds, their proposals, delta and one update.

Habit system: DDPG actor + critic with target networks (soft updates, tau).
Planning system: forward model (next [end, elbow] from [end, elbow] + action)
and inverse model (action from [end_t, elbow_t, end_{t+1}], trained in
hindsight; at action time the target replaces end_{t+1}). Where the task observes
more than the positions (the joint velocities of a dynamic arm), both models read
it too and the forward model predicts it: their input is then a Markov state.
Every network reads each extra entry divided by its scale (``Sizes.extra_scale``).

The update is written once, as losses (:meth:`Agent.losses`) differentiated
by autograd and stepped by ``torch.optim.Adam`` on per-member views of the
``[E, ...]`` weights (each member its own moments and step count; inactive
members get no gradient and are left untouched).

Every member k has its own networks, optimizer state, replay memory, OU noise
and random streams, all derived from ``seeds[k]``. What holds for member k of
an ensemble against the same seed trained alone is tested in
tests/test_agent.py and stated in docs/agent.md.
"""
from __future__ import annotations

import copy
import dataclasses
import functools
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch
from torch import nn

from apac_mj.agent.inputs import NetworkInputs
from apac_mj.agent.networks import (build_actor, build_critic, build_dynamics_model, build_forward_model,
                                    build_inverse_model, dynamics_loss)
from apac_mj.agent.noise import OUNoise
from apac_mj.agent.precision import autocast, fp32_unless
from apac_mj.agent.replay import EnsembleReplay
from apac_mj.config import FREEZABLE, PRECISIONS, AgentConfig
from apac_mj.kinematics import Geometry
from apac_mj.layout import ARM, ELBOW, END, Sizes, StateLayout
from apac_mj.types import LOSSES

if TYPE_CHECKING:
    from apac_mj.rules import MPCParams

NETWORKS = ("actor", "critic", "forward_model", "inverse_model", "target_actor", "target_critic")
#: Networks trained by the optimizer, with the AgentConfig field of their learning rate.
TRAINED = {"critic": "critic_lr", "actor": "actor_lr", "forward_model": "forward_lr", "inverse_model": "inverse_lr"}


def member_generators(seed: int) -> tuple[torch.Generator, torch.Generator, torch.Generator]:
    """Three independent CPU generators (init, replay, noise) derived from one seed."""
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seeds must be non-negative integers, got {seed!r}")
    states = np.random.SeedSequence(int(seed)).generate_state(3, dtype=np.uint64)
    return tuple(torch.Generator().manual_seed(int(s) & (2**63 - 1)) for s in states)  # type: ignore


class Agent:
    """E independent APAC agents (an :class:`apac_mj.types.Policy`): their proposals, forward model and TD
    error for the episode loop, their replay memory and :meth:`update` for the trainer.

    ``dynamics``: the settings of a dynamics model to learn beside the paper's networks (``agent.mpc``, for a
    planner that plans through one: ``PlannerKind.model``; the builder passes them); None: none.
    Construction switches on ``torch.set_flush_denormal`` for the process (docs/agent.md): tiny weights
    flush to zero, as in every run the numbers were measured with.
    """

    def __init__(self, cfg: AgentConfig, seeds: Sequence[int], device: str = "cpu", precision: str = "fp32",
                 geometry: Geometry | None = None, sizes: Sizes | None = None,
                 dynamics: MPCParams | None = None) -> None:
        self.device = _checked_device(device, precision, seeds)
        torch.set_flush_denormal(True)
        #: The task's sizes (state and action dimensions, action bound), from its dm_env specs.
        self.sizes = sizes or Sizes()
        #: The state's parts by name, and the habit's view of it.
        self.layout = StateLayout(self.sizes)
        self.state_dim, self.action_dim = self.sizes.state_dim, self.sizes.action_dim
        cfg = in_action_units(cfg, self.sizes)
        self.cfg, self.seeds, self.precision = cfg, [int(s) for s in seeds], precision
        self.geometry = geometry or Geometry()
        self.plane_scale = _plane_scale(cfg, self.geometry)
        self.E = len(self.seeds)
        #: ``with self._precision(net):`` inside the update: fp32 for a network ``bf16_networks`` leaves out.
        self._precision = functools.partial(fp32_unless, device_type=self.device.type, precision=precision,
                                            networks=cfg.bf16_networks)
        #: How the networks read the state and the action (network units).
        self.inputs = NetworkInputs(self.layout, cfg, self.plane_scale, self.device)
        gens = [member_generators(s) for s in self.seeds]
        decay = self._build_networks([g[0] for g in gens], dynamics)
        self.optimizer, self._views = _member_adam(
            {n: (getattr(self, n), lr, decay[n]) for n, lr in self.trained.items()}, self.E)
        self.replay = EnsembleReplay([g[1] for g in gens], cfg.replay_size, self.state_dim, self.action_dim,
                                     device=self.device)
        self.noise = OUNoise([g[2] for g in gens], dim=self.action_dim, theta=cfg.ou_theta, sigma=cfg.ou_sigma,
                             device=self.device)
        self._soft_pairs = [(t.detach(), o.detach()) for net, tnet in
                            ((self.actor, self.target_actor), (self.critic, self.target_critic))
                            for t, o in zip(tnet.parameters(), net.parameters())]
        self._soft_views = [(t.unbind(0), o.unbind(0)) for t, o in self._soft_pairs]
        #: Per member: its ``cfg.frozen`` learners learn nothing in this update (a lesion; :meth:`update` sets it).
        self._lesioned = [False] * self.E

    def _build_networks(self, init: list[torch.Generator], dynamics: MPCParams | None) -> dict[str, float]:
        """The networks, initialized from the members' ``init`` generators in a fixed order (the dynamics model
        last, so that the others start as in every kind); returns each trained network's L2 weight decay."""
        cfg, S, A, X = self.cfg, self.state_dim, self.action_dim, self.sizes.motion_dim
        self.actor = build_actor(cfg.actor_hidden, init, S, A).to(self.device)
        self.critic = build_critic(cfg.critic_hidden, init, cfg.critic_form, S, A).to(self.device)
        self.forward_model = build_forward_model(cfg.forward_hidden, self.plane_scale, init, A, X).to(self.device)
        self.inverse_model = build_inverse_model(cfg.inverse_hidden, init, A, X).to(self.device)
        self.target_actor = _frozen_copy(self.actor)
        self.target_critic = _frozen_copy(self.critic)
        #: The networks the optimizer trains, with their learning rates; and every network a checkpoint keeps.
        self.trained = {n: getattr(cfg, lr) for n, lr in TRAINED.items()}
        self.networks: tuple[str, ...] = NETWORKS
        #: The planning system's dynamics model (``dynamics``); None: the kind has none.
        self.dynamics_model: nn.Module | None = None
        #: Extra Adam steps of the dynamics model alone after every update (``mpc.model_updates``; 0: none).
        self.model_updates = 0
        #: The losses :meth:`update` reports, in the order of metrics.parquet's ``<name>_loss`` columns.
        self.loss_names: tuple[str, ...] = LOSSES
        decay = {n: cfg.weight_decay for n in self.trained}  # the paper's weight decay on its own networks
        if cfg.inverse_weight_decay is not None:
            decay["inverse_model"] = cfg.inverse_weight_decay
        if dynamics is not None:
            self.model_updates = dynamics.model_updates
            self.dynamics_model = build_dynamics_model(dynamics.model_hidden, init, A, X, dynamics.model_heads,
                                                       dynamics.held_out_heads).to(self.device)
            self.trained["dynamics_model"], decay["dynamics_model"] = dynamics.model_lr, dynamics.model_weight_decay
            self.networks, self.loss_names = (*NETWORKS, "dynamics_model"), (*LOSSES, "dynamics")
        return decay

    # -- actions -----------------------------------------------------------------
    def feasible_range(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint-angle changes ``(low, high)`` ``[..., 2]`` that keep both joints in range from the pose in
        ``s`` (raw cm: [end, elbow, ...]); ``±action_scale`` for unbounded joints and for actions that are
        not joint-angle changes (torques)."""
        if not self.sizes.angle_actions:
            lo = torch.full((*s.shape[:-1], self.action_dim), -self.cfg.action_scale, dtype=s.dtype,
                            device=s.device)
            return lo, -lo
        return self.geometry.feasible_changes(s[..., END], s[..., ELBOW], self.cfg.action_scale)

    def to_action(self, u: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """A network's tanh output ``u`` in [-1, 1] -> joint-angle changes (degrees) in state ``s``
        (``action_squash``: "tanh" 180 u; "feasible" onto the pose's feasible range)."""
        if self.cfg.action_squash == "tanh":
            return u * self.cfg.action_scale
        lo, hi = self.feasible_range(s)
        return lo + (hi - lo) * (u + 1.0) / 2.0

    def executable(self, a: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        """The part of command ``a`` ``[E,2]`` the plant can execute from the pose in ``s`` (the joint
        limits clip the rest): the action the forward model predicts with, delta is computed on and,
        as the executed change, the critic and the forward model learn from."""
        lo, hi = self.feasible_range(s)
        return torch.minimum(torch.maximum(a, lo), hi)

    def _check(self, name: str, x: torch.Tensor, dim: int) -> torch.Tensor:
        x = torch.as_tensor(x, dtype=torch.float32, device=self.device)
        if tuple(x.shape) != (self.E, dim):
            raise ValueError(f"{name} must have shape ({self.E}, {dim}), got {tuple(x.shape)}")
        return x

    # -- proposals -------------------------------------------------------------
    @torch.no_grad()
    def actor_action(self, state: torch.Tensor) -> torch.Tensor:
        """Habit proposal ``pi(s)``: state ``[E, S] -> [E, A]`` (no noise)."""
        s = self._check("state", state, self.state_dim)
        actor = self.target_actor if self.cfg.act_with_target_actor else self.actor
        return self.to_action(actor(self.inputs.habit(self.inputs.state(s))[:, None])[:, 0], s)

    @torch.no_grad()
    def inverse_action(self, state: torch.Tensor) -> torch.Tensor:
        """Planning proposal: the inverse model with the target as the hand's goal, from the state's motion
        (:meth:`StateLayout.motion_parts`): ``[E, S] -> [E, A]`` (no noise)."""
        s = self._check("state", state, self.state_dim)
        return self.to_action(self.inverse_model(self.inputs.plan_input(self.inputs.state(s))[:, None])[:, 0], s)

    @torch.no_grad()
    def predict_arm(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Forward model: state ``[E, S]`` (it reads the motion) + action ``[E, A]`` -> next ``[end, elbow]``
        ``[E, 4]`` (cm)."""
        x = self.inputs.state(self._check("state", state, self.state_dim))
        a = self._check("action", action, self.action_dim)
        return self.forward_model(self.inputs.model_input(x, a)[:, None])[:, 0, ARM]

    # -- the learned model, batched for planning ([E, B, ...]: B candidates per member) -------------------
    @torch.no_grad()
    def imagine(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The next state ``[E, B, S]`` (raw units) the model predicts from ``state`` and the executable
        ``action`` ``[E, B, A]``: its arm and motion, the target and cue unchanged. The model is the dynamics
        model where the kind has one, else the paper's forward model."""
        x = self.inputs.state(state)
        if self.dynamics_model is not None:
            change = self.dynamics_model(self.inputs.model_input(x, action))
            return self.inputs.from_motion(self.inputs.motion_x(x) + change, state)
        return self.inputs.from_forward(self.forward_model(self.inputs.model_input(x, action)), state)

    @torch.no_grad()
    def habit_u(self, state: torch.Tensor) -> torch.Tensor:
        """The actor's tanh output ``[E, B, A]`` in ``state`` ``[E, B, S]`` (:meth:`to_action` makes it an action)."""
        return self.actor(self.inputs.habit(self.inputs.state(state)))

    @torch.no_grad()
    def value(self, state: torch.Tensor) -> torch.Tensor:
        """The critic's ``Q(s, pi(s))`` ``[E, B]`` (cm of return) in ``state`` ``[E, B, S]``."""
        x = self.inputs.habit(self.inputs.state(state))
        return self.critic(x, self.inputs.act(self.to_action(self.actor(x), state)))

    @torch.no_grad()
    def td_error(self, s: torch.Tensor, a: torch.Tensor, r: torch.Tensor, s2: torch.Tensor,
                 done: torch.Tensor) -> torch.Tensor:
        """``delta = r + gamma (1 - done) Q'(s2, pi'(s2)) - Q(s, a)`` per member: ``[E]``."""
        s, s2 = self._check("s", s, self.state_dim)[:, None], self._check("s2", s2, self.state_dim)[:, None]
        a = self._check("a", a, self.action_dim)[:, None]
        r, done = self._check("r", torch.as_tensor(r)[:, None], 1), self._check("done", torch.as_tensor(done)[:, None], 1)
        y = self._target(r, s2, done)
        return (y - self.critic(self.inputs.habit(self.inputs.state(s)), self.inputs.act(a)))[:, 0]

    def _target(self, r: torch.Tensor, s2: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """TD target ``r + gamma (1 - done) Q'(s2, pi'(s2))``; ``[E,B]`` (s2 raw cm)."""
        x2 = self.inputs.habit(self.inputs.state(s2))
        with self._precision("actor"):
            a2 = self.to_action(self.target_actor(x2).float(), s2)
        with self._precision("critic"):
            q2 = self.target_critic(x2, self.inputs.act(a2)).float()
        return r + self.cfg.gamma * (1.0 - done) * q2

    # -- learning ----------------------------------------------------------------
    def update(self, active: torch.Tensor | Sequence[bool],
               lesioned: torch.Tensor | Sequence[bool] | None = None) -> dict[str, torch.Tensor]:
        """One update of critic, actor, forward and inverse model for members that are
        ``active`` and hold at least one transition; soft target update for them. For members that are
        ``lesioned`` the learners of ``cfg.frozen`` learn nothing (their weights, targets and Adam moments stay).
        Returns per-member losses ``[E]`` (NaN for members not updated)."""
        act = torch.as_tensor(active).cpu().bool().tolist()
        if len(act) != self.E:
            raise ValueError(f"active must have {self.E} entries, got {len(act)}")
        self._lesioned = self._lesion_mask(lesioned)
        members = [k for k in range(self.E) if act[k] and self.replay.count[k] >= 1]
        nan = torch.full((self.E,), float("nan"), device=self.device)
        if not members:
            return {name: nan.clone() for name in self.loss_names}
        losses = self.gradients(self.replay.sample(self.cfg.batch_size, members), members)
        self.optimizer.step()
        self._soft_update(self._learning("actor", members))  # the habit's targets: frozen with the actor
        for _ in range(self.model_updates):
            self._model_step(self.replay.sample(self.cfg.batch_size, members), members)
        for _ in range(self.cfg.inverse_updates):
            self._model_step(self.replay.sample(self.cfg.batch_size, members), members, "inverse_model")
        keep = torch.zeros(self.E, dtype=torch.bool, device=self.device)
        keep[members] = True
        return {name: torch.where(keep, loss, nan) for name, loss in losses.items()}

    def _lesion_mask(self, lesioned: torch.Tensor | Sequence[bool] | None) -> list[bool]:
        """``lesioned`` as E booleans (None: no member); a mask for an agent with nothing frozen is refused."""
        if lesioned is None:
            return [False] * self.E
        mask = torch.as_tensor(lesioned).cpu().bool().tolist()
        if len(mask) != self.E:
            raise ValueError(f"lesioned must have {self.E} entries, got {len(mask)}")
        if any(mask) and not self.cfg.frozen:
            raise ValueError("lesioned members given, but agent.frozen names no learner to freeze")
        return mask

    def _learning(self, net: str, members: Sequence[int]) -> list[int]:
        """``members`` whose network ``net`` learns this update (not frozen by a lesion)."""
        if not any(net in FREEZABLE[name] for name in self.cfg.frozen):
            return list(members)
        return [k for k in members if not self._lesioned[k]]

    def _model_step(self, batch: dict[str, torch.Tensor], members: Sequence[int],
                    net: str = "dynamics_model") -> None:
        """One more Adam step of the model ``net`` alone on ``batch`` for ``members`` (the dynamics model:
        ``mpc.model_updates``; the inverse model: ``inverse_updates``): every other network's per-member views
        get no gradient, so Adam leaves them untouched; nor do members whose ``net`` a lesion froze."""
        members = self._learning(net, members)
        if not members:
            return
        for views in self._views.values():
            for vs in views:
                for v in vs:
                    v.grad = None
        model = getattr(self, net)
        model.zero_grad(set_to_none=True)
        with autocast(self.device.type, self.precision):
            x = self.inputs.state(batch["state"])
            loss = self._dynamics_loss(x, batch["action"], batch["next_state"]) if net == "dynamics_model" \
                else self._inverse_loss(x, batch)
        weight = torch.zeros(self.E, device=self.device)
        weight[list(members)] = 1.0
        (loss * weight).sum().backward()
        on = set(members)
        for p, vs in zip(model.parameters(), self._views[net]):
            for k, (v, g) in enumerate(zip(vs, p.grad.unbind(0))):
                v.grad = g if k in on else None
        self.optimizer.step()

    def _inverse_loss(self, x: torch.Tensor, b: dict[str, torch.Tensor]) -> torch.Tensor:
        """The inverse model's error ``[E]``: its action for the reached hand against the executed action."""
        with self._precision("inverse_model"):
            u = self.inverse_model(self.inputs.inverse_input(x, self.inputs.pos(b["next_state"][..., END]))).float()
        return (self.to_action(u, b["state"]) - b["executed_action"]).pow(2).mean((1, 2))

    def _dynamics_loss(self, x: torch.Tensor, a: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        """The dynamics model's error ``[E]`` (:func:`~apac_mj.agent.networks.dynamics_loss`) from the
        network-unit state ``x`` and the action ``a`` to the raw next state ``s2``."""
        target = self.inputs.motion_x(self.inputs.state(s2)) - self.inputs.motion_x(x)
        return dynamics_loss(self.dynamics_model, self.inputs.model_input(x, a), target)

    def gradients(self, batch: dict[str, torch.Tensor], members: Sequence[int]) -> dict[str, torch.Tensor]:
        """Losses ``[E]`` on ``batch`` and, by autograd, their gradients: each network's ``.grad``
        (``[E, ...]``), and on the optimizer's per-member views those of ``members`` (None for the
        others, so Adam leaves them untouched)."""
        for net in self.trained:
            getattr(self, net).zero_grad(set_to_none=True)
        with autocast(self.device.type, self.precision):
            losses = self.losses(batch)
        weight = torch.zeros(self.E, device=self.device)
        weight[members] = 1.0
        sum(((loss * weight).sum() for loss in losses.values()), torch.zeros((), device=self.device)).backward()
        for net, views in self._views.items():
            on = [False] * self.E
            for k in self._learning(net, members):
                on[k] = True
            for p, vs in zip(getattr(self, net).parameters(), views):
                for v, g, k_on in zip(vs, p.grad.unbind(0), on):  # one unbind per parameter, not E indexings
                    v.grad = g if k_on else None
        return {name: loss.detach().float() for name, loss in losses.items()}

    def losses(self, b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Per-member losses ``[E]`` on a minibatch ``[E,B,...]``: the update, written once.

        Each loss reaches only its own network's weights: the actor's loss differentiates
        Q(s, pi(s)) through the critic's current weights as constants (``detach``)."""
        cfg, inputs = self.cfg, self.inputs
        s, a, s2 = b["state"], b["action"], b["next_state"]
        with torch.no_grad():
            y = self._target(b["reward"], s2, b["done"])
        x = inputs.state(s)
        h = inputs.habit(x)  # the habit's view (on a cued task: the cue, not the target's position)
        with self._precision("critic"):
            q = self.critic(h, inputs.act(a)).float()
        with self._precision("actor"):
            u = self.actor(h).float()
        pi = self.to_action(u, s)
        with self._precision("critic"):
            actor_loss = -self.critic(h, inputs.act(pi), detach=True).float().mean(1)
        if cfg.habit_distillation_weight > 0:  # kinds that arbitrate only (apac_mj.kinds.check)
            with torch.no_grad(), self._precision("inverse_model"):
                plan = self.to_action(self.inverse_model(inputs.plan_input(x)).float(), s)
            distance = ((pi - plan) / cfg.action_scale).pow(2).sum(-1).mean(1)
            actor_loss = actor_loss + cfg.habit_distillation_weight * distance
        if cfg.feasibility_weight > 0:
            excess = (pi - self.executable(pi, s)) / cfg.action_scale
            actor_loss = actor_loss + cfg.feasibility_weight * excess.pow(2).sum(-1).mean(1)
        with self._precision("forward_model"):
            arm_next = self.forward_model(inputs.model_input(x, a)).float()
        out = {"critic": (y - q).pow(2).mean(1),
               "actor": actor_loss,
               "forward": self._forward_error(arm_next, s2).pow(2).mean((1, 2)),
               "inverse": self._inverse_loss(x, b)}
        if self.dynamics_model is not None:
            out["dynamics"] = self._dynamics_loss(x, a, s2)
        return out

    def _forward_error(self, y: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        """The forward model's error per output ``[E,B,4 + motion]``: the arm in cm; each motion entry normalized
        by its scale and weighed as half the plane's width (cm), so an error of one scale (500 deg/s) counts
        as much as half the plane."""
        err = y[..., ARM] - s2[..., ARM]
        if not self.layout.motion_dim:
            return err
        half = self.plane_scale / 2
        motion = s2[..., self.layout.motion] / self.inputs.motion_scale
        return torch.cat([err, (self.inputs.forward_extra(y) - motion) * half], -1)

    @torch.no_grad()
    def _soft_update(self, members: list[int]) -> None:
        """``theta' <- tau theta + (1 - tau) theta'`` for the target actor and critic of ``members``."""
        tau = self.cfg.tau
        if not members:
            return
        if len(members) == self.E:
            torch._foreach_lerp_([t for t, _ in self._soft_pairs], [o for _, o in self._soft_pairs], tau)
            return
        torch._foreach_lerp_([tv[k] for tv, _ in self._soft_views for k in members],
                             [ov[k] for _, ov in self._soft_views for k in members], tau)

    # -- persistence -------------------------------------------------------------
    def state_dict(self) -> dict:
        """Everything needed to continue bit-exactly; only tensors, lists, dicts, numbers, strings."""
        return {"seeds": list(self.seeds), "precision": self.precision,
                "networks": {n: {k: v.detach().clone() for k, v in getattr(self, n).state_dict().items()}
                             for n in self.networks},
                "optimizer": self.optimizer.state_dict(), "replay": self.replay.state_dict(),
                "noise": self.noise.state_dict()}

    def load_state_dict(self, d: dict) -> None:
        if list(d["seeds"]) != self.seeds:
            raise ValueError(f"state is for seeds {list(d['seeds'])}, this agent has {self.seeds}")
        with torch.no_grad():
            for n in self.networks:
                net = getattr(self, n)
                for k, v in net.state_dict().items():
                    src = d["networks"][n][k]
                    if src.shape != v.shape:
                        raise ValueError(f"{n}.{k}: shape {tuple(src.shape)} != {tuple(v.shape)}")
                    v.copy_(src)
        self.optimizer.load_state_dict(d["optimizer"])
        self.replay.load_state_dict(d["replay"])
        self.noise.load_state_dict(d["noise"])


def _checked_device(device: str, precision: str, seeds: Sequence[int]) -> torch.device:
    """The agent's device, with its seeds and ``precision`` checked (a clear error where CUDA is missing)."""
    if len(seeds) < 1:
        raise ValueError("Agent needs at least one seed")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
    out = torch.device(device)
    if out.type == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but CUDA is not available")
    return out


def _member_adam(nets: dict[str, tuple[nn.Module, float, float]], E: int,
                 ) -> tuple[torch.optim.Adam, dict[str, list[tuple[torch.Tensor, ...]]]]:
    """``torch.optim.Adam`` over per-member views ``p[k]`` of every parameter (one param group per network
    ``name -> (network, learning rate, L2 weight decay)``, the decay added to the gradient as in Adam's
    ``weight_decay``).

    Adam keeps moments and the step count per tensor, so each member has its own; a view whose
    ``.grad`` is None is skipped, so members that are not updated stay bit-identical."""
    views = {n: [p.detach().unbind(0) for p in net.parameters()] for n, (net, _, _) in nets.items()}
    groups = [{"params": [v for vs in views[n] for v in vs], "lr": lr, "weight_decay": wd}
              for n, (_, lr, wd) in nets.items()]
    opt = torch.optim.Adam(groups, fused=True)
    return opt, views


def in_action_units(cfg: AgentConfig, sizes: Sizes) -> AgentConfig:
    """``cfg`` for a task's actions: unchanged (the same object) for joint-angle changes; for other actions
    (torques) the action scale becomes the task's bound and the babbling range and exploration noise, given
    in degrees of a 180-degree scale, keep their fraction of the action range."""
    if sizes.angle_actions:
        return cfg
    r = sizes.action_bound / cfg.action_scale
    return dataclasses.replace(cfg, action_scale=sizes.action_bound, babbling_scale=cfg.babbling_scale * r,
                               ou_sigma=cfg.ou_sigma * r,
                               ou_sigma_initial=None if cfg.ou_sigma_initial is None else cfg.ou_sigma_initial * r)


def _plane_scale(cfg: AgentConfig, geometry: Geometry) -> float:
    """The plane's size (cm) the networks scale positions by: the task's (``geometry``), which must be
    square (the forward model has one output scale); ``cfg.plane_scale``, if set, must agree."""
    w, h = geometry.plane_size
    if w != h:
        raise ValueError(f"the agent needs a square plane (one output scale for the forward model); "
                         f"the task's plane is {w} x {h} cm")
    if cfg.plane_scale is not None and cfg.plane_scale != w:
        raise ValueError(f"AgentConfig.plane_scale = {cfg.plane_scale} but the task's plane is {w} x {h} cm: "
                         f"set plane_scale = {w:g} or None (None: the task's plane)")
    return float(w)


def _frozen_copy(net: nn.Module) -> nn.Module:
    target = copy.deepcopy(net)
    for p in target.parameters():
        p.requires_grad_(False)
    return target
