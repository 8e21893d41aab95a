"""The adaptation study's report (:mod:`apac_mj.experiments.adaptation`): per kind, the signatures with 95%
intervals over seeds, the two-state model fitted to each seed's channel trials, which controller acted, and the
figures a motor-control reader expects (learning curves of the lateral error, channel adaptation with the
two-state fit, after-effects), with MotorNet's curves beside the agents' where its trials table is given
(``bench/motornet_adaptation.py``).

Writes ``OUT/trials.csv`` (every kind's per-trial table), ``signatures.csv`` (per seed), ``summary.csv`` (mean and
interval per kind and signature), ``two_state.csv`` (per seed fits) and ``two_state_summary.csv``, the figures
``learning.png``, ``channel.png``, ``after_effects.png`` and ``report.md``.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from apac_mj.experiments import adaptation as study_mod
from apac_mj.report import two_state
from apac_mj.report.stats import TOO_FEW, seed_interval

#: The name MotorNet's rows carry in the tables.
MOTORNET = "motornet"
#: Trials in the running mean of the learning curves (field and null trials; catch trials drawn one by one).
SMOOTH = 5
#: What each kind's habit share means (the controllers of the kinds of the published study).
#: The published lesioned runs (:data:`apac_mj.experiments.adaptation.LESIONS` of the study's arbitrated kind).
HABIT_FROZEN, MODEL_FROZEN = (study_mod.lesion_label(study_mod.LESIONED_KIND, x) for x in study_mod.LESIONS)
CONTROLLERS = {**dict(zip(study_mod.STUDY_KINDS, ("habit only", "internal model only", "both, arbitrated"))),
               MOTORNET: "one network", HABIT_FROZEN: "both act; only the internal model learns",
               MODEL_FROZEN: "both act; only the habit learns"}


def load_study(study: str | Path, motornet: str | Path | None = None) -> pd.DataFrame:
    """Every kind's per-trial table (a ``kind`` column), read from ``STUDY/runs/<kind>/metrics.parquet``, plus
    MotorNet's ``trials.csv`` if given. A study without runs is refused."""
    from apac_mj.run.run_dir import RunDir
    from apac_mj.util.files import read_json

    study = Path(study)
    record = read_json(study / study_mod.PROTOCOL_FILE, fix="rerun apac-mj adaptation run")
    if record is None:
        raise FileNotFoundError(f"{study}: no {study_mod.PROTOCOL_FILE} (run apac-mj adaptation run --out {study})")
    b = next(blk["field_b"] for blk in record["task_spec"]["trials"]["blocks"] if blk["name"] == "adaptation")
    frames = []
    lesions = [study_mod.lesion_label(record.get("lesioned_kind", study_mod.LESIONED_KIND), x)
               for x in record.get("lesions", [])]
    for kind in [*record["agents"], *lesions]:
        rd = RunDir(study_mod.run_path(study, kind))
        if not rd.has_metrics():
            continue
        frames.append(study_mod.trial_table(rd.metrics(), b).assign(kind=kind))
    if motornet is not None:
        frames.append(check_trials(pd.read_csv(motornet), str(motornet)).assign(kind=MOTORNET))
    if not frames:
        raise FileNotFoundError(f"{study}: no run has metrics yet (run apac-mj adaptation run --out {study})")
    return pd.concat(frames, ignore_index=True)


def check_trials(df: pd.DataFrame, source: str) -> pd.DataFrame:
    """``df`` has every per-trial column and known block names; else ValueError naming the file. A table from
    before centre-out targets (no ``direction``) reads as targets anywhere (-1)."""
    if "direction" not in df.columns:
        df = df.assign(direction=-1)
    missing = sorted(set(study_mod.TRIAL_COLUMNS) - set(df.columns))
    if missing:
        raise ValueError(f"{source}: lacks the per-trial columns {missing}")
    unknown = sorted(set(df["block"]) - set(study_mod.BLOCKS) - {"training"})
    if unknown:
        raise ValueError(f"{source}: unknown blocks {unknown}")
    return df.astype({"channel": bool, "catch": bool})


