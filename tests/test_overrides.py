"""One --set grammar and one seed grammar for every command; bad values refused before anything runs;
every field's doc in --help."""
from __future__ import annotations

import argparse
import dataclasses

import pytest

from apac_mj.experiments import grid
from apac_mj.experiments.presets import PresetError, load_preset
from apac_mj.util import overrides
from apac_mj.cli import build_parser, main
from apac_mj.commands import train as train_cmd
from apac_mj import kinds, rules
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.experiments.presets import Preset
from apac_mj.experiments.presets import Tests as PresetTests


def _train_args(*sets: str, seeds: str | None = None) -> argparse.Namespace:
    argv = ["train", "--out", "unused"] + (["--seeds", seeds] if seeds else [])
    return build_parser().parse_args(argv + [a for s in sets for a in ("--set", s)])


@pytest.mark.parametrize("text", ["3", "2-4", "0,3,5", "[1, 4]", "6-6"])
def test_one_seed_grammar(text):
    grid_seeds = load_preset("smoke", [f"seeds={text}"]).seeds
    assert train_cmd.train_config(_train_args(seeds=text)).seeds == grid_seeds
    assert train_cmd.train_config(_train_args(f"seeds={text}")).seeds == grid_seeds
    assert {"3": (0, 1, 2), "6-6": (6,)}.get(text, grid_seeds) == grid_seeds


def test_one_override_grammar_for_train_and_grid():
    sets = ["actor_hidden=64,64", "agent.batch_size=32", "ou_sigma_initial=none", "normalize_inputs=false",
            "episodes=7", 'task_overrides={at_limit = "unbounded"}']
    cfg = train_cmd.train_config(_train_args(*sets))
    preset = load_preset("smoke", sets)
    cell = grid.cells(preset)[0].train_config(preset)
    for c in (cfg, cell):
        assert c.agent.actor_hidden == (64, 64) and c.agent.batch_size == 32 and c.agent.ou_sigma_initial is None
        assert c.agent.normalize_inputs is False and c.episodes == 7 and c.task_overrides == {"at_limit": "unbounded"}
    assert load_preset("smoke", ["agent.actor_hidden=[64, 64]"]).run.agent.actor_hidden == (64, 64)


@pytest.mark.parametrize("item, message", [
    ("agent.actor_hidden=abc,64", "agent.actor_hidden must be an integer, got 'abc'"),
    ("actor_hidden=64,64,64", "agent.actor_hidden must have 2 entries"),
    ("batch_size=1.5", "agent.batch_size must be an integer, got 1.5"),
    ("normalize_inputs=maybe", "agent.normalize_inputs must be true or false"),
    ("task_overrides=3", "task_overrides must be a table"),
    ("agent.uncertainty.window=abc", "agent.uncertainty.window must be an integer, got 'abc'"),
    ("kalman.process_floor=x", "agent.kalman.process_floor must be a number, got 'x'"),
    ("agent.reliability.windw=3", "agent.reliability: unknown ReliabilityParams field(s) ['windw']"),
    ("agent.kalman=3", "agent.kalman is a table of KalmanParams fields"),
])
def test_bad_values_are_refused_by_both_before_anything_runs(tmp_path, capsys, item, message):
    with pytest.raises(PresetError, match="preset 'smoke'") as e:
        load_preset("smoke", [item])
    assert message in str(e.value)
    with pytest.raises(overrides.OverrideError) as e:
        train_cmd.train_config(_train_args(item))
    assert message in str(e.value)
    assert main(["grid", "--preset", "smoke", "--out", str(tmp_path / "g"), "--set", item]) == 2
    assert main(["train", "--out", str(tmp_path / "t"), "--set", item]) == 2
    assert message in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


def test_a_rule_parameter_out_of_range_is_refused_naming_it(tmp_path, capsys):
    message = "agent.speed_accuracy.window must be >= 1, got 0"
    with pytest.raises(PresetError, match=message):
        load_preset("smoke", ["agent.speed_accuracy.window=0"])
    assert main(["train", "--out", str(tmp_path / "t"), "--set", "speed_accuracy.window=0"]) == 2
    assert message in capsys.readouterr().err and not any(tmp_path.iterdir())


def test_a_bad_task_override_is_refused_before_a_grid_writes(tmp_path):
    with pytest.raises(ValueError, match="unknown override"):
        grid.run_grid(load_preset("smoke", ["task_overrides={no_such = 1}"]), tmp_path / "g", progress=False)
    assert not (tmp_path / "g").exists()


