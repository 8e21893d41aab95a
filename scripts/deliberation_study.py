"""The world that does not wait (issue 42 item 1): success and time-to-target, decisions' time included, of
habit-only, always-planning and arbitrating agents on ``changing_target_torque_no_wait``; the front they span.

Three steps (each resumable; runs under ``--out``, ignored by git; tables and the figure under ``--docs``)::

    python scripts/deliberation_study.py train --out results/deliberation --seeds 0,1,2 --episodes 100
    python scripts/deliberation_study.py test --out results/deliberation --docs docs/results/deliberation --limit 20
    python scripts/deliberation_study.py report --docs docs/results/deliberation

More seeds without retraining the first: ``train`` and ``test`` them under another ``--out`` and ``--docs``
(``--drop 'kind:variant,...'`` leaves variants out so both parts test the same rows), then ``combine --parts
first.csv,second.csv --docs DOCS`` writes one ``per_seed.csv`` (refused: a seed in two parts, or parts that
test different rows) for ``report``, which also writes ``paired.csv`` (per-seed differences, :data:`PAIRS`).

``test`` runs each trained run's frozen networks on the 100 angle-grid targets per seed (``--limit``: a spread of
fewer) in the world that does not wait (the trained one) and in one that waits (``time_scale`` 0, same deadline);
SPAC-MPC also at test-time budgets of 1 and 2 iterations, APAC-VOC's networks also as their habit alone and always
planning at 1 and K iterations (the compute front of one set of networks). A row per seed,
variant and world: ``per_seed.csv``. ``report`` writes ``summary.csv`` (means over seeds, 95% intervals by
:func:`apac_mj.report.stats.interval`) and ``front.png``.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

TASK = "changing_target_torque_no_wait"
KINDS = ("ddpg", "spac_mpc", "apac_mpc", "apac_voc")
#: The per-seed table's columns.
COLUMNS = ("kind", "variant", "world", "iterations", "seed", "episodes", "success", "time_to_target_ms",
           "episode_ms", "decision_ms_per_step", "plant_ms_per_step", "decision_ms_per_episode", "planned_share",
           "steps")


def train_all(out: Path, kinds: list[str], seeds: tuple[int, ...], episodes: int, babbling: int) -> None:
    """Train every kind on the no-wait task (3 seeds side by side, one process), resumable."""
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.run.trainer import train

    for kind in kinds:
        agent = AgentConfig(kind=kind, batch_size=64, replay_size=20000, babbling_episodes=babbling)
        cfg = TrainConfig(task=TASK, seeds=seeds, episodes=episodes, checkpoint_every=max(1, episodes // 4),
                          agent=agent)
        print(f"train {kind}: {len(seeds)} seeds x {episodes} episodes (+{babbling} babbling)", flush=True)
        train(cfg, out / kind, progress=True)


class _Priced:
    """Records each decision's priced time (ms, before ``time_scale``: what it computed, in either world)."""

    def __init__(self, E: int) -> None:
        from apac_mj.run import deliberation

        self.last, self.meter = np.zeros(E), deliberation.Meter
        self.original = self.meter.decision_ms

    def __enter__(self) -> "_Priced":
        from apac_mj.run import timing

        def decision_ms(meter: Any, planner: Any, choice: Any, action: Any) -> np.ndarray:
            self.last = np.array([timing.decision_ms(c, meter.timing) for c in meter.counts(planner, choice)])
            return self.original(meter, planner, choice, action)

        self.meter.decision_ms = decision_ms
        return self

    def __exit__(self, *exc: Any) -> None:
        self.meter.decision_ms = self.original


