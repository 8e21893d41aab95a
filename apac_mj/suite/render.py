"""Offscreen renders of the arm from the MJCF's overhead camera, JPEG-encoded.

Rendering costs a few ms with software GL (bench/record.py), so it is done only
for recorded episodes, never during plain training steps. Nothing here needs a
display: MuJoCo renders offscreen through ``MUJOCO_GL`` (``egl`` by default,
set by :mod:`apac_mj`; ``osmesa`` is the software fallback).
"""
from __future__ import annotations

import io
import os

import imageio.v3 as iio
import numpy as np
from PIL import Image


def _gl_hint(e: BaseException) -> str:
    backend = os.environ.get("MUJOCO_GL", "<unset>")
    return (
        f"cannot create an offscreen OpenGL context with MUJOCO_GL={backend!r} ({type(e).__name__}: {e}). "
        "Rendering needs no display but needs an OpenGL backend: install EGL (e.g. apt-get install libegl1) "
        "and keep MUJOCO_GL=egl, or install OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=osmesa; "
        "set MUJOCO_GL before importing apac_mj, mujoco or dm_control."
    )


try:
    import mujoco
except Exception as e:  # mujoco loads the MUJOCO_GL backend on import: a missing library fails here
    raise RuntimeError(_gl_hint(e)) from e

#: Default frame size (height, width) in pixels: square, as the overhead camera frames the square plane.
FRAME_SHAPE = (240, 240)
#: The MJCF camera that looks straight down on the plane.
CAMERA = "overhead"


class Renderer:
    """One offscreen MuJoCo renderer for one physics (one environment).

    Args:
      physics: a dm_control ``Physics`` (its ``model.ptr``/``data.ptr`` are rendered).
      height, width: frame size in pixels (at most the MJCF's offscreen buffer, 640 x 640).
      camera: name of the MJCF camera.
      multisamples: MSAA samples of the offscreen buffer. 0 (the default) costs less than half the
        time of MuJoCo's default 4 under software GL, for slightly jagged edges.
    """

    def __init__(self, physics, height: int = FRAME_SHAPE[0], width: int = FRAME_SHAPE[1], camera: str = CAMERA,
                 multisamples: int = 0) -> None:
        if height < 1 or width < 1:
            raise ValueError(f"frame size must be positive, got {height} x {width}")
        self.physics = physics
        self.camera = camera
        model = physics.model.ptr
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise ValueError(f"the model has no camera named {camera!r}")
        if multisamples < 0:
            raise ValueError(f"multisamples must be >= 0, got {multisamples}")
        # The GL context reads the sample count when it is created: set it for this renderer only.
        saved = model.vis.quality.offsamples
        model.vis.quality.offsamples = multisamples
        try:
            self._renderer = _make_renderer(model, height, width)
        finally:
            model.vis.quality.offsamples = saved

    def render(self) -> np.ndarray:
        """The current frame, uint8 RGB of shape (height, width, 3)."""
        self._renderer.update_scene(self.physics.data.ptr, camera=self.camera)
        return self._renderer.render()

    def close(self) -> None:
        self._renderer.close()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _make_renderer(model, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer``, or a RuntimeError that says how to get an OpenGL backend."""
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except ValueError:
        raise  # frame larger than the offscreen buffer: mujoco's message names the limit
    except Exception as e:  # mujoco raises several types when no GL context can be made
        raise RuntimeError(_gl_hint(e)) from e


def encode_jpeg(rgb: np.ndarray, quality: int = 75) -> bytes:
    """JPEG bytes of a uint8 RGB frame (a 240 x 320 arm frame is a few KB)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected a uint8 RGB frame of shape (H, W, 3), got {rgb.dtype} {rgb.shape}")
    if not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality must be in [1, 100], got {quality}")
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=quality)  # ~0.3 ms; imageio's wrapper costs ~2 ms
    return buf.getvalue()


def write_video(path, frames: list[np.ndarray], fps: int = 10) -> None:
    """Write frames as ``.mp4`` (imageio-ffmpeg) or ``.gif`` (pillow)."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".mp4", ".gif"):
        raise ValueError(f"video file must end in .mp4 or .gif, got {path!r}")
    if not frames:
        raise ValueError("no frames to write")
    if ext == ".gif":
        iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000 / fps, loop=0)
    else:
        iio.imwrite(path, np.stack(frames), extension=".mp4", fps=fps, codec="libx264", macro_block_size=8)
