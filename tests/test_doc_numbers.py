"""Sizes the docs state, checked against files made here (issue 29 item 12: the docs said "about 21 MB" for a
checkpoint of the demo's networks, measured 27 MB; "~230 KB" for a one-episode recording, measured 318-333 KB).
The numbers are read from the docs, so a doc that drifts from the code fails here. Durations and the
.venv's size depend on the machine and are stated with it in the docs, not checked."""
from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.report import stats
from apac_mj.run.trainer import train

from conftest import TINY

DOCS = Path(__file__).resolve().parents[1] / "docs"


def _stated(path: Path, pattern: str) -> tuple[float, ...]:
    m = re.search(pattern, path.read_text(), flags=re.S)
    assert m, f"{path.name}: no match for {pattern!r} (the sentence moved: update this test with it)"
    return tuple(float(g) for g in m.groups())


def test_checkpoint_size_of_the_demos_networks(tmp_path) -> None:
    """docs/experiments.md: a checkpoint of the demo's 3 seeds (the paper's networks, the demo's minibatch)."""
    (stated,) = _stated(DOCS / "experiments.md",
                        r"`checkpoints/previous.pt` \((\d+(?:\.\d+)?) MB each for the demo's 3")
    cfg = TrainConfig(task="changing_target", seeds=(0, 1, 2), episodes=1, actuation="kinematic",
                      agent=AgentConfig(kind="apac", batch_size=64, babbling_episodes=0))
    run = train(cfg, tmp_path / "run", progress=False)
    size = (run / "checkpoints" / "latest.pt").stat().st_size / 1e6
    assert size == pytest.approx(stated, rel=0.05), f"a checkpoint is {size:.1f} MB, the docs say {stated} MB"


def test_one_episode_recording_size(tmp_path) -> None:
    """docs/recording.md: a 30-step episode as ``--record-every`` writes it."""
    from apac_mj.recording.recording import EpisodeRecorder
    from apac_mj.run.run_dir import config_dict

    low, high = _stated(DOCS / "recording.md", r"(\d+)-(\d+) KB a file of 30 steps")
    cfg = TrainConfig(task="changing_target", seeds=(0,), episodes=1, actuation="kinematic",
                      agent=AgentConfig(kind="apac", **TINY))  # babbling: one 30-step episode
    with EpisodeRecorder(tmp_path / "recordings", record_every=1, config=config_dict(cfg)) as recorder:
        train(cfg, tmp_path / "run", progress=False, hooks=[recorder])
    import pandas as pd

    steps = pd.read_parquet(tmp_path / "run" / "metrics.parquet").set_index("episode")["steps"]
    files = {int(p.stem.split("_")[1]): p.stat().st_size / 1e3 for p in (tmp_path / "recordings").glob("*.rrd")}
    thirty = [kb for episode, kb in files.items() if steps[episode] == 30]
    assert thirty, f"no 30-step episode recorded: {dict(steps)}"
    for kb in thirty:
        assert 0.9 * low <= kb <= 1.1 * high, f"a 30-step recording is {kb:.0f} KB, the docs say {low:.0f}-{high:.0f}"


# --- issue 41: every published interval is the report's measured interval of the shipped per-seed values ---

RESULTS = DOCS / "results"
NUM = r"([−-]?\d+(?:\.\d+)?)"


def _printed(page: str, pattern: str) -> tuple[float, ...]:
    """The numbers a page prints at ``pattern`` (Unicode minus read as minus), and their decimals."""
    text = (RESULTS / page).read_text()
    m = re.search(pattern.replace("NUM", NUM), text, flags=re.S)
    assert m, f"{page}: no match for {pattern!r} (the sentence moved: update this test with it)"
    return tuple(float(g.replace("−", "-")) for g in m.groups())


def _seeds(csv: str, quantity: str, agent: str, condition: str) -> tuple[pd.Series, float, float]:
    """A key number's per-seed values (by seed), its mean and its samples, from a shipped key_numbers.csv."""
    df = pd.read_csv(RESULTS / csv)
    r = df[(df.quantity == quantity) & (df.agent == agent) & (df.condition == condition)].iloc[0]
    per = dict(item.split(":") for item in r.per_seed.split(";"))
    return pd.Series({int(s): float(v) for s, v in per.items()}), float(r["mean"]), float(r.samples)


def _rate(values: pd.Series, mean: float, samples: float) -> tuple[float, float]:
    return stats.interval(values.tolist(), [mean * samples / 100], [samples])[1:]


def _rate_difference(a: tuple, b: tuple) -> tuple[float, float]:
    """Paired interval of two rates' per-seed values, widened to Newcombe's of the pooled counts."""
    _, lo, hi, paired = stats.paired_difference(a[0], b[0], bounds=(-100.0, 100.0))
    assert paired
    nlo, nhi = stats.newcombe_interval(a[1] * a[2] / 100, a[2], b[1] * b[2] / 100, b[2])
    return min(lo, 100 * nlo), max(hi, 100 * nhi)


