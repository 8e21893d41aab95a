"""How biased is each estimate of the graded rule's gain of planning, against MuJoCo's own physics?

    python bench/voc_gain_bias.py RUN_DIR [--targets 10] [--out results/voc_gain/bias.csv]
    python bench/voc_gain_bias.py --combine A.csv B.csv [--out results/voc_gain/all.csv]

The measurement of the fidelity audit (§3.1): at every decision of frozen episodes on the run's grid targets, each
member plans from its state with its own networks at the full budget (a copy of the run's ``MPCPlanner``, its warm
start and random streams, so the plan is the one the agent would make), then the habit's imagined sequence and the
best sequence after each iteration ``k`` are valued as the planner values them (discounted -distance until
arrival, ``gamma^H Q(s_H, pi(s_H))`` by the member's critic) with every step taken on MuJoCo's physics
(``bench/ceiling.py``'s ``Model``: the environment's own sub-steps from a snapshot) instead of the learned model.
``G`` (the truth) is the best sequence's true value minus the habit's. The estimates of ``G`` beside it:

* ``imagined``: the imagined best minus the imagined habit (the rule's before issue 42: ``voc.gain = "imagined"``);
* ``advantage``: the critic's advantage of the best first action, ``Q(s, a_k) - Q(s, pi(s))``
  (``voc.gain = "advantage"``, :func:`apac_mj.agent.arbitrators.critic_advantage`);
* ``realized``: the outcome of the planned step (its first action on MuJoCo's physics, then the critic):
  ``-d(s_1) + gamma Q(s_1, pi(s_1)) - Q(s, pi(s))`` (an oracle here: a run sees it only for the action it took);
* ``heldout``: the same two sequences valued through the run's held-out dynamics heads, a model the plan was not
  selected by (``voc.gain = "heldout"``, :func:`apac_mj.agent.arbitrators.heldout_gains`; a run with
  ``mpc.held_out_heads`` >= 1);
* ``forward``: the same two sequences valued through the paper's forward model (trained beside, never planned
  through);
* ``other_member``: the same two sequences imagined by another member's dynamics model and critic (needs two
  members or more; a diagnostic: a run's members do not share networks).

One row per (decision, member, k) to ``--out``; the summary (per estimate and ``k``: the mean bias with its 95%
intervals over the decisions, the episodes and the seeds, and per seed) is printed and written beside it
(``*_summary.csv``), and the decomposition of the imagined and held-out biases into the error on the chosen
sequence and on the habit's, each split into the distance part and the critic's terminal value
(``*_decomposition.csv``). ``--combine A.csv B.csv ...`` summarizes the rows of runs of disjoint seeds as one.
"""
from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import ceiling  # noqa: E402  (bench/ceiling.py: the environment's own physics as a model)

from apac_mj.agent.arbitrators import AgentView, HeldOutView, critic_advantage, heldout_gains  # noqa: E402
from apac_mj.agent.networks import DynamicsHeads  # noqa: E402
from apac_mj.report.stats import seed_interval  # noqa: E402
from apac_mj.run.build import episode_loop, load_run  # noqa: E402
from apac_mj.run.evaluate import eval_env, evaluation_targets  # noqa: E402
from apac_mj.run.run_dir import RunDir  # noqa: E402
from apac_mj.suite import spec_for  # noqa: E402
from apac_mj.types import Arbitrator  # noqa: E402
from apac_mj.util.progress import progress_iter  # noqa: E402

ESTIMATES = ("imagined", "heldout", "forward", "advantage", "realized", "other_member")


class NoTerminalView(AgentView):
    """An agent (or a view) whose critic values every state 0: a rollout through it is the distance part alone."""

    @torch.no_grad()
    def value(self, state: torch.Tensor) -> torch.Tensor:
        return torch.zeros(state.shape[:-1], device=state.device)


