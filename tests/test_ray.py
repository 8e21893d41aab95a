"""The Ray executor on a local Ray instance bound to 127.0.0.1: same cells, same layout, same numbers as local."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd
import pytest
import torch

from apac_mj.experiments import grid
from apac_mj.experiments.presets import load_preset
from apac_mj.experiments.results import load_results, load_tests
from apac_mj.experiments.executors import LocalExecutor, RayExecutor, make_executor

from conftest import deterministic

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
        pd.testing.assert_frame_equal(deterministic(load(tmp_path / "local")), deterministic(load(tmp_path / "ray")),
                                      check_exact=True)


# -- a real cluster: `ray start --head`, a second `ray start --address` node, `apac-mj grid --ray-address` --------

#: Cells of the cluster test: 4 cells (2 agents x 2 conditions) of 2 seeds, long enough (6 episodes,
#: checkpoint every one) that a node can be killed while one of its cells runs.
CLUSTER = ["seeds=2", "episodes=6", "checkpoint_every=1", "conditions=static_target,changing_target",
           "agents=spac,apac", "tests.generalization=false"]
CELL_PROC = "ray::_safe_run_cell"  # the process title of a Ray worker running a cell


def _ray_start(*args: str, temp_dir: str, env: dict[str, str]) -> None:
    import subprocess

    cmd = ["ray", "start", *args, "--num-cpus=1", "--object-store-memory=80000000", "--disable-usage-stats",
           f"--temp-dir={temp_dir}"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env=env)
    assert out.returncode == 0, f"{' '.join(cmd)} failed:\n{out.stdout}\n{out.stderr}"


def _node_processes(*marks: str) -> list:
    """The processes whose command lines name one of ``marks`` (a node's temp dir, the head's address), and
    their children: exactly one Ray cluster's processes."""
    import psutil

    found = {}
    for p in psutil.process_iter(["cmdline"]):
        line = " ".join(p.info["cmdline"] or [])
        if any(m in line for m in marks) and p.pid != os.getpid() and "pytest" not in line:
            found[p.pid] = p
    for p in list(found.values()):
        try:
            found.update({c.pid: c for c in p.children(recursive=True)})
        except psutil.NoSuchProcess:
            pass
    return list(found.values())


def _raylet(temp_dir: str):
    return next(p for p in _node_processes(temp_dir) if "raylet" in p.name())


def _running_cells(raylet) -> int:
    import psutil

    try:
        return sum(" ".join(c.cmdline()).startswith(CELL_PROC) for c in raylet.children())
    except psutil.NoSuchProcess:
        return 0


def _kill(processes) -> None:
    import psutil

    for p in processes:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass
    psutil.wait_procs(processes, timeout=10)


@pytest.mark.slow
def test_grid_on_a_ray_cluster_survives_a_killed_worker_node(tmp_path: Path) -> None:
    """The way a user scales out: `ray start --head`, a second node with `ray start --address`, then
    `apac-mj grid --executor ray --ray-address`. The cells run on both nodes at once; the worker node is
    killed (SIGKILL, raylet and its workers) while a cell runs there; the grid still finishes, every cell
    done, with results identical to a local run. Teardown kills exactly this cluster's processes (a
    `ray stop` would stop every Ray instance of the machine, other users' included)."""
    pytest.importorskip("ray", reason="the optional Ray extra is not installed (pip install 'apac_mj[ray]')")
    import secrets
    import shutil
    import socket
    import subprocess
    import tempfile
    import time

    with socket.socket() as s:  # a free port for the head's GCS
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    head_dir, worker_dir = tempfile.mkdtemp(prefix="rh"), tempfile.mkdtemp(prefix="rw")  # short: socket paths
    sets = [a for kv in CLUSTER for a in ("--set", kv)]
    # Ray 2.60's head turns token authentication on: every node and the driver carry the cluster's token
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    proc, address = None, None
    try:
        _ray_start("--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--include-dashboard=false",
                   temp_dir=head_dir, env=env)
        address = (Path(head_dir) / "ray_current_cluster").read_text().strip()
        _ray_start(f"--address={address}", temp_dir=worker_dir, env=env)
        head, worker = _raylet(head_dir), _raylet(worker_dir)
        proc = subprocess.Popen(["apac-mj", "grid", "--preset", "smoke", *sets, "--executor", "ray",
                                 "--ray-address", address, "--out", str(tmp_path / "ray"), "--no-progress"],
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 300
        while not (_running_cells(head) and _running_cells(worker)):  # spread: a cell on each node at once
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()[0][-3000:]
            time.sleep(0.2)
        time.sleep(2.0)  # into the cell: imports done, training under way
        assert _running_cells(worker) and proc.poll() is None, "the worker's cell ended before the kill"
        _kill(_node_processes(worker_dir))
        assert not worker.is_running() and proc.poll() is None
        unfinished = [d.name for d in (tmp_path / "ray").iterdir() if d.is_dir() and not grid.cell_done(d)]
        assert len(unfinished) >= 2  # the killed cell and the head's, at least
        out, _ = proc.communicate(timeout=600)
        assert proc.returncode == 0, out[-3000:]
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
        _kill(_node_processes(worker_dir, head_dir, *([address] if address else [])))
        shutil.rmtree(head_dir, ignore_errors=True)
        shutil.rmtree(worker_dir, ignore_errors=True)
    assert all(c["status"] == "done" for c in _cells(tmp_path / "ray").values())
    threads = torch.get_num_threads()
    try:
        grid.run_grid(load_preset("smoke", CLUSTER), tmp_path / "local", LocalExecutor(), progress=False)
    finally:
        torch.set_num_threads(threads)
    assert _cells(tmp_path / "ray") == _cells(tmp_path / "local")
    for load in (load_results, load_tests):
        pd.testing.assert_frame_equal(deterministic(load(tmp_path / "local")), deterministic(load(tmp_path / "ray")),
                                      check_exact=True)