def summarize(per_seed: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """Mean and 95% interval over seeds (:func:`seed_interval`) of each column, per kind (a habit share's clipped
    to [0, 1])."""
    rows = []
    for kind, g in per_seed.groupby("kind", sort=False):
        for col in columns:
            v = g[col].to_numpy(float)
            v = v[np.isfinite(v)]
            lo, hi = seed_interval(v, (0.0, 1.0) if col.startswith("habit_") else None) if v.size else (math.nan,
                                                                                                         math.nan)
            rows.append({"kind": kind, "quantity": col, "mean": float(v.mean()) if v.size else math.nan,
                         "lo": lo, "hi": hi, "seeds": int(v.size)})
    return pd.DataFrame(rows)


def fits(trials: pd.DataFrame) -> pd.DataFrame:
    """The two-state model fitted to each kind's and seed's channel trials from the baseline on (per seed)."""
    out = []
    for kind, g in trials[trials["block"] != "training"].groupby("kind", sort=False):
        out.append(two_state.fit_seeds(g).assign(kind=kind))
    return pd.concat(out, ignore_index=True)


def verdict(row: pd.Series, positive: bool) -> str:
    """Whether the interval shows the signature's sign: "yes", "no" (the interval excludes it) or "unclear"."""
    if math.isnan(row["mean"]):
        return "no data"
    if math.isnan(row["lo"]):
        return TOO_FEW
    if (row["lo"] > 0) if positive else (row["hi"] < 0):
        return "yes"
    return "no" if ((row["hi"] < 0) if positive else (row["lo"] > 0)) else "unclear (interval spans 0)"


#: Which learner each lesioned run keeps learning: the run whose learner shows a signature carries it.
LEARNS = {HABIT_FROZEN: "internal model", MODEL_FROZEN: "habit"}
#: Which learner each lesioned run froze: the intact run minus it is what that learner's learning adds.
FROZEN = {HABIT_FROZEN: "habit", MODEL_FROZEN: "internal model"}


def carriers(summary: pd.DataFrame) -> pd.DataFrame:
    """Which controller carries each signature, from the lesioned runs (:data:`LEARNS`): "habit" where the run in
    which only the habit learns shows it (its interval on the human side of 0) and the run in which only the
    internal model learns does not; "internal model" the reverse; "both" where both show it. Where neither shows
    it but a run's interval lies on the other side of 0, that learner carries the opposite of the human signature
    ("habit, opposite the human sign"); else "neither". One row per signature: each run's verdict
    (:func:`verdict`) and the carrier; empty without the two lesioned runs."""
    s = summary.set_index(["kind", "quantity"])
    runs = [k for k in LEARNS if (k, "field_push") in s.index]
    if len(runs) < 2:
        return pd.DataFrame(columns=["signature", *LEARNS, "carried_by"])
    rows = []
    for name in study_mod.SIGNATURES:
        says = {k: verdict(s.loc[(k, name)], name != "after_effect") for k in runs}
        rows.append({"signature": name, **says, "carried_by": _carrier(says)})
    return pd.DataFrame(rows)


def _carrier(says: dict[str, str]) -> str:
    """The learner(s) whose lesioned run shows the signature ("yes"), else shows its opposite ("no"), else
    "neither"."""
    for word, suffix in (("yes", ""), ("no", ", opposite the human sign")):
        shown = [LEARNS[k] for k, v in says.items() if v == word]
        if shown:
            return ("both" if len(shown) == 2 else shown[0]) + suffix
    return "neither"


def load_studies(studies: list[str | Path], motornet: str | Path | None = None) -> pd.DataFrame:
    """Several studies of one protocol run over disjoint seeds (``--set seeds=10-19``) as one per-trial table:
    their protocol.json must agree but for the seeds, and no kind may hold a seed twice; else ValueError naming
    the study and what differs."""
    from apac_mj.util.files import read_json

    records = [read_json(Path(s) / study_mod.PROTOCOL_FILE, fix="rerun apac-mj adaptation run") for s in studies]
    first = _without_seeds(records[0])
    for s, r in zip(studies[1:], records[1:]):
        if r is None or _without_seeds(r) != first:
            raise ValueError(f"{s} holds another protocol than {studies[0]} (settings other than the seeds "
                             "differ): only parts of one protocol over disjoint seeds are reported as one")
    table = pd.concat([load_study(s) for s in studies], ignore_index=True)
    twice = table.groupby(["kind", "seed"])["trial"].apply(lambda t: t.duplicated().any())
    if twice.any():
        kind, seed = twice[twice].index[0]
        raise ValueError(f"seed {seed} of {kind!r} is in more than one of the studies {', '.join(map(str, studies))}")
    if motornet is not None:
        table = pd.concat([table, check_trials(pd.read_csv(motornet), str(motornet)).assign(kind=MOTORNET)],
                          ignore_index=True)
    return table


def _without_seeds(record: dict | None) -> dict | None:
    if record is None:
        return None
    return {**record, "run": {k: v for k, v in record.get("run", {}).items() if k != "seeds"}}


def lesion_effects(per_seed: pd.DataFrame, intact: str = study_mod.LESIONED_KIND) -> pd.DataFrame:
    """What each learner's learning adds to each signature: per seed, the intact run's signature minus the run's
    in which that learner was frozen (:data:`FROZEN`; the two runs are the same until the adaptation block, so the
    difference is paired), mean and 95% interval over seeds (:func:`seed_interval`), and its verdict on the human
    sign ("yes": the learning moves the signature towards the human sign; "no": away from it). Empty without the
    runs."""
    rows = []
    base = per_seed[per_seed["kind"] == intact].set_index("seed")
    for kind, learner in FROZEN.items():
        lesioned = per_seed[per_seed["kind"] == kind].set_index("seed")
        seeds = base.index.intersection(lesioned.index)
        if not len(seeds):
            continue
        for name in study_mod.SIGNATURES:
            d = (base.loc[seeds, name] - lesioned.loc[seeds, name]).to_numpy(float)
            d = d[np.isfinite(d)]
            lo, hi = seed_interval(d) if d.size else (math.nan, math.nan)
            row = {"learner": learner, "signature": name, "mean": float(d.mean()) if d.size else math.nan,
                   "lo": lo, "hi": hi, "seeds": int(d.size)}
            rows.append({**row, "verdict": verdict(pd.Series(row), name != "after_effect")})
    return pd.DataFrame(rows, columns=["learner", "signature", "mean", "lo", "hi", "seeds", "verdict"])


def write_report(study: str | Path | list[str | Path], out: str | Path | None = None,
                 motornet: str | Path | None = None) -> Path:
    """Tables, figures and report.md into ``out`` (default ``STUDY/report``, the first study's); returns ``out``.
    ``study`` may be a list: one protocol's parts over disjoint seeds (:func:`load_studies`)."""
    studies = list(study) if isinstance(study, (list, tuple)) else [study]
    out = Path(out) if out is not None else Path(studies[0]) / "report"
    trials = load_studies(studies, motornet) if len(studies) > 1 else load_study(studies[0], motornet)
    return write_tables(trials, out)


def write_tables(trials: pd.DataFrame, out: Path) -> Path:
    """The report of per-trial tables with a ``kind`` column (:func:`load_study`) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    per_seed = pd.concat([study_mod.signatures(g).assign(kind=k) for k, g in trials.groupby("kind", sort=False)])
    habit = [f"habit_{b}" for b in study_mod.BLOCKS]
    summary = summarize(per_seed, [*study_mod.SIGNATURES, *habit])
    corrected = pd.concat([study_mod.baseline_corrected(g) for _, g in trials.groupby(["kind", "seed"], sort=False)])
    fitted = fits(corrected)  # the two-state model's x starts at 0: each direction's baseline taken off
    fit_summary = pd.concat([two_state.summarize(g).assign(kind=k) for k, g in fitted.groupby("kind", sort=False)])
    trials.to_csv(out / "trials.csv", index=False)
    per_seed.to_csv(out / "signatures.csv", index=False)
    summary.to_csv(out / "summary.csv", index=False)
    fitted.to_csv(out / "two_state.csv", index=False)
    fit_summary.to_csv(out / "two_state_summary.csv", index=False)
    carriers(summary).to_csv(out / "carriers.csv", index=False)
    effects = lesion_effects(per_seed)
    effects.to_csv(out / "lesion_effects.csv", index=False)
    _figures(corrected, fitted, per_seed, out)
    (out / "report.md").write_text(_markdown(summary, fit_summary, trials, effects))
    return out


def _curve(trials: pd.DataFrame, column: str) -> pd.DataFrame:
    """Mean over seeds per kind and trial of ``column`` (rows where it is finite)."""
    t = trials[np.isfinite(trials[column].to_numpy(float))]
    mean = t.groupby(["kind", "trial"], sort=False)[column].mean().reset_index()
    return mean.sort_values("trial", kind="stable")


def _figures(trials: pd.DataFrame, fitted: pd.DataFrame, per_seed: pd.DataFrame, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from apac_mj.report.labels import kind_colors

    palette = kind_colors()
    spare = iter(("tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:olive"))
    color = {k: palette.get(k) or ("black" if k == MOTORNET else next(spare, "grey")) for k in trials["kind"].unique()}
    shown = trials[trials["block"] != "training"]
    fig, ax = plt.subplots(figsize=(9, 4))
    for kind, g in _curve(shown[~shown["catch"]], "lateral_error").groupby("kind", sort=False):
        smooth = g["lateral_error"].rolling(SMOOTH, center=True, min_periods=1).mean()
        ax.plot(g["trial"], smooth, color=color[kind], lw=1, label=kind)
    for kind, g in _curve(shown[shown["catch"]], "lateral_error").groupby("kind", sort=False):
        ax.plot(g["trial"], g["lateral_error"], "v", color=color[kind], ms=4)
    _blocks(ax, shown)
    ax.set(xlabel="trial (training episode)", ylabel="lateral error - baseline (cm; + with field)",
           title=f"Learning curves (mean over seeds, running mean of {SMOOTH} trials; triangles: catch trials)")
    ax.axhline(0, color="grey", lw=0.5)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "learning.png", dpi=110)
    plt.close(fig)
    _channel_figure(shown, fitted, color, out, plt)
    _after_effect_figure(per_seed, color, out, plt)


def _blocks(ax, trials: pd.DataFrame) -> None:
    """Shade the blocks and name them."""
    first = trials.groupby("block", sort=False)["trial"].agg(["min", "max"])
    for i, (name, r) in enumerate(first.iterrows()):
        if i % 2:
            ax.axvspan(r["min"] - 0.5, r["max"] + 0.5, color="0.93", zorder=0)
        ax.text((r["min"] + r["max"]) / 2, 0.98, name, transform=ax.get_xaxis_transform(), ha="center", va="top",
                fontsize=7)


def _channel_figure(trials: pd.DataFrame, fitted: pd.DataFrame, color: dict, out: Path, plt) -> None:
    """Adaptation on channel trials (mean over seeds) and the two-state fit (mean of the per-seed predictions)."""
    fig, ax = plt.subplots(figsize=(9, 4))
    for kind, g in _curve(trials, "adaptation").groupby("kind", sort=False):
        ax.plot(g["trial"], g["adaptation"], "o", ms=3, color=color[kind], label=f"{kind} channel trials")
    for kind, f in fitted.groupby("kind", sort=False):
        sims = []
        for _, row in f.iterrows():
            s = trials[(trials["kind"] == kind) & (trials["seed"] == row["seed"])].sort_values("trial")
            p = two_state.TwoState(*(row[n] for n in two_state.PARAMETERS))
            sims.append(two_state.simulate(p, s["field"], s["channel"].to_numpy(bool))["x"].to_numpy())
            trial = s["trial"].to_numpy()
        ax.plot(trial, np.mean(sims, axis=0), color=color[kind], lw=1.2, label=f"{kind} two-state fit")
    _blocks(ax, trials)
    ax.axhline(0, color="grey", lw=0.5)
    ax.set(xlabel="trial", ylabel="adaptation (learned force / field force)",
           title="Channel trials and the two-state model (mean over seeds)")
    ax.legend(fontsize=7, ncol=2, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "channel.png", dpi=110)
    plt.close(fig)


def _after_effect_figure(per_seed: pd.DataFrame, color: dict, out: Path, plt) -> None:
    """Per-seed after-effects (catch-trial lateral error minus baseline) per kind, with the mean."""
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for i, (kind, g) in enumerate(per_seed.groupby("kind", sort=False)):
        v = g["after_effect"].to_numpy(float)
        ax.plot(np.full(v.size, i), v, "o", color=color[kind], alpha=0.6)
        ax.plot([i - 0.25, i + 0.25], [np.nanmean(v)] * 2, color=color[kind], lw=2)
    kinds_ = list(per_seed.groupby("kind", sort=False).groups)
    ax.set_xticks(range(len(kinds_)), kinds_)
    ax.axhline(0, color="grey", lw=0.5)
    ax.set(ylabel="catch-trial lateral error - baseline (cm)", title="After-effects (< 0: opposite the field)")
    fig.tight_layout()
    fig.savefig(out / "after_effects.png", dpi=110)
    plt.close(fig)


def _fmt(row: pd.Series) -> str:
    if math.isnan(row["mean"]):
        return "-"
    ci = TOO_FEW if math.isnan(row["lo"]) else f"[{row['lo']:.3g}, {row['hi']:.3g}]"
    return f"{row['mean']:.3g} {ci}"


def _markdown(summary: pd.DataFrame, fit_summary: pd.DataFrame, trials: pd.DataFrame,
              effects: pd.DataFrame | None = None) -> str:
    """report.md: per kind, each signature with its interval and verdict, the fits and the habit's shares."""
    lines = ["# Adaptation study", "", "Mean over seeds [95% interval, Student-t over seeds (97.5% quantile)].", "",
             "| kind (controllers) | seeds | " + " | ".join(study_mod.SIGNATURES) + " |",
             "|---|---|" + "---|" * len(study_mod.SIGNATURES)]
    s = summary.set_index(["kind", "quantity"])
    for kind in summary["kind"].unique():
        cells = []
        for name in study_mod.SIGNATURES:
            row = s.loc[(kind, name)]
            positive = name != "after_effect"
            cells.append(f"{_fmt(row)}: {verdict(row, positive)}")
        seeds = int(s.loc[(kind, "after_effect"), "seeds"])
        lines.append(f"| {kind} ({CONTROLLERS.get(kind, '')}) | {seeds} | " + " | ".join(cells) + " |")
    lines += ["", "Signs: " + "; ".join(f"{k}: {v}" for k, v in study_mod.SIGNATURES.items()) + ".", "",
              "## Who acted: the habit's share of the actions per block", "",
              "| kind | " + " | ".join(study_mod.BLOCKS) + " |", "|---|" + "---|" * len(study_mod.BLOCKS)]
    for kind in summary["kind"].unique():
        lines.append(f"| {kind} | " + " | ".join(_fmt(s.loc[(kind, f'habit_{b}')]) for b in study_mod.BLOCKS) + " |")
    carried = carriers(summary)
    if len(carried):
        lines += ["", "## Which controller carries it: the lesioned runs", "",
                  "| signature | only the internal model learns | only the habit learns | carried by |",
                  "|---|---|---|---|"]
        lines += [f"| {r['signature']} | {' | '.join(r[k] for k in LEARNS)} | {r['carried_by']} |"
                  for _, r in carried.iterrows()]
    if effects is not None and len(effects):
        lines += ["", "## What each learner's learning adds: intact APAC minus the lesioned run, paired by seed", "",
                  "| signature | " + " | ".join(f"{x}'s learning" for x in effects["learner"].unique()) + " |",
                  "|---|" + "---|" * effects["learner"].nunique()]
        e = effects.set_index(["learner", "signature"])
        for name in study_mod.SIGNATURES:
            cells = [f"{_fmt(e.loc[(x, name)])}: {e.loc[(x, name), 'verdict']}" for x in effects["learner"].unique()]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Two-state model fitted to the channel trials (per seed, then over seeds)", "",
              "| kind | " + " | ".join(two_state.PARAMETERS) + " |", "|---|" + "---|" * 4]
    f = fit_summary.set_index(["kind", "parameter"])
    for kind in fit_summary["kind"].unique():
        lines.append(f"| {kind} | " + " | ".join(_fmt(f.loc[(kind, p)]) for p in two_state.PARAMETERS) + " |")
    lines += ["", f"Smith et al. 2006's simulation values: {two_state.SMITH_2006}.", ""]
    return "\n".join(lines)
