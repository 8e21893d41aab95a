"""The cued task, the habit's view of it, and the forced-response test's timing (docs/forced_response.md)."""
import dataclasses

import numpy as np
import pytest
import torch

from apac_mj import suite
from apac_mj.config import AgentConfig
from apac_mj.layout import Sizes
from apac_mj.run import forced_response as fr
from apac_mj.suite.task_spec import Cues, TaskSpecError, load_task, parse_task

CUED = load_task("cued_targets")


# -- the cued task ------------------------------------------------------------------------------------------------
def test_the_cue_is_observed_and_its_target_is_the_cues_under_the_mapping_in_force():
    env = suite.load(task_name="cued_targets")
    seen = set()
    for _ in range(40):
        obs = env.reset().observation
        cue = int(np.argmax(obs["cue"]))
        assert obs["cue"].sum() == 1 and cue == env.task.cue
        np.testing.assert_allclose(obs["target"], CUED.cues.targets[cue])
        seen.add(cue)
    assert seen == {0, 1, 2, 3}
    env.task.set_mapping_override(True)
    env.task.set_cue_override(1)
    obs = env.reset().observation
    np.testing.assert_allclose(obs["target"], CUED.cues.targets[2])  # cue 1 now shows cue 2's old target
    np.testing.assert_allclose(obs["cue"], [0, 1, 0, 0])


def test_the_remap_starts_at_its_training_episode_after_babbling():
    from apac_mj.suite.vec_env import VecEnv

    spec = CUED.replace(cues={"targets": [list(t) for t in CUED.cues.targets], "swap": [[1, 2]], "remap_episode": 2})
    env = VecEnv(spec, [0], episode_offset=3)
    env.set_cue_override([1])
    targets = []
    for _ in range(6):  # episodes -3..2 as the run counts them
        env.reset()
        targets.append(env.targets()[0].tolist())
    assert targets[:5] == [list(CUED.cues.targets[1])] * 5 and targets[5] == list(CUED.cues.targets[2])


def test_the_cue_and_the_overrides_survive_a_checkpoint():
    from apac_mj.suite.vec_env import VecEnv

    a, b = VecEnv(CUED, [0, 1]), VecEnv(CUED, [0, 1])
    a.set_mapping_override(True)
    a.set_cue_override([2, 3])
    a.reset()
    b.set_state(a.get_state())
    assert b.cues().tolist() == [2, 3]
    b.reset()
    a.reset()
    np.testing.assert_allclose(b.targets(), a.targets())
    assert b.cues().tolist() == [2, 3]


@pytest.mark.parametrize("cues, problem", [
    ({"targets": [[24, 22]]}, "2 to"),
    ({"targets": [[24, 22], [29.9, 29.9]]}, "out of the arm's reach"),
    ({"targets": [[24, 22], [24.5, 22]]}, "apart"),
    ({"targets": [[24, 22], [8, 24]], "swap": [[0, 0]]}, "two different cues"),
    ({"targets": [[24, 22], [8, 24], [5.5, 15.5]], "swap": [[0, 1], [1, 2]]}, "one pair at most"),
    ({"targets": [[24, 22], [8, 24]], "remap_episode": -1}, "remap_episode"),
    ({"targets": [[24, 22], [8, 24]], "cue": 1}, "unknown key"),
])
def test_bad_cue_tables_are_refused_naming_the_problem(cues, problem):
    with pytest.raises(TaskSpecError, match=problem):
        parse_task({"cues": cues}, "bad")


def test_a_cued_task_may_not_draw_static_targets():
    with pytest.raises(TaskSpecError, match="changing"):
        parse_task({"target": {"mode": "static"}, "cues": {"targets": [[24, 22], [8, 24]]}}, "bad")


