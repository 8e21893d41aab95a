"""scripts/hardwick_human.py: the human curves' window, crossing and recoding, against hand computations."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("scipy")
_PATH = Path(__file__).resolve().parents[1] / "scripts" / "hardwick_human.py"
_spec = importlib.util.spec_from_file_location("hardwick_human", _PATH)
hh = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(hh)


def test_the_window_counts_codes_in_the_half_open_100_ms_window_and_needs_four_trials():
    # centre 400 ms: window (350, 450] ms holds 0.36, 0.40, 0.42, 0.45 (0.35 is outside, 0.45 inside)
    rt = np.array([0.35, 0.36, 0.40, 0.42, 0.45, 0.90])
    y = np.array([2, 1, 2, 2, 3, 1])
    p = hh.window_probs(rt, y)
    j = int(np.flatnonzero(hh.CENTRES_MS == 400)[0])
    np.testing.assert_allclose(p[:, j], [1 / 4, 2 / 4, 1 / 4])
    k = int(np.flatnonzero(hh.CENTRES_MS == 900)[0])  # one trial: too few
    assert np.all(np.isnan(p[:, k]))


def test_unchanged_curves_hold_p_error_and_no_habitual_error():
    rt = np.linspace(0.36, 0.44, 10)  # all in the 400 ms window (350, 450]
    y = np.array([1] * 7 + [3] * 3)
    cur = hh.subject_curves([{"rt_unchanged": rt, "y_unchanged": y}], "unchanged")
    j = int(np.flatnonzero(hh.CENTRES_MS == 400)[0])
    assert np.isnan(cur[0, 1]).all() and cur[0, 0, j] == pytest.approx(0.7) and cur[0, 2, j] == pytest.approx(0.3)


def test_first_crossing_interpolates_between_centres():
    p = np.zeros(len(hh.CENTRES_MS))
    i = int(np.flatnonzero(hh.CENTRES_MS == 500)[0])
    p[i - 1], p[i:] = 0.25, 0.75  # 475 ms at 0.25, 500 ms at 0.75: 0.5 is reached at 487.5 ms
    assert hh.first_crossing(p) == pytest.approx(487.5)
    assert np.isnan(hh.first_crossing(np.zeros(len(hh.CENTRES_MS))))


def test_the_fits_summary_counts_habit_favoured_subjects_and_keeps_subjects_out_of_out(tmp_path):
    from apac_mj.report import hardwick as hw

    def subject(params, habit, seed):
        rng = np.random.default_rng(seed)
        rt = rng.uniform(0.0, 1.2, 400)
        return {"rt_remapped": rt, "y_remapped": hw.simulate(rt, params, habit, rng)}

    habit, none = (0.4, 0.06, 0.55, 0.08, 0.95, 0.25, 0.05), (0.5, 0.08, 0.95, 0.25)
    data = {c: [subject(habit if c != "minimal" else none, c != "minimal", 10 * k + i) for i in range(3)]
            for k, c in enumerate(hh.CONDITIONS)}
    hh.write_fits(data, tmp_path, None)
    summ = pd.read_csv(tmp_path / "hardwick_fits.csv")
    assert summ.condition.tolist() == list(hh.CONDITIONS) and summ.n.tolist() == [3, 3, 3]
    assert summ.habit_wins.tolist() == [0, 3, 3]
    assert abs(summ.mu_habit[1] - 400.0) < 40.0 and summ.mu_habit_lo[1] <= summ.mu_habit[1] <= summ.mu_habit_hi[1]
    assert [p.name for p in tmp_path.iterdir()] == ["hardwick_fits.csv"]  # no per-subject table unless asked


def test_subject_fits_without_fits_is_refused(tmp_path, monkeypatch, capsys):
    mat = tmp_path / "HabitData.mat"
    mat.write_bytes(b"")
    monkeypatch.setattr("sys.argv", ["hardwick_human.py", "--mat", str(mat), "--out", str(tmp_path / "o"),
                                     "--subject-fits", str(tmp_path / "s.csv")])
    with pytest.raises(SystemExit):
        hh.main()
    assert "--subject-fits needs --fits" in capsys.readouterr().err and not (tmp_path / "o").exists()
