"""A run is built once (apac_mj.run.build): one read of its task file, E environments, one Agent constructor."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import build
from apac_mj.run.trainer import train
from apac_mj.suite import planar_arm, task_spec

from conftest import TINY8 as TINY

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def counted(monkeypatch):
    """Counts of task-file reads and MuJoCo environments built while the test runs."""
    counts = {"task_reads": 0, "environments": 0}
    read, make = task_spec.load_task_file, planar_arm.make_environment

    def load_task_file(path):
        counts["task_reads"] += 1
        return read(path)

    def make_environment(*args, **kwargs):
        counts["environments"] += 1
        return make(*args, **kwargs)

    monkeypatch.setattr(task_spec, "load_task_file", load_task_file)
    monkeypatch.setattr(planar_arm, "make_environment", make_environment)
    return counts


@pytest.mark.parametrize("task", ["changing_target", "changing_target_torque"])
def test_a_train_reads_its_task_once_and_builds_E_environments(tmp_path, counted, task):
    seeds = (0, 1, 2)
    cfg = TrainConfig(task=task, seeds=seeds, episodes=1, checkpoint_every=1, agent=AgentConfig(**TINY))
    train(cfg, tmp_path / "run", progress=False)
    assert counted == {"task_reads": 1, "environments": len(seeds)}
    counted.update(task_reads=0, environments=0)  # resuming a finished run builds nothing
    train(cfg, tmp_path / "run", progress=False)
    assert counted == {"task_reads": 1, "environments": 0}


def test_an_evaluation_reads_the_task_once_and_builds_E_environments_per_protocol(tmp_path, counted):
    from apac_mj.run.evaluate import evaluate

    cfg = TrainConfig(task="changing_target", seeds=(0, 1), episodes=1, checkpoint_every=1,
                      agent=AgentConfig(kind="spac", **TINY))
    train(cfg, tmp_path / "run", progress=False)
    counted.update(task_reads=0, environments=0)
    evaluate(tmp_path / "run", ("grid", "occluded"), limit=1)
    assert counted == {"task_reads": 1, "environments": 2 * 2}


def test_a_forced_response_test_reads_the_task_once_and_builds_E_environments(tmp_path, counted, monkeypatch):
    """The test is built on the loaded run (``frozen_loop``): one task read, E environments, and one arbitrator
    for both of the delta rule's variants."""
    from apac_mj import kinds
    from apac_mj.run.forced_response import test_run

    cfg = TrainConfig(task="cued_targets", seeds=(0, 1), episodes=1, checkpoint_every=1,
                      agent=AgentConfig(kind="apac", **TINY))
    train(cfg, tmp_path / "run", progress=False)
    counted.update(task_reads=0, environments=0)
    built, make = [], kinds.arbitrator_for
    for module in (kinds, build):  # the registry's function, and the builder's name for it
        monkeypatch.setattr(module, "arbitrator_for", lambda c, state=None: built.append(c.kind) or make(c, state))
    df = test_run(tmp_path / "run", [300.0, 600.0], trials=2, repeats=1)
    assert counted == {"task_reads": 1, "environments": 2}
    assert set(df.variant) == {"apac", "apac_imagined"}
    assert built == ["apac"]


def test_the_agent_is_sized_by_the_environments_it_acts_in():
    cfg = TrainConfig(task="changing_target_torque", seeds=(0,), agent=AgentConfig(**TINY))
    run = build.build(cfg, build.check(cfg))
    assert run.agent.sizes == run.env.sizes and run.agent.state_dim == 6 + run.env.extra.shape[1] > 6
    assert run.agent.sizes.angle_actions is False and run.loop.env is run.env and run.loop.agent is run.agent


def test_the_agent_is_constructed_in_one_place():
    """``Agent(`` in the library and the bench scripts only in run/build.py (tests build bare agents)."""
    places = [f"{p.relative_to(ROOT)}:{i}" for folder in ("apac_mj", "bench") for p in sorted((ROOT / folder).rglob("*.py"))
              for i, line in enumerate(p.read_text().splitlines(), 1)
              if re.search(r"(?<![\w.])Agent\(", line) and not line.lstrip().startswith(("class ", "#"))]
    assert places == [f"apac_mj/run/build.py:{_line('apac_mj/run/build.py', 'return Agent(')}"], places


def _line(path: str, text: str) -> int:
    return next(i for i, line in enumerate((ROOT / path).read_text().splitlines(), 1) if text in line)


def test_the_environments_own_the_babbling_offset():
    cfg = TrainConfig(task="changing_target_changing_kinematics", seeds=(0,), agent=AgentConfig(babbling_episodes=3))
    spec = build.check(cfg)
    env = build.environments(cfg, spec)
    assert env.episode_offset == 3 and env.spec.growth_start_episode == spec.growth_start_episode + 3
    env.reset()
    assert env.episode(0) == -3  # the first babbling episode, as the trainer numbers it (LoopState.fresh)
    frozen = build.environments(cfg, spec, training=False)
    assert frozen.episode_offset == 0 and frozen.spec.growth_start_episode == spec.growth_start_episode


def test_a_config_checks_itself_and_is_frozen():
    for bad, match in ((dict(episodes=0), "episodes"), (dict(seeds=()), "seed"), (dict(seeds=(1, 1)), "distinct"),
                       (dict(checkpoint_every=True), "checkpoint_every"), (dict(precision="fp16"), "precision"),
                       (dict(actuation="torque"), "actuation"), (dict(device="tpu"), "device")):
        with pytest.raises(ValueError, match=match):
            TrainConfig(**bad)
    cfg = TrainConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.episodes = 3  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.agent.kind = "spac"  # type: ignore[misc]
    assert dataclasses.replace(cfg, episodes=3).episodes == 3


def test_each_set_of_choices_is_declared_once():
    """The precisions, actuations and devices are written out only in config.py."""
    patterns = {'"fp32", "bf16"': "PRECISIONS", '"servo", "kinematic"': "ACTUATIONS", '"cpu", "cuda"': "DEVICES"}
    found = [f"{p.relative_to(ROOT)}: {text}" for p in sorted((ROOT / "apac_mj").rglob("*.py"))
             if p.name != "config.py" for text in patterns if text in p.read_text()]
    assert not found, found


def test_the_trainer_carries_its_state_as_an_object():
    """No trainer function takes more than 5 parameters (``self`` not counted; the public ``train`` keeps its
    documented keywords): the loop's state lives on the ``Trainer``, not in argument lists."""
    import ast

    tree = ast.parse((ROOT / "apac_mj/run/trainer.py").read_text())
    wide = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef) and node.name != "train":
            args = [a.arg for a in node.args.args + node.args.kwonlyargs if a.arg not in ("self", "cls")]
            if len(args) > 5:
                wide[node.name] = args
    assert not wide, wide
    from apac_mj.run.run_dir import RunDir
    from apac_mj.run.trainer import Trainer

    trainer = Trainer(TrainConfig(), build.check(TrainConfig()), RunDir("not-written"))
    assert {"run", "state", "rows", "babbling_generators", "saved_at"} <= set(vars(trainer))
