"""Progress off a terminal (issue 45 item 12): plain lines, no cursor codes, at most one per finished cell or tenth
of a run; the grid's ``--no-progress`` prints one line per finished cell instead of nothing."""
from __future__ import annotations

import io
import re

from tqdm import tqdm

from apac_mj.util.progress import PlainProgress, progress_bar, progress_iter

#: What a redrawn bar leaves in a file: carriage returns and ANSI cursor codes.
CURSOR = re.compile(r"\r|\x1b\[")


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_file_gets_plain_lines_a_terminal_the_bar():
    out = io.StringIO()
    bar = progress_bar(100, "apac changing_target x2", "ep", file=out)
    assert isinstance(bar, PlainProgress)
    for _ in range(100):
        bar.set_postfix(success="0.50", habit="0.10", refresh=False)
        bar.update(1)
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 10 and not CURSOR.search(out.getvalue())
    assert lines[-1].startswith("apac changing_target x2: 100/100 ep (") and lines[-1].endswith("success=0.50, habit=0.10")
    assert isinstance(progress_bar(10, "x", "ep", file=_Terminal()), tqdm)
    assert isinstance(progress_bar(10, "x", "ep", file=_Terminal(), plain=True), PlainProgress)


def test_a_disabled_bar_writes_nothing():
    out = io.StringIO()
    assert list(progress_iter(range(5), 5, "record", "episode", enabled=False, file=out)) == list(range(5))
    assert out.getvalue() == ""


def test_a_resumed_bar_counts_from_where_it_was():
    out = io.StringIO()
    bar = progress_bar(10, "grid", "cell", initial=7, every=1, file=out)
    bar.update(3)
    assert out.getvalue().splitlines() == [out.getvalue().splitlines()[0]]
    assert out.getvalue().startswith("grid: 10/10 cell (")


def test_training_off_a_terminal_writes_a_line_per_tenth(capsys, tmp_path):
    """The trainer's bar under a captured (non-terminal) stderr: 20 episodes, at most 10 plain lines."""
    import apac_mj

    cfg = apac_mj.TrainConfig(task="changing_target", seeds=(0,), episodes=20, actuation="kinematic",
                              agent=apac_mj.AgentConfig(kind="ddpg", actor_hidden=(8, 8), critic_hidden=(8, 8),
                                                        forward_hidden=(8, 8), inverse_hidden=(8, 8), batch_size=4,
                                                        replay_size=32, babbling_episodes=1))
    apac_mj.train(cfg, tmp_path / "run", progress=True)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("ddpg changing_target x1: ")]
    assert not CURSOR.search(err), err[:500]
    babbling = [line for line in lines if "motor babbling" in line]
    assert len(babbling) == 1 and babbling[0].startswith("ddpg changing_target x1: 0/20 ep"), err
    counts = [line.split(": ", 1)[1].split(" ep")[0] for line in lines if line not in babbling]
    assert counts == [f"{n}/20" for n in range(2, 21, 2)], err


def _fake_cell(cell_dir: str, progress: bool, threads: int) -> dict:
    return {"cell": cell_dir.rsplit("/", 1)[-1], "status": "done"}


def test_the_grid_without_progress_says_each_finished_cell(capsys):
    from apac_mj.experiments.executors import LocalExecutor

    results: list[dict] = []
    LocalExecutor(1).run(["r/a__x", "r/b__x", "r/c__x"], _fake_cell, results.append, progress=False)
    err = capsys.readouterr().err
    assert [line.split(" (")[0] for line in err.splitlines()] == ["grid: 1/3 cell", "grid: 2/3 cell", "grid: 3/3 cell"]
    assert err.splitlines()[0].endswith("a__x: done") and not CURSOR.search(err)
    assert len(results) == 3


def test_a_label_between_counts_is_a_line_of_its_own():
    """The trainer's babbling label (shown before the first training episode) gets one line per new text."""
    out = io.StringIO()
    bar = progress_bar(5, "ddpg changing_target x1", "ep", file=out)
    for k in (1, 1, 2):
        bar.set_postfix_str(f"motor babbling: episode {k} of 2")
    bar.set_postfix_str("")
    assert [line.split(" (")[1] for line in out.getvalue().splitlines()] == [
        "0 s) motor babbling: episode 1 of 2", "0 s) motor babbling: episode 2 of 2"]
