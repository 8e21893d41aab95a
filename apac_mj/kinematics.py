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


#: The action spec's name of the paper's actions (``apac_mj.suite.planar_arm``): joint-angle changes in degrees.
ANGLE_ACTIONS = "joint_angle_change_deg"


@dataclasses.dataclass(frozen=True)
class Sizes:
    """The agent's sizes, read from the task's dm_env specs (:meth:`from_specs`): a task that observes joint
    velocities or commands torques needs no agent edit. The defaults are the paper's.

    The agent's state is ``[end (2), elbow (2), target (2), extra ...]``: every observed array but the vision
    flag, in the observation's order, the paper's 6 positions first.
    """

    #: Length of the agent's state: the paper's 6 positions plus the task's extra observations
    #: (e.g. joint velocities, deg/s).
    state_dim: int = 6
    #: Length of an action.
    action_dim: int = 2
    #: Bound of each action component (the action spec's): 180 degrees for joint-angle changes, or N·m.
    action_bound: float = 180.0
    #: The actions are joint-angle changes (degrees), which the joint range limits (:class:`Geometry`);
    #: False: other actions (torques), bounded only by ``action_bound``.
    angle_actions: bool = True
    #: The scale of each extra entry (the scale its observation spec carries, e.g. 500 deg/s for joint velocities): the
    #: networks read ``extra / extra_scale``, order 1 as the normalized positions. One per extra entry.
    extra_scale: tuple[float, ...] = ()
    #: Width of a cued task's cue (one-hot, the state's last entries; :attr:`cue`): the habit (actor and critic)
    #: reads the cue in place of the target's position, the internal models read neither. 0: no cue.
    cue_dim: int = 0

    def __post_init__(self) -> None:
        if not 0 <= self.cue_dim <= self.extra_dim:
            raise ValueError(f"Sizes: cue_dim must be in 0..{self.extra_dim} (the extra entries), got {self.cue_dim}")
        if len(self.extra_scale) != self.extra_dim:
            raise ValueError(f"Sizes: {self.extra_dim} extra state entries need as many scales, got "
                             f"extra_scale={self.extra_scale}")
        if not all(math.isfinite(v) and v > 0 for v in self.extra_scale):
            raise ValueError(f"Sizes: extra_scale must be positive finite numbers, got {self.extra_scale}")

    @property
    def extra_dim(self) -> int:
        """Observed entries beyond the paper's 6 positions."""
        return self.state_dim - 6

    @property
    def motion_dim(self) -> int:
        """Extra entries that describe the arm's motion (the joint velocities, where observed): the extra ones
        before the cue; what the forward, inverse and dynamics models read and predict beyond the positions."""
        return self.extra_dim - self.cue_dim

    @property
    def motion(self) -> slice:
        """Where the motion's extra entries lie in the state."""
        return slice(6, 6 + self.motion_dim)

    @property
    def cue(self) -> slice:
        """Where the cue lies in the state (empty: none)."""
        return slice(6 + self.motion_dim, self.state_dim)

    @classmethod
    def from_specs(cls, observation_spec, action_spec) -> "Sizes":
        """Sizes from a dm_env environment's ``observation_spec()`` (a dict of arrays whose first three are
        end_effector, elbow and target) and ``action_spec()`` (a bounded array, symmetric bounds)."""
        names = list(observation_spec)
        if names[:3] != ["end_effector", "elbow", "target"]:
            raise ValueError(f"the agent needs the observations end_effector, elbow, target first, got {names}")
        state_dim = sum(int(np.prod(s.shape)) for name, s in observation_spec.items() if name != "vision")
        scales: list[float] = []
        if "cue" in names and [n for n in names if n != "vision"][-1] != "cue":
            raise ValueError(f"the cue must be the last observation (the state's last entries), got {names}")
        cue_dim = int(np.prod(observation_spec["cue"].shape)) if "cue" in names else 0
        for name, s in list(observation_spec.items())[3:]:
            if name == "vision":
                continue
            scale = getattr(s, "scale", None)  # suite.planar_arm.ScaledArray
            if scale is None or not math.isfinite(scale) or scale <= 0:
                raise ValueError(f"the agent reads every observation beyond the positions by its scale: "
                                 f"{name!r} must be a spec with a positive scale (suite.planar_arm.ScaledArray), "
                                 f"got {s}")
            scales.extend([float(scale)] * int(np.prod(s.shape)))
        lo, hi = np.broadcast_to(action_spec.minimum, action_spec.shape), np.broadcast_to(action_spec.maximum,
                                                                                            action_spec.shape)
        if len(action_spec.shape) != 1 or not np.all(hi == -lo) or not np.all(hi == hi.flat[0]) or hi.flat[0] <= 0:
            raise ValueError(f"the agent needs a 1-D action with one symmetric bound, got shape "
                             f"{action_spec.shape}, bounds [{action_spec.minimum}, {action_spec.maximum}]")
        return cls(state_dim=state_dim, action_dim=int(action_spec.shape[0]), action_bound=float(hi.flat[0]),
                   angle_actions=action_spec.name == ANGLE_ACTIONS, extra_scale=tuple(scales), cue_dim=cue_dim)