def test_the_mapping_swaps_only_the_named_cues():
    cues = Cues(targets=((1, 1), (2, 2), (3, 3), (4, 4)), swap=((1, 2),))
    np.testing.assert_array_equal(cues.mapping(True), [[1, 1], [3, 3], [2, 2], [4, 4]])
    np.testing.assert_array_equal(cues.mapping(False), [[1, 1], [2, 2], [3, 3], [4, 4]])
    assert cues.remapped == (1, 2) and not cues.remapped_at(10) and Cues(cues.targets, cues.swap, 5).remapped_at(5)


# -- the agent on a cued task -------------------------------------------------------------------------------------
def _cued_agent():
    from apac_mj.agent.agent import Agent

    env = suite.load(task_name="cued_targets")
    sizes = Sizes.from_specs(env.observation_spec(), env.action_spec())
    return Agent(AgentConfig(kind="apac"), seeds=[0, 1], sizes=sizes), sizes


def _state(target, cue):
    s = torch.zeros(2, 10)
    s[:, 0:2] = torch.tensor([12.0, 15.0])
    s[:, 2:4] = torch.tensor([20.0, 15.0])
    s[:, 4:6] = torch.tensor(target, dtype=torch.float32)
    s[:, 6 + cue] = 1.0
    return s


def test_sizes_place_the_cue_after_the_motion():
    _, sizes = _cued_agent()
    assert (sizes.cue_dim, sizes.motion_dim, sizes.cue, sizes.motion) == (4, 0, slice(6, 10), slice(6, 6))


def test_the_habit_reads_the_cue_not_the_target_and_the_planner_the_target_not_the_cue():
    agent, _ = _cued_agent()
    a, b = _state([24.0, 22.0], 0), _state([8.0, 24.0], 0)  # same cue, another target
    torch.testing.assert_close(agent.actor_action(a), agent.actor_action(b))
    torch.testing.assert_close(agent.value(a[:, None]), agent.value(b[:, None]))
    assert not torch.allclose(agent.inverse_action(a), agent.inverse_action(b))
    c = _state([24.0, 22.0], 2)  # same target, another cue
    assert not torch.allclose(agent.actor_action(a), agent.actor_action(c))
    torch.testing.assert_close(agent.inverse_action(a), agent.inverse_action(c))
    action = torch.full((2, 2), 10.0)
    torch.testing.assert_close(agent.predict_arm(a, action), agent.predict_arm(c, action))


def test_the_imagined_state_keeps_the_cue():
    agent, _ = _cued_agent()
    s = _state([24.0, 22.0], 3)
    nxt = agent.imagine(s[:, None], torch.full((2, 1, 2), 5.0))[:, 0]
    torch.testing.assert_close(nxt[:, 6:], s[:, 6:])
    torch.testing.assert_close(nxt[:, 4:6], s[:, 4:6])


# -- timing -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("field, value", [("habit_latency_ms", -1.0), ("perception_ms", float("nan")),
                                          ("latency_sd_ms", float("inf")), ("mpc_iteration_ms", 0.0),
                                          ("step_ms", 0.0), ("habit_latency_ms", True)])
def test_invalid_timing_is_refused(field, value):
    with pytest.raises(ValueError, match=field):
        fr.Timing(**{field: value})


def test_a_deadline_shorter_than_a_step_is_refused():
    with pytest.raises(ValueError, match="shorter than a step"):
        fr.Timing(step_ms=50).check_deadlines([100, 40])
    with pytest.raises(ValueError, match="finite"):
        fr.Timing().check_deadlines([float("nan")])


def test_invalid_settings_are_refused_before_anything_is_written(tmp_path, capsys):
    from apac_mj.cli import main

    out = tmp_path / "study"
    for bad in ("timing.habit_latency_ms=-5", "timing.model_pass_ms=nan", "prep_times_ms=10,500", "trials=0",
                "default=wait"):
        assert main(["forced-response", "run", "--out", str(out), "--set", bad]) != 0
        assert not out.exists()
    err = capsys.readouterr().err
    assert "habit_latency_ms" in err and "default must be one of ('guess', 'still'), got 'wait'" in err


