"""The zoo (apac_mj/run/zoo.py, apac-mj zoo; docs/zoo.md): a cell reproduces its run's frozen tests, loads
tensors only, names the contract part that changed, and refuses tensors that cannot fit."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
import torch

from apac_mj.cli import main
from apac_mj.config import AgentConfig, TrainConfig
from apac_mj.run import zoo
from apac_mj.run.evaluate import evaluate
from apac_mj.run.run_dir import DONE, RunDir
from apac_mj.run.trainer import train
from apac_mj.util import paths

from conftest import TINY, deterministic


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    cfg = TrainConfig(task="changing_target", seeds=(0, 1), episodes=3, checkpoint_every=3, actuation="kinematic",
                      agent=AgentConfig(kind="apac", **TINY))
    return train(cfg, tmp_path_factory.mktemp("run"), progress=False)


@pytest.fixture(scope="module")
def tiny_cell(tiny_run, tmp_path_factory) -> Path:
    """An fp16 cell of the tiny run, with two regression episodes per seed."""
    cell = zoo.export(tiny_run, tmp_path_factory.mktemp("zoo") / "tiny", dtype="fp16")
    zoo.store_regression(cell, 2, tmp_path_factory.mktemp("cache"))
    return cell


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("APAC_MJ_ZOO_CACHE", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _grid(run: Path) -> pd.DataFrame:
    evaluate(run, protocols=("grid",), limit=4, threads=1)
    return deterministic(pd.read_parquet(RunDir(run).eval_path("grid")))


def test_an_fp32_cell_reproduces_its_runs_frozen_tests_exactly(tiny_run, tmp_path):
    """Every network the tests read ships (the target actor and critic too: delta reads Q'(s', pi'(s')))."""
    expected = _grid(tiny_run)
    cell = zoo.export(tiny_run, tmp_path / "cell32", dtype="fp32")
    pd.testing.assert_frame_equal(_grid(zoo.materialize(cell)), expected)
    manifest = zoo.read_manifest(cell)
    assert set(manifest["networks"]) == {"actor", "critic", "target_actor", "target_critic", "forward_model",
                                         "inverse_model"}
    assert manifest["kind"] == "apac" and manifest["seeds"] == [0, 1] and manifest["network_episodes"] == [3, 3]
    assert set(manifest["contract"]) == set(zoo.CONTRACT_PARTS)


def test_a_half_precision_cell_loads_into_fp32_networks(tiny_run, tiny_cell):
    from safetensors import safe_open

    with safe_open(str(tiny_cell / zoo.WEIGHTS), framework="pt") as f:
        shipped = {k: f.get_tensor(k) for k in f.keys() if k.startswith("networks/")}
    assert len(shipped) == 6 * 6 and {t.dtype for t in shipped.values()} == {torch.float16}
    cell = zoo.read_cell(tiny_cell)
    loaded = cell.networks["actor"]["layers.0.weight"]
    trained = RunDir(tiny_run).load_checkpoint().agent["networks"]["actor"]["layers.0.weight"]
    assert loaded.dtype == torch.float32 and torch.equal(loaded, trained.half().float())
    assert cell.changed == {}


def test_loading_reads_no_pickle(tiny_cell, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("torch.load (pickle) was called")

    monkeypatch.setattr(torch, "load", refuse)
    assert zoo.read_cell(tiny_cell).networks["critic"]


def test_the_shipped_regression_episodes_come_back_exactly(tiny_cell):
    zoo.check_regression(tiny_cell)


def _perturb_task(tmp_path, monkeypatch):
    tasks = shutil.copytree(paths.tasks_dir(), tmp_path / "tasks")
    file = tasks / "changing_target.toml"
    file.write_text(file.read_text() + "\n[target]\nzone_radius = 0.75\n")
    monkeypatch.setattr(paths, "tasks_dir", lambda: tasks)


def _perturb_plant(tmp_path, monkeypatch):
    xml = tmp_path / "planar_arm.xml"
    xml.write_text(paths.arm_xml_path().read_text().replace('kp="10000"', 'kp="9000"'))
    monkeypatch.setattr(paths, "arm_xml_path", lambda: xml)


def _perturb_motion_function(tmp_path, monkeypatch):
    original = zoo.motion_function
    monkeypatch.setattr(zoo, "motion_function", lambda a, b, l1, l2: original(a, b, l1 * 1.01, l2))


@pytest.mark.parametrize("part, perturb", [("task", _perturb_task), ("plant", _perturb_plant),
                                           ("motion_function", _perturb_motion_function)])
def test_a_changed_contract_part_is_a_warning_naming_it(tiny_cell, tmp_path, monkeypatch, capsys, part, perturb):
    perturb(tmp_path, monkeypatch)
    cell = zoo.read_cell(tiny_cell)
    assert set(cell.changed) == {part}
    assert f"the environment contract's part {part!r} changed" in capsys.readouterr().err


def test_a_changed_task_fails_the_regression_check_naming_it(tiny_cell, tmp_path, monkeypatch):
    _perturb_task(tmp_path, monkeypatch)
    with pytest.raises(zoo.ZooError, match=r"regression episodes differ .*task changed \(zone_radius: 0\.5"):
        zoo.check_regression(tiny_cell)


@pytest.mark.parametrize("machine, scale, passes", [("same", 1 + 1e-12, False), ("other", 1 + 1e-9, True),
                                                    ("other", 1 + 1e-3, False)])
def test_regression_episodes_are_identical_on_their_machine_type_and_close_on_another(tiny_cell, tmp_path, machine,
                                                                                        scale, passes):
    cell = Path(shutil.copytree(tiny_cell, tmp_path / "moved"))
    block = zoo.read_manifest(cell)["regression"]
    block["rows"][1]["final_distance"] *= scale
    block["machine"] = zoo.machine() if machine == "same" else "another CPU"
    zoo.update_manifest(cell, regression=block)
    if passes:
        zoo.check_regression(cell)
    else:
        with pytest.raises(zoo.ZooError, match="1 of 4 regression episodes differ .* no contract part changed"):
            zoo.check_regression(cell)


def test_tensors_that_cannot_fit_are_refused(tiny_cell, tmp_path):
    cell = Path(shutil.copytree(tiny_cell, tmp_path / "wide"))
    manifest = json.loads((cell / zoo.MANIFEST).read_text())
    manifest["config"]["agent"]["actor_hidden"] = [17, 16]
    (cell / zoo.MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(zoo.ZooError, match=r"actor\.layers\.0\.\w+ has shape \(2, [\d, ]*16\), .* needs \(2, [\d, ]*17\)"):
        zoo.read_cell(cell)
    manifest["config"]["agent"]["actor_hidden"] = [16, 16]
    manifest["dtype"] = "float32"
    (cell / zoo.MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(zoo.ZooError, match="is torch.float16, the manifest says float32"):
        zoo.read_cell(cell)


def test_a_damaged_weights_file_is_named(tiny_cell, tmp_path):
    cell = Path(shutil.copytree(tiny_cell, tmp_path / "damaged"))
    data = (cell / zoo.WEIGHTS).read_bytes()
    (cell / zoo.WEIGHTS).write_bytes(data[: len(data) // 2])
    with pytest.raises(zoo.ZooError, match=r"networks\.safetensors is damaged"):
        zoo.read_cell(cell)


def test_export_refuses_an_unfinished_run_and_an_occupied_out(tiny_run, tiny_cell, tmp_path):
    run = Path(shutil.copytree(tiny_run, tmp_path / "unfinished"))
    (run / DONE).unlink()
    with pytest.raises(zoo.ZooError, match="has not finished training"):
        zoo.export(run, tmp_path / "new")
    assert not (tmp_path / "new").exists()
    with pytest.raises(zoo.ZooError, match="exists and is not empty"):
        zoo.export(tiny_run, tiny_cell)
    with pytest.raises(zoo.ZooError, match="dtype must be one of"):
        zoo.export(tiny_run, tmp_path / "new", dtype="bf16")


def test_the_resolver_materializes_a_cell_once_and_passes_a_run_through(tiny_run, tiny_cell, cache):
    assert zoo.resolve_run(tiny_run) == Path(tiny_run)
    run = zoo.resolve_run(tiny_cell)
    assert run.parent == cache and (run / DONE).is_file() and zoo.resolve_run(str(tiny_cell)) == run
    with pytest.raises(FileNotFoundError, match="zoo:nope is not a zoo cell"):
        zoo.resolve_run("zoo:nope")


def test_a_cell_trained_on_a_gpu_runs_on_the_cpu(tiny_cell, tmp_path):
    cell = Path(shutil.copytree(tiny_cell, tmp_path / "gpu"))
    manifest = json.loads((cell / zoo.MANIFEST).read_text())
    manifest["config"]["device"] = "cuda"
    (cell / zoo.MANIFEST).write_text(json.dumps(manifest))
    run = zoo.materialize(cell)
    assert RunDir(run).train_config().device == "cpu"
    assert evaluate(run, protocols=("grid",), limit=1, threads=1)["protocols"]["grid"]["episodes"] == 2


def test_evaluate_and_zoo_list_accept_a_cell(tiny_cell, capsys):
    assert main(["evaluate", str(tiny_cell), "--protocols", "grid", "--limit", "1", "--no-progress", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["agent"] == "apac" and out["protocols"]["grid"]["episodes"] == 2
    assert main(["zoo", "list", "--root", str(tiny_cell.parent)]) == 0
    assert "apac on changing_target, seeds 0-1 x 3 episodes, float16" in capsys.readouterr().out


def test_forced_response_test_reads_a_cell_of_a_planning_kind_as_its_run(tmp_path, capsys):
    """A cued task and a kind with a dynamics model and a planner's random streams: the cell's table is the run's."""
    from conftest import TINY_MPC

    cfg = TrainConfig(task="cued_targets", seeds=(0,), episodes=2, checkpoint_every=2, actuation="kinematic",
                      agent=AgentConfig(kind="apac_voc", **{**TINY, "planning_episodes": 1}, params=TINY_MPC))
    run = train(cfg, tmp_path / "run", progress=False)
    cell = zoo.export(run, tmp_path / "cell", dtype="fp32")
    assert "dynamics_model" in zoo.read_manifest(cell)["networks"]
    small = ["--set", "trials=2", "--set", "repeats=1", "--set", "prep_times_ms=900"]
    tables = []
    for source, out in ((run, tmp_path / "run.parquet"), (cell, tmp_path / "cell.parquet")):
        assert main(["forced-response", "test", str(source), "--out", str(out), *small]) == 0
        tables.append(deterministic(pd.read_parquet(out)))
    pd.testing.assert_frame_equal(tables[1], tables[0])
    rrd = tmp_path / "cell.rrd"
    assert main(["forced-response", "record", str(cell), "--out", str(rrd), "--prep-times", "900"]) == 0
    assert rrd.stat().st_size > 1000


@pytest.mark.parametrize("cell", zoo.list_cells(), ids=lambda p: p.name)
def test_a_shipped_cell_rescores_its_stored_episodes_exactly(cell):
    """CI's regression test: the shipped weights, on their stored targets, give the stored numbers to the bit; a
    change to the plant, the task or the inference path fails here, naming the contract part that moved."""
    zoo.check_regression(cell)


def test_no_shipped_weight_file_is_over_5_mb():
    """A cell's weights are split into files of at most SHARD_BYTES (a larger tensor alone), so a repository keeps
    no file over 5 MB; packing keeps every tensor and its order."""
    import torch

    for cell in zoo.list_cells():
        assert all(f.stat().st_size < 5_000_000 for f in zoo.weight_files(cell)), cell
    t = {f"t{i}": torch.zeros(n) for i, n in enumerate((600_000, 600_000, 2_000_000, 10))}
    groups = zoo._shard(t)
    assert [list(g) for g in groups] == [["t0"], ["t1"], ["t2"], ["t3"]]  # 2.4 + 2.4 MB > 4 MB; 8 MB alone
    assert [k for g in groups for k in g] == list(t)