class ForwardModelView(AgentView):
    """An agent whose imagination is the paper's forward model (trained beside the dynamics model, never planned
    through): another model the plans were not selected by."""

    @torch.no_grad()
    def imagine(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        a = self.agent
        return a.inputs.from_forward(a.forward_model(a.inputs.model_input(a.inputs.state(state), action)), state)


def true_state(model: ceiling.Model) -> np.ndarray:
    """The physics now in the agent's state layout: hand, elbow, target (cm), joint velocities (deg/s)."""
    ph = model.physics
    return np.concatenate([ph.end_effector(), ph.elbow(), ph.target(), ph.joint_velocities()])


def true_rollout(agent: Any, model: ceiling.Model, u: torch.Tensor, gamma: float) -> tuple[float, np.ndarray, bool]:
    """Sequence ``u`` ``[H, A]`` (tanh units) from the saved physics: its discounted -distance until the episode
    would end, the true state after it and whether it is still running (the terminal value is added by the caller)."""
    model.restore()
    value, alive = 0.0, True
    for t in range(u.shape[0]):
        s = torch.as_tensor(true_state(model), dtype=torch.float32)
        action = agent.executable(agent.to_action(u[t][None].to(agent.device), s[None].to(agent.device)),
                                  s[None].to(agent.device))
        d = model.step(action[0].double().cpu().numpy())
        value -= gamma ** t * d
        if model.reached(d):
            alive = False
            break
    state = true_state(model)
    model.restore()
    return value, state, alive


class Measuring(Arbitrator):
    """The run's own rule, with the measurement of every estimate made before each of its decisions."""

    def __init__(self, base: Arbitrator, loop: Any, rows: list[dict[str, Any]]) -> None:
        self.base, self.loop, self.rows = base, loop, rows
        self.needs_habit_action, self.needs_habit_probe = base.needs_habit_action, base.needs_habit_probe
        self.models = [ceiling.Model(env) for env in loop.env.envs]
        self.target_index = 0
        #: The members whose frozen episode is still running (their rows of a context are not stale).
        self.running = np.zeros(len(self.models), dtype=bool)
        #: The largest difference between an agent's state and the physics' (cm or deg/s) at a decision.
        self.state_gap = 0.0

    def use_habit(self, ctx: Any) -> Any:
        self.measure(ctx)
        return self.base.use_habit(ctx)

    def observe(self, info: Any, mask: np.ndarray, adapt: bool = True) -> None:
        self.base.observe(info, mask, adapt)
        self.running &= ~(np.asarray(mask, dtype=bool) & info.done)

    def measure(self, ctx: Any) -> None:
        agent, planner, E = self.loop.agent, copy.deepcopy(self.loop.planner), ctx.E
        K, gamma = planner.max_iterations, agent.cfg.gamma
        state = ctx.state
        plan = planner.propose(agent, ctx, torch.full((E,), K))
        _, _, habit_u = planner._habit(agent, state)  # [E, 1, H, A]: the habit's imagined sequence
        seqs = torch.cat([habit_u.cpu(), plan.best_sequences], 1)  # [E, 1 + K, H, A]
        imagined = (plan.best_values - plan.habit_value[:, None]).numpy()
        advantage = critic_advantage(agent, state, plan.best_sequences[:, :, 0].to(state.device)).cpu().numpy()
        best = plan.best_sequences.to(state.device)
        held = isinstance(agent.dynamics_model, DynamicsHeads) and agent.dynamics_model.held_out > 0
        heldout = heldout_gains(agent, planner, state, best).cpu().numpy() if held else np.full((E, K), np.nan)
        forward = self.valued(ForwardModelView(agent), planner, state, seqs)
        other = self.other_member(agent, planner, state, seqs) if E > 1 else np.full((E, K), np.nan)
        truth, realized, total, distance = self.truth(agent, seqs, gamma, state)
        parts = {"true": (total, distance), "imagined": self.sides(agent, planner, state, seqs)}
        if held:
            parts["heldout"] = self.sides(HeldOutView(agent), planner, state, seqs)
        for k in np.flatnonzero(self.running):
            for i in range(K):
                row = {"seed": self.loop.env.seeds[k], "target": self.target_index, "step": int(ctx.step[k]),
                       "k": i + 1, "G": truth[k, i], "imagined": imagined[k, i], "heldout": heldout[k, i],
                       "forward": forward[k, i], "advantage": advantage[k, i], "realized": realized[k, i],
                       "other_member": other[k, i], "imagined_best": float(plan.best_values[k, i]),
                       "imagined_habit": float(plan.habit_value[k])}
                for name, (value, dist) in parts.items():
                    for side, b in (("best", i + 1), ("habit", 0)):
                        row.setdefault(f"{name}_{side}", float(value[k, b]))
                        row[f"{name}_{side}_distance"] = float(dist[k, b])
                self.rows.append(row)

    @staticmethod
    def sides(view: Any, planner: Any, state: torch.Tensor, seqs: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """``[E, 1 + K]`` each sequence's value through ``view``'s imagination (the habit's first) and its distance
        part (the discounted -distance until arrival; the rest is the critic's terminal value)."""
        u = seqs.to(state.device)
        v, _, _ = planner.rollout(view, state, u)
        d, _, _ = planner.rollout(NoTerminalView(view), state, u)
        return v.cpu().numpy(), d.cpu().numpy()

    @staticmethod
    def valued(view: Any, planner: Any, state: torch.Tensor, seqs: torch.Tensor) -> np.ndarray:
        """``[E, K]`` the best sequences minus the habit's, valued through ``view``'s imagination."""
        v, _, _ = planner.rollout(view, state, seqs.to(state.device))
        return (v[:, 1:] - v[:, :1]).cpu().numpy()

    @staticmethod
    def other_member(agent: Any, planner: Any, state: torch.Tensor, seqs: torch.Tensor) -> np.ndarray:
        """``[E, K]`` member ``k``'s sequences valued by member ``k + 1``'s model and critic: best minus habit."""
        E = state.shape[0]
        other = torch.roll(torch.arange(E), 1)  # row j holds member j - 1's state and sequences
        v, _, _ = planner.rollout(agent, state[other], seqs[other].to(state.device))
        v = v.cpu()[torch.argsort(other)]
        return (v[:, 1:] - v[:, :1]).numpy()

    def truth(self, agent: Any, seqs: torch.Tensor, gamma: float, state: torch.Tensor) -> tuple[np.ndarray, ...]:
        """``[E, K]`` the true gain of each best sequence over the habit's, the realized one-step estimate, and
        ``[E, 1 + K]`` each sequence's true value (the habit's first) and its distance part."""
        E, B, H = seqs.shape[:3]
        values, ends, alive = np.zeros((E, B)), np.zeros((E, B, state.shape[1])), np.zeros((E, B))
        firsts, first_alive, first_d = np.zeros((E, B, state.shape[1])), np.zeros((E, B)), np.zeros((E, B))
        for k, model in enumerate(self.models):
            if not self.running[k]:
                continue
            model.save()
            self.state_gap = max(self.state_gap, float(np.abs(true_state(model) - state[k].cpu().numpy()).max()))
            for b in range(B):
                values[k, b], ends[k, b], alive[k, b] = true_rollout(agent, model, seqs[k, b], gamma)
                v1, firsts[k, b], first_alive[k, b] = true_rollout(agent, model, seqs[k, b, :1], gamma)
                first_d[k, b] = -v1
        dev = state.device
        q_end = agent.value(torch.as_tensor(ends, dtype=torch.float32, device=dev)).cpu().numpy()
        q_first = agent.value(torch.as_tensor(firsts, dtype=torch.float32, device=dev)).cpu().numpy()
        q_now = agent.value(state[:, None]).cpu().numpy()
        total = values + gamma ** H * alive * q_end
        realized = -first_d + gamma * first_alive * q_first - q_now
        return total[:, 1:] - total[:, :1], realized[:, 1:], total, values


def run(run_dir: Path, targets_per_member: int, progress: bool = True) -> pd.DataFrame:
    """The rows of every decision of frozen episodes on the first ``targets_per_member`` grid targets."""
    rd = RunDir(run_dir)
    cfg = rd.train_config()
    spec = spec_for(cfg)
    env = eval_env(cfg, spec, None, False)
    loaded = load_run(rd.path, "cpu", env=env, spec=spec)
    ckpt = loaded.ckpt
    targets = [t[:targets_per_member] for t in evaluation_targets(spec, ckpt.member_lengths(), ckpt.member_targets())]
    env.set_link_lengths(ckpt.member_lengths())
    loop = episode_loop(loaded.agent, env, zone_radius=spec.zone_radius, adapt=False)
    loop.load_state_dict(ckpt.running_statistics() or {})
    rows: list[dict[str, Any]] = []
    measuring = Measuring(loop.arbitrator, loop, rows)
    loop = loop.with_arbitrator(measuring)
    measuring.loop = loop
    n = min(len(t) for t in targets)
    members = np.ones(env.E, dtype=bool)
    for i in progress_iter(range(n), n, "voc gain bias", "target", enabled=progress):
        env.set_target_override(np.stack([t[i] for t in targets]), members)
        measuring.target_index, measuring.running = i, members.copy()
        st = loop.begin(members)
        for _ in loop.steps(st, members, i, arbitration_episode=cfg.agent.planning_episodes):
            pass
    print(f"largest gap between an agent's state and the physics at a decision: {measuring.state_gap:.3g}",
          file=sys.stderr)
    return pd.DataFrame(rows)


def clustered_se(err: pd.Series, cluster: pd.Series) -> float:
    """The standard error of ``err``'s mean with the decisions of one episode (``cluster``) correlated: the
    cluster-robust (sandwich) estimate, ``sqrt(sum_c (sum_{i in c} (e_i - mean))^2) / n``."""
    centred = (err - err.mean()).groupby(cluster.to_numpy()).sum()
    return float(np.sqrt((centred ** 2).sum()) / len(err))


def spread(err: pd.Series, g: pd.DataFrame) -> dict[str, Any]:
    """The mean of ``err`` (one value per decision of ``g``) and its 95% intervals at three levels: 1.96 standard
    errors over the decisions (as the audit; a lower bound), over the episodes (cluster-robust: the decisions of
    one episode are correlated), and the report's Student-t over the seeds' means (:func:`seed_interval`; NaN
    with fewer than 3 seeds). ``seed_sd``, the spread of the seeds' means, against ``within_seed_se``, the root
    mean square of each seed's episode-clustered standard error: a spread well above it is an offset fixed per
    seed (its trained networks), which the decision and episode intervals do not see."""
    per_seed = err.groupby(g["seed"]).mean()
    lo, hi = seed_interval(per_seed.to_numpy())
    within = [clustered_se(e, g.loc[e.index, "target"]) for _, e in err.groupby(g["seed"])]
    return {"bias": err.mean(), "seed_mean": per_seed.mean(),
            "bias_half_width": 1.96 * err.std(ddof=1) / np.sqrt(len(g)),
            "bias_half_width_episodes": 1.96 * clustered_se(err, g["seed"] * 10**6 + g["target"]),
            "seed_lo": lo, "seed_hi": hi, "seeds": len(per_seed),
            "bias_per_seed": " ".join(f"{v:+.2f}" for v in per_seed),
            "seed_sd": per_seed.std(ddof=1), "within_seed_se": float(np.sqrt(np.mean(np.square(within))))}


def summary(df: pd.DataFrame) -> pd.DataFrame:
    """Per estimate and ``k``: decisions, mean truth, mean estimate, bias (mean estimate - truth) with its
    intervals over the decisions, the episodes and the seeds (:func:`spread`), the per-seed biases, and how often
    the truth and the estimate were negative."""
    out = []
    for name in ESTIMATES:
        for k, g in df.groupby("k"):
            g = g[np.isfinite(g[name])]
            if g.empty:
                continue
            err = g[name] - g["G"]
            out.append({"estimate": name, "k": k, "decisions": len(g), "mean_G": g["G"].mean(),
                        "mean_estimate": g[name].mean(), **spread(err, g),
                        "rmse": float(np.sqrt((err ** 2).mean())), "G_negative": (g["G"] < 0).mean(),
                        "estimate_negative": (g[name] < 0).mean()})
    return pd.DataFrame(out)


def part_errors(g: pd.DataFrame, name: str, side: str) -> dict[str, pd.Series]:
    """Per decision: how far ``name``'s value of one sequence (``side``: best or habit) lies from its truth, in
    all (``total``) and split into the distance part and the critic's terminal value (where the rows have them)."""
    out = {"total": g[f"{name}_{side}"] - g[f"true_{side}"]}
    if f"{name}_{side}_distance" in g and f"true_{side}_distance" in g:
        out["distance"] = g[f"{name}_{side}_distance"] - g[f"true_{side}_distance"]
        out["terminal"] = out["total"] - out["distance"]
    return out


def decomposition(df: pd.DataFrame) -> pd.DataFrame:
    """Per estimate valued by sequences (imagined, heldout) and ``k``: how far its value of the chosen sequence
    (``best``) and of the habit's (``habit``) lie from their truth, and their difference (``gain``: the estimate's
    bias), each in all and split into the distance part and the terminal value, with :func:`spread`'s
    intervals."""
    out = []
    for name in ("imagined", "heldout"):
        if f"{name}_best" not in df:
            continue
        for k, g in df.groupby("k"):
            g = g[np.isfinite(g[f"{name}_best"])]
            best, habit = part_errors(g, name, "best"), part_errors(g, name, "habit")
            for part in best:
                for side, err in (("best", best[part]), ("habit", habit[part]), ("gain", best[part] - habit[part])):
                    out.append({"estimate": name, "k": k, "side": side, "part": part, **spread(err, g)})
    return pd.DataFrame(out)


def combine(paths: Sequence[Path]) -> pd.DataFrame:
    """The rows of several measurements (``--out`` files of runs with disjoint seeds) as one."""
    frames = [pd.read_csv(p) for p in paths]
    seeds = [s for f in frames for s in f["seed"].unique()]
    if len(seeds) != len(set(seeds)):
        raise ValueError(f"the measurements share a seed ({sorted(seeds)}): combine runs of disjoint seeds")
    return pd.concat(frames, ignore_index=True)


def main(argv: Sequence[str] | None = None) -> pd.DataFrame:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path, nargs="?", help="a trained run of kind apac_voc (or any with the mpc planner)")
    p.add_argument("--targets", type=int, default=10, help="grid targets per member (default 10)")
    p.add_argument("--out", type=Path, default=Path("results/voc_gain/bias.csv"))
    p.add_argument("--combine", type=Path, nargs="+", metavar="CSV",
                   help="instead of measuring a run: summarize the rows of these measurements (runs of disjoint "
                        "seeds) as one, written to --out")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if (args.run is None) == (args.combine is None):
        p.error("give a run to measure or --combine CSV..., not both")
    torch.set_num_threads(1)
    df = combine(args.combine) if args.combine else run(args.run, args.targets, not args.no_progress)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    table = summary(df)
    table.to_csv(args.out.with_name(args.out.stem + "_summary.csv"), index=False)
    parts = decomposition(df)
    parts.to_csv(args.out.with_name(args.out.stem + "_decomposition.csv"), index=False)
    with pd.option_context("display.width", 250, "display.max_columns", 20):
        print(table.round(3).to_string(index=False))
        print(parts.round(3).to_string(index=False))
    return table


if __name__ == "__main__":
    main()
