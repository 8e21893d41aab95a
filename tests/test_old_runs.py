"""A run directory written by release 936695d (tests/fixtures/run_936695d: flat rule fields, ``agent.agent``,
the speed-accuracy rule's flat statistics) still evaluates and resumes with the numbers it had, and its
config migrates to today's shape with every value kept."""
from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from apac_mj.config import MOVED, migrate, to_dict, train_config_from_dict
from apac_mj.run.evaluate import MEASURED_COLUMNS, evaluate
from apac_mj.run.run_dir import TIMING_COLUMNS
from apac_mj.run.trainer import train

FIXTURE = Path(__file__).resolve().parent / "fixtures" / "run_936695d"
#: The fixture was written on an AVX2-only CPU; on an AVX-512 CPU the GEMM kernels sum in another order, so its
#: floats come back equal only to float32 rounding (measured on a Xeon with AMX: relative differences <= 1e-7 in
#: returns and distances after two more training episodes). Integer and boolean columns (steps, success, seeds)
#: are compared exactly; a migration that restored a wrong weight, statistic or rule would change actions, and
#: with them these numbers, by far more than this.
FLOAT_TOLERANCE = {"check_exact": False, "rtol": 1e-5, "atol": 1e-6}


def _stored() -> dict:
    d = json.loads((FIXTURE / "config.json").read_text())
    d.pop("git_commit")
    return d


def test_migrate_keeps_every_value_and_gives_todays_shape():
    old = _stored()
    before = copy.deepcopy(old)
    new = migrate(old)
    assert old == before, "pure: its argument is left as it was"
    assert migrate(new) == new, "idempotent"
    agent = new["agent"]
    assert agent["kind"] == "apac_speed_accuracy" and "agent" not in agent
    for key, value in old["agent"].items():
        if key in MOVED:
            assert key not in agent and all(agent[t][f] == value for t, f in MOVED[key])
        elif key != "agent":
            assert agent[key] == value, key
    assert agent["uncertainty"]["window"] == agent["reliability"]["window"] == 50
    assert agent["speed_accuracy"] == {"window": 7} and new["episodes"] == 6
    # today's shape exactly: what the current release writes for the same configuration
    assert json.loads(json.dumps(to_dict(train_config_from_dict(old)))) == new


@pytest.fixture()
def run(tmp_path) -> Path:
    return Path(shutil.copytree(FIXTURE, tmp_path / "run"))


def test_an_old_run_evaluates_to_the_same_rows(run):
    evaluate(run, limit=6)
    for protocol in ("grid", "occluded"):
        rows, expected = (pd.read_parquet(d / "eval" / f"{protocol}.parquet") for d in (run, FIXTURE))
        assert list(rows.columns) == list(expected.columns) + list(MEASURED_COLUMNS)  # measured since: appended
        pd.testing.assert_frame_equal(rows[expected.columns], expected, **FLOAT_TOLERANCE)


def test_an_old_run_extends_with_the_numbers_of_its_release(run):
    cfg = train_config_from_dict({**_stored(), "episodes": 8})
    train(cfg, run, progress=False)
    metrics = pd.read_parquet(run / "metrics.parquet")
    expected = pd.read_parquet(FIXTURE / "expected_metrics_8_episodes.parquet")
    assert list(metrics.columns) == [*expected.columns, *TIMING_COLUMNS]  # measured since: appended, NaN before
    assert metrics.planning_seconds.isna().sum() == len(pd.read_parquet(FIXTURE / "metrics.parquet"))
    pd.testing.assert_frame_equal(metrics[expected.columns], expected, **FLOAT_TOLERANCE)
    assert json.loads((run / "config.json").read_text())["agent"]["kind"] == "apac_speed_accuracy"
