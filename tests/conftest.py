"""Test-wide settings: one torch thread (the networks here are small; on a shared 2-core machine
two intra-op threads spinning at barriers made updates 10-25x slower), offscreen GL."""
import os

os.environ.setdefault("MUJOCO_GL", "egl")

import torch  # noqa: E402

torch.set_num_threads(1)
