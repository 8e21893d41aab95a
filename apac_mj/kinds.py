"""The registry of agent kinds: the one place that says what ``ddpg``, ``spac`` and ``apac`` are.

An agent kind is a name (``AgentConfig.kind``) with what the rest of the
project needs to know about it: its label and colour in figures, the
arbitrator that decides between the actor and the inverse model (an
:class:`apac_mj.types.Arbitrator`) and the table of its parameters
(:mod:`apac_mj.rules`), which of the two controllers it uses, and whether it
can act in the dark (the occluded-vision test runs only for kinds that can).
Every module asks the registry; none tests a kind's name. A new kind is one
:func:`register` call from any code, inside the package or not
(docs/extending.md)::

    from apac_mj import kinds
    from apac_mj.agent.arbitration import DeltaArbitrator

    kinds.register(kinds.AgentKind("apac_strict", "APAC (strict)", "tab:purple",
                                   arbitrator=lambda cfg: DeltaArbitrator(cfg)))

Kinds registered at run time exist in the process that registered them: the
local executor with one worker and the library functions see them; process
pools and Ray workers only if the registering module is imported there too.
"""
from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Callable

from apac_mj import rules, systems
from apac_mj.rules import (MPCParams, ReliabilityParams, SpeedAccuracyParams, UncertaintyParams,
                           ValueOfComputationParams, VisionAwareParams)
from apac_mj.util.registry import Registry

if TYPE_CHECKING:
    from apac_mj.config import AgentConfig
    from apac_mj.types import Arbitrator


class UnknownKindError(ValueError, KeyError):
    """An agent kind that is not registered (a ValueError for config checks, a KeyError for look-ups)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


@dataclasses.dataclass(frozen=True)
class AgentKind:
    """One kind of agent and everything the project needs to know about it."""

    #: The name used in configs, presets, run directories and the command line.
    name: str
    #: How figures and tables call it.
    label: str
    #: Its colour in figures: kept where it is one of the colour-blind-safe palette's (``report.labels.SAFE_PALETTE``)
    #: and no earlier kind has it; otherwise the figures give the kind the palette's first free colour.
    color: str
    #: ``AgentConfig -> Arbitrator``: builds the rule that decides between habit and planning.
    arbitrator: Callable[[AgentConfig], Arbitrator]
    #: The actor (habit) can act.
    uses_habit: bool = True
    #: The inverse model (planning) can act.
    uses_planner: bool = True
    #: The kind can act without vision (it has a planner moving on the forward model's estimate), so the
    #: occluded-vision test applies to it.
    acts_occluded: bool = True
    #: Why the occluded test does not apply (when ``acts_occluded`` is False); shown in eval summaries.
    occluded_reason: str = ""
    #: The table of the rule's parameters (apac_mj.rules: a dataclass with a ``table`` name; registered with
    #: the kind, so ``agent.<table>.<field>`` reaches it); None: the rule reads only AgentConfig's fields.
    params: type | None = None
    #: The planning system, a registered planner (:mod:`apac_mj.systems`): "inverse" (the paper's inverse model,
    #: one query per step), "mpc" (model-predictive control through a learned dynamics model, its table
    #: ``agent.mpc``) or one registered by ``systems.register_planner``.
    planner: str = "inverse"

    def __post_init__(self) -> None:
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ValueError(f"agent kind name must be a non-empty identifier, got {self.name!r}")
        if not (self.uses_habit or self.uses_planner):
            raise ValueError(f"agent kind {self.name!r} must use the habit, the planner or both")
        if self.planner not in systems.PLANNERS:
            raise ValueError(f"agent kind {self.name!r}: planner must be a registered planner, one of "
                             f"{systems.PLANNERS.names()} (apac_mj.systems.register_planner adds one), "
                             f"got {self.planner!r}")
        if not callable(self.arbitrator):
            raise ValueError(f"agent kind {self.name!r}: arbitrator must be callable (AgentConfig -> Arbitrator)")

    @property
    def arbitrates(self) -> bool:
        """Both controllers can act, so the arbitration (habit share) is worth showing."""
        return self.uses_habit and self.uses_planner


_KINDS: Registry[AgentKind] = Registry(
    "agent kind", error=UnknownKindError,
    unknown="unknown agent kind {name!r}; registered kinds: {names} (apac_mj.kinds.register adds one)")


def register(kind: AgentKind, replace: bool = False) -> AgentKind:
    """Add ``kind`` (and its parameter table) to the registry (after the kinds already there); a taken name
    needs ``replace=True``."""
    return systems.add(_KINDS, kind, replace)


def unregister(name: str) -> None:
    """Remove a kind registered at run time (tests, notebooks); the built-in ones stay."""
    if name in BUILTIN:
        raise ValueError(f"the built-in agent kind {name!r} cannot be removed")
    _KINDS.unregister(name)


def get(name: str) -> AgentKind:
    """The registered kind ``name``; an unknown name is an error listing the known ones."""
    return _KINDS.get(name)


def names() -> tuple[str, ...]:
    """Every registered kind's name, in registration order (the built-in ones first)."""
    return _KINDS.names()


