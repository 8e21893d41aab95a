"""report.md: what the results are, the figures with their captions, the key numbers and differences.

Every number is printed from the tables (:mod:`apac_mj.report.quantities`) with two decimals, beside
its 95% interval, the samples it rests on (fewer than :data:`FEW_SAMPLES` marked ``*``), the per-seed
values (up to :data:`~apac_mj.report.figures.LIST_SEEDS` seeds) and what the paper states.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import pandas as pd

from apac_mj.report.figures import LIST_SEEDS, FigureSpec
from apac_mj.report.labels import AGENT_LABEL, agents, condition_label, condition_order, condition_short, episodes
from apac_mj.report.quantities import fmt
from apac_mj.report.stats import MIN_SEEDS, TOO_FEW

#: A mean resting on fewer samples than this is marked in report.md.
FEW_SAMPLES = 10


def report_md(title: str | None, manifest: dict, metrics: pd.DataFrame, table: pd.DataFrame, diffs: pd.DataFrame,
              figures: Sequence[tuple[FigureSpec, bool]]) -> str:
    """report.md's text; ``figures``: each registered figure and whether it was drawn (it applies)."""
    seeds = sorted(set(metrics["seed"]))
    return "\n".join(_header(title, manifest, metrics, seeds) + _figures(figures)
                     + _key_numbers(table, len(seeds) <= LIST_SEEDS) + _differences(diffs)) + "\n"


def _header(title: str | None, manifest: dict, metrics: pd.DataFrame, seeds: list[int]) -> list[str]:
    """Title, the preset's description, what the results hold and how to read the numbers."""
    preset = manifest.get("preset", {})
    n_episodes = int(metrics.loc[metrics["phase"] == "train", "episode"].max()) + 1
    lines = [f"# {title or 'APAC results: ' + str(preset.get('name', 'grid'))}", ""]
    if manifest.get("partial"):
        lines += [f"**{manifest['partial']}.**", ""]
    if preset.get("description"):
        lines += [preset["description"], ""]
    order = condition_order(metrics["condition"])
    conditions = "; ".join(f"{condition_short(c)} = {condition_label(c)}" for c in order)
    return lines + [
        f"Agents: {', '.join(AGENT_LABEL[a] for a in agents(metrics))}. Conditions: {conditions}. "
        f"{len(seeds)} seeds, {episodes(n_episodes)} of training per seed.", "",
        "Every number is computed per seed, then averaged over seeds. **Intervals** (95%): a Student-t "
        "interval over seeds at the 97.5% quantile, clipped to the quantity's range, whose coverage of a 95% "
        "was measured at >= 0.93 for 3, 5 and 10 seeds on values shaped like these (docs/statistics.md); "
        "for rates (%) widened to contain the Wilson score interval of the count pooled over seeds, so a "
        f"rate every seed hits still shows its sampling uncertainty. With fewer than {MIN_SEEDS} seeds no "
        f"interval is given ({TOO_FEW}): read the per-seed values. The figures' bands are percentile "
        "bootstraps, narrower than these at few seeds. **samples**: the episodes, targets or actions behind "
        f"a mean (`k of n` where only some count, e.g. steps of the reached targets); fewer than {FEW_SAMPLES} "
        "are marked with `*`. 'paper' quotes what Fard & Trappenberg state in their Results section.", ""]


def _figures(figures: Sequence[tuple[FigureSpec, bool]]) -> list[str]:
    lines = ["## Figures", ""]
    for f, drawn in figures:
        if drawn:
            lines += [f"![{f.caption}]({f.file})", "", f"*{f.caption}*", ""]
        else:
            lines += [f"*{f.caption.split(' (')[0]}: not drawn, these results have no data for it.*", ""]
    return lines


def _key_numbers(table: pd.DataFrame, show_seeds: bool) -> list[str]:
    head = "| figure | quantity | agent | condition | seeds | samples | mean | 95% CI |"
    head += " per seed |" if show_seeds else ""
    lines = ["## Key numbers", "", head + " paper |", "|---" * (head.count("|")) + "|"]
    for r in table.itertuples():
        cells = [r.figure, f"{r.description} ({r.unit})", AGENT_LABEL[r.agent], condition_short(r.condition),
                 r.n_seeds, _samples(r.samples, r.samples_of), fmt(r.mean), _ci(r.ci95_low, r.ci95_high, r.n_seeds)]
        cells += [r.per_seed] if show_seeds else []
        lines.append(table_row(cells + [r.paper or "-"]))
    return lines


def _differences(diffs: pd.DataFrame) -> list[str]:
    lines = ["", "## Key differences", ""]
    if diffs.empty:
        return lines + ["*No pair of cells to compare in these results.*"]
    lines += ["Per-seed values subtracted, seeds paired where both sides have the same seeds; 95% interval of "
              "the per-seed differences as above (Welch's t where the seeds differ), for rates widened to "
              "contain Newcombe's score interval of the pooled counts. An interval that excludes 0 is a "
              "difference these seeds resolve.",
              "", "| quantity | comparison | seeds | difference | 95% CI |", "|---|---|---|---|---|"]
    for r in diffs.itertuples():
        lines.append(table_row([f"{r.description} ({r.unit})", r.comparison, r.n_seeds, fmt(r.difference),
                                _ci(r.ci95_low, r.ci95_high, r.n_seeds)]))
    return lines


def table_row(cells: Sequence[object]) -> str:
    """One row of a Markdown table; a ``|`` inside a cell (``|estimate - truth|``) is escaped so it
    does not split the cell, a line break becomes a space."""
    return "| " + " | ".join(str(c).replace("\\", "\\\\").replace("|", "\\|").replace("\n", " ")
                             for c in cells) + " |"


def _ci(lo: float, hi: float, seeds: int) -> str:
    """An interval as the report prints it; with fewer than MIN_SEEDS seeds, :data:`TOO_FEW`."""
    if math.isnan(lo):
        return TOO_FEW if 1 < seeds < MIN_SEEDS else "-"
    return f"[{fmt(lo)}, {fmt(hi)}]"


def _samples(n: float, of: float | None) -> str:
    mark = "*" if n < FEW_SAMPLES else ""
    if of is None or (isinstance(of, float) and math.isnan(of)):
        return f"{int(n)}{mark}"
    return f"{int(n)}{mark} of {int(of)}"
