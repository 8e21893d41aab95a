"""What the commands add to an error: the cells of a grid's results directory given where a run is expected."""
from __future__ import annotations

from pathlib import Path


def results_dir_hint(path: str | Path, command: str) -> str | None:
    """For a grid's results directory (not itself a run): why it is not a run directory, and its cells to
    ``command`` instead; None for anything else."""
    from apac_mj.experiments.results import cell_dirs
    from apac_mj.run.run_dir import RunDir

    path = Path(path)
    if not path.is_dir() or RunDir(path).exists():
        return None
    cells = [d for d in cell_dirs(path) if RunDir(d).exists()]
    if not cells:
        return None
    return (f"{path} is a grid's results directory, not a run directory; {command} one of its cells: "
            + ", ".join(str(d) for d in cells))