def test_classify_names_correct_habitual_other_and_timeout():
    cues = Cues(targets=((24, 22), (17.5, 27), (8, 24), (5.5, 15.5)), swap=((1, 2),))
    now, before, start = cues.mapping(True), cues.mapping(False), np.array([12.0, 15.0])
    hands = np.array([now[1] + 0.3, before[1], [20.0, 10.0], start + 0.2])
    assert fr.classify(hands, start, now, before, 1, 3.0).tolist() == [0, 1, 2, 3]
    # an unchanged cue has no habitual error: its old target is its target
    assert fr.classify(np.array([now[0], now[3]]), start, now, before, 0, 3.0).tolist() == [0, 2]


def test_a_guess_of_each_target_is_correct_habitual_or_other_by_the_cues_mapping():
    cues = Cues(targets=((24, 22), (17.5, 27), (8, 24), (5.5, 15.5)), swap=((1, 2),))
    g = fr.guesses(cues.mapping(True), cues.mapping(False))
    # guess j aims at targets_now[j]: cue c's own is correct; cue 1's old target is now cue 2's (habitual), and
    # cue 2's cue 1's; unchanged cues have no habitual guess
    assert g.tolist() == [[0, 2, 2, 2], [2, 0, 1, 2], [2, 1, 0, 2], [2, 2, 2, 0]]


def _candidates(habit_outcome, plan_outcomes, rule_habit, rule_iterations=None, guess=(0, 1, 2, 2)):
    E, n, R = 1, 1, 1
    K = len(plan_outcomes)
    return fr.Candidates(np.full((E, n, R), habit_outcome), np.array(plan_outcomes).reshape(E, n, R, K),
                         np.full((E, n, R), 3), np.full((E, n, R), rule_habit),
                         np.full((E, n, R), rule_iterations or K), {}, np.array([guess]))


def _sched(K, rule_ms=0.0, iteration=100.0, setup=0.0, after_habit=False, uses_habit=True, uses_planner=True):
    """Habit ready at 300 ms, a planner that does not wait for it starting at 300 ms."""
    return fr.Schedule(300.0, 300.0, rule_ms, setup + iteration * np.arange(1, K + 1), after_habit, uses_habit,
                       uses_planner)


def _rates(c, times, sched=None, default="still", trials=10):
    sched = _sched(c.plan.shape[-1]) if sched is None else sched
    counts = fr.simulate(c, sched, 0.0, times, trials, 0, default)
    return counts["outcomes"][0, 0] / trials, counts["acted"][0, 0] / trials


def test_the_habit_acts_once_ready_and_the_plan_replaces_it_once_a_plan_is_ready():
    c = _candidates(1, [2, 0], rule_habit=False)  # habit: the old target; plan: other after 1, correct after 2
    out, acted = _rates(c, [200, 350, 450, 550])
    assert out[:, fr.OUTCOMES.index("timeout")].tolist() == [1, 0, 0, 0]   # nothing ready
    assert out[:, fr.OUTCOMES.index("habitual")].tolist() == [0, 1, 0, 0]  # only the habit ready
    assert out[:, fr.OUTCOMES.index("other")].tolist() == [0, 0, 1, 0]     # one iteration done
    assert out[:, fr.OUTCOMES.index("correct")].tolist() == [0, 0, 0, 1]   # two
    assert acted[:, fr.ACTORS.index("planner")].tolist() == [0, 0, 1, 1]


def test_a_plan_that_needs_the_habits_rollout_is_never_ready_before_the_habit():
    """The MPC plan's pool holds the habit's sequence: its iterations count from the habit's readiness."""
    c = _candidates(1, [0], rule_habit=False)
    sched = _sched(1, iteration=30.0, after_habit=True)
    H, S = np.array([500.0, 200.0]), np.array([200.0, 500.0])
    plan, habit, _ = fr.choose(480.0, H, S, np.array([False, False]), np.array([1, 1]), sched)
    assert plan.tolist() == [False, True] and habit.tolist() == [False, False]  # 1st: habit not ready at 480
    free = _sched(1, iteration=30.0)
    assert fr.choose(480.0, H, S, np.array([False, False]), np.array([1, 1]), free)[0].tolist() == [True, False]
    assert _rates(c, [320, 340], sched)[0][:, fr.OUTCOMES.index("correct")].tolist() == [0, 1]


