"""Where cells run: this machine (LocalExecutor) or a Ray cluster (RayExecutor).

Both run the cell runner they are given (``grid.run_grid`` gives ``grid.run_cell``) on prepared cell directories,
so the results directory layout and the resume behaviour do not depend on the
executor. A cluster needs the results directory on a file system every node
sees (NFS, a mounted bucket); Ray carries only the cell's path and status.

Stopping: Ctrl-C or SIGTERM of the grid's main process cancels the cells not started, interrupts the
running ones (each says what its checkpoint holds; the next run resumes them) and returns within
seconds (:data:`STOP_SECONDS`, then the workers are killed). A pool worker also stops when the main
process dies without a word (kill -9): it asks the kernel for SIGTERM at its parent's death
(``PR_SET_PDEATHSIG``; elsewhere a thread watches the parent), so no worker writes on after it.
"""
from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from apac_mj.util.progress import PlainProgress, progress_bar

#: Seconds the grid waits for interrupted workers to say what they saved and exit before killing them.
STOP_SECONDS = 10.0

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


# -- pool workers: stop with the grid ------------------------------------------------------------
#: A pool worker is running a cell (an interrupt then stops the cell, which says what it saved).
_IN_CELL = False


def _worker_init(parent: int) -> None:
    """Set up a pool worker: SIGINT and SIGTERM interrupt its cell as Ctrl-C does (an idle worker just exits),
    and it gets SIGTERM when ``parent`` (the grid's main process) dies. A SIGINT the grid ignores (a job
    started in the background by a shell) stays ignored, as it does for the grid itself. Its progress bars
    share a thread lock (:func:`_bars_without_semaphore`)."""
    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, _on_interrupt)
    signal.signal(signal.SIGTERM, _on_interrupt)
    _die_with_parent(parent)
    _bars_without_semaphore()


def _bars_without_semaphore() -> None:
    """tqdm's bars lock a multiprocessing RLock, which in a spawned worker is a named semaphore the resource
    tracker holds until the worker's exit handlers release it: a worker killed with -9 (or ended by
    ``os._exit`` when its cell is interrupted) never runs them, and the grid's exit then printed
    "resource_tracker: There appear to be 2 leaked semaphore objects". The lock is the worker's own (no other
    process shares it), so a thread lock does the same work and leaves nothing behind."""
    from tqdm import tqdm as std_tqdm

    std_tqdm.set_lock(threading.RLock())


def _on_interrupt(signum: int, frame: object) -> None:
    if _IN_CELL:
        raise KeyboardInterrupt
    os._exit(128 + signum)


