"""The built wheel ships the MJCF model and the task files, and apac_mj.util.paths finds them."""
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """Build from a copy of the project files (no network, nothing written into the checkout)."""
    pytest.importorskip("setuptools")
    pytest.importorskip("wheel")
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    for name in ("apac_mj", "assets", "tasks"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.tmp"))
    out = tmp_path_factory.mktemp("whl")
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(src), "-w", str(out), "--no-deps",
                    "--no-build-isolation", "-q"], check=True, capture_output=True, cwd=src)
    (whl,) = out.glob("apac_mj-*.whl")
    return whl


def test_wheel_contains_model_and_task_files(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "apac_mj/assets/planar_arm.xml" in names
    tasks = {p.name for p in (REPO / "tasks").glob("*.toml")}
    assert {"static_target.toml", "changing_target_changing_kinematics_occluded.toml"} <= tasks  # every file, below
    assert {f"apac_mj/tasks/{t}" for t in tasks} <= names
    presets = {p.name for p in (REPO / "tasks" / "presets").glob("*.toml")}
    assert {"paper.toml", "quick.toml", "smoke.toml", "demo.toml"} <= presets
    assert {f"apac_mj/tasks/presets/{t}" for t in presets} <= names
    assert "apac_mj/suite/planar_arm.py" in names and "apac_mj/commands/check_kinematics.py" in names


def test_installed_paths_find_the_data(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import apac_mj.util.paths as p, apac_mj.suite as s; "
            "print(p.arm_xml_path()); print(p.tasks_dir()); print(len(s.ALL_TASKS))")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                         cwd=tmp_path, env=env).stdout.split()
    n_tasks = len(list((REPO / "tasks").glob("*.toml")))
    assert out == [str(site / "apac_mj/assets/planar_arm.xml"), str(site / "apac_mj/tasks"), str(n_tasks)]


# -- the torch build .ci/in-venv installs (the selection only; nothing is installed) ----------

def _torch_choice(tmp_path: Path, value: str | None, gpu: bool, index: str | None = None):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(exist_ok=True)
    fake = bin_dir / "nvidia-smi"
    if gpu:
        fake.write_text("#!/bin/sh\necho 'GPU 0: NVIDIA H200 (UUID: GPU-0)'\n")
        fake.chmod(0o755)
    else:
        fake.unlink(missing_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("APAC_MJ_TORCH")}
    env["PATH"] = f"{bin_dir}:/usr/bin:/bin"  # no real nvidia-smi unless faked
    if value is not None:
        env["APAC_MJ_TORCH"] = value
    if index is not None:
        env["APAC_MJ_TORCH_INDEX"] = index
    return subprocess.run(["bash", str(REPO / ".ci" / "torch-choice")], env=env, capture_output=True, text=True)


@pytest.mark.parametrize("value, gpu, expected", [
    (None, False, ["cpu", "torch==2.13.0", "--index-url", "https://download.pytorch.org/whl/cpu"]),
    ("auto", False, ["cpu", "torch==2.13.0", "--index-url", "https://download.pytorch.org/whl/cpu"]),
    (None, True, ["cuda", "torch==2.13.0"]),
    ("cpu", True, ["cpu", "torch==2.13.0", "--index-url", "https://download.pytorch.org/whl/cpu"]),
    ("cuda", False, ["cuda", "torch==2.13.0"]),
])
def test_torch_build_choice(tmp_path, value, gpu, expected):
    out = _torch_choice(tmp_path, value, gpu)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == expected


def test_torch_choice_index_override_and_bad_value(tmp_path):
    out = _torch_choice(tmp_path, "cuda", False, index="https://download.pytorch.org/whl/cu126")
    assert out.stdout.split() == ["cuda", "torch==2.13.0", "--index-url", "https://download.pytorch.org/whl/cu126"]
    out = _torch_choice(tmp_path, "rocm", False)
    assert out.returncode == 2 and "APAC_MJ_TORCH must be cpu, cuda or auto, got 'rocm'" in out.stderr


def test_torch_pin_matches_the_package():
    """.ci/torch-choice installs exactly the torch that pyproject.toml pins (so pip keeps it)."""
    import tomllib

    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    pin = next(d for d in deps if d.startswith("torch"))
    assert f'TORCH_PIN="{pin}"' in (REPO / ".ci" / "torch-choice").read_text()
    assert "torch-choice" in (REPO / ".ci" / "in-venv").read_text()
