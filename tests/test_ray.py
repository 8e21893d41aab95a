"""The Ray executor on a local Ray instance bound to 127.0.0.1: same cells, same layout, same numbers as local."""
from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
import torch

from apac_mj.experiments import grid
from apac_mj.experiments.presets import load_preset
from apac_mj.experiments.results import load_results, load_tests
from apac_mj.experiments.executors import LocalExecutor, RayExecutor, make_executor

pytestmark = pytest.mark.ray

TINY = ["seeds=2", "episodes=2", "checkpoint_every=1", "conditions=changing_target", "agents=spac,apac",
        "tests.generalization=false"]


def test_make_executor_errors() -> None:
    with pytest.raises(ValueError, match="--ray-address needs --executor ray"):
        make_executor("local", ray_address="auto")
    with pytest.raises(ValueError, match="unknown executor 'slurm'"):
        make_executor("slurm")
    with pytest.raises(ValueError, match="workers must be >= 1"):
        LocalExecutor(0)


def _cells(results: Path) -> dict:
    cells = json.loads((results / "manifest.json").read_text())["cells"]
    return {name: {k: v for k, v in c.items() if k != "wall_s"} for name, c in cells.items()}


def test_ray_grid_equals_local_grid(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="the optional Ray extra is not installed (pip install 'apac_mj[ray]')")
    pytest.importorskip("apac_mj.run.trainer", reason="the trainer has not landed yet")
    pytest.importorskip("apac_mj.run.evaluate", reason="the evaluation has not landed yet")
    preset = load_preset("smoke", TINY)
    threads = torch.get_num_threads()
    try:
        grid.run_grid(preset, tmp_path / "local", LocalExecutor(), progress=False)
    finally:
        torch.set_num_threads(threads)  # run_cell sets the preset's threads (1) in this process
    assert not ray.is_initialized()
    manifest = grid.run_grid(preset, tmp_path / "ray", RayExecutor(num_cpus=1), progress=False)
    assert not ray.is_initialized(), "the executor shuts down the Ray instance it started"
    assert manifest["executor"] == "RayExecutor"
    assert _cells(tmp_path / "ray") == _cells(tmp_path / "local")
    assert all(c["status"] == "done" for c in _cells(tmp_path / "ray").values())
    names = sorted(p.relative_to(tmp_path / "local").as_posix() for p in (tmp_path / "local").rglob("*")
                   if "checkpoints" not in p.parts and p.name != "manifest.json")
    assert names == sorted(p.relative_to(tmp_path / "ray").as_posix() for p in (tmp_path / "ray").rglob("*")
                           if "checkpoints" not in p.parts and p.name != "manifest.json")
    for load in (load_results, load_tests):
        pd.testing.assert_frame_equal(load(tmp_path / "local"), load(tmp_path / "ray"), check_exact=True)