def _die_with_parent(parent: int) -> None:
    """SIGTERM to this process when ``parent`` dies: the kernel's PR_SET_PDEATHSIG on Linux, else a watcher thread."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(1, signal.SIGTERM, 0, 0, 0) != 0:  # PR_SET_PDEATHSIG = 1
            raise OSError(ctypes.get_errno(), "prctl")
    except (OSError, AttributeError):
        def watch() -> None:
            while os.getppid() == parent:
                time.sleep(1.0)
            os.kill(os.getpid(), signal.SIGTERM)

        threading.Thread(target=watch, daemon=True).start()
    if os.getppid() != parent:  # it died before the request took effect
        os.kill(os.getpid(), signal.SIGTERM)


def _pool_run_cell(run_cell: CellRunner, cell_dir: str, progress: bool, threads: int = 1) -> dict[str, Any]:
    """:func:`_safe_run_cell` in a pool worker; an interrupted cell ends the worker (the grid is stopping)."""
    global _IN_CELL
    _IN_CELL = True
    try:
        return _safe_run_cell(run_cell, cell_dir, progress, threads)
    except KeyboardInterrupt:
        sys.stderr.flush()
        os._exit(130)
    finally:
        _IN_CELL = False


def _stop_pool(pool: cf.ProcessPoolExecutor, workers: list[multiprocessing.Process]) -> None:
    """Cancel the cells not started, interrupt the running ones (SIGTERM), kill what is left after STOP_SECONDS."""
    pool.shutdown(wait=False, cancel_futures=True)
    for p in workers:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + STOP_SECONDS
    for p in workers:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)


def _grid_bar(progress: bool, done: int, total: int) -> tqdm | PlainProgress:
    """The grid's bar of finished cells: tqdm's on a terminal; elsewhere, and without ``progress`` (the cells'
    own bars off: ``--no-progress``), one plain line per finished cell."""
    return progress_bar(total, "grid", "cell", initial=done, plain=True if not progress else None, every=1,
                        position=0, dynamic_ncols=True)


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
            before = set(multiprocessing.active_children())
            pool = cf.ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=_worker_init,
                                          initargs=(os.getpid(),))
            try:
                futures = [pool.submit(_pool_run_cell, run_cell, d, progress, threads) for d in cell_dirs]
                for fut in cf.as_completed(futures):
                    try:
                        res = fut.result()
                    except cf.BrokenExecutor:
                        raise RuntimeError("a grid worker process died (killed, or out of memory); finished cells "
                                           "are kept: run the same command again to resume the others") from None
                    _report(bar, on_result, res)
            except BaseException:
                _stop_pool(pool, [p for p in multiprocessing.active_children() if p not in before])
                raise
            pool.shutdown(wait=True)


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
        watchdog = _ray_watchdog() if started_here and not self.address else None
        pending: list[Any] = []
        try:
            remote = ray.remote(num_cpus=threads, max_retries=RAY_CELL_RETRIES)(_safe_run_cell)
            pending = [remote.remote(run_cell, d, False, threads) for d in cell_dirs]
            with _grid_bar(progress, done, total or len(cell_dirs)) as bar:
                while pending:
                    ready, pending = ray.wait(pending, num_returns=1)
                    _report(bar, on_result, ray.get(ready[0]))
        except BaseException:
            for ref in pending:  # stop the running and queued cells (their last checkpoints are kept)
                ray.cancel(ref, force=True)
            raise
        finally:
            if started_here:
                ray.shutdown()
            if watchdog is not None:
                watchdog.kill()
                watchdog.wait()

    def _init(self, ray: Any) -> bool:
        if ray.is_initialized():
            return False
        if self.address:
            ray.init(address=self.address, log_to_driver=True)
        else:
            ray.init(address="local", include_dashboard=False, num_cpus=self.num_cpus,
                     _node_ip_address="127.0.0.1", log_to_driver=True, configure_logging=False)
        return True


#: Where :func:`apac_mj.experiments.grid.run_grid` runs its cells.
Executor = LocalExecutor | RayExecutor

#: The directory holding this apac_mj package: the watchdog starts there, so ``-m`` finds this same package.
_PACKAGE_PARENT = str(Path(__file__).resolve().parents[2])


def _ray_watchdog() -> subprocess.Popen[bytes] | None:
    """A process (:mod:`apac_mj.experiments.watchdog`) that stops the local Ray instance's processes if this
    process (the driver) dies without shutting it down (kill -9): Ray's own agents outlive their driver by a
    minute or more (they wait 60 s to report the death to the gone GCS). Linux only (/proc); elsewhere None."""
    if not os.path.isdir(f"/proc/{os.getpid()}/task"):
        return None
    return subprocess.Popen([sys.executable, "-m", "apac_mj.experiments.watchdog", str(os.getpid())],
                            start_new_session=True, cwd=_PACKAGE_PARENT, stdin=subprocess.DEVNULL,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def import_ray() -> Any:
    try:
        import ray
    except ImportError as e:
        raise RuntimeError("--executor ray needs the optional Ray extra: pip install 'apac_mj[ray]'") from e
    return ray


def _report(bar: tqdm, on_result: OnResult, res: dict[str, Any]) -> None:
    on_result(res)
    bar.set_postfix_str(f"{res['cell']}: {res['status']}", refresh=False)  # before the update: a plain line has it
    bar.update(1)


def make_executor(name: str, workers: int = 1, ray_address: str | None = None) -> Executor:
    """``--executor`` to an executor: "local" or "ray"."""
    if name == "local":
        if ray_address:
            raise ValueError("--ray-address needs --executor ray")
        return LocalExecutor(workers)
    if name == "ray":
        return RayExecutor(address=ray_address)
    raise ValueError(f"unknown executor {name!r}; choose 'local' or 'ray'")
