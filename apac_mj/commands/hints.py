"""What the commands add to an error: the cells of a grid's results directory given where a run is expected, and
the way on from a run directory given where a grid's results directory is expected."""
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


def run_dir_hint(path: str | Path, command: str) -> str | None:
    """For a run directory (``apac-mj train``'s, or one cell of a grid) given where a grid's results directory
    is expected: why it is not one, and what to run instead; None for anything else."""
    from apac_mj.experiments.results import CELL_FILE, cell_dirs
    from apac_mj.run.run_dir import RunDir

    path, run = Path(path), RunDir(path)
    if not path.is_dir() or not (run.exists() or run.has_metrics()) or cell_dirs(path):
        return None
    instead = (f"apac-mj {command} {path.parent} (its grid's results directory)" if (path / CELL_FILE).is_file()
               else f"apac-mj evaluate {path} to test this run and print its summary")
    return (f"{path} is a run directory, not a grid's results directory: {command} reads the results directory "
            f"apac-mj grid writes (one run directory per cell); run {instead}")