def test_presets_embed_the_run_config():
    run_fields = {f.name for f in dataclasses.fields(TrainConfig)}
    assert not run_fields & ({f.name for f in dataclasses.fields(Preset)} - {"agent"})  # not declared again
    p = load_preset("smoke")
    assert isinstance(p.run, TrainConfig) and p.run.seeds == p.seeds == (0, 1) and p.run.agent.batch_size == 16


def _help(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit):
        main(argv + ["--help"])
    return capsys.readouterr().out


def test_every_field_and_its_doc_is_in_help(capsys):
    train_help, grid_help = _help(["train"], capsys), _help(["grid"], capsys)
    tables = [(table, f"{name}.") for name, table in rules.tables().items()]
    for cls, prefix in ((TrainConfig, ""), (AgentConfig, ""), (Preset, ""), (PresetTests, "tests."), *tables):
        docs = overrides.field_docs(cls)
        for f in dataclasses.fields(cls):
            if f.name in ("agent", "name", "run", "tests", "params", "kind"):
                continue
            assert docs.get(f.name), f"{cls.__name__}.{f.name} has no doc"
            first = docs[f.name].split()[0]
            if f.name != "task":  # each cell's, not a preset key
                grid_prefix = f"agent.{prefix}" if (cls, prefix) in tables else prefix
                assert f"{grid_prefix}{f.name} = " in grid_help and first in grid_help
            if cls in (TrainConfig, AgentConfig) or (cls, prefix) in tables:
                assert f"  {prefix}{f.name} = " in train_help, f"{f.name} missing from train --help"


def test_field_docs_read_the_comments():
    @dataclasses.dataclass
    class Example:
        # -- a section ---
        #: First line,
        #: second line.
        a: int = 1
        b: str = "x"

    assert overrides.field_docs(Example) == {"a": "First line, second line.", "b": "(section: a section)"}


def test_a_rule_parameter_reaches_its_rule_from_the_command_line_and_presets(tmp_path):
    sets = ["agent.uncertainty.window=50", "reliability.slope=3", "agent.kalman.window=100", "integrator=kalman"]
    cfg = train_cmd.train_config(_train_args(*sets, "kind=apac_uncertainty"))
    preset = load_preset("smoke", sets + ["agents=apac_uncertainty"])
    for c in (cfg, grid.cells(preset)[0].train_config(preset)):
        assert c.agent.kind == "apac_uncertainty"
        assert c.agent.params["uncertainty"] == rules.UncertaintyParams(window=50)
        assert c.agent.params["reliability"].slope == 3.0 and c.agent.params["kalman"].window == 100
        assert kinds.arbitrator_for(c.agent).rate == 1 / 50
    (tmp_path / "p.toml").write_text('agents = ["apac_reliability"]\n[agent.reliability]\nrate = 0.25\n')
    p = load_preset(tmp_path / "p.toml")
    assert kinds.arbitrator_for(p.train_config("changing_target", "apac_reliability").agent).A == 0.25


def test_a_kind_that_cannot_take_the_config_is_refused_by_the_preset():
    with pytest.raises(PresetError, match="agent 'ddpg': habit_distillation_weight = 5.0 needs a kind"):
        load_preset("smoke", ["agent.habit_distillation_weight=5"])
    with pytest.raises(PresetError, match="unknown agent kind 'nope'"):
        load_preset("smoke", ["agent.vision_aware.base=nope"])


def test_agent_overrides_for_scripts_use_the_same_grammar():
    assert train_cmd.agent_overrides(["batch_size=64", "agent.actor_hidden=64,64"]) == {
        "batch_size": 64, "actor_hidden": (64, 64)}
    assert train_cmd.agent_overrides(["agent.kalman.window=9"]) == {"params": {"kalman": {"window": 9}}}
    with pytest.raises(ValueError, match="unknown AgentConfig field"):
        train_cmd.agent_overrides(["no_such=1"])


def test_a_misspelled_field_gets_the_nearest_names_not_a_list_of_unrelated_ones(capsys):
    from apac_mj.cli import main

    assert main(["train", "--task", "static_target", "--agent", "ddpg", "--set", "batchsize=64", "--out", "unused"]) != 0
    err = capsys.readouterr().err
    assert "apac-mj train: error: --set batchsize: unknown key(s) ['batchsize']; did you mean 'batch_size'?" in err
    assert "checkpoint_every" not in err  # no list of the run's unrelated fields
