"""Offscreen renders of the arm from the MJCF's overhead camera, JPEG-encoded.

Rendering costs about as much as one training update (~18 ms for 240 x 320 with
software GL), so it is done only for recorded episodes. Nothing here needs a
display: MuJoCo renders offscreen through ``MUJOCO_GL`` (``egl`` by default,
set by :mod:`apac_mj`; ``osmesa`` is the software fallback).
"""
from __future__ import annotations

import io
import os

import imageio.v3 as iio
import mujoco
import numpy as np

#: Default frame size (height, width) in pixels.
FRAME_SHAPE = (240, 320)
#: The MJCF camera that looks straight down on the plane.
CAMERA = "overhead"


class Renderer:
    """One offscreen MuJoCo renderer for one physics (one environment).

    Args:
      physics: a dm_control ``Physics`` (its ``model.ptr``/``data.ptr`` are rendered).
      height, width: frame size in pixels (at most the MJCF's offscreen buffer, 640 x 640).
      camera: name of the MJCF camera.
    """

    def __init__(self, physics, height: int = FRAME_SHAPE[0], width: int = FRAME_SHAPE[1], camera: str = CAMERA) -> None:
        if height < 1 or width < 1:
            raise ValueError(f"frame size must be positive, got {height} x {width}")
        self.physics = physics
        self.camera = camera
        model = physics.model.ptr
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise ValueError(f"the model has no camera named {camera!r}")
        self._renderer = _make_renderer(model, height, width)

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
        backend = os.environ.get("MUJOCO_GL", "<unset>")
        raise RuntimeError(
            f"cannot create an offscreen OpenGL context with MUJOCO_GL={backend!r} ({type(e).__name__}: {e}). "
            "Rendering needs no display but needs an OpenGL backend: install EGL (e.g. apt-get install libegl1) "
            "and keep MUJOCO_GL=egl, or install OSMesa (apt-get install libosmesa6) and set MUJOCO_GL=osmesa; "
            "set MUJOCO_GL before importing apac_mj, mujoco or dm_control."
        ) from e


def encode_jpeg(rgb: np.ndarray, quality: int = 75) -> bytes:
    """JPEG bytes of a uint8 RGB frame (a 240 x 320 arm frame is a few KB)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected a uint8 RGB frame of shape (H, W, 3), got {rgb.dtype} {rgb.shape}")
    if not 1 <= quality <= 100:
        raise ValueError(f"JPEG quality must be in [1, 100], got {quality}")
    buf = io.BytesIO()
    iio.imwrite(buf, rgb, extension=".jpg", quality=quality)
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
