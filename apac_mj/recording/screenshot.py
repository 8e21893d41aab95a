"""A screenshot of a recording in the real Rerun viewer, headless (``apac-mj screenshot``).

The viewer is started under ``xvfb-run`` (a virtual X display) with ``--screenshot-to``; it saves one frame
and exits. Xvfb starts its pointer at the centre of its screen, and the viewer shows a hover tooltip
wherever the pointer rests over a spatial view: with the screen as large as the window (``xvfb-run``'s
default) the pointer sits on the plane view and every screenshot has a tooltip over the arm. The screen is
therefore made more than twice the window's largest drawn size in each direction, so that its centre lies
outside the window (which the X server places at the screen's top-left corner; the viewer may draw at up to
:data:`MAX_SCALE` times the requested size).

The recording is read through to its end before the viewer starts (:func:`check_recording`): the viewer shows
an error page for a file it cannot load, and a screenshot of that page is no screenshot of a recording.
``xvfb-run``, Xvfb and the viewer run in a session of their own, ended as a whole on every way out (done,
failed, timed out, interrupted), so that no process outlives the command and no ``NAME.partial.png`` appears
later.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

#: The largest factor between the requested window size and the pixels the viewer draws (its screenshots
#: of a 1400x800 window are 2800x1600 under Xvfb with Mesa's llvmpipe).
MAX_SCALE = 2
#: Pixels beyond ``2 * MAX_SCALE`` times the window on each axis, so the centre is strictly outside.
MARGIN = 64
#: The viewer's window size, in its logical pixels (what ``--window-size`` takes).
DEFAULT_WINDOW = (1400, 800)
#: Seconds the viewer may take to load a recording and save the frame (software rendering is slow).
DEFAULT_TIMEOUT_S = 180.0

INSTALL_HINT = "apt-get install -y xvfb mesa-vulkan-drivers"
#: Seconds the viewer's processes get to end after SIGTERM before they are killed.
STOP_GRACE_S = 2.0


class NotARecording(ValueError):
    """The file given as a recording is not one the viewer can show (empty, cut short, not a Rerun file, or
    holding no recording); the message names the file and the cause. Nothing was started or written."""


@dataclasses.dataclass(frozen=True)
class Geometry:
    """The viewer window and the virtual screen it is shown on (pixels)."""

    window: tuple[int, int]
    screen: tuple[int, int]

    @property
    def pointer(self) -> tuple[int, int]:
        """Where Xvfb starts the pointer: the screen's centre."""
        return self.screen[0] // 2, self.screen[1] // 2

    def pointer_outside_window(self) -> bool:
        """Whether the pointer lies outside the window at the top-left corner at its largest drawn size."""
        px, py = self.pointer
        return px >= MAX_SCALE * self.window[0] or py >= MAX_SCALE * self.window[1]


def geometry(window: tuple[int, int] = DEFAULT_WINDOW) -> Geometry:
    """The virtual screen for a viewer window of ``window`` (width, height): its centre, where the pointer
    starts, lies beyond the window's largest drawn size on both axes."""
    w, h = window
    if w < 1 or h < 1:
        raise ValueError(f"--window-size must be positive, got {w}x{h}")
    return Geometry((w, h), (2 * MAX_SCALE * w + MARGIN, 2 * MAX_SCALE * h + MARGIN))


