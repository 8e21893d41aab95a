"""``apac-mj zoo``: the zoo's cells listed, a finished run exported as a cell, a cell's published numbers re-scored.

A cell (:mod:`apac_mj.run.zoo`, docs/zoo.md) ships a finished run's networks as safetensors with a manifest and an
environment contract. Its published numbers are the frozen tests' key numbers of the shipped weights (each with
the report's interval over seeds, :func:`apac_mj.report.stats.interval`) and the training's late numbers of the
run it came from; ``rescore`` runs the frozen tests again from the shipped weights and prints each published number
beside the re-scored one.
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
from pathlib import Path
from typing import Any

EPILOG = """\
examples:
  apac-mj zoo list
  apac-mj zoo export results/zoo_train/apac --out zoo/apac_changing_target
  apac-mj zoo rescore zoo:apac_changing_target
  apac-mj record --run zoo:apac_changing_target --episodes 5 --out apac.rrd   # then: rerun apac.rrd
  apac-mj evaluate zoo:apac_changing_target
  apac-mj forced-response test zoo:NAME --out fr.parquet                     # a cell of a cued task

evaluate, record and forced-response test accept a cell (zoo:NAME or its directory) wherever they accept a run:
the cell is checked (the environment contract part by part: a changed part is a warning naming it; every
network tensor's shape and dtype: a refusal where they cannot fit) and written once as a run directory under
the cache ($APAC_MJ_ZOO_CACHE, else ~/.cache/apac_mj/zoo). docs/zoo.md says how a study ships its networks."""
#: The frozen-test protocols a cell is scored on (DDPG: occluded not applicable, said so in the summary).
PROTOCOLS = ("grid", "occluded")
#: The training quantities a cell's manifest records from its run (not re-scorable from the weights).
TRAINING = ("train_success_late", "habit_fraction_late", "habit_crossing_episode", "steps_late", "time_late")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("zoo", help="trained networks that ship: list, export a finished run, re-score a cell",
                       description="Trained networks that ship (docs/zoo.md): the zoo's cells listed, a finished run "
                                   "exported as a cell with its numbers, a cell's published numbers re-scored from "
                                   "its weights.", epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    actions = p.add_subparsers(dest="zoo_command", metavar="ACTION", required=True)
    a = actions.add_parser("list", help="the cells in zoo/: kind, task, seeds, episodes, size, test success")
    a.add_argument("--root", type=Path, default=None, help="a folder of cells (default: the checkout's zoo/)")
    a.set_defaults(func=run_list)
    e = actions.add_parser("export", help="ship a finished run's networks as a cell, with its numbers")
    e.add_argument("run_dir", help="a finished run directory (apac-mj train ... --out RUN_DIR)")
    e.add_argument("--out", type=Path, required=True, help="the cell directory to write, e.g. zoo/apac_changing_target")
    e.add_argument("--dtype", choices=("fp16", "fp32"), default="fp16",
                   help="the networks' precision on disk (default fp16, as the zoo ships: half the size; loaded into "
                        "fp32 networks, the shipped cells kept their test success and moved other test numbers by "
                        "under 1%%, docs/zoo.md; fp32: the re-scored numbers are the run's to the bit)")
    e.add_argument("--regression-targets", type=int, default=3, metavar="N",
                   help="grid targets per seed whose episodes the manifest stores for the CI regression test "
                        "(default 3)")
    e.set_defaults(func=run_export)
    r = actions.add_parser("rescore", help="the frozen tests again from a cell's weights, beside its published numbers")
    r.add_argument("cell", help="zoo:NAME or a cell directory")
    r.add_argument("--json", action="store_true", help="print the comparison as JSON")
    r.set_defaults(func=run_rescore)


# -- numbers ---------------------------------------------------------------------------------------------
def tagged(df: Any, kind: str, task: str, **extra: str) -> Any:
    """A run's table tagged as a report's cell (agent, condition, region "all")."""
    df = df.copy()
    for i, (k, v) in enumerate({"agent": kind, "condition": task, "region": "all", **extra}.items()):
        df.insert(i, k, v)
    return df


def numbers(run_dir: str | Path, kind: str, task: str, training: bool = False) -> dict[str, dict[str, Any]]:
    """The key numbers of a run's frozen tests (``training``: of its metrics.parquet's late training instead), each
    with the report's interval and its exact per-seed values: ``{quantity: {mean, ci95_low, ci95_high, ...}}``."""
    import pandas as pd

    from apac_mj.report.quantities import key_numbers, per_seed
    from apac_mj.run.run_dir import METRIC_COLUMNS, RunDir

    run = RunDir(run_dir)
    empty = pd.DataFrame(columns=["agent", "condition", "region", *METRIC_COLUMNS])
    metrics = tagged(run.metrics(), kind, task) if training else empty
    tests = pd.concat([tagged(pd.read_parquet(f), kind, task, protocol=f.stem) for f in run.eval_paths()]
                      or [pd.DataFrame(columns=["protocol"])], ignore_index=True) if not training else \
        pd.DataFrame(columns=["protocol"])
    values = per_seed(metrics, tests)
    if training:
        values = values[values["quantity"].isin(TRAINING)]
    out = {}
    for row in key_numbers(values).to_dict("records"):
        seeds = values[values["quantity"] == row["quantity"]].sort_values("seed")
        out[row["quantity"]] = {"description": row["description"], "unit": row["unit"], "mean": row["mean"],
                                "ci95_low": row["ci95_low"], "ci95_high": row["ci95_high"],
                                "interval": row["interval"], "n_seeds": row["n_seeds"], "samples": row["samples"],
                                "per_seed": {str(int(s)): float(v) for s, v in zip(seeds["seed"], seeds["value"])}}
    return out


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


