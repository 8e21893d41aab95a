"""The paper's results section from a grid's results directory: Figs. 3-9 and a key-number table.

Every number is computed per seed first, then summarized over seeds as the mean with a 95% interval that
respects the quantity's range: a percentile bootstrap over seeds, and for rates that interval widened to
contain the Wilson score interval of the pooled count, so that a rate every seed hits (100 of 100) still
shows its sampling uncertainty. The same intervals are drawn in the figures. Beside every mean the table
gives the per-seed values and the count of samples (episodes, targets, actions) it rests on, and
intervals of the key comparisons (APAC vs SPAC success, APAC's habit share across conditions).
``key_numbers.csv`` and ``differences.csv`` hold them all and ``report.md`` shows them beside the values
the paper states.

The pipeline, one module per stage: :mod:`~apac_mj.report.stats` (intervals),
:mod:`~apac_mj.report.quantities` (per-seed values, key numbers, differences),
:mod:`~apac_mj.report.figures` (the figure registry and the paper's figures in it),
:mod:`~apac_mj.report.markdown` (report.md); :mod:`~apac_mj.report.labels` says how agents and
conditions are called and coloured (the kind registry, the task files' ``[report]`` tables). A figure of
your own is one :func:`register_figure` call (docs/extending.md).
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

from apac_mj.experiments.results import MANIFEST, Results, completeness, load_results, load_tests, result_roots
from apac_mj.report.figures import (DEFAULT_DPI, FigureSpec, ReportData, check_format, draw_figures, register_figure,
                                    registered_figures, unregister_figure)
from apac_mj.report.labels import (AGENT_COLOR, AGENT_LABEL, check_kinds, condition_colors, condition_label,
                                   condition_short)
from apac_mj.report.markdown import report_md
from apac_mj.report.quantities import QUANTITIES, differences, key_numbers, per_seed
from apac_mj.util.files import read_json


def write_report(results: Results, out: str | Path | None = None, title: str | None = None,
                 draw: bool = True, fmt: str = "png", dpi: int = DEFAULT_DPI) -> Path:
    """Write every registered figure that applies (``draw=False``: none, the tables only; as ``fmt`` at ``dpi``),
    key_numbers.csv, differences.csv and report.md into ``out`` (default: ``results/report``); returns the
    directory. ``results``: one grid's results directory, or several read as one (e.g. cells of one preset run
    as separate grids; each cell in only one of them, and ``out`` is then required). Damaged tables are refused
    (:class:`~apac_mj.experiments.results.ResultsError`); a grid not complete is reported with a "partial"
    notice at the top of report.md (:func:`~apac_mj.experiments.results.completeness`)."""
    roots = result_roots(results)
    if len(roots) > 1 and out is None:
        raise ValueError("several results directories need --out (the report's directory)")
    check_format(fmt, dpi)
    metrics, tests = load_results(roots), load_tests(roots)
    check_kinds(metrics)  # before anything is written
    out = Path(out) if out else roots[0] / "report"
    out.mkdir(parents=True, exist_ok=True)
    seed_values = per_seed(metrics, tests)
    table, diffs = key_numbers(seed_values), differences(seed_values)
    table.to_csv(out / "key_numbers.csv", index=False)
    diffs.to_csv(out / "differences.csv", index=False)
    data = ReportData(roots[0], metrics, tests, seed_values, table)
    if draw:
        matplotlib.use("Agg")  # the figures are files: no window, whatever the display
    figures = draw_figures(data, out, fmt, dpi, draw=draw)
    manifest = {**_manifest(roots), "partial": completeness(roots).notice()}
    (out / "report.md").write_text(report_md(title, manifest, metrics, table, diffs, figures))
    return out


def _manifest(roots: list[Path]) -> dict:
    """The grid manifest of one results directory; for several, one whose preset name and description list
    each directory's."""
    manifests = [read_json(r / MANIFEST) or {} for r in roots]
    if len(manifests) == 1:
        return manifests[0]
    presets = [m.get("preset", {}) for m in manifests]
    names = list(dict.fromkeys(str(p.get("name", "grid")) for p in presets))
    by_description: dict[str, list[str]] = {}
    for root, preset in zip(roots, presets):
        by_description.setdefault(str(preset.get("description", "")), []).append(f"`{root.name}`")
    described = [", ".join(dirs) + (f": {d}" if d else "") for d, dirs in by_description.items()]
    return {"preset": {"name": " + ".join(names),
                       "description": f"Read from {len(roots)} results directories, " + "; ".join(described)}}


__all__ = ["write_report", "ReportData", "FigureSpec", "register_figure", "unregister_figure", "AGENT_LABEL",
           "AGENT_COLOR", "condition_label", "condition_short", "condition_colors", "QUANTITIES"]
