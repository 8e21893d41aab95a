"""apac_mj: the Arbitrated Predictive Actor-Critic (Fard & Trappenberg) on a MuJoCo arm."""
import os

# Offscreen rendering must pick its OpenGL backend before dm_control/mujoco load it.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