def _episodes(loop: Any, targets: list[np.ndarray], arbitration_episode: int) -> list[dict[str, Any]]:
    """Frozen episodes of ``loop`` to every member's ``targets``: one row per member and target."""
    from apac_mj.suite import deliberation as clock

    env, rows = loop.env, []
    interval = clock.interval_ms(env.spec)
    for i in range(min(len(t) for t in targets)):
        members = np.ones(env.E, dtype=bool)
        env.set_target_override(np.stack([t[i] for t in targets]), members)
        st = loop.begin(members)
        reached, steps = np.zeros(env.E, dtype=bool), np.zeros(env.E, dtype=np.int64)
        planned, priced_ms = np.zeros(env.E, dtype=np.int64), np.zeros(env.E)
        with _Priced(env.E) as priced:
            for info, stepped in loop.steps(st, members, i, arbitration_episode=arbitration_episode):
                reached |= stepped & info.reached
                steps += stepped
                planned += stepped & (info.plan_iterations > 0)
                priced_ms += np.where(stepped, priced.last, 0.0)  # finished members' rows are stale
        for k in range(env.E):
            end = clock.elapsed_ms(env.physics(k))
            rows.append({"seed": env.seeds[k], "success": bool(reached[k]), "episode_ms": end, "steps": int(steps[k]),
                         "waited_ms": end - steps[k] * interval, "decision_ms": float(priced_ms[k]),
                         "planned": int(planned[k])})
    return rows


def _per_seed(rows: list[dict[str, Any]], **labels: Any) -> list[dict[str, Any]]:
    """The episode rows of one variant as one row per seed."""
    df = pd.DataFrame(rows)
    out = []
    for seed, g in df.groupby("seed"):
        hit = g[g.success]
        out.append({**labels, "seed": int(seed), "episodes": len(g), "success": 100.0 * g.success.mean(),
                    "time_to_target_ms": float(hit.episode_ms.mean()) if len(hit) else float("nan"),
                    "episode_ms": float(g.episode_ms.mean()),
                    "decision_ms_per_step": float(g.decision_ms.sum() / g.steps.sum()),
                    "plant_ms_per_step": float(g.waited_ms.sum() / g.steps.sum()),
                    "decision_ms_per_episode": float(g.decision_ms.mean()),
                    "planned_share": float(g.planned.sum() / g.steps.sum()), "steps": float(g.steps.mean())})
    return out


def _variants(kind: str, K: int, drop: frozenset[tuple[str, str]] = frozenset()
              ) -> list[tuple[str, str | None, int | None, tuple[str, ...]]]:
    """(variant, arbitrator override, test-time iterations, worlds) to test a trained ``kind`` under: its own
    rule in both worlds; SPAC-MPC also at 1 and 2 iterations, APAC-VOC's networks also as their habit alone and
    always planning at 1 and K iterations, in the world that does not wait (the compute front). ``drop``: the
    (kind, variant) pairs left out."""
    both, no_wait = ("no_wait", "waits"), ("no_wait",)
    if kind == "ddpg":
        out = [("habit", None, None, both)]
    elif kind == "spac_mpc":
        out = [(f"plan k={k}", None, k, both if k == K else no_wait) for k in sorted({1, 2, K})]
    elif kind == "apac_voc":
        out = [("graded", None, None, both), ("habit", "AlwaysHabit", None, no_wait),
               *((f"plan k={k}", "AlwaysPlan", k, no_wait) for k in sorted({1, K}))]
    else:
        out = [("delta rule", None, None, both)]
    return [v for v in out if (kind, v[0]) not in drop]


def parse_drop(text: str) -> frozenset[tuple[str, str]]:
    """``"spac_mpc:plan k=2,apac_voc:plan k=1"`` as {(kind, variant)}; a part without a colon is refused."""
    pairs = [part.split(":", 1) for part in text.split(",") if part.strip()]
    if any(len(p) != 2 for p in pairs):
        raise ValueError(f"--drop wants kind:variant[,kind:variant...], got {text!r}")
    return frozenset((k.strip(), v.strip()) for k, v in pairs)


