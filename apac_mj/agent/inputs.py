"""How the agent's networks read the state: the layout's views (:class:`apac_mj.layout.StateLayout`) in network
units.

With ``normalize_inputs`` every network reads the positions scaled to [-1, 1] over the plane (``plane_scale``),
each extra entry (the joint velocities) divided by its scale (``Sizes.extra_scale``, e.g. 500 deg/s) and the
actions divided by ``action_scale``; without it (the paper's networks) they read raw cm and degrees. The
internal models read the motion (:meth:`StateLayout.motion_parts`), the habit its own view (the cue in the place
of the target on a cued task).
"""
from __future__ import annotations

import torch

from apac_mj.config import AgentConfig
from apac_mj.layout import ARM, EXTRA, MOTION_EXTRA, POSITIONS, TARGET, StateLayout


class NetworkInputs:
    """The state's and the action's network units for one agent (its layout, ``cfg`` and plane)."""

    def __init__(self, layout: StateLayout, cfg: AgentConfig, plane_scale: float, device: torch.device) -> None:
        self.layout, self.plane_scale = layout, plane_scale
        self.normalize, self.action_scale = cfg.normalize_inputs, cfg.action_scale
        #: Scale of each extra state entry (its observation spec's ``scale``): networks read extra / scale.
        self.extra_scale = torch.tensor(layout.sizes.extra_scale, dtype=torch.float32, device=device)
        #: The scales of the motion's extra entries (the internal models' extra inputs and outputs).
        self.motion_scale = self.extra_scale[:layout.motion_dim]

    def pos(self, x: torch.Tensor) -> torch.Tensor:
        """Positions (cm) in network units."""
        if not self.normalize:
            return x
        half = self.plane_scale / 2
        return (x - half) / half

    def state(self, s: torch.Tensor) -> torch.Tensor:
        """A state ``[..., S]`` in network units: the positions as :meth:`pos`, each extra entry divided by its
        scale; on the paper's tasks (no extra) exactly :meth:`pos`."""
        if not self.layout.sizes.extra_dim or not self.normalize:
            return self.pos(s)
        return torch.cat([self.pos(s[..., POSITIONS]), s[..., EXTRA] / self.extra_scale], -1)

    def act(self, a: torch.Tensor) -> torch.Tensor:
        """Actions (degrees or N·m) in network units."""
        return a / self.action_scale if self.normalize else a

    def habit(self, x: torch.Tensor) -> torch.Tensor:
        """The habit's view of a network-unit state (:meth:`StateLayout.habit_view`)."""
        return self.layout.habit_view(x)

    def model_input(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """The forward and dynamics models' input: the motion of the network-unit state ``x`` and the raw action
        ``a``."""
        return torch.cat([*self.layout.motion_parts(x), self.act(a)], -1)

    def inverse_input(self, x: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The inverse model's input: the motion and the hand's goal ``[..., 2]`` (network units):
        ``[end, elbow, goal]`` on the paper's tasks."""
        return torch.cat([*self.layout.motion_parts(x), goal], -1)

    def plan_input(self, x: torch.Tensor) -> torch.Tensor:
        """The inverse model's input at action time: the target in the place of the next hand position."""
        return self.inverse_input(x, x[..., TARGET])

    def motion_x(self, x: torch.Tensor) -> torch.Tensor:
        """The motion ``[..., 4 + motion]`` of a network-unit state ``x``."""
        return torch.cat(self.layout.motion_parts(x), -1)

    def forward_extra(self, y: torch.Tensor) -> torch.Tensor:
        """The forward model's extra outputs ``y[..., MOTION_EXTRA]`` (sigmoid x plane_scale) as normalized
        extras, in ``[-2, 2]`` (the observed entries divided by their scale; the arm may exceed the scale)."""
        return 2.0 * (2.0 * y[..., MOTION_EXTRA] / self.plane_scale - 1.0)

    def from_forward(self, y: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The raw next state from the paper's forward model's output ``y`` (raw cm, the extras as
        :meth:`forward_extra`) and ``state``'s target and cue."""
        motion = self.forward_extra(y) * self.motion_scale if self.layout.motion_dim else None
        return self.layout.assemble(y[..., ARM], motion, state)

    def from_motion(self, m: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """The raw state ``[..., S]`` from a network-unit motion ``m`` and ``state``'s target and cue."""
        arm = m[..., ARM]
        if self.normalize:
            half = self.plane_scale / 2
            arm = arm * half + half
        motion = None
        if self.layout.motion_dim:
            motion = m[..., MOTION_EXTRA] * self.motion_scale if self.normalize else m[..., MOTION_EXTRA]
        return self.layout.assemble(arm, motion, state)