def _close(printed: tuple[float, ...], computed: tuple[float, ...], page: str) -> None:
    assert printed == pytest.approx(computed, abs=0.051), f"{page} prints {printed}, the per-seed values give {computed}"


STOP, CT = "planning/stop/key_numbers.csv", "planning/changing_target/key_numbers.csv"


@pytest.mark.parametrize("page, pattern, computed", [
    ("planning/README.md", r"\*\*SPAC-MPC\*\* \| \*\*54\.4%\*\* \[NUM, NUM\]",
     lambda: _rate(*_seeds(STOP, "test_success", "spac_mpc", "changing_target_torque_stop"))),
    ("planning/README.md", r"last 20% \(episodes 800-999\) \| 79\.6% \[NUM, NUM\]",
     lambda: _rate(*_seeds(CT, "habit_fraction_late", "apac_voc", "changing_target"))),
    ("planning/README.md", r"SPAC-MPC − SPAC \*\*\+52\.0 points \[NUM, NUM\]\*\*",
     lambda: _rate_difference(_seeds(STOP, "test_success", "spac_mpc", "changing_target_torque_stop"),
                              _seeds(STOP, "test_success", "spac", "changing_target_torque_stop"))),
    ("planning/README.md", r"APAC-MPC − SPAC-MPC −13\.0 \[NUM, NUM\]",
     lambda: _rate_difference(_seeds(STOP, "test_success", "apac_mpc", "changing_target_torque_stop"),
                              _seeds(STOP, "test_success", "spac_mpc", "changing_target_torque_stop"))),
    ("contested/README.md", r"APAC − SPAC \*\*−5\.6 \[NUM, NUM\]\*\*",
     lambda: _rate_difference(_seeds("contested/key_numbers.csv", "test_success", "apac", "changing_target"),
                              _seeds("contested/key_numbers.csv", "test_success", "spac", "changing_target"))),
    ("README.md", r"\(−5\.6 \[NUM, NUM\] points\)",
     lambda: _rate_difference(_seeds("contested/key_numbers.csv", "test_success", "apac", "changing_target"),
                              _seeds("contested/key_numbers.csv", "test_success", "spac", "changing_target"))),
    ("fidelity/README.md", r"test is −8\.2 \[NUM, NUM\] points \(cs\)",
     lambda: _rate_difference(_seeds("fidelity/key_numbers.csv", "test_success", "apac", "changing_target"),
                              _seeds("fidelity/key_numbers.csv", "test_success", "spac", "changing_target"))),
    ("generalization/README.md", r"\| \+11\.9 \[NUM, NUM\] \|",
     lambda: _rate_difference(
         _seeds("generalization/key_numbers.csv", "generalization_success", "spac",
                "changing_target_changing_kinematics"),
         _seeds("generalization/key_numbers.csv", "generalization_success", "ddpg",
                "changing_target_changing_kinematics"))),
    ("arbitrators/README.md", r"APAC-U − SPAC \+5\.2 \[NUM, NUM\]",
     lambda: _rate_difference(_seeds("arbitrators/key_numbers.csv", "test_success", "apac_uncertainty",
                                     "changing_target"),
                              _seeds("arbitrators/key_numbers.csv", "test_success", "spac", "changing_target"))),
])
def test_headline_intervals_follow_from_the_shipped_per_seed_values(page: str, pattern: str, computed) -> None:
    """Each page's headline interval, recomputed here from its study's per-seed values with the report's method
    (issue 41: the pages printed percentile-bootstrap intervals that undercover, four of them not even that)."""
    _close(_printed(page, pattern), computed(), page)


def test_the_dynamics_headline_follows_from_the_per_seed_test_table() -> None:
    """docs/results/dynamics: SPAC's torque-arm test success from tests.csv's per-seed counts."""
    t = pd.read_csv(RESULTS / "dynamics" / "tests.csv")
    t = t[(t.agent == "spac") & (t.condition == "changing_target_torque")]
    m, lo, hi = stats.interval((100 * t.success).tolist(), [t.successes.sum()], [t.targets.sum()])
    _close(_printed("dynamics/README.md", r"\*\*76\.8%\*\* \[NUM, NUM\] \(71, 66, 80, 86, 81\)"), (lo, hi),
           "dynamics/README.md")


def test_no_published_interval_is_stale() -> None:
    """scripts/rereport.py --check: every table, report.md and page interval equals its recomputation."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rereport", DOCS.parent / "scripts" / "rereport.py")
    rereport = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(rereport)
    assert rereport.main(["--check", "--results", str(RESULTS)]) == 0, "run `python scripts/rereport.py`"