def compare(published: dict[str, dict[str, Any]], now: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Each published number beside the re-scored one: identical (mean and every seed, to the bit) and inside the
    published interval."""
    rows = []
    for q, pub in published.items():
        new = now.get(q)
        if new is None:
            rows.append({"quantity": q, "published": pub["mean"], "rescored": None, "identical": False,
                         "within": False})
            continue
        lo, hi = pub["ci95_low"], pub["ci95_high"]
        within = (lo <= new["mean"] <= hi) if not (math.isnan(lo) or math.isnan(hi)) else _same(pub["mean"],
                                                                                                new["mean"])
        identical = _same(pub["mean"], new["mean"]) and pub["per_seed"].keys() == new["per_seed"].keys() and all(
            _same(v, new["per_seed"][s]) for s, v in pub["per_seed"].items())
        rows.append({"quantity": q, "unit": pub["unit"], "published": pub["mean"], "ci95_low": lo, "ci95_high": hi,
                     "rescored": new["mean"], "identical": identical, "within": bool(within)})
    return rows


# -- the actions -----------------------------------------------------------------------------------------
def run_list(args: argparse.Namespace) -> int:
    from apac_mj.run import zoo

    cells = zoo.list_cells(args.root)
    if not cells:
        print(f"no cells in {args.root or 'zoo/'} (apac-mj zoo export RUN_DIR --out zoo/NAME makes one)")
        return 0
    for cell in cells:
        m = zoo.read_manifest(cell)
        size = sum(f.stat().st_size for f in cell.iterdir() if f.is_file()) / 1e6
        test = m.get("published", {}).get("tests", {}).get("test_success")
        score = f"test success {test['mean']:.1f}% [{test['ci95_low']:.1f}, {test['ci95_high']:.1f}]" if test else \
            "no published numbers"
        print(f"{zoo.PREFIX + cell.name if args.root is None else cell}  {m['kind']} on {m['task']}, seeds {_seeds(m['seeds'])} x {m['episodes']} "
              f"episodes, {m['dtype']}, {size:.1f} MB, {score}")
    return 0


def _seeds(seeds: list[int]) -> str:
    return f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) else ",".join(map(str, seeds))


def run_export(args: argparse.Namespace) -> int:
    from apac_mj.run import zoo

    if args.regression_targets < 1:
        raise ValueError(f"--regression-targets must be >= 1, got {args.regression_targets}")
    cell = zoo.export(args.run_dir, args.out, args.dtype)
    try:
        manifest = publish(cell, Path(args.run_dir), args.regression_targets)
    except BaseException:
        shutil.rmtree(cell, ignore_errors=True)  # no cell without its numbers
        raise
    size = sum(f.stat().st_size for f in cell.iterdir()) / 1e6
    print(f"wrote {cell} ({size:.2f} MB, {manifest['dtype']}): {manifest['kind']} on {manifest['task']}, "
          f"seeds {_seeds(manifest['seeds'])} x {manifest['episodes']} episodes")
    _print_numbers(manifest["published"]["tests"])
    for row in manifest.get("fp32_run", {}).get("comparison", []):
        print(f"  fp32 run {row['quantity']}: {row['published']:.6g}, shipped {manifest['dtype']}: "
              f"{row['rescored']:.6g}, identical: {row['identical']}")
    return 0


def publish(cell: Path, source: Path, targets: int) -> dict[str, Any]:
    """Score a new cell from its shipped weights (the frozen tests), record its run's late training numbers, the
    fp32 run's own test numbers beside them (where it was evaluated) and the regression episodes."""
    from apac_mj.run import zoo
    from apac_mj.run.evaluate import evaluate
    from apac_mj.run.run_dir import RunDir

    m = zoo.read_manifest(cell)
    kind, task = m["kind"], m["task"]
    regression = zoo.store_regression(cell, targets)
    run = zoo.materialize(cell)  # the same run directory (cached)
    evaluate(run, protocols=PROTOCOLS, threads=1)
    tests = numbers(run, kind, task)
    fields: dict[str, Any] = {"published": {"tests": tests, "training": numbers(source, kind, task, training=True),
                                            "machine": zoo.machine(), "protocols": list(PROTOCOLS)},
                              "regression": regression}
    if RunDir(source).eval_paths():  # the fp32 run's own frozen tests: does the shipped precision reproduce them?
        fp32 = numbers(source, kind, task)
        fields["fp32_run"] = {"tests": fp32, "comparison": compare(fp32, tests)}
    return zoo.update_manifest(cell, **fields)


def run_rescore(args: argparse.Namespace) -> int:
    from apac_mj.run import zoo
    from apac_mj.run.evaluate import evaluate

    cell = zoo.cell_path(args.cell)
    m = zoo.read_manifest(cell)
    published = m.get("published", {}).get("tests")
    if not published:
        raise ValueError(f"{cell} has no published numbers: export it with apac-mj zoo export")
    run = zoo.materialize(cell)
    evaluate(run, protocols=tuple(m["published"].get("protocols", PROTOCOLS)), threads=1)
    rows = compare(published, numbers(run, m["kind"], m["task"]))
    if args.json:
        print(json.dumps({"cell": cell.name, "machine": zoo.machine(), "published_on": m["published"].get("machine"),
                          "numbers": rows}, indent=2))
    else:
        print(f"{cell.name}: {m['kind']} on {m['task']}, seeds {_seeds(m['seeds'])} x {m['episodes']} episodes; "
              f"published on {m['published'].get('machine')}, re-scored on {zoo.machine()}")
        for r in rows:
            print(f"  {r['quantity']:<24} published {_fmt(r['published'])} [{_fmt(r.get('ci95_low'))}, "
                  f"{_fmt(r.get('ci95_high'))}]  re-scored {_fmt(r['rescored'])}  "
                  f"{'identical' if r['identical'] else 'differs'}, {'within' if r['within'] else 'OUTSIDE'} "
                  "the interval")
    return 0 if all(r["within"] for r in rows) else 1


def _fmt(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.4g}"


def _print_numbers(tests: dict[str, dict[str, Any]]) -> None:
    for q, v in tests.items():
        print(f"  {q:<24} {_fmt(v['mean'])} [{_fmt(v['ci95_low'])}, {_fmt(v['ci95_high'])}] {v['unit']}")
