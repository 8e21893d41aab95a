"""docs/extending.md: every example runs as written, from a directory outside the package, in its own process."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "extending.md"
EXAMPLES = re.findall(r"```python\n(.*?)```", DOC.read_text(), flags=re.S)


def test_the_doc_has_an_example_per_extension():
    assert len(EXAMPLES) == 6
    for api in ("kinds.register", "use_habit", "register_planner", "register_integrator", "register_task",
                "register_figure"):
        assert any(api in e for e in EXAMPLES), api
    assert not any("apac_mj/" in line for e in EXAMPLES for line in e.splitlines() if "open(" in line)


@pytest.mark.parametrize("index", range(len(EXAMPLES)))
def test_example_runs_as_written(index, tmp_path):
    script = tmp_path / f"example_{index}.py"
    script.write_text(EXAMPLES[index])
    env = {**os.environ, "PYTHONPATH": str(REPO), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
           "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    res = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().splitlines()[-1].startswith("ok: "), res.stdout
    assert not list(REPO.joinpath("tasks").glob("offset_shoulder*.toml"))  # nothing written into the package