def test_run(run_path: Path, limit: int | None, worlds: dict[str, float],
             drop: frozenset[tuple[str, str]] = frozenset()) -> list[dict[str, Any]]:
    """Every variant of one trained run in every world (``name -> time_scale``): per-seed rows."""
    from apac_mj.agent import arbitration
    from apac_mj.run.build import episode_loop, load_run
    from apac_mj.run.evaluate import eval_env, evaluation_targets

    loaded = load_run(run_path)
    cfg, spec, agent, ckpt = loaded.cfg, loaded.spec, loaded.agent, loaded.ckpt
    lengths = ckpt.member_lengths()
    targets = [t if limit is None else t[np.unique(np.linspace(0, len(t) - 1, limit).round().astype(int))]
               for t in evaluation_targets(spec, lengths, ckpt.member_targets())]  # a spread of the grid
    K = cfg.agent.params["mpc"].iterations if "mpc" in cfg.agent.params else 0
    out = []
    for world, scale in worlds.items():
        world_spec = spec.replace(deliberation={"deadline_ms": spec.deliberation.deadline_ms, "time_scale": scale})
        for variant, rule, k, tested in _variants(cfg.agent.kind, K, drop):
            if world not in tested:
                continue
            env = eval_env(cfg, world_spec, lengths, occluded=False)
            arbitrator = None if rule is None else getattr(arbitration, rule)(cfg.agent)
            loop = episode_loop(agent, env, arbitrator=arbitrator, adapt=False)
            loop.load_state_dict(ckpt.running_statistics() if rule is None else {})
            if k is not None:
                loop.planner.max_iterations = k
            rows = _episodes(loop, targets, cfg.agent.planning_episodes)
            out += _per_seed(rows, kind=cfg.agent.kind, variant=variant, world=world,
                             iterations=k if k is not None else (K if cfg.agent.kind == "apac_voc" else 0))
            print(f"  {cfg.agent.kind} {variant} ({world}): {pd.DataFrame(rows).success.mean():.1%}", flush=True)
    return out


def test_all(out: Path, docs: Path, kinds: list[str], limit: int | None,
             drop: frozenset[tuple[str, str]] = frozenset()) -> None:
    rows = []
    docs.mkdir(parents=True, exist_ok=True)
    for kind in kinds:  # the table written after each kind: a cut-short test keeps what it finished
        rows += test_run(out / kind, limit, {"no_wait": 1.0, "waits": 0.0}, drop)
        pd.DataFrame(rows, columns=list(COLUMNS)).round(4).to_csv(docs / "per_seed.csv", index=False)


def combine(parts: list[pd.DataFrame]) -> pd.DataFrame:
    """Per-seed tables of disjoint seed sets as one (the first part's row order, seeds ascending within a
    variant). Refused: a seed in two parts, or parts that do not test the same (kind, variant, world) rows."""
    groups = [set(map(tuple, p[["kind", "variant", "world"]].drop_duplicates().to_numpy())) for p in parts]
    if any(g != groups[0] for g in groups):
        odd = sorted(set.union(*groups) - set.intersection(*groups))
        raise ValueError(f"the parts test different variants: {odd}")
    seen: set[int] = set()
    for p in parts:
        overlap = seen & set(p.seed.astype(int))
        if overlap:
            raise ValueError(f"seeds {sorted(overlap)} are in more than one part")
        seen |= set(p.seed.astype(int))
    df = pd.concat(parts, ignore_index=True)
    order = {g: i for i, g in enumerate(dict.fromkeys(map(tuple, parts[0][["kind", "variant", "world"]].to_numpy())))}
    key = df[["kind", "variant", "world"]].apply(lambda r: order[tuple(r)], axis=1)
    return df.assign(_k=key).sort_values(["_k", "seed"], kind="stable").drop(columns="_k").reset_index(drop=True)