def test_a_rule_that_keeps_the_habit_keeps_it_and_a_rule_not_ready_defers_to_the_habit():
    keep = _candidates(1, [0], rule_habit=True)
    assert _rates(keep, [350, 900])[0][:, fr.OUTCOMES.index("habitual")].tolist() == [1, 1]
    slow = _candidates(1, [0], rule_habit=False)  # the rule's inputs are ready at 600 ms
    assert _rates(slow, [450, 650], _sched(1, rule_ms=300.0))[0][:, fr.OUTCOMES.index("correct")].tolist() == [0, 1]


def test_habit_only_and_planning_only_kinds():
    c = _candidates(1, [0], rule_habit=True)
    ddpg = _rates(c, [200, 500, 1000], _sched(1, uses_planner=False))[0]
    assert ddpg[:, fr.OUTCOMES.index("habitual")].tolist() == [0, 1, 1]
    spac = _rates(c, [200, 350, 1000], _sched(1, uses_habit=False))[0]
    assert spac[:, fr.OUTCOMES.index("timeout")].tolist() == [1, 1, 0]
    assert spac[:, fr.OUTCOMES.index("habitual")].tolist() == [0, 0, 0]


def test_the_graded_rule_gets_no_more_iterations_than_it_granted():
    c = _candidates(1, [2, 2, 0, 0], rule_habit=False, rule_iterations=2)
    out, _ = _rates(c, [1000])
    assert out[0, fr.OUTCOMES.index("other")] == 1  # 4 iterations were ready, the rule granted 2


def test_latency_spread_smooths_the_curve():
    c = _candidates(1, [0], rule_habit=False)
    counts = fr.simulate(c, _sched(1), 50.0, [300], 2000, 0, "still")["outcomes"][0, 0, 0] / 2000
    assert 0.4 < counts[fr.OUTCOMES.index("timeout")] < 0.6  # the habit ready in half the trials at its mean


def test_with_nothing_ready_the_agent_guesses_a_uniformly_drawn_cued_target():
    """Guesses of 4 targets, one correct, one habitual, two other: 1/4, 1/4, 1/2, and the table says so."""
    c = _candidates(1, [0], rule_habit=False, guess=(0, 1, 2, 2))
    n = 8000
    counts = fr.simulate(c, _sched(1), 0.0, [100, 1000], n, 0, "guess")
    early = counts["outcomes"][0, 0, 0] / n
    np.testing.assert_allclose(early, [0.25, 0.25, 0.5, 0.0], atol=4 * np.sqrt(0.25 / n))
    assert counts["acted"][0, 0, 0, fr.ACTORS.index("default")] == counts["guessed"][0, 0, 0] == n
    assert counts["guessed"][0, 0, 1] == 0 and counts["outcomes"][0, 0, 1, 0] == n  # the plan, at 1000 ms
    per_target = np.bincount(np.random.default_rng(0).integers(0, 4, n), minlength=4)  # the same stream's draws
    assert per_target.min() > 0.9 * n / 4
    still = fr.simulate(c, _sched(1), 0.0, [100], n, 0, "still")
    assert still["outcomes"][0, 0, 0, fr.OUTCOMES.index("timeout")] == n and still["guessed"].sum() == 0


def test_the_guesses_are_the_tests_random_stream_same_seed_same_guesses():
    c = _candidates(1, [0], rule_habit=False, guess=(0, 1, 2, 3))
    a, b = (fr.simulate(c, _sched(1), 0.0, [100], 50, 7, "guess")["outcomes"] for _ in range(2))
    other = fr.simulate(c, _sched(1), 0.0, [100], 50, 8, "guess")["outcomes"]
    assert (a == b).all() and not (a == other).all()


