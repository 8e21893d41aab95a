"""Agent: the APAC networks for E independent seeds, their proposals, delta and one update.

Habit system: DDPG actor + critic with target networks (soft updates, tau).
Planning system: forward model (next [end, elbow] from [end, elbow] + action)
and inverse model (action from [end_t, elbow_t, end_{t+1}], trained in
hindsight; at action time the target replaces end_{t+1}).

Every member k has its own networks, optimizer state, replay memory, OU noise
and random streams, all derived from ``seeds[k]``; member k of an ensemble
behaves exactly like the same seed trained alone (E = 1). See docs/agent.md.
"""
from __future__ import annotations

import contextlib
import copy
from typing import Sequence

import numpy as np
import torch
from torch import nn

from apac_mj.buffer import EnsembleReplay
from apac_mj.config import AgentConfig
from apac_mj.networks import (Workspace, act_backward_, build_actor, build_critic, build_forward_model,
                              build_inverse_model, mlp_backward, mlp_forward)
from apac_mj.noise import OUNoise
from apac_mj.optim import EnsembleAdam

PRECISIONS = ("fp32", "bf16")
NETWORKS = ("actor", "critic", "forward_model", "inverse_model", "target_actor", "target_critic")
LOSSES = ("critic", "actor", "forward", "inverse")
#: Networks trained by the optimizer, in its group order.
TRAINED = ("critic", "actor", "forward_model", "inverse_model")


def member_generators(seed: int) -> tuple[torch.Generator, torch.Generator, torch.Generator]:
    """Three independent CPU generators (init, replay, noise) derived from one seed."""
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seeds must be non-negative integers, got {seed!r}")
    states = np.random.SeedSequence(int(seed)).generate_state(3, dtype=np.uint64)
    return tuple(torch.Generator().manual_seed(int(s) & (2**63 - 1)) for s in states)  # type: ignore


