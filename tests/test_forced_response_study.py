"""The forced-response study's command line, reruns, one writer per study, and the report's checks of its tables
(issue 45; docs/forced_response.md). None of these trains: they run in seconds."""
import json
import re
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from apac_mj import cli
from apac_mj.commands.forced_response import protocol
from apac_mj.experiments import forced_response as exp
from apac_mj.report import forced_response as rep
from apac_mj.run.timing import COLUMNS

SMALL = ["seeds=1", "practice=1", "agents=ddpg", "trials=5", "repeats=1"]


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit):
        cli.main(["forced-response", *argv, "--help"])
    return capsys.readouterr().out


def test_each_action_is_a_sub_command_with_only_its_options(capsys):
    """``run|test|report|record --help`` differ, each listing only the options it acts on (F9, item 7)."""
    run, test, report, record = (_help(capsys, a) for a in ("run", "test", "report", "record"))
    assert len({run, test, report, record}) == 4
    assert "--no-progress" in run and "Protocol fields" in run and "--prep-times" not in run
    assert "--prep-times" not in test and "--cue" not in test and "--variant" not in test and "--member" not in test
    assert "prep_times_ms" in test and "--no-progress" not in test and "agents =" not in test
    assert "--set" not in report and "--out DIR" in report
    for option in ("--prep-times", "--cue", "--member", "--variant"):
        assert option in record
    assert "trials =" not in record


@pytest.mark.parametrize("argv, says", [
    (["--prep-times", "300"], "unrecognized arguments: --prep-times"),
    (["--cue", "9"], "unrecognized arguments: --cue"),
    (["--variant", "nosuch"], "unrecognized arguments: --variant"),
    (["--member", "5"], "unrecognized arguments: --member"),
    (["--set", "seeds=2"], "unknown key(s) ['seeds']"),
])
def test_the_test_refuses_what_it_would_ignore(tmp_path, capsys, argv, says):
    """FR-O1: ``forced-response test`` exited 0 ignoring record's options (even invalid values) and run fields."""
    out = tmp_path / "t.parquet"
    try:
        code = cli.main(["forced-response", "test", str(tmp_path / "run"), "--out", str(out), *argv])
    except SystemExit as e:  # argparse
        code = e.code
    assert code != 0 and not out.exists()
    assert says in capsys.readouterr().err


def test_record_takes_only_timing_settings(tmp_path, capsys):
    assert cli.main(["forced-response", "record", str(tmp_path), "--out", str(tmp_path / "x.rrd"),
                     "--set", "trials=5"]) != 0
    assert "unknown key(s) ['trials']" in capsys.readouterr().err


# -- the report's tables ------------------------------------------------------------------------------------------
def _table(trials: int = 10) -> pd.DataFrame:
    """A test table as ``test_run`` writes it: 2 seeds, a remapped and an unchanged cue, 3 preparation times."""
    rows = []
    for seed in (0, 1):
        for cue, remapped in ((0, False), (1, True)):
            for i, t in enumerate((100.0, 400.0, 900.0)):
                habitual = 3 * i if remapped and i == 1 else 0
                correct = trials - habitual if i else 0
                rows.append(dict(seed=seed, episode=5, variant="ddpg", prep_ms=t, cue=cue, remapped=remapped,
                                 trials=trials, correct=correct, habitual=habitual, other=0,
                                 timeout=trials - correct - habitual, habit_acted=correct + habitual,
                                 planner_acted=0, default_acted=trials - correct - habitual, guessed=0))
    return pd.DataFrame(rows, columns=list(COLUMNS))


def _study(tmp_path, df: pd.DataFrame, folder: str = "p5"):
    path = tmp_path / "study" / "tests" / folder / "ddpg.parquet"
    path.parent.mkdir(parents=True)
    df.to_parquet(path)
    return tmp_path / "study", path


def test_a_sound_table_reports_and_report_out_goes_where_asked(tmp_path, capsys):
    """FR-O2: ``report --out`` was ignored (the report went to STUDY/report)."""
    study, _ = _study(tmp_path, _table())
    elsewhere = tmp_path / "elsewhere"
    assert cli.main(["forced-response", "report", str(study), "--out", str(elsewhere)]) == 0
    assert not (study / "report").exists()
    curves = pd.read_csv(elsewhere / "curves.csv")
    assert curves.correct.between(0, 1).all() and (elsewhere / "forced_response.png").is_file()
    peaks = pd.read_csv(elsewhere / "peaks.csv")
    assert peaks.peak_ms.tolist() == [400.0] and peaks.peak.tolist() == [pytest.approx(0.3)]