def test_the_schedule_follows_the_counts_at_the_timings_prices():
    """APAC-VOC at the defaults: habit at perception + an actor pass, the rule after the probe's rest, the plan
    after the habit's rollout; SPAC's inverse model one pass after perception, not waiting for a habit."""
    from apac_mj.run import timing as tm

    t = fr.Timing()
    voc = fr.schedule("apac_voc", AgentConfig(kind="apac_voc"), t, 4)
    assert voc.habit_ms == t.perception_ms + t.actor_pass_ms and voc.start_ms == t.perception_ms
    assert voc.rule_ms == pytest.approx(4 * t.actor_pass_ms + 4 * t.model_pass_ms + t.critic_pass_ms)
    assert voc.after_habit and voc.uses_habit and voc.uses_planner
    assert voc.plan_ms.tolist() == pytest.approx(
        [tm.decision_ms(tm.mpc_counts(AgentConfig().params["mpc"], k) - tm.HABIT, t) for k in (1, 2, 3, 4)])
    assert voc.plan_ms[0] > voc.rule_ms  # the plan's pool needs the probe's rollout: never before the rule
    told = fr.schedule("apac_voc", AgentConfig(kind="apac_voc"), t, 4, cues=4)
    extra = tm.decision_ms(tm.told_counts(4, 4), t)
    assert told.rule_ms == pytest.approx(voc.rule_ms + extra) and told.plan_ms == pytest.approx(voc.plan_ms + extra)
    spac = fr.schedule("spac", AgentConfig(kind="spac"), t, 1, cues=4)
    assert not spac.after_habit and spac.plan_ms.tolist() == [t.inverse_pass_ms] and not spac.uses_habit
    assert spac.rule_ms == 0.0
    ddpg = fr.schedule("ddpg", AgentConfig(kind="ddpg"), t, 1)
    assert not ddpg.uses_planner and ddpg.uses_habit


def test_what_the_agent_learned_moves_the_curve_at_fixed_timing():
    """Issue 42 item 4: one Timing, one schedule (APAC-VOC's), three agents that learned differently: a model
    that plans the told target in one iteration, one that needs three, and a rule that keeps a wrong habit."""
    sched = fr.schedule("apac_voc", AgentConfig(kind="apac_voc"), fr.Timing(), 4)
    H = sched.habit_ms
    times = [H + (sched.plan_ms[0] + sched.plan_ms[1]) / 2, H + sched.plan_ms[2] + 1.0]
    quick = _candidates(1, [0, 0, 0, 0], rule_habit=False)
    slow = _candidates(1, [2, 2, 0, 0], rule_habit=False)
    keeps = _candidates(1, [0, 0, 0, 0], rule_habit=True)
    correct, habitual = fr.OUTCOMES.index("correct"), fr.OUTCOMES.index("habitual")
    assert _rates(quick, times, sched)[0][:, correct].tolist() == [1, 1]
    assert _rates(slow, times, sched)[0][:, correct].tolist() == [0, 1]  # its P(correct) rises 2 iterations later
    assert _rates(keeps, times, sched)[0][:, habitual].tolist() == [1, 1]  # and never falls


def test_imagined_delta_is_the_td_error_of_the_forward_models_transition():
    agent, _ = _cued_agent()
    s = _state([24.0, 22.0], 0)
    a = torch.full((2, 2), 20.0)
    nxt = agent.imagine(s[:, None], agent.executable(a, s)[:, None])[:, 0]
    d = torch.linalg.vector_norm(nxt[:, :2] - nxt[:, 4:6], dim=1)
    expected = agent.td_error(s, agent.executable(a, s), -d, nxt, (d <= 0.5).float())
    torch.testing.assert_close(fr.imagined_delta(agent, s, a, 0.5), expected)
    assert dataclasses.is_dataclass(fr.Timing())


