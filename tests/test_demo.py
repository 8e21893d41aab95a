"""apac-mj demo as a library function: grid, report and a recording of the arbitrating agent, no CLI re-entry."""
from __future__ import annotations

from apac_mj.demo import run_demo


def test_demo_runs_grid_report_and_recording(tmp_path):
    said = []
    result = run_demo("smoke", tmp_path / "demo", ["conditions=changing_target", "episodes=2",
                                                   "tests.generalization=false", "tests.limit=2"],
                      record_episodes=1, progress=False, say=said.append)
    assert said and "preset 'smoke'" in said[0]
    assert (result.report_dir / "report.md").is_file() and list(result.report_dir.glob("fig*.png"))
    assert result.recording == tmp_path / "demo" / "apac__changing_target.rrd"
    assert result.recording.stat().st_size > 0 and result.wall_s > 0
