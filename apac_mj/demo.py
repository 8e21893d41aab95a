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


def run_demo(preset: str | Path = "demo", out: str | Path = "results/demo", overrides: Sequence[str] = (),
             record_episodes: int = 3, progress: bool = True,
             say: Callable[[str], None] = lambda _: None) -> DemoResult:
    """Run the preset's grid into ``out`` (resuming), write its report, then record ``record_episodes``
    episodes of the first arbitrating kind's main-study cell (0: none)."""
    from apac_mj.experiments import grid
    from apac_mj.experiments.presets import load_preset
    from apac_mj.recording.record import reached_targets, record, showcase_member
    from apac_mj.report import write_report

    if record_episodes < 0:
        raise ValueError(f"--record-episodes must be >= 0, got {record_episodes}")
    start = time.perf_counter()
    p = load_preset(preset, overrides)
    out = Path(out)
    say(grid.describe(p))
    grid.run_grid(p, out, progress=progress)
    report_dir = write_report(out)
    rrd = None
    arbitrating = [c for c in grid.cells(p) if kinds.get(c.agent).arbitrates and c.region == "all"]
    if record_episodes and arbitrating:
        rrd, run = out / f"{arbitrating[0].name}.rrd", out / arbitrating[0].name
        reached = reached_targets(run, record_episodes)
        member = showcase_member(reached)
        say(f"recording seed {p.seeds[member]} of {arbitrating[0].name}: its {record_episodes} frozen episodes "
            f"reach {int(reached[member].sum())} of {record_episodes} targets (all seeds: "
            f"{int(reached.sum())} of {reached.size})")
        record(rrd, run=run, member=member, episodes=record_episodes, progress=progress)
    return DemoResult(report_dir, rrd, time.perf_counter() - start)
