"""Issue 45's refusals: bad input refused before anything runs or is written, each error naming its real cause.

* a refusal comes before train's planning-phase note (item 9);
* a cued task as a grid condition is refused before any cell trains (campaign 3, F5);
* planner and physics sizes that cannot fit or would not finish are refused naming the setting and the limit (F8);
* errors name the setting the user gave (F12): plant.max_torque, plant.velocity_scale, agent.mpc.max_std, and the
  plant overrides behind MuJoCo's unstable-state stop.
"""
from __future__ import annotations

import dataclasses

import pytest

from apac_mj.cli import main
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.rules import MPCParams
from apac_mj.suite import spec_for
from apac_mj.suite.task_spec import TaskSpecError
from apac_mj.util import memory

TINY = ["--set", "actor_hidden=8,8", "--set", "critic_hidden=8,8", "--set", "forward_hidden=8,8",
        "--set", "inverse_hidden=8,8", "--set", "batch_size=4", "--set", "replay_size=32"]


def _train(capsys, tmp_path, *flags: str) -> tuple[int, str]:
    out = tmp_path / "run"
    code = main(["train", "--agent", "apac", "--seeds", "1", "--episodes", "50", "--no-progress", *TINY, *flags,
                 "--out", str(out)])
    assert not out.exists(), "a refused run wrote its directory"
    return code, capsys.readouterr().err


# -- item 9: refuse first, note after ---------------------------------------------------------------------------

@pytest.mark.parametrize("flags,error", [
    (["--task", "no_such_task"], "no_such_task"),
    (["--task", "changing_target_torque", "--actuation", "kinematic"], "actuation 'kinematic'"),
])
def test_a_refusal_comes_without_the_planning_note(capsys, tmp_path, flags, error):
    code, err = _train(capsys, tmp_path, *flags)
    assert code == 2 and error in err
    assert "plans in all" not in err, err


