"""Mutation testing (mutmut 3) of the modules whose mistakes a run would not show: each module is mutated alone and
run against its own fast test files; the score per module is printed and written as CSV (docs/mutation.md).

    .venv/bin/pip install -e '.[mutation]'
    nice -n 5 .venv/bin/python bench/mutation.py [--modules planner arbitrators ...] [--work DIR] [--out CSV]

Each module runs in its own scratch copy of the project (``--work``, default a folder under the system's
temporary directory), so the tree is never touched; ``mutmut`` is run there with the ``[tool.mutmut]`` settings
of ``pyproject.toml``, its ``only_mutate`` and test selection set to the module's row of :data:`MODULES`, one
test process at a time. Not in CI: about 30 CPU-minutes for every module on one core.
"""
from __future__ import annotations

import argparse
import csv
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from collections import Counter
from datetime import date, timezone, datetime
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parents[1]
#: The project's folders a test run needs (the package, its package data folders, the tests, the benches, the
#: published pages and the scripts that tests/test_doc_numbers.py recomputes them with).
COPIED = ("apac_mj", "assets", "tasks", "tests", "bench", "docs", "scripts")
#: Tests that run a training or a subprocess: they compare the code with itself (a resumed run with an
#: uninterrupted one) or check the command line; left out so that every mutant runs in seconds.
SLOW = ("not killed_and_resumed and not resume_ and not before_anything_is_written and not bench "
        "and not checkpointed and not recordings and not command_line and not record_labels and not being_trained "
        "and not end_to_end and not every_kind_trains and not extended_run and not metrics_carry")
#: name -> (files mutated, test files run against them). Order: the report's statistics last (issue 41).
MODULES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "planner": (("apac_mj/agent/planner.py",),
                ("tests/test_planner_properties.py", "tests/test_planner.py", "tests/test_habit_candidates.py")),
    "arbitrators": (("apac_mj/agent/arbitrators.py", "apac_mj/agent/arbitration.py"),
                    ("tests/test_arbitration_rules.py", "tests/test_arbitration_gaps.py", "tests/test_arbitrators.py",
                     "tests/test_planner.py")),
    "integrator": (("apac_mj/agent/integrator.py",),
                   ("tests/test_integrator.py", "tests/test_integrator_properties.py")),
    "timing": (("apac_mj/run/timing.py",), ("tests/test_timing.py", "tests/test_forced_response.py")),
    "losses": (("apac_mj/agent/networks.py", "apac_mj/agent/agent.py"),
               ("tests/test_losses_properties.py", "tests/test_update.py", "tests/test_networks.py",
                "tests/test_agent.py", "tests/test_precision.py", "tests/test_inverse_updates.py")),
    "stats": (("apac_mj/report/stats.py",), ("tests/test_stats_coverage.py", "tests/test_stats_known.py",
                                             "tests/test_doc_numbers.py", "tests/test_dynamics_bench.py")),
    "two_state": (("apac_mj/report/two_state.py",), ("tests/test_two_state.py",)),
    "hardwick": (("apac_mj/report/hardwick.py",), ("tests/test_hardwick_model.py", "tests/test_hardwick_human.py",
                                                  "tests/test_hardwick_report.py")),
    "signals": (("apac_mj/suite/signals.py",), ("tests/test_signals.py",)),
    "trials": (("apac_mj/suite/trials.py",), ("tests/test_trials.py",)),
    "adaptation": (("apac_mj/experiments/adaptation.py", "apac_mj/report/adaptation.py"), ("tests/test_adaptation.py",)),
}
#: mutmut's outcomes that count as killed (a test failed, or the mutant hung past the timeout).
KILLED = ("killed", "timeout")


