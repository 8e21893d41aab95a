"""The built wheel ships the MJCF model and the task files, and apac_mj.paths finds them."""
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
    assert len(tasks) == 12
    assert {f"apac_mj/tasks/{t}" for t in tasks} <= names
    presets = {p.name for p in (REPO / "tasks" / "presets").glob("*.toml")}
    assert {"paper.toml", "quick.toml", "smoke.toml", "demo.toml"} <= presets
    assert {f"apac_mj/tasks/presets/{t}" for t in presets} <= names
    assert "apac_mj/suite/planar_arm.py" in names and "apac_mj/commands/check_kinematics.py" in names


def test_installed_paths_find_the_data(wheel, tmp_path):
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import apac_mj.paths as p, apac_mj.suite as s; "
            "print(p.arm_xml_path()); print(p.tasks_dir()); print(len(s.ALL_TASKS))")
    env = {**os.environ, "PYTHONPATH": str(site)}
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                         cwd=tmp_path, env=env).stdout.split()
    assert out == [str(site / "apac_mj/assets/planar_arm.xml"), str(site / "apac_mj/tasks"), "12"]