@pytest.fixture(scope="module")
def trained_runs(tmp_path_factory):
    """Tiny DDPG and APAC-VOC runs on the cued task (2 seeds, 3 episodes): the protocol's inputs."""
    from conftest import TINY, TINY_MPC

    from apac_mj.config import TrainConfig
    from apac_mj.run.trainer import train

    root = tmp_path_factory.mktemp("fr")
    runs = {}
    for kind in ("ddpg", "apac_voc"):
        cfg = TrainConfig(task="cued_targets", seeds=(0, 1), episodes=3, checkpoint_every=3,
                          agent=AgentConfig(kind=kind, **{**TINY, "planning_episodes": 1}, params=TINY_MPC))
        train(cfg, root / "runs" / kind, progress=False)
        runs[kind] = root / "runs" / kind
    return root, runs


def test_the_command_line_tests_reports_and_records_a_trained_run(trained_runs, capsys):
    """``forced-response test`` writes every column for each variant, cue and preparation time, each trial
    counted once; ``report`` reads the tests back; ``record`` writes a recording and refuses to overwrite it."""
    import pandas as pd

    from apac_mj import cli

    root, runs = trained_runs
    prep = [100.0, 400.0, 900.0]
    for kind, run in runs.items():
        out = root / "tests" / "p3" / f"{kind}.parquet"
        out.parent.mkdir(parents=True, exist_ok=True)
        assert cli.main(["forced-response", "test", str(run), "--out", str(out), "--set", "trials=7",
                         "--set", "repeats=1", "--set", "prep_times_ms=100,400,900"]) == 0
        df = pd.read_parquet(out)
        assert set(fr.COLUMNS) <= set(df.columns)
        assert set(df.variant) == {kind} and sorted(df.prep_ms.unique()) == prep  # neither has a delta rule
        assert sorted(df.cue.unique()) == [0, 1, 2, 3] and sorted(df.seed.unique()) == [0, 1]
        assert (df[list(fr.OUTCOMES)].sum(axis=1) == 7).all()
        early = df[df.prep_ms == 100.0]  # nothing is ready at 100 ms: a guess, and the table says so
        assert (early.guessed == 7).all() and (early.default_acted == 7).all() and (early.timeout == 0).all()
        if kind == "ddpg":
            assert (df.remapped == df.cue.isin([1, 2])).all()
    report = root / "report"
    assert cli.main(["forced-response", "report", str(root)]) == 0
    peaks = pd.read_csv(report / "peaks.csv")
    assert set(peaks.variant) == {"ddpg", "apac_voc"} and set(peaks.practice) == {3}
    assert (report / "forced_response.png").stat().st_size > 10_000
    rrd = root / "trials.rrd"
    argv = ["forced-response", "record", str(runs["apac_voc"]), "--out", str(rrd), "--prep-times", "100,900"]
    assert cli.main(argv) == 0
    said = capsys.readouterr().out
    assert "deadline 100 ms" in said and "nothing is ready: a guess, target " in said and "deadline 900 ms" in said
    assert rrd.stat().st_size > 1000
    size = rrd.stat().st_size
    assert cli.main(argv) != 0 and rrd.stat().st_size == size
    assert "exists" in capsys.readouterr().err


