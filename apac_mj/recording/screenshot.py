"""A screenshot of a recording in the real Rerun viewer, headless (``apac-mj screenshot``).

The viewer is started under ``xvfb-run`` (a virtual X display) with ``--screenshot-to``; it saves one frame
and exits. Xvfb starts its pointer at the centre of its screen, and the viewer shows a hover tooltip
wherever the pointer rests over a spatial view: with the screen as large as the window (``xvfb-run``'s
default) the pointer sits on the plane view and every screenshot has a tooltip over the arm. The screen is
therefore made more than twice the window's largest drawn size in each direction, so that its centre lies
outside the window (which the X server places at the screen's top-left corner; the viewer may draw at up to
:data:`MAX_SCALE` times the requested size).
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import subprocess
import sys
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


def screenshot(rrd: str | Path, png: str | Path, window: tuple[int, int] = DEFAULT_WINDOW,
               timeout_s: float = DEFAULT_TIMEOUT_S) -> Path:
    """Save a screenshot of the recording ``rrd`` to ``png`` (a new or replaced file; nothing is written when
    the viewer fails). Needs ``xvfb-run`` and a Vulkan or OpenGL driver (:data:`INSTALL_HINT`)."""
    rrd, png = Path(rrd), Path(png)
    if not rrd.is_file():
        raise FileNotFoundError(f"recording {rrd} does not exist (make one with `apac-mj record --out {rrd}`)")
    if png.suffix.lower() != ".png":
        raise ValueError(f"--out must end in .png, got {str(png)!r}")
    if shutil.which("xvfb-run") is None:
        raise FileNotFoundError(f"xvfb-run was not found on PATH: the headless viewer needs it ({INSTALL_HINT})")
    if not png.parent.is_dir():
        raise FileNotFoundError(f"the folder of --out, {png.parent}, does not exist")
    partial = png.with_name(png.stem + ".partial.png")
    partial.unlink(missing_ok=True)
    argv = command(rrd, partial.resolve(), window, viewer_binary())
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        partial.unlink(missing_ok=True)
        raise TimeoutError(f"the viewer did not save a screenshot of {rrd} within {timeout_s:.0f} s "
                           f"(a software renderer on a busy machine is slow: try --timeout)") from None
    if done.returncode != 0 or not partial.is_file() or partial.stat().st_size == 0:
        partial.unlink(missing_ok=True)
        tail = "\n".join((done.stderr or "").strip().splitlines()[-5:])
        raise RuntimeError(f"the viewer exited with status {done.returncode} without a screenshot of {rrd}; "
                           f"it needs a Vulkan or OpenGL driver ({INSTALL_HINT}). Its last lines:\n{tail}")
    os.replace(partial, png)
    return png