#: The paired comparisons ``paired.csv`` reports: (name, a, b), each (kind, variant, world); a - b by seed.
PAIRS = (
    ("graded - own networks planning at k=4", ("apac_voc", "graded", "no_wait"), ("apac_voc", "plan k=4", "no_wait")),
    ("graded - own networks planning at k=1", ("apac_voc", "graded", "no_wait"), ("apac_voc", "plan k=1", "no_wait")),
    ("graded - own networks' habit alone", ("apac_voc", "graded", "no_wait"), ("apac_voc", "habit", "no_wait")),
    ("graded - SPAC-MPC k=1", ("apac_voc", "graded", "no_wait"), ("spac_mpc", "plan k=1", "no_wait")),
    ("graded - SPAC-MPC k=4", ("apac_voc", "graded", "no_wait"), ("spac_mpc", "plan k=4", "no_wait")),
    ("DDPG: waits - no wait", ("ddpg", "habit", "waits"), ("ddpg", "habit", "no_wait")),
    ("SPAC-MPC k=4: waits - no wait", ("spac_mpc", "plan k=4", "waits"), ("spac_mpc", "plan k=4", "no_wait")),
    ("APAC-MPC: waits - no wait", ("apac_mpc", "delta rule", "waits"), ("apac_mpc", "delta rule", "no_wait")),
    ("APAC-VOC graded: waits - no wait", ("apac_voc", "graded", "waits"), ("apac_voc", "graded", "no_wait")),
)


def paired(per_seed: pd.DataFrame, pairs: tuple = PAIRS,
           columns: tuple[str, ...] = ("success", "decision_ms_per_step")) -> pd.DataFrame:
    """Per-seed differences a - b (:func:`apac_mj.report.stats.paired_difference`: the report's t interval of the
    differences where both have the same seeds) and the ratio of the means; a pair with a missing side is skipped."""
    from apac_mj.report.stats import paired_difference

    rows = []
    for name, a, b in pairs:
        sides = [per_seed[(per_seed.kind == s[0]) & (per_seed.variant == s[1]) & (per_seed.world == s[2])]
                 .set_index("seed") for s in (a, b)]
        if any(s.empty for s in sides):
            continue
        for col in columns:
            diff, lo, hi, is_paired = paired_difference(sides[0][col], sides[1][col])
            wins = int((sides[0][col] > sides[1][col].reindex(sides[0].index)).sum())
            rows.append({"comparison": name, "metric": col, "seeds": len(sides[0]), "difference": diff, "lo": lo,
                         "hi": hi, "paired": is_paired, "a_higher_seeds": wins,
                         "ratio": sides[0][col].mean() / sides[1][col].mean()})
    return pd.DataFrame(rows).round(3)


def summarize(per_seed: pd.DataFrame) -> pd.DataFrame:
    """Means over seeds with 95% intervals (rates widened to the pooled Wilson interval)."""
    from apac_mj.report.stats import interval

    rows = []
    for (kind, variant, world), g in per_seed.groupby(["kind", "variant", "world"], sort=False):
        row: dict[str, Any] = {"kind": kind, "variant": variant, "world": world, "seeds": len(g)}
        n = g.episodes.to_numpy(float)
        for col in ("success", "time_to_target_ms", "episode_ms", "decision_ms_per_step", "plant_ms_per_step",
                    "planned_share", "steps"):
            k = g.success.to_numpy() / 100 * n if col == "success" else None
            mean, lo, hi = interval(g[col].to_numpy(float), k=k, n=n if col == "success" else None,
                                    bounds=(0.0, math.inf))  # times, shares and counts are >= 0
            row.update({col: mean, f"{col}_lo": lo, f"{col}_hi": hi})
        rows.append(row)
    return pd.DataFrame(rows).round(3)


def front(summary: pd.DataFrame, world: str = "no_wait") -> pd.DataFrame:
    """The compute front in ``world``: for every variant but the graded rule, sorted by decision time per step,
    the best success at that decision time or less (``front``), and whether the variant is on it."""
    s = summary[(summary.world == world) & (summary.variant != "graded")].sort_values("decision_ms_per_step")
    s = s.assign(front=s.success.cummax())
    return s.assign(on_front=s.success >= s.front)


