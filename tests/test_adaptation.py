"""The adaptation study (issue 44 item 3): the per-trial table from a run's metrics, the signatures with known
answers (and the two-state model's: spontaneous recovery, after-effects opposite the field), the protocol's
refusals before anything is written, and the command."""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from apac_mj.experiments import adaptation as ad
from apac_mj.report import two_state as ts


def _metrics(rows: list[dict]) -> pd.DataFrame:
    base = {"seed": 0, "phase": "train", "trial_block": "adaptation", "trial_field_b": 100.0, "lateral_error": 1.0,
            "channel_force_at_peak_speed": math.nan, "peak_speed": 40.0, "habit_actions": 3, "planning_actions": 1}
    return pd.DataFrame([{**base, "episode": i, **r} for i, r in enumerate(rows)])


def test_trial_table_adaptation_and_signs_by_hand():
    m = _metrics([{"trial_type": "field"},
                  # the agent pushes -2 N against the channel at 4 cm/s (0.04 m/s): 2 / (100 * 0.04) = 0.5
                  {"trial_type": "channel", "trial_field_b": 0.0, "channel_force_at_peak_speed": -2.0,
                   "peak_speed": 4.0, "lateral_error": 0.01},
                  {"trial_type": "catch", "trial_field_b": 0.0, "lateral_error": -0.7, "habit_actions": 0,
                   "planning_actions": 0},
                  {"trial_type": "field", "phase": "babbling"},
                  {"trial_type": "channel", "trial_field_b": 0.0, "channel_force_at_peak_speed": 0.0,
                   "peak_speed": 0.0}])  # a hand that never moved: no adaptation to measure
    t = ad.trial_table(m, 100.0)
    assert list(t.columns) == list(ad.TRIAL_COLUMNS) and len(t) == 4  # babbling rows left out
    np.testing.assert_allclose(t["adaptation"], [np.nan, 0.5, np.nan, np.nan])
    np.testing.assert_allclose(t["lateral_error"], [1.0, np.nan, -0.7, np.nan])
    np.testing.assert_allclose(t["field"], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(t["habit_share"], [0.75, 0.75, np.nan, 0.75])
    assert t["channel"].tolist() == [False, True, False, True] and t["catch"].tolist() == [False, False, True, False]
    # a protocol whose adaptation field is b < 0: + still means "where the adaptation field pushes"
    t_neg = ad.trial_table(m.assign(trial_field_b=-m["trial_field_b"]), -100.0)
    np.testing.assert_allclose(t_neg["lateral_error"], [-1.0, np.nan, 0.7, np.nan])
    np.testing.assert_allclose(t_neg["adaptation"], [np.nan, -0.5, np.nan, np.nan])
    with pytest.raises(ValueError, match="lack"):
        ad.trial_table(m.drop(columns="peak_speed"), 100.0)


def _table(block_values: list[tuple], directions: list[int] | None = None) -> pd.DataFrame:
    """A per-trial table from (block, type, value) rows: the value is the lateral error, or on a channel trial the
    adaptation; ``directions``: each row's centre-out direction (default -1: targets anywhere)."""
    rows = []
    directions = directions or [-1] * len(block_values)
    for i, ((block, kind, v), d) in enumerate(zip(block_values, directions)):
        channel = kind == "channel"
        field = {"field": 1.0, "reverse": -1.0}.get(kind, 0.0)
        rows.append({"seed": 0, "trial": i, "block": block, "field": field, "channel": channel,
                     "catch": kind == "catch", "lateral_error": math.nan if channel else v,
                     "adaptation": v if channel else math.nan, "habit_share": 0.25 if block == "channel" else 1.0,
                     "direction": d})
    return pd.DataFrame(rows, columns=list(ad.TRIAL_COLUMNS))


def test_signatures_by_hand():
    rows = ([("baseline", "null", 1.0)] * 2 + [("baseline", "channel", 0.0)]
            + [("adaptation", "channel", 0.2)] + [("adaptation", "field", 5.0)] * 10
            + [("adaptation", "catch", -2.0), ("adaptation", "field", 1.0), ("adaptation", "channel", 0.6)]
            + [("reverse", "reverse", -3.0)] * 2
            + [("channel", "channel", v) for v in (0.0, 0.1, -0.1, 0.3, 0.5)]
            + [("reexposure", "field", 3.0)] * 10 + [("reexposure", "catch", -4.0)])
    s = ad.signatures(_table(rows)).iloc[0]
    assert s["after_effect"] == pytest.approx(-3.0 - 1.0)  # catch mean -3, baseline null mean 1
    assert s["field_push"] == pytest.approx(5.0 - 1.0)
    assert s["error_reduction"] == pytest.approx(5.0 - (9 * 5.0 + 1.0) / 10)  # the last 10 field trials hold the 1.0
    assert s["spontaneous_recovery"] == pytest.approx(0.4 - 0.0)
    assert s["savings"] == pytest.approx(5.0 - 3.0)
    assert s["adaptation_late"] == pytest.approx(0.6)  # the second half's channel trial only
    assert s["habit_channel"] == pytest.approx(0.25) and s["habit_adaptation"] == pytest.approx(1.0)


def test_each_trial_is_measured_against_its_own_directions_baseline():
    rows = [("baseline", "null", 1.0), ("baseline", "null", 3.0), ("baseline", "null", -1.0),
            ("baseline", "channel", 0.2), ("adaptation", "field", 5.0), ("adaptation", "field", 0.0),
            ("adaptation", "catch", -3.0), ("adaptation", "channel", 0.5), ("adaptation", "channel", 0.9)]
    directions = [0, 0, 1, 0, 0, 1, 1, 1, 0]
    t = ad.baseline_corrected(_table(rows, directions))
    # lateral: direction 0's baseline 2.0, direction 1's -1.0; adaptation: direction 0's 0.2, direction 1 has no
    # baseline channel trial and takes the mean over directions (0.2)
    np.testing.assert_allclose(t["lateral_error"], [-1.0, 1.0, 0.0, np.nan, 3.0, 1.0, -2.0, np.nan, np.nan])
    np.testing.assert_allclose(t["adaptation"], [np.nan] * 3 + [0.0, np.nan, np.nan, np.nan, 0.3, 0.7])
    one = ad.baseline_corrected(_table(rows))  # one direction: the baseline block's means
    np.testing.assert_allclose(one["lateral_error"][:3], [0.0, 2.0, -2.0])
    s = ad.signatures(_table(rows, directions)).iloc[0]
    assert s["field_push"] == pytest.approx((3.0 + 1.0) / 2) and s["after_effect"] == pytest.approx(-2.0)
    no_base = _table([("baseline", "null", 1.0), ("adaptation", "channel", 0.4)])
    assert ad.baseline_corrected(no_base)["adaptation"].iloc[1] == pytest.approx(0.4)  # no baseline channel: 0


def _model_blocks() -> tuple[list[tuple[str, str]], list[str]]:
    blocks = ([("baseline", "null")] * 10 + [("adaptation", "field")] * 80 + [("reverse", "reverse")] * 12
              + [("channel", "channel")] * 30 + [("reexposure", "field")] * 20)
    kinds_ = [k for _, k in blocks]
    for i in range(19, 90, 10):
        kinds_[i] = "catch"
    return blocks, kinds_


def _model_schedule() -> tuple[np.ndarray, np.ndarray]:
    _, kinds_ = _model_blocks()
    return (np.array([{"field": 1.0, "reverse": -1.0}.get(k, 0.0) for k in kinds_]),
            np.array([k == "channel" for k in kinds_]))


def _model_table(params: ts.TwoState, seed: int = 0) -> pd.DataFrame:
    """The protocol simulated by the two-state model: the lateral error is the error e (field - x; the catch
    trial's is -x), a channel trial measures x."""
    blocks, kinds_ = _model_blocks()
    sim = ts.simulate(params, *_model_schedule())
    values = np.where(_model_schedule()[1], sim["x"], sim["e"])
    return _table([(b, k, v) for (b, _), k, v in zip(blocks, kinds_, values)]).assign(seed=seed)


def test_two_state_learner_shows_the_signatures_one_state_learner_no_spontaneous_recovery():
    two = ad.signatures(_model_table(ts.TwoState(A_f=0.8, B_f=0.2, A_s=0.995, B_s=0.03))).iloc[0]
    assert two["after_effect"] < -0.2  # opposite the field
    assert two["spontaneous_recovery"] > 0.05
    assert two["savings"] > 0.0
    one_state = ts.TwoState(A_f=0.0, B_f=0.0, A_s=0.98, B_s=0.1)
    x = ts.simulate(one_state, *_model_schedule())["x"].to_numpy()
    assert x[102] < 0 and x[131] > x[102]  # de-adapted below 0, then rising back towards 0 in the channel block
    one = ad.signatures(_model_table(one_state)).iloc[0]
    assert one["spontaneous_recovery"] <= 0.0
    assert one["after_effect"] < 0.0


def test_protocol_refuses_a_task_without_the_blocks(tmp_path):
    from apac_mj.config import TrainConfig

    with pytest.raises(ValueError, match="no \\[trials\\] table"):
        ad.Protocol(run=TrainConfig(task="changing_target_compliant_curl_field")).episodes()
    blocks = [{"name": n, "episodes": 2, "field_b": b} for n, b in
              (("baseline", 0.0), ("adaptation", 100.0), ("channel", 0.0), ("reexposure", 100.0))]
    cfg = TrainConfig(task=ad.TASK, task_overrides={"trials": {"block": blocks}})
    with pytest.raises(ValueError, match="needs the blocks"):
        ad.check_task(cfg)
    with pytest.raises(ValueError, match="distinct"):
        ad.Protocol(agents=("ddpg", "ddpg"))
    with pytest.raises(ValueError):
        ad.Protocol(agents=("nonesuch",))
    study = tmp_path / "s"
    with pytest.raises(ValueError, match="no \\[trials\\]"):
        ad.run(study, ad.Protocol(run=TrainConfig(task="changing_target")), progress=False)
    assert not study.exists()


def test_the_published_task_holds_the_protocol():
    p = ad.Protocol()
    trials = ad.check_task(p.run)
    assert p.episodes() == sum(b.episodes for b in trials.blocks) and ad.adaptation_b(p.run) == 100.0
    assert p.train_config("spac").agent.kind == "spac" and p.train_config("spac").episodes == p.episodes()


def test_rerun_with_other_settings_is_refused(tmp_path):
    record = {"agents": ["ddpg"], "run": {"seeds": [0, 1]}, "task_spec": {}}
    (tmp_path / ad.PROTOCOL_FILE).write_text(json.dumps(record))
    ad.check_rerun(tmp_path, {**record, "agents": ["ddpg", "apac"]})  # adding a kind: fine
    with pytest.raises(ValueError, match="run"):
        ad.check_rerun(tmp_path, {**record, "run": {"seeds": [0, 1, 2]}})
    with pytest.raises(ValueError, match="agents"):
        ad.check_rerun(tmp_path, {**record, "agents": ["apac"]})


def test_command_refuses_before_writing(tmp_path, capsys):
    from apac_mj.cli import main

    out = tmp_path / "study"
    assert main(["adaptation", "run", "--out", str(out), "--set", "task=changing_target"]) == 2
    assert "no [trials] table" in capsys.readouterr().err
    assert main(["adaptation", "run", "--out", str(out), "--set", "agents=ddpg,nonesuch"]) == 2
    assert main(["adaptation", "run", "--out", str(out), "--set", "frobnicate=1"]) == 2
    assert main(["adaptation", "run", "--out", str(out), "--set", "lesions=cerebellum"]) == 2
    assert "lesions must be distinct names" in capsys.readouterr().err
    assert not out.exists()
    assert main(["adaptation", "report", str(out)]) == 2


def test_motornet_bench_runs_the_agents_schedule_and_its_loads_push_the_right_way():
    pytest.importorskip("motornet")
    import importlib.util
    from pathlib import Path

    import torch

    path = Path(__file__).resolve().parents[1] / "bench" / "motornet_adaptation.py"
    spec = importlib.util.spec_from_file_location("motornet_adaptation", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    trials = bench.schedule(ad.TASK, seed=0)
    blocks = ad.check_task(ad.Protocol().run).blocks
    assert len(trials) == sum(b.episodes for b in blocks)
    assert trials.loc[trials["block"] == "channel", "channel"].all()
    assert (trials.loc[trials["block"] == "reverse", "field"] == -1.0).all()

    class Push(torch.nn.Module):  # a fixed activation pattern that moves the hand: no learning needed
        def init_hidden(self, n):
            return torch.zeros(1, n, 1)

        def forward(self, obs, h):
            return torch.tensor([[0.6, 0.0, 0.0, 0.6, 0.0, 0.0]]).repeat(obs.shape[0], 1), h

    env = bench.make_env()
    move = bench.reach(env, Push(), torch.zeros(1), "none", 0.0)
    dx, dy = (move["path"][-1, 0] - move["start"][0]).tolist()
    angle = torch.tensor([math.atan2(dy, dx)])  # the line along the unperturbed movement: its normal is "right"
    right = np.array([dy, -dx]) / math.hypot(dx, dy)

    def mean_deviation(load: str, b: float) -> float:
        out = bench.reach(env, Push(), angle, load, b)
        return float(((out["path"][:, 0].numpy() - out["start"][0].numpy()) @ right).mean())

    none, cw, ccw = mean_deviation("none", 0.0), mean_deviation("field", 30.0), mean_deviation("field", -30.0)
    channel = mean_deviation("channel", 0.0)
    assert cw - none > 0.002 and ccw - none < -0.002  # m: b > 0 pushes clockwise of the movement
    assert abs(channel) < 0.7 * abs(none)  # the channel (a spring: deviation = force / K) holds the hand nearer the line


def test_report_of_two_state_learners_states_the_signatures(tmp_path):
    from apac_mj.report import adaptation as rep

    params = ts.TwoState(A_f=0.8, B_f=0.2, A_s=0.995, B_s=0.03)
    trials = []
    for seed in range(3):
        t = _model_table(params, seed)
        noise = np.random.default_rng(seed).normal(0.0, 0.01, len(t))
        trials.append(t.assign(adaptation=t["adaptation"] + noise, lateral_error=t["lateral_error"] + noise))
    out = rep.write_tables(pd.concat(trials).assign(kind="apac"), tmp_path / "report")
    for name in ("trials.csv", "signatures.csv", "summary.csv", "two_state.csv", "two_state_summary.csv",
                 "learning.png", "channel.png", "after_effects.png", "report.md"):
        assert (out / name).is_file(), name
    s = pd.read_csv(out / "summary.csv").set_index("quantity")
    assert s.loc["spontaneous_recovery", "lo"] > 0 and s.loc["after_effect", "hi"] < 0
    assert rep.verdict(s.loc["spontaneous_recovery"], positive=True) == "yes"
    assert rep.verdict(s.loc["after_effect"], positive=False) == "yes"
    fits = pd.read_csv(out / "two_state.csv")
    assert (fits["A_s"] >= fits["A_f"]).all() and (fits["rmse"] < 0.05).all()
    assert "| apac (both, arbitrated) | 3 |" in (out / "report.md").read_text()


@pytest.mark.slow
def test_study_end_to_end_resumes_and_reports(tmp_path):
    from apac_mj.config import AgentConfig, TrainConfig
    from apac_mj.report.adaptation import write_report

    blocks = [{"name": n, "episodes": e, "field_b": b, **extra} for n, e, b, extra in (
        ("training", 2, 0.0, {}), ("baseline", 2, 0.0, {"channel_probability": 0.5}),
        ("adaptation", 4, 100.0, {"channel_probability": 0.3, "catch_probability": 0.3}), ("reverse", 1, -100.0, {}),
        ("channel", 3, 0.0, {"channel": True}), ("reexposure", 3, 100.0, {"catch_probability": 0.5}))]
    run = TrainConfig(task=ad.TASK, seeds=(0, 1, 2), task_overrides={"trials": {"block": blocks}},
                      agent=AgentConfig(batch_size=16, babbling_episodes=1))
    proto = ad.Protocol(agents=("ddpg",), run=run, lesions=("model",))
    study = ad.run(tmp_path / "s", proto, progress=False, say=lambda _: None)
    metrics = (study / "runs" / "ddpg" / "metrics.parquet").read_bytes()
    ad.run(study, proto, progress=False, say=lambda _: None)  # a finished study: nothing trains again
    assert (study / "runs" / "ddpg" / "metrics.parquet").read_bytes() == metrics
    out = write_report(study)
    trials = pd.read_csv(out / "trials.csv")
    assert len(trials) == 2 * 3 * 15 and set(trials["block"]) == {"training", *ad.BLOCKS}
    assert set(trials["kind"]) == {"ddpg", "apac_model_frozen"}
    lesion = json.loads((study / "runs" / "apac_model_frozen" / "config.json").read_text())["agent"]
    assert (lesion["kind"], lesion["frozen"], lesion["frozen_from_episode"]) == ("apac", ["model"], 2 + 2)
    assert trials.loc[trials["block"] == "channel", "adaptation"].notna().all()
    with pytest.raises(ValueError, match="other settings"):
        ad.run(study, dataclasses_replace_seeds(proto, (0, 1)), progress=False)


def dataclasses_replace_seeds(proto: ad.Protocol, seeds: tuple[int, ...]) -> ad.Protocol:
    import dataclasses

    return dataclasses.replace(proto, run=dataclasses.replace(proto.run, seeds=seeds))


def test_the_carrier_is_the_learner_whose_lesioned_run_still_shows_the_signature():
    from apac_mj.report.adaptation import carriers

    def rows(kind, intervals):
        return [{"kind": kind, "quantity": q, "mean": (lo + hi) / 2, "lo": lo, "hi": hi, "seeds": 10}
                for q, (lo, hi) in intervals.items()]

    unclear = (-1.0, 1.0)
    habit_frozen = {**{q: unclear for q in ad.SIGNATURES}, "field_push": (0.5, 1.0), "after_effect": (-2.0, -0.5),
                    "error_reduction": (0.1, 0.4)}
    model_frozen = {**{q: unclear for q in ad.SIGNATURES}, "field_push": (0.2, 0.9), "savings": (0.3, 0.8),
                    "after_effect": (0.5, 2.0), "error_reduction": (0.2, 0.5)}
    summary = pd.DataFrame(rows("apac_habit_frozen", habit_frozen) + rows("apac_model_frozen", model_frozen)
                           + rows("apac", {q: (0.1, 0.2) for q in ad.SIGNATURES}))
    c = carriers(summary).set_index("signature")["carried_by"].to_dict()
    assert c == {"field_push": "both", "error_reduction": "both", "after_effect": "internal model",
                 "savings": "habit", "adaptation_late": "neither", "spontaneous_recovery": "neither"}
    reversed_ = summary.copy()
    worse = (reversed_["kind"] == "apac_model_frozen") & (reversed_["quantity"] == "spontaneous_recovery")
    reversed_.loc[worse, ["lo", "hi"]] = [-0.8, -0.2]  # only the habit learns, and it rises the other way
    c = carriers(reversed_).set_index("signature")["carried_by"].to_dict()
    assert c["spontaneous_recovery"] == "habit, opposite the human sign" and c["field_push"] == "both"
    assert carriers(summary[summary["kind"] != "apac_model_frozen"]).empty  # one lesion alone says nothing


def test_the_lesioned_arms_freeze_their_learner_from_the_adaptation_block():
    proto = ad.Protocol()
    arms = proto.arms()
    assert list(arms) == ["ddpg", "spac", "apac", "apac_habit_frozen", "apac_model_frozen"]
    start = sum(b.episodes for b in ad.check_task(proto.run).blocks[:2])  # training + baseline
    assert ad.block_start(proto.run, "adaptation") == start == 98
    for label, lesion in (("apac_habit_frozen", ("habit",)), ("apac_model_frozen", ("model",))):
        agent = arms[label].agent
        assert (agent.kind, agent.frozen, agent.frozen_from_episode) == ("apac", lesion, start)
    assert all(arms[k].agent.frozen == () for k in ("ddpg", "spac", "apac"))
    assert all(c.episodes == proto.episodes() == 200 for c in arms.values())
    with pytest.raises(ValueError, match="lesions must be distinct names"):
        ad.Protocol(lesions=("actor",))
    with pytest.raises(ValueError, match="lesioned_kind"):
        ad.Protocol(lesioned_kind="ddpg")
    assert list(ad.Protocol(lesions=()).arms()) == ["ddpg", "spac", "apac"]


def test_parts_of_one_protocol_over_disjoint_seeds_report_as_one(tmp_path, monkeypatch):
    from apac_mj.report import adaptation as rep

    record = {"agents": ["ddpg"], "run": {"seeds": [0, 1], "task": "t"}, "lesions": []}
    parts = {}
    for name, seeds in (("a", [0, 1]), ("b", [2]), ("c", [1]), ("d", [3])):
        (tmp_path / name).mkdir()
        changed = {**record, "run": {**record["run"], "seeds": seeds}}
        if name == "d":
            changed["run"]["task"] = "other"
        (tmp_path / name / ad.PROTOCOL_FILE).write_text(json.dumps(changed))
        parts[str(tmp_path / name)] = pd.concat([_table([("baseline", "null", 1.0)]).assign(seed=s) for s in seeds])
    monkeypatch.setattr(rep, "load_study", lambda s, motornet=None: parts[str(s)].assign(kind="ddpg"))
    both = rep.load_studies([tmp_path / "a", tmp_path / "b"])
    assert sorted(both["seed"]) == [0, 1, 2]
    with pytest.raises(ValueError, match="seed 1 of 'ddpg' is in more than one"):
        rep.load_studies([tmp_path / "a", tmp_path / "c"])
    with pytest.raises(ValueError, match="holds another protocol"):
        rep.load_studies([tmp_path / "a", tmp_path / "d"])


def test_a_learners_contribution_is_the_intact_run_minus_the_run_that_froze_it_paired_by_seed():
    from apac_mj.report.adaptation import lesion_effects

    rows = []
    for seed, (intact, no_habit, no_model) in enumerate(((1.0, 0.2, 1.1), (1.4, 0.5, 1.2), (0.8, 0.1, 0.9))):
        for kind, v in (("apac", intact), ("apac_habit_frozen", no_habit), ("apac_model_frozen", no_model)):
            rows.append({"kind": kind, "seed": seed, **{q: v for q in ad.SIGNATURES}})
    rows.append({"kind": "apac_habit_frozen", "seed": 9, **{q: 50.0 for q in ad.SIGNATURES}})  # unpaired: left out
    e = lesion_effects(pd.DataFrame(rows)).set_index(["learner", "signature"])
    habit, model = e.loc[("habit", "savings")], e.loc[("internal model", "savings")]
    assert habit["mean"] == pytest.approx(0.8) and habit["seeds"] == 3  # (0.8 + 0.9 + 0.7) / 3
    d = np.array([0.8, 0.9, 0.7])
    half = 6.205346816 * d.std(ddof=1) / math.sqrt(3)  # Student-t, 2 degrees of freedom, at 98.75% (stats.py)
    assert (habit["lo"], habit["hi"]) == pytest.approx((0.8 - half, 0.8 + half))
    assert habit["verdict"] == "yes" and model["mean"] == pytest.approx(0.0)
    assert e.loc[("habit", "after_effect"), "verdict"] == "no"  # + is with the field: away from the human sign
    assert lesion_effects(pd.DataFrame(rows)[lambda t: t["kind"] == "apac"]).empty