def test_a_missing_cuda_device_is_refused_without_the_note(capsys, tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: --device cuda is not refused here")
    code, err = _train(capsys, tmp_path, "--task", "changing_target", "--device", "cuda")
    assert code == 2 and "CUDA is not available" in err and "plans in all" not in err


# -- F5: a cued condition in a grid --------------------------------------------------------------------------------

def test_a_grid_with_a_cued_condition_is_refused_before_training(tmp_path, capsys):
    from apac_mj.experiments import grid
    from apac_mj.experiments.presets import load_preset

    preset = load_preset("smoke", ["conditions=cued_targets", "tests.generalization=false"])
    with pytest.raises(grid.CuedConditionError, match="cued task.*forced-response"):
        grid.run_grid(preset, tmp_path / "g", progress=False)
    assert not (tmp_path / "g").exists()
    assert main(["grid", "--preset", "smoke", "--set", "conditions=cued_targets", "--out", str(tmp_path / "g"),
                 "--dry-run"]) == 2
    captured = capsys.readouterr()
    assert "refused: condition 'cued_targets' is a cued task" in captured.out and "cued task" in captured.err
    cell = grid.cells(preset)[0]
    assert grid.cell_status(cell, preset, tmp_path / "g")[0] == "refused"


def test_a_cued_condition_without_tests_is_a_training_grid(tmp_path):
    """Only the tests are refused: with them off, the cued cells train (and forced-response tests them)."""
    from apac_mj.experiments import grid
    from apac_mj.experiments.presets import load_preset

    preset = load_preset("smoke", ["conditions=cued_targets", "tests.generalization=false", "tests.grid=false",
                                   "tests.occluded=false"])
    assert {s for s, _ in grid.check_grid(preset, tmp_path / "g").values()} == {"to run"}


# -- F8: planner and physics sizes --------------------------------------------------------------------------------

def _mpc(**kw) -> AgentConfig:
    return AgentConfig(kind="spac_mpc", params={"mpc": dataclasses.replace(MPCParams(), **kw)})


@pytest.mark.parametrize("field,value", [("candidates", 10**9), ("horizon", 100_000), ("iterations", 10**9),
                                         ("habit_candidates", 10**9)])
def test_planner_work_beyond_the_limit_is_refused(field, value):
    with pytest.raises(ValueError, match=rf"{field} {value}.*imagined steps per decision; at most 100,000"):
        TrainConfig(agent=_mpc(**{field: value}))


def test_the_defaults_and_the_presets_plan_within_the_limit():
    from apac_mj.experiments.presets import load_preset, preset_names

    assert memory.imagined_steps(MPCParams()) == 544
    for name in preset_names():
        load_preset(name)  # every preset's run is made, so checked


def test_a_planner_that_does_not_fit_in_memory_is_refused(monkeypatch):
    agent = _mpc(candidates=20_000, horizon=4, iterations=1)
    need = memory.planner_bytes(agent, 100)
    monkeypatch.setattr(memory, "physical_memory", lambda: need)  # half of it is what a planner may take
    with pytest.raises(ValueError, match=r"planner would hold about .* GiB.*100 seed\(s\).*candidates 20000"):
        TrainConfig(seeds=tuple(range(100)), agent=agent)
    TrainConfig(seeds=tuple(range(40)), agent=agent)  # 40% of it fits


def test_a_physics_time_step_that_would_not_finish_is_refused():
    cfg = TrainConfig(task="changing_target_torque", task_overrides={"plant": {"timestep": 1e-7}})
    with pytest.raises(TaskSpecError, match=r"plant.timestep = 1e-07 s gives 1000000 physics sub-steps.*at most 10000"):
        spec_for(cfg)
    spec_for(dataclasses.replace(cfg, task_overrides={"plant": {"timestep": 1e-5}}))  # 10 000: the limit


# -- F12: the real cause named ----------------------------------------------------------------------------------

@pytest.mark.parametrize("plant,message", [
    ({"max_torque": 1e9}, r"plant.max_torque must be at most 360 N·m"),
    ({"max_torque": 1e6, "link_masses": [0.001, 0.001]}, r"plant.max_torque must be at most 360"),
    ({"velocity_scale": 1e-300}, r"plant.velocity_scale must be in \[0.01, 1e\+06\] deg/s"),
])
def test_plant_errors_name_the_plant_setting(plant, message):
    with pytest.raises(TaskSpecError, match=message):
        spec_for(TrainConfig(task="changing_target_torque", task_overrides={"plant": plant}))


def test_a_huge_planner_spread_names_its_setting():
    with pytest.raises(ValueError, match=r"agent.mpc.max_std must be at most 100, got 1e\+308"):
        _mpc(max_std=1e308)
    _mpc(max_std=100.0)


def test_mujocos_unstable_state_names_the_plant_overrides():
    from dm_control.rl.control import PhysicsError

    from apac_mj.commands.train import unstable_plant

    spec = spec_for(TrainConfig(task="changing_target_torque",
                                task_overrides={"plant": {"link_masses": [1e-12, 1e-12]}}))
    with pytest.raises(PhysicsError) as e, unstable_plant(spec, {"plant": {"link_masses": [1e-12, 1e-12]}}):
        raise PhysicsError("Physics state is invalid. Warning(s) raised: mjWARN_BADQACC")
    assert "mjWARN_BADQACC" in str(e.value) and "the override plant.link_masses = [1e-12, 1e-12]" in str(e.value)
    with pytest.raises(PhysicsError) as e, unstable_plant(spec):  # no override: the task's own plant settings
        raise PhysicsError("Physics state is invalid. Warning(s) raised: mjWARN_BADQACC")
    assert "plant.link_masses = (1e-12, 1e-12)" in str(e.value)


@pytest.mark.slow
def test_an_unstable_plant_stops_training_naming_the_override(capsys, tmp_path):
    """The campaign's DYN-5 end to end: MuJoCo stops at t = 0, the error names plant.link_masses."""
    code = main(["train", "--task", "changing_target_torque", "--agent", "apac", "--seeds", "1", "--episodes", "2",
                 "--no-progress", *TINY, "--set", "task_overrides={plant={link_masses=[1e-12,1e-12]}}",
                 "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and "mjWARN_BADQACC" in err and "plant.link_masses" in err, err


def test_train_names_the_next_command_a_cued_run_takes():
    """Campaign 3's CUE-E: train on a cued task ended with "next: apac-mj evaluate RUN", which refuses cued runs."""
    from apac_mj.commands.train import next_command

    assert next_command(spec_for(TrainConfig(task="cued_targets")), "r").startswith("apac-mj forced-response test r")
    assert next_command(spec_for(TrainConfig(task="changing_target")), "r") == "apac-mj evaluate r"
