"""apac-mj demo as a library function: grid, report and a recording of the arbitrating agent, no CLI re-entry."""
from __future__ import annotations

from apac_mj.demo import run_demo


def test_the_demo_records_enough_episodes_for_its_steps(tmp_path):
    """By default the demo records as many episodes as take ``record_steps`` steps (it was 3 episodes: 8
    frames for a trained agent): the recording then has at least that many step frames."""
    from apac_mj.recording import recording as R

    said = []
    result = run_demo("smoke", tmp_path / "demo", ["conditions=changing_target", "episodes=2", "seeds=1",
                                                   "tests.generalization=false", "tests.limit=1"],
                      progress=False, say=said.append, record_steps=40)
    entities, _, _ = R.read_recording(result.recording)
    texts = [t[0] for t in entities[R.EVENTS].components["TextLog:text"]]
    episodes = sum(t.startswith(("target reached", "time limit")) for t in texts)
    frames, _ = R.scalar_series(entities[R.DISTANCE])  # one per step and one per episode start
    steps = len(frames) - episodes
    assert steps >= 40 and episodes >= 1
    line = next(s for s in said if s.startswith("recording seed"))
    assert f"its {episodes} frozen episodes take {steps} steps" in line