def _hold_lock(directory):
    """A process holding ``directory``'s lock (what a training does), started and holding."""
    import subprocess
    import sys

    holder = subprocess.Popen([sys.executable, "-c", "import time; from apac_mj.util.lock import locked\n"
                               f"with locked({str(directory)!r}):\n print('held', flush=True); time.sleep(120)"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_run_being_trained_is_refused_and_an_unfinished_one_is_tested_with_its_episode(trained_runs, tmp_path,
                                                                                         capsys):
    """F2 (FR-C2, FR-C3): ``test`` and ``record`` read a run still training, or killed, without a word, and the
    table did not say which episode the networks were from."""
    import json
    import shutil

    import pandas as pd

    from apac_mj import cli

    _, runs = trained_runs
    small = ["--set", "trials=2", "--set", "repeats=1", "--set", "prep_times_ms=400"]
    holder = _hold_lock(runs["ddpg"])
    try:
        for argv in (["test", str(runs["ddpg"]), "--out", str(tmp_path / "t.parquet"), *small],
                     ["record", str(runs["ddpg"]), "--out", str(tmp_path / "t.rrd"), "--prep-times", "400"]):
            assert cli.main(["forced-response", *argv]) != 0
            assert f"PID {holder.pid}" in capsys.readouterr().err
        assert not list(tmp_path.iterdir())
    finally:
        holder.kill()
        holder.wait()
    killed = tmp_path / "killed"  # killed while extending from 3 to 5 episodes, after its last checkpoint
    shutil.copytree(runs["ddpg"], killed)
    (killed / "DONE").unlink()
    config = json.loads((killed / "config.json").read_text())
    (killed / "config.json").write_text(json.dumps({**config, "episodes": 5}))
    for run, warned in ((runs["ddpg"], False), (killed, True)):
        out = tmp_path / f"{run.name}.parquet"
        assert cli.main(["forced-response", "test", str(run), "--out", str(out), *small]) == 0
        assert pd.read_parquet(out).episode.unique().tolist() == [3]
        err = capsys.readouterr().err
        assert ("is not finished" in err and "from episode 3 of 5" in err) == warned


def test_record_labels_each_trial_and_says_what_the_kind_has(trained_runs, tmp_path, capsys):
    """Item 7 and F14: every trial was "episode 0 starts", DDPG's caption spoke of its planner, and an unchanged
    cue was called "(remapped)"."""
    from apac_mj import cli

    _, runs = trained_runs
    assert cli.main(["forced-response", "record", str(runs["ddpg"]), "--out", str(tmp_path / "d.rrd"),
                     "--prep-times", "100,900", "--cue", "0"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[0].startswith("trial 1 of 2 (deadline 100 ms, cue 0 (unchanged)): deadline 100 ms: nothing is ready")
    assert said[1].startswith("trial 2 of 2 (deadline 900 ms, cue 0 (unchanged)): deadline 900 ms: the habit acts")
    assert all("no planner (DDPG has none)" in line and "remapped" not in line for line in said[:2])
    assert cli.main(["forced-response", "record", str(runs["apac_voc"]), "--out", str(tmp_path / "v.rrd"),
                     "--prep-times", "900"]) == 0
    said = capsys.readouterr().out
    assert "trial 1 of 1 (deadline 900 ms, cue 1 (remapped))" in said and "iteration(s) by the deadline" in said


def test_the_frozen_grid_tests_refuse_a_cued_task(trained_runs):
    """``evaluate`` (the paper's angle grid) has no cue to show: it points to the forced-response test."""
    from apac_mj.run.evaluate import evaluate

    _, runs = trained_runs
    with pytest.raises(ValueError, match="forced-response test"):
        evaluate(runs["ddpg"])


def _tests_table(habitual_by_time: dict[float, list[int]], correct_by_time: dict[float, list[int]], trials: int = 10):
    """A test table of 3 seeds, one remapped and one unchanged cue: the remapped cue's habitual and correct
    counts per time and seed as given (the rest time-outs), the unchanged cue all correct."""
    import pandas as pd

    rows = []
    for t, habitual in habitual_by_time.items():
        for seed, (h, c) in enumerate(zip(habitual, correct_by_time[t])):
            for cue, remapped in ((1, True), (0, False)):
                hh, cc = (h, c) if remapped else (0, trials)
                rows.append(dict(practice=5, variant="apac_voc", seed=seed, cue=cue, remapped=remapped, prep_ms=t,
                                 trials=trials, correct=cc, habitual=hh, other=0, timeout=trials - hh - cc,
                                 habit_acted=hh, planner_acted=cc, default_acted=trials - hh - cc, guessed=0))
    return pd.DataFrame(rows)


def test_the_peak_table_finds_the_peak_its_ends_and_when_half_the_responses_are_correct():
    """Hand-computed: the habitual peak at 400 ms (mean 0.6 over seeds) above both ends (0), separated; the
    remapped P(correct) passes 0.5 halfway between 400 ms (0.2) and 1000 ms (0.8): 700 ms."""
    from apac_mj.report import forced_response as rep

    table = _tests_table({100.0: [0, 0, 0], 400.0: [5, 6, 7], 1000.0: [0, 0, 0]},
                         {100.0: [0, 0, 0], 400.0: [2, 2, 2], 1000.0: [8, 8, 8]})
    row = rep.peaks(rep.per_seed(table)).iloc[0]
    assert row.peak_ms == 400.0 and row.peak == pytest.approx(0.6)
    assert 0 < row.peak_lo < 0.6 < row.peak_hi <= 1  # issue 41: the measured (wider) interval, inside [0, 1]
    assert row.short == 0.0 and row.long == 0.0 and bool(row.separated)
    assert row.t50_correct_remapped_ms == pytest.approx(700.0) and row.t50_correct_unchanged_ms == 100.0
    assert row.remapped_correct_long == pytest.approx(0.8) and row.unchanged_error_peak == 0.0
    flat = _tests_table({100.0: [6, 6, 6], 400.0: [6, 6, 6], 1000.0: [6, 6, 6]},
                        {100.0: [0, 0, 0], 400.0: [0, 0, 0], 1000.0: [0, 0, 0]})
    row = rep.peaks(rep.per_seed(flat)).iloc[0]
    assert not bool(row.separated) and np.isnan(row.t50_correct_remapped_ms)


def test_variants_follow_the_kinds_rule_not_its_name():
    """A kind whose rule is the delta rule (any name) is also tested on the imagined delta; a rule reading the
    habit's probe (wrapped or not) is charged the probe's model passes, the others nothing."""
    from apac_mj import kinds
    from apac_mj.agent.arbitration import DeltaArbitrator
    from apac_mj.run import variants as vn
    from apac_mj.run.timing import Timing

    kinds.register(kinds.AgentKind("delta_renamed", "Renamed", "k", arbitrator=lambda cfg: DeltaArbitrator(cfg)))
    try:
        assert fr.variants(AgentConfig(kind="delta_renamed")) == ("delta_renamed", "delta_renamed_imagined")
        assert vn.base_kind("delta_renamed_imagined") == "delta_renamed"
        assert vn.label("delta_renamed_imagined") == "Renamed, delta of the imagined transition"
        assert vn.label("delta_renamed", fr.variants(AgentConfig(kind="delta_renamed"))) == "Renamed, paper's delta rule"
    finally:
        kinds.unregister("delta_renamed")
    spac, ddpg, voc = (AgentConfig(kind=k) for k in ("spac", "ddpg", "apac_voc"))
    assert fr.variants(spac) == ("spac",) and fr.variants(voc) == ("apac_voc",)
    t = Timing(actor_pass_ms=1.0, critic_pass_ms=10.0, model_pass_ms=100.0, inverse_pass_ms=1000.0, row_ms=0.5)
    assert voc.params["mpc"].horizon == 4
    # the probe beyond the habit's own pass: 4 actor, 4 model passes and the terminal critic
    assert fr.rule_ms("apac_voc", voc, t) == 4 * 1 + 4 * 100 + 10
    assert fr.rule_ms("spac", spac, t) == fr.rule_ms("ddpg", ddpg, t) == 0.0
    assert fr.rule_ms("apac", AgentConfig(kind="apac"), t) == 0.0
    assert fr.rule_ms("apac_imagined", AgentConfig(kind="apac"), t) == 1 + 2 * 10 + 100  # pi', Q', Q, the model
    seen = AgentConfig(kind="apac_vision")
    seen.params["vision_aware"] = dataclasses.replace(seen.params["vision_aware"], base="apac_voc")
    assert kinds.arbitrator_for(seen).needs_habit_probe
    assert not kinds.arbitrator_for(AgentConfig(kind="apac_vision")).needs_habit_probe
    assert vn.label("ddpg") == "DDPG (habit only)" and vn.label("spac") == "SPAC (planning only)"
    assert vn.order(["apac_voc", "apac_imagined", "ddpg", "apac"]) == ["ddpg", "apac", "apac_imagined", "apac_voc"]