def place(summary: pd.DataFrame, world: str = "no_wait") -> pd.DataFrame:
    """Where the graded rule sits: its success against the front's at its decision time (``front_success``: the
    best of the variants that compute at most as long per step) and against always planning at the full budget."""
    f, rows = front(summary, world), []
    for _, g in summary[(summary.world == world) & (summary.variant == "graded")].iterrows():
        cheaper = f[f.decision_ms_per_step <= g.decision_ms_per_step]
        best = cheaper.loc[cheaper.success.idxmax()] if len(cheaper) else None
        rows.append({"world": world, "graded_success": g.success, "graded_lo": g.success_lo, "graded_hi": g.success_hi,
                     "graded_ms_per_step": g.decision_ms_per_step,
                     "front_success": np.nan if best is None else best.success,
                     "front_variant": "" if best is None else f"{best.kind} {best.variant}",
                     "front_ms_per_step": np.nan if best is None else best.decision_ms_per_step})
    return pd.DataFrame(rows).round(3)


def figure(summary: pd.DataFrame, path: Path) -> None:
    """Success and time-to-target against decision time per step, in both worlds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for world, marker in (("no_wait", "o"), ("waits", "x")):
        s = summary[summary.world == world]
        for ax, col in zip(axes, ("success", "time_to_target_ms")):
            for (kind, variant), r in s.set_index(["kind", "variant"]).iterrows():
                err = [[r[col] - r[f"{col}_lo"]], [r[f"{col}_hi"] - r[col]]]
                ax.errorbar(r.decision_ms_per_step, r[col], yerr=err, fmt=marker, capsize=2,
                            color=_colour(kind), alpha=1.0 if world == "no_wait" else 0.45)
                if world == "no_wait":
                    ax.annotate(f"{kind} {variant}", (r.decision_ms_per_step, r[col]), fontsize=6)
    f = front(summary)
    axes[0].step(f.decision_ms_per_step, f.front, where="post", color="k", lw=0.8, label="front (not graded)")
    axes[0].legend(fontsize=7, loc="lower right")
    axes[0].set(xlabel="decision time per step (ms, priced counts)", ylabel="success (%)",
                title="o: the world does not wait; x: it waits")
    axes[1].set(xlabel="decision time per step (ms, priced counts)", ylabel="time to target (ms, successes)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _colour(kind: str) -> str:
    from apac_mj import kinds

    return kinds.get(kind).color


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("step", choices=("train", "test", "combine", "report"))
    ap.add_argument("--out", type=Path, default=Path("results/deliberation"))
    ap.add_argument("--docs", type=Path, default=Path("docs/results/deliberation"))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--babbling", type=int, default=30)
    ap.add_argument("--limit", type=int, default=None, help="targets per seed in the test (default: all 100)")
    ap.add_argument("--drop", default="", help="test: variants left out, 'kind:variant,...'")
    ap.add_argument("--parts", default="", help="combine: per-seed tables of disjoint seeds, comma-separated")
    a = ap.parse_args(argv)
    kinds = a.kinds.split(",")
    if a.step == "train":
        train_all(a.out, kinds, tuple(int(s) for s in a.seeds.split(",")), a.episodes, a.babbling)
    elif a.step == "test":
        test_all(a.out, a.docs, kinds, a.limit, parse_drop(a.drop))
    elif a.step == "combine":
        a.docs.mkdir(parents=True, exist_ok=True)
        combine([pd.read_csv(p) for p in a.parts.split(",")]).to_csv(a.docs / "per_seed.csv", index=False)
    else:
        summary = summarize(pd.read_csv(a.docs / "per_seed.csv"))
        summary.to_csv(a.docs / "summary.csv", index=False)
        figure(summary, a.docs / "front.png")
        placed = pd.concat([place(summary, w) for w in ("no_wait", "waits")])
        placed.to_csv(a.docs / "graded_on_front.csv", index=False)
        pairs = paired(pd.read_csv(a.docs / "per_seed.csv"))
        pairs.to_csv(a.docs / "paired.csv", index=False)
        print(summary.to_string(), placed.to_string(), pairs.to_string(), sep="\n\n", file=sys.stdout)


if __name__ == "__main__":
    main()
