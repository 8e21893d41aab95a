"""scripts/deliberation_study.py's combine, drop and paired steps, on hand-made per-seed tables."""

import importlib.util
from pathlib import Path

import pandas as pd
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "deliberation_study.py"


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location("deliberation_study", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _table(rows: list[tuple[str, str, str, int, float, float]]) -> pd.DataFrame:
    """(kind, variant, world, seed, success, decision_ms_per_step) rows."""
    return pd.DataFrame(rows, columns=["kind", "variant", "world", "seed", "success", "decision_ms_per_step"])


def test_combine_refuses_a_seed_in_two_parts(study) -> None:
    a = _table([("ddpg", "habit", "no_wait", 0, 10.0, 1.5), ("ddpg", "habit", "no_wait", 1, 20.0, 1.5)])
    b = _table([("ddpg", "habit", "no_wait", 1, 30.0, 1.5), ("ddpg", "habit", "no_wait", 2, 40.0, 1.5)])
    with pytest.raises(ValueError, match=r"seeds \[1\]"):
        study.combine([a, b])


def test_combine_refuses_parts_that_test_different_rows(study) -> None:
    a = _table([("ddpg", "habit", "no_wait", 0, 10.0, 1.5)])
    b = _table([("ddpg", "habit", "no_wait", 1, 30.0, 1.5), ("spac_mpc", "plan k=2", "no_wait", 1, 30.0, 66.0)])
    with pytest.raises(ValueError, match="plan k=2"):
        study.combine([a, b])


def test_combine_keeps_the_first_parts_order_and_sorts_seeds(study) -> None:
    a = _table([("ddpg", "habit", "no_wait", 0, 10.0, 1.5), ("apac_voc", "graded", "no_wait", 0, 50.0, 49.0)])
    b = _table([("apac_voc", "graded", "no_wait", 4, 60.0, 44.0), ("ddpg", "habit", "no_wait", 4, 40.0, 1.5),
                ("apac_voc", "graded", "no_wait", 3, 70.0, 45.0), ("ddpg", "habit", "no_wait", 3, 30.0, 1.5)])
    out = study.combine([a, b])
    assert list(zip(out.kind, out.seed)) == [("ddpg", 0), ("ddpg", 3), ("ddpg", 4),
                                              ("apac_voc", 0), ("apac_voc", 3), ("apac_voc", 4)]
    assert list(out.success) == [10.0, 30.0, 40.0, 50.0, 70.0, 60.0]  # rows travel whole


def test_drop_leaves_out_exactly_the_named_variants(study) -> None:
    assert [v[0] for v in study._variants("spac_mpc", 4)] == ["plan k=1", "plan k=2", "plan k=4"]
    drop = study.parse_drop("spac_mpc:plan k=2, apac_voc:plan k=1")
    assert drop == {("spac_mpc", "plan k=2"), ("apac_voc", "plan k=1")}
    assert [v[0] for v in study._variants("spac_mpc", 4, drop)] == ["plan k=1", "plan k=4"]
    assert [v[0] for v in study._variants("apac_voc", 4, drop)] == ["graded", "habit", "plan k=4"]
    assert [v[0] for v in study._variants("ddpg", 0, drop)] == ["habit"]
    with pytest.raises(ValueError, match="kind:variant"):
        study.parse_drop("spac_mpc plan k=2")


def test_paired_differences_by_seed_with_the_reports_t_interval(study) -> None:
    graded = [("apac_voc", "graded", "no_wait", s, v, 49.0) for s, v in zip((0, 1, 2), (30.0, 40.0, 40.0))]
    plan = [("apac_voc", "plan k=4", "no_wait", s, v, 108.0) for s, v in zip((2, 0, 1), (25.0, 25.0, 30.0))]
    pairs = (("g - p", ("apac_voc", "graded", "no_wait"), ("apac_voc", "plan k=4", "no_wait")),
             ("absent", ("ddpg", "habit", "waits"), ("apac_voc", "graded", "no_wait")))
    out = study.paired(_table(graded + plan), pairs).set_index("metric")
    # differences by seed 5, 10, 15: mean 10, sd 5; t at the 0.9875 quantile, 2 dof: 0.975 / sqrt(2 * 0.9875 *
    # 0.0125) = 6.2054, half-width 6.2054 * 5 / sqrt(3) = 17.913
    s = out.loc["success"]
    assert (s.difference, s.lo, s.hi, s.a_higher_seeds, s.seeds) == pytest.approx((10.0, -7.913, 27.913, 3, 3))
    assert s.ratio == pytest.approx((110 / 3) / (80 / 3), abs=1e-3) and bool(s.paired)
    d = out.loc["decision_ms_per_step"]
    assert (d.difference, d.lo, d.hi, d.ratio) == pytest.approx((-59.0, -59.0, -59.0, 49 / 108), abs=1e-3)
    assert list(out.comparison) == ["g - p", "g - p"]  # the pair with a missing side is skipped