def test_a_table_written_before_the_guesses_still_reports(tmp_path):
    """A table from before the ``guessed`` column (and ``episode``) reads as one with no guesses."""
    study, _ = _study(tmp_path, _table().drop(columns=["guessed", "episode"]))
    assert cli.main(["forced-response", "report", str(study)]) == 0
    assert pd.read_csv(study / "report" / "peaks.csv").peak.tolist() == [pytest.approx(0.3)]


def _nan_counts(df):
    df.loc[df.correct > 0, "correct"] = np.nan
    return df


def _inf(df):
    df["habitual"] = df["habitual"].astype(float)
    df.loc[0, "habitual"] = np.inf
    return df


@pytest.mark.parametrize("damage, says", [
    (lambda df: df.assign(trials=np.where(df.index < 5, 0, df.trials)), "'trials' must hold integers >= 1"),  # FRREP-8
    (_nan_counts, "'correct' is not a finite number"),  # FRREP-7
    (_inf, "'habitual' is not a finite number"),  # REP-13's forced-response twin
    (lambda df: df.assign(correct=df.correct + np.where(df.index == 4, 5, 0)), "do not sum to 'trials'"),  # FRREP-3
    (lambda df: df.drop(columns=["habit_acted"]), "missing column(s) ['habit_acted']"),  # FRREP-9
    (lambda df: pd.concat([df, df.iloc[:3]], ignore_index=True), "duplicated rows"),
    (lambda df: df.iloc[:0], "no rows"),
    (lambda df: df.assign(habit_acted=df.habit_acted + 1), "do not sum to 'trials'"),
    (lambda df: df.assign(episode=4), "networks from episode(s) [4], not this folder's 5"),  # FR-C6's race result
])
def test_a_damaged_table_is_refused_naming_file_column_and_rows(tmp_path, capsys, damage, says):
    """F4 (forced-response): NaN, inf, zero trials, miscounts, missing columns, duplicates, no rows and a table of
    other networks were reported (a probability of 2.0 reached curves.csv): now refused, nothing written."""
    study, path = _study(tmp_path, damage(_table()))
    assert cli.main(["forced-response", "report", str(study)]) != 0
    err = capsys.readouterr().err
    assert says in err and str(path) in err and "nothing was written" in err
    assert not (study / "report").exists()


def test_a_folder_that_is_not_a_practice_length_is_refused(tmp_path, capsys):
    """FRREP-5: a copy ``tests/p1_old`` ended in "invalid literal for int()"."""
    study, _ = _study(tmp_path, _table(), folder="p5_old")
    with pytest.raises(rep.TestTableError, match="p5_old is not a practice folder"):
        rep.write_report(study)


def test_a_table_from_before_the_episode_column_still_reports(tmp_path):
    study, _ = _study(tmp_path, _table().drop(columns=["episode"]))
    assert (rep.write_report(study) / "peaks.csv").is_file()


# -- reruns of a study ----------------------------------------------------------------------------------------------
def _record(items: list[str]) -> dict:
    return exp.protocol_record(protocol(items), {"cues": {"swap": [[1, 2]]}})


def test_a_rerun_with_other_settings_is_refused_naming_old_and_new(tmp_path):
    """F1: a rerun with more seeds, another timing or trials, or an edited task's cues, mixed or ignored the
    tests silently; each is refused naming the setting with both values."""
    study = tmp_path / "study"
    study.mkdir()
    (study / exp.PROTOCOL_FILE).write_text(json.dumps(_record(SMALL + ["practice=1,2", "agents=ddpg,apac"])))
    for change, says in ((["seeds=2"], "run.seeds: [0] in the study, [0, 1] now"),
                         (["timing.perception_ms=250"], "timing.perception_ms: 400.61 in the study, 250.0 now"),
                         (["default=still"], "default: 'guess' in the study, 'still' now"),
                         (["trials=9"], "trials: 5 in the study, 9 now"),
                         (["agents=ddpg"], "agents: ['ddpg', 'apac'] in the study, ['ddpg'] now"),
                         (["practice=1"], "practice: [1, 2] in the study, [1] now")):
        with pytest.raises(ValueError, match=re.escape(says)):
            exp.check_rerun(study, _record(SMALL + ["practice=1,2", "agents=ddpg,apac"] + change))
    edited = exp.protocol_record(protocol(SMALL + ["practice=1,2", "agents=ddpg,apac"]), {"cues": {"swap": [[0, 3]]}})
    with pytest.raises(ValueError, match=r"task_spec.cues.swap: \[\[1, 2\]\] in the study, \[\[0, 3\]\] now"):
        exp.check_rerun(study, edited)
    assert exp.check_rerun(study, _record(SMALL + ["practice=1,2", "agents=ddpg,apac"])) == []


