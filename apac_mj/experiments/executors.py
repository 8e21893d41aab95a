"""Where cells run: this machine (LocalExecutor) or a Ray cluster (RayExecutor).

Both run the cell runner they are given (``grid.run_grid`` gives ``grid.run_cell``) on prepared cell directories,
so the results directory layout and the resume behaviour do not depend on the
executor. A cluster needs the results directory on a file system every node
sees (NFS, a mounted bucket); Ray carries only the cell's path and status.
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from tqdm.auto import tqdm

OnResult = Callable[[dict[str, Any]], None]
#: How often Ray reruns a cell whose worker process or node died (a Python exception in a cell is not
#: retried: it is the cell's "failed" status). The rerun resumes from the cell's last checkpoint, so the
#: numbers equal an uninterrupted run's (tests/test_ray.py kills a worker node mid-cell).
RAY_CELL_RETRIES = 3
#: ``run_cell(cell_dir, progress, threads) -> {"cell", "status", ...}``; a module-level function (pickled
#: for process pools and Ray).
CellRunner = Callable[[str, bool, int], dict[str, Any]]


def _safe_run_cell(run_cell: CellRunner, cell_dir: str, progress: bool, threads: int = 1) -> dict[str, Any]:
    """``run_cell``, with a failure reported as a status instead of ending the grid."""
    try:
        return run_cell(cell_dir, progress, threads)
    except Exception as e:  # noqa: BLE001 - a failed cell is recorded, the others go on
        traceback.print_exc()
        return {"cell": cell_dir.rstrip("/").rsplit("/", 1)[-1], "status": "failed", "error": f"{type(e).__name__}: {e}"}


def _grid_bar(progress: bool, done: int, total: int) -> tqdm:
    return tqdm(total=total, initial=done, desc="grid", unit="cell", position=0, disable=not progress,
                dynamic_ncols=True)


class LocalExecutor:
    """Cells on this machine: one after another in-process (workers=1), or in a process pool."""

    def __init__(self, workers: int = 1) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = workers

    def run(self, cell_dirs: Sequence[str], run_cell: CellRunner, on_result: OnResult, progress: bool = True,
            done: int = 0, total: int | None = None, threads: int = 1) -> None:
        """``run_cell`` on every directory; ``on_result`` gets each status as it arrives."""
        with _grid_bar(progress, done, total or len(cell_dirs)) as bar:
            if self.workers == 1:
                for d in cell_dirs:
                    _report(bar, on_result, _safe_run_cell(run_cell, d, progress, threads))
                return
            ctx = multiprocessing.get_context("spawn")
            with cf.ProcessPoolExecutor(self.workers, mp_context=ctx) as pool:
                futures = [pool.submit(_safe_run_cell, run_cell, d, progress, threads) for d in cell_dirs]
                for fut in cf.as_completed(futures):
                    _report(bar, on_result, fut.result())


class RayExecutor:
    """One Ray task per cell, reserving as many CPUs as the preset's torch threads.

    ``address=None`` starts a local Ray instance bound to 127.0.0.1 (``num_cpus`` caps it).
    """

    def __init__(self, address: str | None = None, num_cpus: int | None = None) -> None:
        self.address = address
        self.num_cpus = num_cpus

    def run(self, cell_dirs: Sequence[str], run_cell: CellRunner, on_result: OnResult, progress: bool = True,
            done: int = 0, total: int | None = None, threads: int = 1) -> None:
        """One Ray task of ``run_cell`` per directory; ``on_result`` gets each status as it arrives."""
        ray = import_ray()
        started_here = self._init(ray)
        try:
            remote = ray.remote(num_cpus=threads, max_retries=RAY_CELL_RETRIES)(_safe_run_cell)
            pending = [remote.remote(run_cell, d, False, threads) for d in cell_dirs]
            with _grid_bar(progress, done, total or len(cell_dirs)) as bar:
                while pending:
                    ready, pending = ray.wait(pending, num_returns=1)
                    _report(bar, on_result, ray.get(ready[0]))
        finally:
            if started_here:
                ray.shutdown()

    def _init(self, ray: Any) -> bool:
        if ray.is_initialized():
            return False
        if self.address:
            ray.init(address=self.address, log_to_driver=True)
        else:
            ray.init(address="local", include_dashboard=False, num_cpus=self.num_cpus,
                     _node_ip_address="127.0.0.1", log_to_driver=True, configure_logging=False)
        return True


def import_ray() -> Any:
    try:
        import ray
    except ImportError as e:
        raise RuntimeError("--executor ray needs the optional Ray extra: pip install 'apac_mj[ray]'") from e
    return ray


def _report(bar: tqdm, on_result: OnResult, res: dict[str, Any]) -> None:
    on_result(res)
    bar.update(1)
    bar.set_postfix_str(f"{res['cell']}: {res['status']}")


def make_executor(name: str, workers: int = 1, ray_address: str | None = None) -> LocalExecutor | RayExecutor:
    """``--executor`` to an executor: "local" or "ray"."""
    if name == "local":
        if ray_address:
            raise ValueError("--ray-address needs --executor ray")
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(address=ray_address)
    raise ValueError(f"unknown executor {name!r}; choose 'local' or 'ray'")
