"""The paper's motion function (Fard & Trappenberg, Appendix 1, Algorithm 1).

This is the analytic reference the MuJoCo arm is checked against. Angles are in
degrees, lengths in centimetres, exactly as in the paper.
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    import torch

#: Shoulder position on the paper's 30 x 30 plane.
DEFAULT_ORIGIN = (15.0, 15.0)


def motion_function(
    alpha_deg: ArrayLike,
    beta_deg: ArrayLike,
    l1: ArrayLike,
    l2: ArrayLike,
    origin: ArrayLike = DEFAULT_ORIGIN,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions of the end-effector and the elbow (Algorithm 1).

    Args:
      alpha_deg: shoulder angle(s) in degrees.
      beta_deg: elbow angle(s) in degrees, relative to the upper arm.
      l1: upper-arm length(s) (shoulder -> elbow).
      l2: forearm length(s) (elbow -> hand).
      origin: shoulder position, shape (2,) or broadcastable to (..., 2).

    Returns:
      ``(end_xy, elbow_xy)``, each of shape ``broadcast(...) + (2,)``.
    """
    a1 = np.asarray(alpha_deg, dtype=np.float64) * (np.pi / 180.0)
    b1 = np.asarray(beta_deg, dtype=np.float64) * (np.pi / 180.0)
    l1 = np.asarray(l1, dtype=np.float64)
    l2 = np.asarray(l2, dtype=np.float64)
    o = np.asarray(origin, dtype=np.float64)
    elbow_x = np.cos(a1) * l1
    elbow_y = np.sin(a1) * l1
    end_x = elbow_x + np.cos(b1 + a1) * l2
    end_y = elbow_y + np.sin(b1 + a1) * l2
    end = np.stack(np.broadcast_arrays(end_x, end_y), axis=-1) + o
    elbow = np.stack(np.broadcast_arrays(elbow_x, elbow_y), axis=-1) + o
    return end, elbow


def angle_grid(n: int = 10, low: float = 0.0, high: float = 180.0) -> np.ndarray:
    """A regular ``n x n`` grid in joint-angle space, at cell centres.

    The paper tests on "a set of target points on a regular grid in angle
    space". Cell centres (9, 27, ..., 171 degrees for n = 10) keep every target
    off the joint limits, so no test target coincides with the start pose
    (0, 180) or with the fully stretched arm. Returns shape ``(n*n, 2)`` of
    (shoulder, elbow) angles in degrees, shoulder-major.
    """
    step = (high - low) / n
    centres = low + step * (np.arange(n) + 0.5)
    alpha, beta = np.meshgrid(centres, centres, indexing="ij")
    return np.stack([alpha.ravel(), beta.ravel()], axis=-1)


@dataclasses.dataclass(frozen=True)
class Geometry:
    """What the agent knows of the arm's geometry: the plane, the shoulder and the joints' range.

    The task gives it (:meth:`from_spec`); ``joint_range`` None means unbounded joints
    (the task's ``joints.at_limit = "unbounded"``).
    """

    origin: tuple[float, float] = DEFAULT_ORIGIN
    #: (width, height) of the plane in cm; the plane spans [0, w] x [0, h].
    plane_size: tuple[float, float] = (30.0, 30.0)
    #: (low, high) of both joints in degrees; None: no limit.
    joint_range: tuple[float, float] | None = (0.0, 180.0)

    @classmethod
    def from_spec(cls, spec) -> "Geometry":
        """The geometry of a :class:`apac_mj.suite.task_spec.TaskSpec`."""
        return cls(origin=tuple(spec.origin), plane_size=tuple(spec.plane_size),
                   joint_range=tuple(spec.joint_range) if spec.at_limit == "clip" else None)

    def joint_angles(self, end: torch.Tensor, elbow: torch.Tensor) -> torch.Tensor:
        """(shoulder, elbow) angles in degrees ``[..., 2]`` from the end and elbow positions ``[..., 2]`` (cm),
        the inverse of Algorithm 1 (angles wrapped to [-90, 270))."""
        import torch

        o = torch.as_tensor(self.origin, dtype=end.dtype, device=end.device)
        rel, arm = elbow - o, end - elbow
        alpha = torch.rad2deg(torch.atan2(rel[..., 1], rel[..., 0]))
        total = torch.rad2deg(torch.atan2(arm[..., 1], arm[..., 0]))
        alpha = torch.remainder(alpha + 90.0, 360.0) - 90.0
        beta = torch.remainder(total - alpha + 90.0, 360.0) - 90.0
        return torch.stack([alpha, beta], -1)

    def feasible_changes(self, end: torch.Tensor, elbow: torch.Tensor,
                         bound: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The joint-angle changes ``(low, high)`` ``[..., 2]`` that stay inside the joint range
        from this pose, within ``±bound``; unbounded joints: ``(-bound, bound)``."""
        import torch

        if self.joint_range is None:
            lo = torch.full((*end.shape[:-1], 2), -bound, dtype=end.dtype, device=end.device)
            return lo, -lo
        angles = self.joint_angles(end, elbow)
        lo_j, hi_j = self.joint_range
        return (lo_j - angles).clamp(-bound, bound), (hi_j - angles).clamp(-bound, bound)