def parse_window_size(text: str) -> tuple[int, int]:
    """``"1400x800"`` -> (1400, 800), with an error naming the expected form."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"--window-size must be WIDTHxHEIGHT in pixels (e.g. 1400x800), got {text!r}")
    size = int(parts[0]), int(parts[1])
    if min(size) < 200 or max(size) > 8000:
        raise ValueError(f"--window-size must be between 200 and 8000 pixels per side, got {text!r}")
    return size


def viewer_binary() -> str:
    """The ``rerun`` viewer of this environment (beside its Python first, then on PATH)."""
    here = Path(sys.executable).parent / "rerun"
    if here.is_file() and os.access(here, os.X_OK):
        return str(here)
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("the Rerun viewer `rerun` was not found beside this Python or on PATH; "
                                "install this package's dependencies (rerun-sdk), e.g. `bash .ci/in-venv`")
    return found


def command(rrd: str | Path, png: str | Path, window: tuple[int, int] = DEFAULT_WINDOW,
            viewer: str = "rerun") -> list[str]:
    """The argv that saves a screenshot of ``rrd`` to ``png`` without a tooltip (see the module's doc)."""
    g = geometry(window)
    return ["xvfb-run", "-a", "-s", f"-screen 0 {g.screen[0]}x{g.screen[1]}x24", viewer, str(rrd),
            "--window-size", f"{window[0]}x{window[1]}", "--screenshot-to", str(png)]


def check_recording(rrd: Path) -> None:
    """``rrd`` reads to its end as a Rerun file holding a recording; else :class:`NotARecording` naming it."""
    from rerun.chunk import RrdReader

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the reader's own "no footer" warning: a cut file is said below
            reader = RrdReader(str(rrd))
            chunks = sum(1 for _ in reader.stream())
            recordings = reader.recordings()
    except (RuntimeError, ValueError, OSError) as e:
        raise NotARecording(f"{rrd} is not a Rerun recording the viewer can show ({e}); nothing was written. "
                            f"Give a .rrd that `apac-mj record` wrote") from None
    if not recordings or chunks == 0:
        raise NotARecording(f"{rrd} is a Rerun file but holds no recording (only a layout); nothing was written. "
                            "Give a .rrd that `apac-mj record` wrote")


def screenshot(rrd: str | Path, png: str | Path, window: tuple[int, int] = DEFAULT_WINDOW,
               timeout_s: float = DEFAULT_TIMEOUT_S) -> Path:
    """Save a screenshot of the recording ``rrd`` to ``png`` (a new or replaced file; nothing is written when
    the recording does not read or the viewer fails, and no process of the viewer outlives the call). Needs
    ``xvfb-run`` and a Vulkan or OpenGL driver (:data:`INSTALL_HINT`)."""
    rrd, png = Path(rrd), Path(png)
    _check(rrd, png, timeout_s)
    partial = png.with_name(png.stem + ".partial.png")
    partial.unlink(missing_ok=True)
    argv = command(rrd, partial.resolve(), window, viewer_binary())
    try:
        code, stderr = run_viewer(argv, timeout_s)
    except BaseException as e:  # a timeout or an interrupt: the viewer's processes have ended (run_viewer),
        partial.unlink(missing_ok=True)  # so none writes the partial file after this
        if isinstance(e, subprocess.TimeoutExpired):
            raise TimeoutError(f"the viewer did not save a screenshot of {rrd} within {timeout_s:g} s "
                               f"(a software renderer on a busy machine is slow: try --timeout)") from None
        raise
    if code != 0 or not partial.is_file() or partial.stat().st_size == 0:
        partial.unlink(missing_ok=True)
        tail = "\n".join(stderr.strip().splitlines()[-5:])
        raise RuntimeError(f"the viewer exited with status {code} without a screenshot of {rrd}; "
                           f"it needs a Vulkan or OpenGL driver ({INSTALL_HINT}). Its last lines:\n{tail}")
    os.replace(partial, png)
    return png


def _check(rrd: Path, png: Path, timeout_s: float) -> None:
    """Refuse what the viewer cannot do before anything starts or is written."""
    if not rrd.is_file():
        raise FileNotFoundError(f"recording {rrd} does not exist (make one with `apac-mj record --out {rrd}`)")
    if png.suffix.lower() != ".png":
        raise ValueError(f"--out must end in .png, got {str(png)!r}")
    if not timeout_s > 0:
        raise ValueError(f"--timeout must be a positive number of seconds, got {timeout_s:g}")
    if shutil.which("xvfb-run") is None:
        raise FileNotFoundError(f"xvfb-run was not found on PATH: the headless viewer needs it ({INSTALL_HINT})")
    if not png.parent.is_dir():
        raise FileNotFoundError(f"the folder of --out, {png.parent}, does not exist")
    check_recording(rrd)


def run_viewer(argv: list[str], timeout_s: float) -> tuple[int, str]:
    """Run ``argv`` (``xvfb-run ... rerun ...``) in a session of its own; ``(exit status, stderr)``. On a
    timeout (``subprocess.TimeoutExpired``), an interrupt or any other exit, the whole session (xvfb-run,
    Xvfb, the viewer) is ended before this returns or raises: ``xvfb-run`` killed alone leaves the others."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _, stderr = proc.communicate(timeout=timeout_s)
        return proc.returncode, stderr or ""
    finally:
        stop_group(proc)


def stop_group(proc: subprocess.Popen) -> None:
    """End every process of ``proc``'s process group (SIGTERM, then SIGKILL after STOP_GRACE_S) and reap
    ``proc``; returns once none is left (a group that already ended: nothing to do)."""
    for sig, wait_s in ((signal.SIGTERM, STOP_GRACE_S), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and _group_alive(proc):
            time.sleep(0.05)
        if not _group_alive(proc):
            break
    if proc.returncode is None:
        proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()


def _group_alive(proc: subprocess.Popen) -> bool:
    """Whether a process of ``proc``'s group is still running (``proc`` itself reaped when it ended)."""
    proc.poll()
    try:
        os.killpg(proc.pid, 0)
    except ProcessLookupError:
        return False
    return True