def test_a_study_made_before_an_agent_field_was_added_resumes(tmp_path):
    """A protocol.json written before ``AgentConfig.frozen`` existed (issue 44) resumes: a field added since takes
    the value its release behaved as (config.ADDED); a changed field is still refused."""
    from apac_mj.config import ADDED

    study = tmp_path / "study"
    study.mkdir()
    record = _record(SMALL + ["practice=1,2"])
    old = json.loads(json.dumps(record))
    for name in ("frozen", "frozen_from_episode"):
        del old["run"]["agent"][name]
    (study / exp.PROTOCOL_FILE).write_text(json.dumps(old))
    assert exp.check_rerun(study, record) == []
    assert {"frozen": [], "frozen_from_episode": 0}.items() <= ADDED.items()
    lesioned = json.loads(json.dumps(record))
    lesioned["run"]["agent"]["frozen"] = ["habit"]
    with pytest.raises(ValueError, match=re.escape("run.agent.frozen: [] in the study, ['habit'] now")):
        exp.check_rerun(study, lesioned)


def test_kinds_and_longer_practice_extend_a_study_and_say_so(tmp_path):
    study = tmp_path / "study"
    study.mkdir()
    (study / exp.PROTOCOL_FILE).write_text(json.dumps(_record(SMALL + ["practice=1,3"])))
    said = exp.check_rerun(study, _record(SMALL + ["practice=1,3,5", "agents=ddpg,spac"]))
    assert said == [f"extending {study}: adding agent kind(s) spac",
                    f"extending {study}: adding practice length(s) 5 episodes"]
    with pytest.raises(ValueError, match="lengths above 3 may be added"):  # a run cannot be shortened to 2
        exp.check_rerun(study, _record(SMALL + ["practice=1,2,3"]))


def _fake_study(tmp_path, items: list[str]):
    """A study whose protocol.json is ``items``' and whose only test (p1, ddpg) exists: a rerun trains nothing."""
    study = tmp_path / "study"
    (study / "tests" / "p1").mkdir(parents=True)
    proto = protocol(items)
    from apac_mj.run.build import task_record
    from apac_mj.suite import spec_for

    record = exp.protocol_record(proto, task_record(proto.run, spec_for(proto.run)).spec)
    (study / exp.PROTOCOL_FILE).write_text(json.dumps(record, indent=1) + "\n")
    _table().to_parquet(exp.test_path(study, 1, "ddpg"))
    return study


def test_a_changed_rerun_of_a_study_writes_nothing(tmp_path):
    """FR-R2: ``--set seeds=2`` over a finished one-seed study exited 0 and rewrote protocol.json."""
    study = _fake_study(tmp_path, SMALL)
    before = (study / exp.PROTOCOL_FILE).read_text()
    with pytest.raises(ValueError, match=r"run.seeds: \[0\] in the study, \[0, 1\] now"):
        exp.run(study, protocol(SMALL[1:] + ["seeds=2"]), progress=False, say=lambda s: None)
    assert (study / exp.PROTOCOL_FILE).read_text() == before
    said = []
    exp.run(study, protocol(SMALL), progress=False, say=said.append)  # the same settings: resumes, nothing to do
    assert said == [] and (study / exp.PROTOCOL_FILE).read_text() == before


def test_tests_without_a_protocol_are_refused(tmp_path):
    study = _fake_study(tmp_path, SMALL)
    (study / exp.PROTOCOL_FILE).unlink()
    with pytest.raises(ValueError, match="no protocol.json"):
        exp.run(study, protocol(SMALL), progress=False)
    assert not (study / exp.PROTOCOL_FILE).exists()


def test_one_writer_per_study(tmp_path):
    """F3: two resumes of one study raced (the slower one overwrote a test from the run the other extended);
    a second writer is refused, naming the first's PID, and writes nothing."""
    from apac_mj.util.lock import DirectoryLocked

    study = _fake_study(tmp_path, SMALL)
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from apac_mj.util.lock import locked\n"
                               f"with locked({str(study)!r}):\n print('held', flush=True); time.sleep(60)"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        before = (study / exp.PROTOCOL_FILE).stat().st_mtime_ns
        time.sleep(0.01)
        with pytest.raises(DirectoryLocked, match=f"PID {holder.pid}"):
            exp.run(study, protocol(SMALL), progress=False)
        assert (study / exp.PROTOCOL_FILE).stat().st_mtime_ns == before
    finally:
        holder.kill()
        holder.wait()


def test_a_killed_writers_temporary_table_is_removed_on_resume(tmp_path):
    """The tables are written atomically under a name of the writer's own (PID): what a killed one left goes."""
    study = _fake_study(tmp_path, SMALL)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = study / "tests" / "p1" / f".ddpg.parquet.{int(dead.stdout)}.x1y2z3w4.tmp"
    stale.write_bytes(b"half")
    said = []
    exp.run(study, protocol(SMALL), progress=False, say=said.append)
    assert not stale.exists() and said == [f"removed {stale}, a temporary file a killed writer left"]