def check(cfg: AgentConfig) -> None:
    """Refuse an AgentConfig naming an unregistered kind (an error listing the registered ones), a vision-aware
    base that is not a kind, an unregistered integrator (:mod:`apac_mj.systems`), or habit formation for a kind
    that does not arbitrate."""
    kind = get(cfg.kind)
    get(cfg.params[VisionAwareParams.table].base)
    if cfg.integrator not in systems.INTEGRATORS:
        raise ValueError(f"integrator must be one of {systems.integrator_names()}, got {cfg.integrator!r} "
                         "(apac_mj.systems.register_integrator adds one)")
    if cfg.habit_distillation_weight > 0 and not kind.arbitrates:
        raise ValueError(f"habit_distillation_weight = {cfg.habit_distillation_weight} needs a kind that arbitrates "
                         f"(it pulls the habit towards the planner); {kind.name!r} uses only the "
                         f"{'habit' if kind.uses_habit else 'planner'}: set it to 0")


def arbitrator_for(cfg: AgentConfig, state: dict | None = None) -> Arbitrator:
    """The arbitrator of ``cfg.kind``, built from ``cfg``, with the running statistics ``state`` (a checkpoint's
    ``"arbitrator"`` entry) loaded where given; a factory that builds no :class:`apac_mj.types.Arbitrator`
    is an error naming the kind."""
    from apac_mj.types import Arbitrator

    arbitrator = get(cfg.kind).arbitrator(cfg)
    if not isinstance(arbitrator, Arbitrator):
        raise TypeError(f"agent kind {cfg.kind!r} built a {type(arbitrator).__name__}, not an "
                        "apac_mj.types.Arbitrator (subclass it: use_habit returns a Decision)")
    arbitrator.load_state_dict(state or {})
    return arbitrator


def _builtin(name: str, beyond: bool = False) -> Callable[[AgentConfig], Arbitrator]:
    """A factory of the rule ``name`` of ``apac_mj.agent.arbitration`` (the paper's) or, ``beyond`` the paper,
    ``apac_mj.agent.arbitrators``; imported when first used (this module stays torch-free)."""

    def make(cfg: AgentConfig) -> Arbitrator:
        from apac_mj.agent import arbitration, arbitrators

        return getattr(arbitrators if beyond else arbitration, name)(cfg)

    make.__qualname__ = make.__name__ = name
    return make


register(AgentKind("ddpg", "DDPG", "#E69F00", _builtin("AlwaysHabit"), uses_planner=False,
                   acts_occluded=False, occluded_reason="DDPG has no forward model to move on"))
register(AgentKind("spac", "SPAC", "#009E73", _builtin("AlwaysPlan"), uses_habit=False))
register(AgentKind("apac", "APAC", "#0072B2", _builtin("DeltaArbitrator")))
# Beyond the paper (docs/arbitrators.md): APAC's two systems under other arbitration rules.
register(AgentKind("apac_uncertainty", "APAC-U (uncertainty)", "#CC79A7",
                   _builtin("UncertaintyArbitrator", beyond=True), params=UncertaintyParams))
register(AgentKind("apac_reliability", "APAC-R (reliability)", "#D55E00",
                   _builtin("ReliabilityArbitrator", beyond=True), params=ReliabilityParams))
register(AgentKind("apac_speed_accuracy", "APAC-SA (speed-accuracy)", "#56B4E9",
                   _builtin("SpeedAccuracyArbitrator", beyond=True), params=SpeedAccuracyParams))


def _vision_aware(cfg: AgentConfig) -> Arbitrator:
    """The vision-aware rule over its base kind's rule (built with the default base, so that naming a
    vision-aware kind as the base is refused instead of recursing)."""
    from apac_mj.agent.arbitrators import VisionAwareArbitrator

    params = cfg.params[VisionAwareParams.table]
    base_cfg = dataclasses.replace(cfg, params={**cfg.params, params.table: dataclasses.replace(params, base=DEFAULT)})
    return VisionAwareArbitrator(cfg, base=get(params.base).arbitrator(base_cfg))


register(AgentKind("apac_vision", "APAC-V (vision-aware)", "#332288", _vision_aware, params=VisionAwareParams))
# Beyond the paper (docs/agent.md "Planning through the model"): MPC through the learned forward model as the
# planning system, always (SPAC-MPC), under the paper's delta rule (APAC-MPC), and under a graded arbitrator that
# weighs the expected gain of each planning iteration against its cost (value of computation).
register(AgentKind("spac_mpc", "SPAC-MPC", "#999933", _builtin("AlwaysPlan"), uses_habit=False, params=MPCParams,
                   planner="mpc"))
register(AgentKind("apac_mpc", "APAC-MPC", "#882255", _builtin("DeltaArbitrator"), params=MPCParams, planner="mpc"))
register(AgentKind("apac_voc", "APAC-VOC (graded)", "#44AA99",
                   _builtin("ValueOfComputationArbitrator", beyond=True), params=ValueOfComputationParams,
                   planner="mpc"))
#: The kinds registered here (the built-in ones: they cannot be removed).
BUILTIN = names()
#: The paper's kinds (the default agents of a preset).
PAPER_KINDS = BUILTIN[:3]
#: The default kind.
DEFAULT = rules.DEFAULT_KIND