def scratch(module: str, work: Path) -> Path:
    """A copy of the project for one module, its pyproject's ``[tool.mutmut]`` pointed at that module."""
    files, tests = MODULES[module]
    dest = work / module
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "mutants")
    for name in COPIED:
        shutil.copytree(ROOT / name, dest / name, ignore=ignore)
    present = [t for t in tests if (ROOT / t).exists()]
    text = (ROOT / "pyproject.toml").read_text()
    selection = ", ".join(f'"{t}"' for t in present)
    only = ", ".join(f'"{f}"' for f in files)
    text = re.sub(r'only_mutate = \[.*?\]', f"only_mutate = [{only}]", text, flags=re.S)
    text = re.sub(r'pytest_add_cli_args_test_selection = \[.*?\]',
                  f'pytest_add_cli_args_test_selection = [{selection}, "-m", "not slow", "-k", "{SLOW}"]', text,
                  flags=re.S)
    (dest / "pyproject.toml").write_text(text)
    return dest


def run_module(module: str, work: Path) -> dict[str, object]:
    """Mutate one module in its scratch copy; its counts by outcome and the surviving mutants' diffs."""
    dest = scratch(module, work)
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    mutmut = [sys.executable, "-m", "mutmut"]
    start = datetime.now(timezone.utc)
    run = subprocess.run([*mutmut, "run", "--max-children", "1"], cwd=dest, env=env, check=False,
                         capture_output=True, text=True)
    seconds = (datetime.now(timezone.utc) - start).total_seconds()
    listing = subprocess.run([*mutmut, "results", "--all", "true"], cwd=dest, env=env, capture_output=True,
                             text=True, check=True).stdout
    outcome = dict(line.strip().rsplit(": ", 1) for line in listing.splitlines() if ": " in line)
    counts = Counter(outcome.values())
    survivors = [k for k, v in outcome.items() if v not in KILLED]
    show = ("import sys\nfrom mutmut.mutation.diff_apply import find_mutant, get_diff_for_mutant\n"
            "for name in sys.argv[1:]:\n    print(f'# {name}')\n"
            "    print(get_diff_for_mutant(name, path=find_mutant(name).path))\n")
    diffs = subprocess.run([sys.executable, "-c", show, *survivors], cwd=dest, env=env, capture_output=True,
                           text=True).stdout if survivors else ""
    (work / f"{module}_survivors.txt").write_text(diffs)
    total = sum(counts.values())
    killed = sum(counts[k] for k in KILLED)
    if total and killed + counts["survived"] + counts["no tests"] == 0:  # mutmut stopped before any mutant ran
        tail = "\n".join((run.stdout + run.stderr).splitlines()[-30:])
        raise SystemExit(f"mutmut ran no mutant of {module} (its clean test run failed?); its output ends:\n{tail}")
    return {"module": module, "files": " ".join(MODULES[module][0]), "mutants": total, "killed": counts["killed"],
            "timeout": counts["timeout"], "survived": counts["survived"], "no_tests": counts["no tests"],
            "other": total - killed - counts["survived"] - counts["no tests"],
            "score_pct": round(100.0 * killed / total, 1) if total else float("nan"),
            "seconds": round(seconds), "date": date.today().isoformat(), "tool": f"mutmut {_version()}"}


def _version() -> str:
    from importlib.metadata import version

    return version("mutmut")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--modules", nargs="+", default=list(MODULES), choices=list(MODULES), help="default: all, in order")
    p.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "apac_mj_mutation",
                   help="scratch folder (one project copy per module; survivors' diffs written here)")
    p.add_argument("--out", type=Path, default=None, help="append one row per module to this CSV")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> list[dict[str, object]]:
    args = parse_args(argv)
    try:
        _version()
    except Exception:  # noqa: BLE001  (importlib.metadata.PackageNotFoundError)
        raise SystemExit("mutmut is not installed: .venv/bin/pip install -e '.[mutation]'") from None
    if "mutmut" not in tomllib.loads((ROOT / "pyproject.toml").read_text()).get("tool", {}):
        raise SystemExit("pyproject.toml has no [tool.mutmut] section")
    rows = []
    for module in args.modules:
        row = run_module(module, args.work)
        rows.append(row)
        print(" ".join(f"{k}={v}" for k, v in row.items()), flush=True)
        if args.out is not None:
            new = not args.out.exists()
            with args.out.open("a", newline="") as f:
                w = csv.DictWriter(f, fieldnames=list(row))
                if new:
                    w.writeheader()
                w.writerow(row)
    return rows


if __name__ == "__main__":
    main()
