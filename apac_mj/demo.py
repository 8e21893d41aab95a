"""The demo: a small real experiment (grid, report) and a recording of the trained APAC-like cell."""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable, Sequence

from apac_mj import kinds


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """Where the demo's outputs are."""

    report_dir: Path
    #: The recording of the trained arbitrating agent (None: not recorded).
    recording: Path | None
    wall_s: float


#: Steps the demo's recording shows at least (six seconds of the arm at its 100 ms step; it plays at that
#: rate): a trained agent reaches most targets in 1-3 steps, so three episodes were 8 frames.
RECORD_STEPS = 60
#: The most episodes the demo records to reach :data:`RECORD_STEPS`.
MAX_RECORD_EPISODES = 40


def run_demo(preset: str | Path = "demo", out: str | Path = "results/demo", overrides: Sequence[str] = (),
             record_episodes: int | None = None, progress: bool = True,
             say: Callable[[str], None] = lambda _: None, record_steps: int = RECORD_STEPS) -> DemoResult:
    """Run the preset's grid into ``out`` (resuming), write its report, then record the first arbitrating
    kind's main-study cell: ``record_episodes`` episodes (0: none), by default as many as take
    ``record_steps`` steps (at most :data:`MAX_RECORD_EPISODES`) of the seed that reaches most targets."""
    from apac_mj.experiments import grid
    from apac_mj.experiments.presets import load_preset
    from apac_mj.recording.record import episodes_for_steps, preview, record, showcase_member
    from apac_mj.report import write_report

    if record_episodes is not None and record_episodes < 0:
        raise ValueError(f"--record-episodes must be >= 0, got {record_episodes}")
    if record_steps < 1:
        raise ValueError(f"--record-steps must be >= 1, got {record_steps}")
    start = time.perf_counter()
    p = load_preset(preset, overrides)
    out = Path(out)
    say(grid.describe(p))
    grid.run_grid(p, out, progress=progress)
    report_dir = write_report(out)
    rrd = None
    arbitrating = [c for c in grid.cells(p) if kinds.get(c.agent).arbitrates and c.region == "all"]
    if record_episodes != 0 and arbitrating:
        rrd, run = out / f"{arbitrating[0].name}.rrd", out / arbitrating[0].name
        seen = preview(run, record_episodes or MAX_RECORD_EPISODES,
                       until_steps=None if record_episodes else record_steps)
        member = showcase_member(seen.reached)
        n = record_episodes or episodes_for_steps(seen.steps[member], record_steps)
        reached, steps = seen.reached[member, :n], seen.steps[member, :n]
        say(f"recording seed {p.seeds[member]} of {arbitrating[0].name}: its {n} frozen episodes take "
            f"{int(steps.sum())} steps and reach {int(reached.sum())} of {n} targets (all seeds: "
            f"{int(seen.reached[:, :n].sum())} of {seen.reached[:, :n].size})")
        record(rrd, run=run, member=member, episodes=n, progress=progress)
    return DemoResult(report_dir, rrd, time.perf_counter() - start)
