"""The agent's state and its parts: the one description of the layout.

The state the agent acts and learns on is ``[E, 6 + extra]`` (cm): the paper's six positions, then the task's
extra observations (the joint velocities of a dynamic arm, then a cued task's cue). :data:`END`, :data:`TARGET`
and the other slices name the fixed parts; :class:`Sizes` (read from the task's dm_env specs) says how wide the
extra parts are; :class:`StateLayout` gives a task's parts by name and the views the networks read of a state
(the habit's: the cue in the place of the target). The networks' scaling of these views is the agent's
(:class:`apac_mj.agent.inputs.NetworkInputs`).

This module is torch-free at import (the plant, the command line and the report read it).
"""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

# -- the agent's state ---------------------------------------------------------------------------
# The state the agent acts and learns on (``StepInfo.state``, ``ArbitrationContext.state``, the replay
# memory) is ``[E, 6 + extra]`` (cm), laid out
#
#     [end_x, end_y, elbow_x, elbow_y, target_x, target_y, extra...]
#
# the positions (the integrator's estimate) followed by the task's extra observations, read as they are
# every step (``VecEnv.extra``: e.g. joint velocities on ``changing_target_torque``; none on the paper's
# tasks). Read it through these names, on the last axis (``state[:, TARGET]``, ``s[..., ARM]``), never by
# position. ``[end, elbow]`` arrays (``StepInfo.true_arm``, ``predicted_arm``) share the first four.
#: The end effector (hand).
END = slice(0, 2)
#: The elbow.
ELBOW = slice(2, 4)
#: The arm: ``[end, elbow]`` (what the forward model predicts).
ARM = slice(0, 4)
#: The target.
TARGET = slice(4, 6)
#: The positions: ``[end, elbow, target]`` (what the integrator estimates).
POSITIONS = slice(0, 6)
#: The task's extra observations (empty on the paper's tasks).
EXTRA = slice(6, None)
#: In an ``[end, elbow, extra...]`` array (the forward model's prediction where the task observes more than
#: the positions): the extra part.
MOTION_EXTRA = slice(4, None)
#: Width of the positions; the state is ``POSITION_DIM + extra`` wide.
POSITION_DIM = 6


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
        return self.state_dim - POSITION_DIM

    @property
    def motion_dim(self) -> int:
        """Extra entries that describe the arm's motion (the joint velocities, where observed): the extra ones
        before the cue; what the forward, inverse and dynamics models read and predict beyond the positions."""
        return self.extra_dim - self.cue_dim

    @property
    def motion(self) -> slice:
        """Where the motion's extra entries lie in the state."""
        return slice(POSITION_DIM, POSITION_DIM + self.motion_dim)

    @property
    def cue(self) -> slice:
        """Where the cue lies in the state (empty: none)."""
        return slice(POSITION_DIM + self.motion_dim, self.state_dim)

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


class StateLayout:
    """A task's state layout (its :class:`Sizes`): the parts by name, and the views the networks read.

    ``[end (2), elbow (2), target (2), motion (the joint velocities, where observed), cue (one-hot, a cued task)]``.
    """

    def __init__(self, sizes: Sizes | None = None) -> None:
        self.sizes = sizes or Sizes()
        #: The fixed parts (:data:`END`, ...), here too so that a layout names every part.
        self.end, self.elbow, self.arm, self.target, self.positions, self.extra = END, ELBOW, ARM, TARGET, POSITIONS, EXTRA
        #: The motion's extra entries (the joint velocities, where observed; empty: none).
        self.motion: slice = self.sizes.motion
        #: The cue (empty: not a cued task).
        self.cue: slice = self.sizes.cue
        self.motion_dim, self.cue_dim = self.sizes.motion_dim, self.sizes.cue_dim

    def habit_view(self, x: "torch.Tensor") -> "torch.Tensor":
        """What the habit (actor and critic) reads of a state ``x``: all of it, or on a cued task the target's
        position zeroed (the habit learns cue -> movement; the planner alone is told where the cued target is)."""
        if not self.cue_dim:
            return x
        import torch

        return torch.cat([x[..., :TARGET.start], torch.zeros_like(x[..., TARGET]), x[..., TARGET.stop:]], -1)

    def motion_parts(self, x: "torch.Tensor") -> list["torch.Tensor"]:
        """The arm's motion as the internal models read it: ``[arm]``, or ``[arm, motion]`` where the task
        observes more (the joint velocities: a Markov state under dynamics)."""
        return [x[..., ARM], x[..., self.motion]] if self.motion_dim else [x[..., ARM]]

    def assemble(self, arm: "torch.Tensor", motion: "torch.Tensor | None", state: "torch.Tensor") -> "torch.Tensor":
        """A state ``[..., S]`` from a new ``arm`` ``[..., 4]`` and ``motion`` entries (None where the task has none),
        with ``state``'s target and cue (the parts a movement does not change)."""
        import torch

        parts = [arm, state[..., TARGET]]
        if self.motion_dim:
            parts.append(motion)
        if self.cue_dim:
            parts.append(state[..., self.cue])
        return torch.cat(parts, -1)