class Agent:
    """E independent APAC agents; see docs/architecture.md for the contract."""

    def __init__(self, cfg: AgentConfig, seeds: Sequence[int], device: str = "cpu",
                 precision: str = "fp32") -> None:
        if len(seeds) < 1:
            raise ValueError("Agent needs at least one seed")
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        self.device = torch.device(device)
        if self.device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError("device 'cuda' requested but CUDA is not available")
        torch.set_flush_denormal(True)
        self.cfg, self.seeds, self.precision = cfg, [int(s) for s in seeds], precision
        self.E = len(self.seeds)
        #: Habit formation from planning acts in APAC only: DDPG has no planner to learn from, SPAC no habit.
        self._distill = cfg.habit_distillation_weight if cfg.agent == "apac" else 0.0
        gens = [member_generators(s) for s in self.seeds]
        init = [g[0] for g in gens]
        self.actor = build_actor(cfg.actor_hidden, cfg.action_scale, init).to(self.device)
        self.critic = build_critic(cfg.critic_hidden, init).to(self.device)
        self.forward_model = build_forward_model(cfg.forward_hidden, cfg.plane_scale, init).to(self.device)
        self.inverse_model = build_inverse_model(cfg.inverse_hidden, cfg.action_scale, init).to(self.device)
        self.target_actor = _frozen_copy(self.actor)
        self.target_critic = _frozen_copy(self.critic)
        self.optimizer = EnsembleAdam(
            [(list(self.critic.parameters()), cfg.critic_lr), (list(self.actor.parameters()), cfg.actor_lr),
             (list(self.forward_model.parameters()), cfg.forward_lr),
             (list(self.inverse_model.parameters()), cfg.inverse_lr)],
            weight_decay=cfg.weight_decay)
        self.replay = EnsembleReplay([g[1] for g in gens], cfg.replay_size, device=self.device)
        self.noise = OUNoise([g[2] for g in gens], theta=cfg.ou_theta, sigma=cfg.ou_sigma, device=self.device)
        self._soft_pairs = [(t.detach(), o.detach()) for net, tnet in
                            ((self.actor, self.target_actor), (self.critic, self.target_critic))
                            for t, o in zip(tnet.parameters(), net.parameters())]
        self._soft_views = [(t.unbind(0), o.unbind(0)) for t, o in self._soft_pairs]
        self._init_workspace()

    def _init_workspace(self) -> None:
        """Weights as ``[(W, b), ...]`` per network, gradient buffers and (bf16) working copies."""
        def pairs(tensors: list[torch.Tensor]) -> list[tuple[torch.Tensor, torch.Tensor]]:
            return list(zip(tensors[0::2], tensors[1::2]))
        self._dtype = torch.bfloat16 if self.precision == "bf16" else torch.float32
        self._ws = Workspace(self.device)
        self._params = {n: [p.detach() for p in getattr(self, n).parameters()] for n in NETWORKS}
        self._grads = {n: [torch.zeros_like(p) for p in self._params[n]] for n in TRAINED}
        if self._dtype == torch.float32:
            self._work = self._params
            self._work_grads = self._grads
        else:
            self._work = {n: [p.to(self._dtype) for p in ps] for n, ps in self._params.items()}
            self._work_grads = {n: [g.to(self._dtype) for g in gs] for n, gs in self._grads.items()}
        self._W = {n: pairs(ps) for n, ps in self._work.items()}
        self._G = {n: pairs(gs) for n, gs in self._work_grads.items()}

    # -- inputs ----------------------------------------------------------------
    def _pos(self, x: torch.Tensor) -> torch.Tensor:
        """Network input for positions (cm); identity unless ``normalize_inputs``."""
        if not self.cfg.normalize_inputs:
            return x
        half = self.cfg.plane_scale / 2
        return (x - half) / half

    def _act(self, a: torch.Tensor) -> torch.Tensor:
        """Network input for actions (degrees); identity unless ``normalize_inputs``."""
        return a / self.cfg.action_scale if self.cfg.normalize_inputs else a

    def _autocast(self) -> contextlib.AbstractContextManager:
        if self.precision == "bf16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def _check(self, name: str, x: torch.Tensor, dim: int) -> torch.Tensor:
        x = torch.as_tensor(x, dtype=torch.float32, device=self.device)
        if tuple(x.shape) != (self.E, dim):
            raise ValueError(f"{name} must have shape ({self.E}, {dim}), got {tuple(x.shape)}")
        return x

    # -- proposals -------------------------------------------------------------
    @torch.no_grad()
    def actor_action(self, state: torch.Tensor) -> torch.Tensor:
        """Habit proposal ``pi(s)``: ``[E,6] -> [E,2]`` degrees (no noise)."""
        actor = self.target_actor if self.cfg.act_with_target_actor else self.actor
        return actor(self._pos(self._check("state", state, 6))[:, None])[:, 0]

    @torch.no_grad()
    def inverse_action(self, state: torch.Tensor) -> torch.Tensor:
        """Planning proposal: ``[end, elbow, target]`` ``[E,6] -> [E,2]`` degrees (no noise)."""
        return self.inverse_model(self._pos(self._check("state", state, 6))[:, None])[:, 0]

    @torch.no_grad()
    def predict_arm(self, arm: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Forward model: ``[end, elbow]`` ``[E,4]`` + action ``[E,2]`` -> next ``[end, elbow]`` ``[E,4]``."""
        x = torch.cat([self._pos(self._check("arm", arm, 4)), self._act(self._check("action", action, 2))], -1)
        return self.forward_model(x[:, None])[:, 0]

    @torch.no_grad()
    def td_error(self, s: torch.Tensor, a: torch.Tensor, r: torch.Tensor, s2: torch.Tensor,
                 done: torch.Tensor) -> torch.Tensor:
        """``delta = r + gamma (1 - done) Q'(s2, pi'(s2)) - Q(s, a)`` per member: ``[E]``."""
        s, s2 = self._check("s", s, 6)[:, None], self._check("s2", s2, 6)[:, None]
        a = self._check("a", a, 2)[:, None]
        r, done = self._check("r", torch.as_tensor(r)[:, None], 1), self._check("done", torch.as_tensor(done)[:, None], 1)
        y = self._target(r, s2, done)
        return (y - self.critic(self._pos(s), self._act(a)))[:, 0]

    def _target(self, r: torch.Tensor, s2: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """TD target ``r + gamma (1 - done) Q'(s2, pi'(s2))``; ``[E,B]`` (s2 raw cm)."""
        x2 = self._pos(s2)
        q2 = self.target_critic(x2, self._act(self.target_actor(x2))).float()
        return r + self.cfg.gamma * (1.0 - done) * q2

    # -- learning ----------------------------------------------------------------
    def update(self, active: torch.Tensor | Sequence[bool]) -> dict[str, torch.Tensor]:
        """One update of critic, actor, forward and inverse model for members that are
        ``active`` and hold at least one transition; soft target update for them.
        Returns per-member losses ``[E]`` (NaN for members not updated)."""
        act = torch.as_tensor(active).cpu().bool().tolist()
        if len(act) != self.E:
            raise ValueError(f"active must have {self.E} entries, got {len(act)}")
        members = [k for k in range(self.E) if act[k] and self.replay.count[k] >= 1]
        nan = torch.full((self.E,), float("nan"), device=self.device)
        if not members:
            return {name: nan.clone() for name in LOSSES}
        batch = self.replay.sample(self.cfg.batch_size, members)
        if self._dtype != torch.float32:
            torch._foreach_copy_([w for n in NETWORKS for w in self._work[n]],
                                 [p for n in NETWORKS for p in self._params[n]])
        with torch.no_grad():
            losses = self._gradients(batch)
        if self._dtype != torch.float32:
            torch._foreach_copy_([g for n in TRAINED for g in self._grads[n]],
                                 [g for n in TRAINED for g in self._work_grads[n]])
        self.optimizer.step([self._grads[n] for n in TRAINED], members)
        self._soft_update(members)
        keep = torch.zeros(self.E, dtype=torch.bool, device=self.device)
        keep[members] = True
        return {name: torch.where(keep, loss, nan) for name, loss in losses.items()}

    def _gradients(self, b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Losses ``[E]`` of the four networks and their gradients (into ``self._grads``) by hand:
        the same quantities as :meth:`_losses` + autograd, on preallocated buffers."""
        cfg, dt, W = self.cfg, self._dtype, self._W
        s, a, s2 = b["state"], b["action"], b["next_state"]
        B = s.shape[1]
        x, x2, a_in = self._pos(s).to(dt), self._pos(s2).to(dt), self._act(a).to(dt)
        # TD target y = r + gamma (1 - done) Q'(s2, pi'(s2))
        t_out = mlp_forward(self._ws, "target_actor", W["target_actor"], "relu", "tanh", x2)[-1]
        a2_in = t_out if cfg.normalize_inputs else t_out * cfg.action_scale
        q2 = self._critic_forward("target_critic", x2, a2_in)[2].float()
        y = b["reward"] + cfg.gamma * (1.0 - b["done"]) * q2
        # critic
        h1, h2, q = self._critic_forward("critic", x, a_in)
        q32 = q.float()
        losses = {"critic": (y - q32).pow(2).mean(1)}
        self._critic_backward(x, a_in, h1, h2, (2.0 / B) * (q32 - y))
        # actor: dQ(s, pi(s))/dpi through the critic's pre-update weights
        losses["actor"] = self._actor_gradients(x, s, h2, B)
        # forward model on the next observed arm position
        f_in = self._ws.get("forward_model.in", (*x.shape[:2], 6), dt)
        f_in[..., :4].copy_(x[..., :4])
        f_in[..., 4:].copy_(a_in)
        losses["forward"] = self._regression("forward_model", "sigmoid", f_in, s2[..., :4], cfg.plane_scale)
        # inverse model in hindsight: (end_t, elbow_t, end_{t+1}) -> a_t
        i_in = self._ws.get("inverse_model.in", (*x.shape[:2], 6), dt)
        i_in[..., :4].copy_(x[..., :4])
        i_in[..., 4:].copy_(x2[..., :2])
        losses["inverse"] = self._regression("inverse_model", "relu", i_in, b["executed_action"], cfg.action_scale)
        return losses

    def _critic_forward(self, name: str, x: torch.Tensor, a_in: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``h1 [E,B,400]``, ``h2 [E,B,600]`` (relu'd state half, action half) and ``Q [E,B]``."""
        (w1, b1), (ws, bs), (wa, ba), (wo, bo) = self._W[name]
        E, B, half = x.shape[0], x.shape[1], ws.shape[-1]
        h1 = torch.baddbmm(b1, x, w1, out=self._ws.get(f"{name}.h1", (E, B, w1.shape[-1]), x.dtype)).relu_()
        # GEMMs into contiguous buffers (a strided out= costs a temporary and a copy), relu into h2's halves
        h2 = self._ws.get(f"{name}.h2", (E, B, 2 * half), x.dtype)
        zs = torch.baddbmm(bs, h1, ws, out=self._ws.get(f"{name}.zs", (E, B, half), x.dtype))
        za = torch.baddbmm(ba, a_in, wa, out=self._ws.get(f"{name}.za", (E, B, half), x.dtype))
        torch.clamp_min(zs, 0, out=h2[..., :half])
        torch.clamp_min(za, 0, out=h2[..., half:])
        return h1, h2, _q_head(bo, h2, wo, self._ws.get(f"{name}.q", (E, 1, B), x.dtype))

    def _critic_backward(self, x: torch.Tensor, a_in: torch.Tensor, h1: torch.Tensor, h2: torch.Tensor,
                         dq: torch.Tensor) -> None:
        """Gradients of the critic loss given ``dq = dL/dQ`` ``[E,B]``."""
        (w1, _), (ws, _), _, (wo, _) = self._W["critic"]
        (g1, gb1), (gs, gbs), (ga, gba), (go, gbo) = self._G["critic"]
        dq = dq.to(h2.dtype)
        half = ws.shape[-1]
        # row-vector products ([E,1,B] @ [E,B,600]) are several times faster than [E,600,B] @ [E,B,1]
        torch.bmm(dq[:, None], h2, out=go.view(go.shape[0], 1, -1))
        torch.sum(dq, dim=1, keepdim=True, out=gbo.view(-1, 1))
        # the two halves of dL/dh2 in separate contiguous buffers (strided bf16 GEMM inputs are slow)
        dq3, wo_t, shape = dq[..., None], wo.transpose(1, 2), (*h2.shape[:2], half)
        dzs = torch.mul(dq3, wo_t[..., :half], out=self._ws.get("critic.dzs", shape, h2.dtype))
        dza = torch.mul(dq3, wo_t[..., half:], out=self._ws.get("critic.dza", shape, h2.dtype))
        act_backward_("relu", dzs, h2[..., :half])
        act_backward_("relu", dza, h2[..., half:])
        torch.bmm(a_in.transpose(1, 2), dza, out=ga)
        torch.sum(dza, dim=1, keepdim=True, out=gba)
        torch.bmm(h1.transpose(1, 2), dzs, out=gs)
        torch.sum(dzs, dim=1, keepdim=True, out=gbs)
        dh1 = torch.bmm(dzs, ws.transpose(1, 2), out=self._ws.get("critic.dh1", h1.shape, h1.dtype))
        act_backward_("relu", dh1, h1)
        torch.bmm(x.transpose(1, 2), dh1, out=g1)
        torch.sum(dh1, dim=1, keepdim=True, out=gb1)

    def _actor_gradients(self, x: torch.Tensor, s: torch.Tensor, h2: torch.Tensor, B: int) -> torch.Tensor:
        """Actor loss ``-mean Q(s, pi(s))`` (+ the feasibility penalty) ``[E]``; its gradient into the
        actor's buffers. ``x`` is the network input, ``s`` the raw state (cm)."""
        cfg, W = self.cfg, self._W
        _, (ws, _), (wa, ba), (wo, bo) = W["critic"]
        half = ws.shape[-1]
        xs = mlp_forward(self._ws, "actor", W["actor"], "relu", "tanh", x)
        pi_in = xs[-1] if cfg.normalize_inputs else xs[-1] * cfg.action_scale
        h2pi = self._ws.get("actor.h2", h2.shape, h2.dtype)
        h2pi[..., :half].copy_(h2[..., :half])
        za = torch.baddbmm(ba, pi_in, wa, out=self._ws.get("actor.za", (*h2.shape[:2], half), h2.dtype))
        torch.clamp_min(za, 0, out=h2pi[..., half:])
        q_pi = _q_head(bo, h2pi, wo, self._ws.get("actor.q", (h2.shape[0], 1, B), h2.dtype)).float()
        dza = self._ws.get("actor.dza", (*h2.shape[:2], half), h2.dtype)
        dza.copy_((wo[:, half:].transpose(1, 2) * (-1.0 / B)).expand_as(dza))
        act_backward_("relu", dza, h2pi[..., half:])
        # dL/dpi = dza @ wa^T computed as wa @ dza^T ([E,2,B]; narrow outputs are faster this way)
        dpi_t = self._ws.get("actor.dpi", (pi_in.shape[0], pi_in.shape[2], pi_in.shape[1]), h2.dtype)
        dpi = torch.bmm(wa, dza.transpose(1, 2), out=dpi_t).transpose(1, 2)
        if not cfg.normalize_inputs:
            dpi.mul_(cfg.action_scale)
        loss = -q_pi.mean(1)
        if self._distill > 0:
            # habit formation from planning: pull pi(s) towards the inverse model's proposal f_I(s)
            plan = mlp_forward(self._ws, "inverse_model.distill", W["inverse_model"], "relu", "tanh", x)[-1]
            gap = xs[-1].float() - plan.float()
            dpi.add_((gap * (2.0 * self._distill / B)).to(dpi.dtype))
            loss = loss + self._distill * gap.pow(2).sum(-1).mean(1)
        if cfg.feasibility_weight > 0:
            excess = self._excess(s, xs[-1].float())
            dpi.add_((excess * (2.0 * cfg.feasibility_weight / B)).to(dpi.dtype))
            loss = loss + cfg.feasibility_weight * excess.pow(2).sum(-1).mean(1)
        mlp_backward(self._ws, "actor", W["actor"], "relu", "tanh", xs, dpi, self._G["actor"])
        return loss

    def _excess(self, s: torch.Tensor, squashed: torch.Tensor) -> torch.Tensor:
        """``(a - clip_joints(a)) / action_scale`` ``[E,B,2]`` for the actor's tanh output ``squashed``:
        the part of a command that the joint limits would clip. The actor's loss adds
        ``feasibility_weight * mean_B |excess|^2``, which pulls such commands back to the limit."""
        a = squashed * self.cfg.action_scale
        lo, hi = self._feasible_range(s)
        return (a - torch.minimum(torch.maximum(a, lo), hi)) / self.cfg.action_scale

    def _feasible_range(self, s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint-angle changes that keep both joints in [0, 180] from the arm pose in ``s`` (raw cm)."""
        half = self.cfg.plane_scale / 2
        end, elbow = s[..., 0:2], s[..., 2:4]
        alpha = torch.rad2deg(torch.atan2(elbow[..., 1] - half, elbow[..., 0] - half))
        arm = torch.rad2deg(torch.atan2(end[..., 1] - elbow[..., 1], end[..., 0] - elbow[..., 0]))
        alpha = torch.remainder(alpha + 90.0, 360.0) - 90.0
        beta = torch.remainder(arm - alpha + 90.0, 360.0) - 90.0
        angles = torch.stack([alpha, beta], -1)
        return -angles, 180.0 - angles

    def _regression(self, name: str, hidden_act: str, inputs: torch.Tensor, label: torch.Tensor,
                    scale: float) -> torch.Tensor:
        """MSE of ``scale * out_act(net(inputs))`` against ``label`` ``[E,B,D]``; gradients by hand."""
        out_act = "sigmoid" if name == "forward_model" else "tanh"
        xs = mlp_forward(self._ws, name, self._W[name], hidden_act, out_act, inputs)
        err = xs[-1].float() * scale - label
        grad = (err * (2.0 * scale / err[0].numel())).to(inputs.dtype)
        mlp_backward(self._ws, name, self._W[name], hidden_act, out_act, xs, grad, self._G[name])
        return err.pow(2).mean((1, 2))

    def _update_autograd(self, active: torch.Tensor | Sequence[bool]) -> dict[str, torch.Tensor]:
        """Reference update via autograd (tests compare :meth:`update` against it)."""
        members = [k for k, on in enumerate(torch.as_tensor(active).bool().tolist())
                   if on and self.replay.count[k] >= 1]
        batch = self.replay.sample(self.cfg.batch_size, members)
        with self._autocast():
            losses = self._losses(batch)
        params = [list(getattr(self, n).parameters()) for n in TRAINED]
        weight = torch.zeros(self.E, device=self.device)
        weight[members] = 1.0
        total = sum((loss * weight).sum() for loss in losses.values())
        grads = iter(torch.autograd.grad(total, [p for ps in params for p in ps]))
        self.optimizer.step([[next(grads) for _ in ps] for ps in params], members)
        self._soft_update(members)
        return {name: loss.detach().float() for name, loss in losses.items()}

    def _losses(self, b: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Per-member losses ``[E]`` on a minibatch ``[E,B,...]``."""
        s, a, s2 = b["state"], b["action"], b["next_state"]
        with torch.no_grad():
            y = self._target(b["reward"], s2, b["done"])
        x = self._pos(s)
        features = self.critic.features(x)
        q = self.critic.head(features, self._act(a)).float()
        # Actor: gradient of Q(s, pi(s)) through the critic's (pre-update) weights, not into them.
        pi = self.actor(x)
        q_pi = self.critic.head(features.detach(), self._act(pi), detach=True).float()
        actor_loss = -q_pi.mean(1)
        if self._distill > 0:
            with torch.no_grad():
                plan = self.inverse_model(x).float() / self.cfg.action_scale
            gap = pi.float() / self.cfg.action_scale - plan
            actor_loss = actor_loss + self._distill * gap.pow(2).sum(-1).mean(1)
        if self.cfg.feasibility_weight > 0:
            excess = self._excess(s, pi.float() / self.cfg.action_scale)
            actor_loss = actor_loss + self.cfg.feasibility_weight * excess.pow(2).sum(-1).mean(1)
        arm_next = self.forward_model(torch.cat([x[..., :4], self._act(a)], -1)).float()
        a_inv = self.inverse_model(torch.cat([x[..., :4], self._pos(s2[..., :2])], -1)).float()
        return {"critic": (y - q).pow(2).mean(1),
                "actor": actor_loss,
                "forward": (arm_next - s2[..., :4]).pow(2).mean((1, 2)),
                "inverse": (a_inv - b["executed_action"]).pow(2).mean((1, 2))}

    @torch.no_grad()
    def _soft_update(self, members: list[int]) -> None:
        """``theta' <- tau theta + (1 - tau) theta'`` for the target actor and critic of ``members``."""
        tau = self.cfg.tau
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
                             for n in NETWORKS},
                "optimizer": self.optimizer.state_dict(), "replay": self.replay.state_dict(),
                "noise": self.noise.state_dict()}

    def load_state_dict(self, d: dict) -> None:
        if list(d["seeds"]) != self.seeds:
            raise ValueError(f"state is for seeds {list(d['seeds'])}, this agent has {self.seeds}")
        with torch.no_grad():
            for n in NETWORKS:
                net = getattr(self, n)
                for k, v in net.state_dict().items():
                    src = d["networks"][n][k]
                    if src.shape != v.shape:
                        raise ValueError(f"{n}.{k}: shape {tuple(src.shape)} != {tuple(v.shape)}")
                    v.copy_(src)
        self.optimizer.load_state_dict(d["optimizer"])
        self.replay.load_state_dict(d["replay"])
        self.noise.load_state_dict(d["noise"])


def _q_head(bo: torch.Tensor, h2: torch.Tensor, wo: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """``Q = h2 @ wo + bo`` as a row-vector product ``wo^T h2^T`` (fast): ``[E,B]``."""
    return torch.baddbmm(bo, wo.transpose(1, 2), h2.transpose(1, 2), out=out)[:, 0]


def _frozen_copy(net: nn.Module) -> nn.Module:
    target = copy.deepcopy(net)
    for p in target.parameters():
        p.requires_grad_(False)
    return target
